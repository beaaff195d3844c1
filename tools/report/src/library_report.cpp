#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <ctime>
#include <exception>
#include <filesystem>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <map>
#include <mutex>
#include <new>
#include <optional>
#include <sstream>
#include <system_error>
#include <thread>

#include "asset_views.h"
#include "report.h"
#include "report_resources.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/json_path.h"
#include "voxfmt/detail/report.h"
#include "voxfmt/version.h"

namespace voxfmt::report {

namespace fs = std::filesystem;

namespace {

constexpr int kViewSize = 128;          // pixels of each of the three views
constexpr int kSliceSize = 160;         // pixels of the slice's longer side
constexpr size_t kScenePoints = 12000;  // point-shell points of the 3D view (whole levels)
constexpr uint32_t kSceneGrid = 40;     // cells of the 3D view's distance grid on its longest side
constexpr size_t kMaxFindings = 50;     // validation findings listed per asset
constexpr const char* kReportKeys[] = {"id",          "name",       "output_name",  "detail", "views",      "slice",
                                       "asset_error", "validation", "memory_bytes", "has_3d", "asset_bytes"};

std::string utc_now() {
  const std::time_t now = std::time(nullptr);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&now));
  return text;
}

// Compact JSON for a script; invalid UTF-8 in hostile strings is replaced, never thrown.
std::string dump(const nlohmann::json& value) {
  return value.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

// The manifest's records, the latest one per output, in output order; lines that are not JSON objects with an
// "output" are counted, not fatal (a hand-edited or torn manifest still gets its report).
struct ManifestRecords {
  std::vector<nlohmann::json> records;
  size_t skipped_lines = 0;
};

// A shard's manifest as `batch --shard I/N` names it: manifest.shard-I-of-N.jsonl, I and N decimal.
bool shard_manifest_name(const std::string& name) {
  const std::string prefix = "manifest.shard-", middle = "-of-", suffix = ".jsonl";
  if (name.size() <= prefix.size() + suffix.size() || name.rfind(prefix, 0) != 0 ||
      name.compare(name.size() - suffix.size(), suffix.size(), suffix) != 0)
    return false;
  const std::string numbers = name.substr(prefix.size(), name.size() - prefix.size() - suffix.size());
  const size_t of = numbers.find(middle);
  const auto decimal = [](const std::string& s) {
    return !s.empty() && s.find_first_not_of("0123456789") == std::string::npos;
  };
  return of != std::string::npos && decimal(numbers.substr(0, of)) && decimal(numbers.substr(of + middle.size()));
}

// The manifest files of a library: manifest.jsonl and the shards' manifest.shard-I-of-N.jsonl. Only those: a
// manifest-backup.jsonl or manifest.old.jsonl beside them would bring back meshes the library no longer has.
std::vector<fs::path> manifest_files(const std::string& library) {
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(library, ec)) {
    const std::string name = entry.path().filename().string();
    if ((name == "manifest.jsonl" || shard_manifest_name(name)) && entry.is_regular_file(ec))
      files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

// Lines nested deeper than this are not records: copying or printing a JSON value recurses once per level, and
// a browser's parser too.
constexpr int kMaxNesting = 64;

bool nested_too_deep(const std::string& line) {
  int depth = 0;
  bool in_string = false, escaped = false;
  for (const char c : line) {
    if (in_string) {
      if (escaped)
        escaped = false;
      else if (c == '\\')
        escaped = true;
      else if (c == '"')
        in_string = false;
      continue;
    }
    if (c == '"') in_string = true;
    if (c == '[' || c == '{') {
      if (++depth > kMaxNesting) return true;
    } else if (c == ']' || c == '}') {
      --depth;
    }
  }
  return false;
}

// A manifest is JSON a person may edit: a field of the wrong type (a number as the status, a string as a time, a
// warning that is no object) is dropped, so the page shows what it can read and counts nothing by mistake.
void drop_mistyped_fields(nlohmann::json& row) {
  const auto number = [](const nlohmann::json& v) { return v.is_number(); };
  const auto text = [](const nlohmann::json& v) { return v.is_string(); };
  const auto object = [](const nlohmann::json& v) { return v.is_object(); };
  const auto coded = [](const nlohmann::json& v) {
    return v.is_object() && v.contains("code") && v["code"].is_string() &&
           (!v.contains("message") || v["message"].is_string());
  };
  const std::vector<std::pair<const char*, std::function<bool(const nlohmann::json&)>>> rules = {
      {"input", text},
      {"output", text},
      {"status",
       [](const nlohmann::json& v) { return v == "ok" || v == "up_to_date" || v == "failed" || v == "removed"; }},
      {"error", [&](const nlohmann::json& v) { return v.is_null() || coded(v); }},
      {"timings_s", [&](const nlohmann::json& v) { return v.is_object() && std::all_of(v.begin(), v.end(), number); }},
      {"warnings", [&](const nlohmann::json& v) { return v.is_array() && std::all_of(v.begin(), v.end(), coded); }},
      {"build_parameters", [](const nlohmann::json& v) { return v.is_object() || v.is_string(); }},
      {"voxelmap", object},
      {"pointshell", object},
      {"total_s", number},
      {"wall_s", number},
      {"input_bytes", number},
      {"file_size_bytes", number},
      {"peak_memory_bytes", number},
      {"input_vertices", number},
      {"input_triangles", number},
      {"volume", number},
      {"tool_version", text},
      {"finished_utc", text},
      {"source_sha256", text}};
  for (const auto& [key, valid] : rules) {
    const auto it = row.find(key);
    if (it != row.end() && !valid(*it)) row.erase(it);
  }
}

std::string text_of(const nlohmann::json& record, const char* key) {
  const auto it = record.find(key);
  return it != record.end() && it->is_string() ? it->get<std::string>() : std::string();
}

// A folder of assets no batch wrote (`voxfmt build` one by one, copied from elsewhere): a record per *.vox.h5 below
// it, by path, as if each were built. Directory links are not followed (a link to a parent would never end).
std::vector<nlohmann::json> assets_below(const std::string& folder) {
  std::vector<std::string> found;
  std::error_code ec;
  const std::string suffix = ".vox.h5";
  for (auto it = fs::recursive_directory_iterator(folder, fs::directory_options::skip_permission_denied, ec);
       !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.size() > suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0 &&
        it->is_regular_file(ec))
      found.push_back(it->path().lexically_relative(folder).generic_string());
  }
  std::sort(found.begin(), found.end());
  std::vector<nlohmann::json> records;
  for (const std::string& relative : found) {
    nlohmann::json record = {{"status", "ok"}, {"unread", true}};  // "ok" by no bake's word: read as described
    set_path(record, "output", relative);
    if (const uintmax_t size = fs::file_size(fs::path(folder) / relative, ec); !ec) record["file_size_bytes"] = size;
    records.push_back(std::move(record));
  }
  return records;
}

Result<ManifestRecords> read_manifest(const std::string& library, const std::string& manifest_file) {
  std::vector<fs::path> files;
  if (!manifest_file.empty()) {
    std::error_code ec;
    if (fs::is_regular_file(manifest_file, ec)) files.push_back(manifest_file);
  } else {
    files = manifest_files(library);
  }
  std::error_code folder_ec;
  if (files.empty() && manifest_file.empty() && fs::is_directory(library, folder_ec)) {
    ManifestRecords m{assets_below(library), 0};
    if (!m.records.empty()) return m;
  }
  if (files.empty()) {
    std::error_code ec;
    const std::string where =
        !manifest_file.empty()
            ? manifest_file + (fs::is_directory(manifest_file, ec) ? ": a folder, not a manifest" : ": no such file")
        : !fs::exists(library, ec) ? library + ": no such folder"
        : !fs::is_directory(library, ec)
            ? library + ": a file, not a library folder (one asset's page: `voxfmt inspect ASSET --html OUT`)"
            : library + ": no manifest.jsonl and no *.vox.h5 asset here";
    return Error(IssueCode::FileNotFound,
                 where + " (a library is the output folder of `voxfmt batch`, or any folder of assets)",
                 manifest_file.empty() ? library : manifest_file);
  }
  ManifestRecords m;
  std::map<std::string, nlohmann::json> last;
  std::map<std::string, std::string> folders;  // manifest_output_key's, resolved once each
  for (const fs::path& file : files) {
    std::error_code ec;
    const fs::path real = fs::weakly_canonical(file, ec);  // the file a batch stamped its records from
    const std::string manifest_path = ec ? file.string() : real.string();
    std::ifstream in(file);
    std::string line;
    bool too_long = false;
    while (read_manifest_line(in, line, too_long)) {
      m.skipped_lines += too_long;
      if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
      nlohmann::json record = nested_too_deep(line) ? nlohmann::json() : nlohmann::json::parse(line, nullptr, false);
      if (!record.is_object() || !record.contains("output") || !record["output"].is_string()) {
        ++m.skipped_lines;
        continue;
      }
      drop_mistyped_fields(record);
      locate_output(record, manifest_path);
      // Across files (the shards' and the whole library's), the record that finished last wins.
      auto [it, inserted] = last.try_emplace(manifest_output_key(path_of(record, "output"), &folders));
      const auto finished = [](const nlohmann::json& r) {
        const auto f = r.find("finished_utc");
        return f != r.end() && f->is_string() ? f->get<std::string>() : std::string();
      };
      if (inserted || finished(record) >= finished(it->second)) it->second = std::move(record);
    }
  }
  for (auto& [output, record] : last)  // an asset `batch --prune` removed is no longer in the library
    if (text_of(record, "status") != "removed") m.records.push_back(std::move(record));
  return m;
}

// A mesh's name in the report: its input file's name ("bunny00.off"), else the output's without ".vox.h5".
std::string mesh_name(const nlohmann::json& record) {
  std::string input = text_of(record, "input");
  if (!input.empty()) return fs::path(input).filename().string();
  std::string name = fs::path(text_of(record, "output")).filename().string();
  const std::string suffix = ".vox.h5";
  if (name.size() > suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0)
    name.resize(name.size() - suffix.size());
  return name;
}

// The asset's path below the library: the longest tail of the manifest's output that names a file in the
// library (batch records OUTDIR as it was typed, relative to where it ran; a library moved or copied keeps its
// layout), else where the record places it below the library (a failed mesh's asset never existed: its
// subfolder still tells it from a mesh of the same name in another), else the output's file name. What the
// report shows, and what two bakes are compared by.
std::string library_relative(const std::string& library, const nlohmann::json& record) {
  const std::string output = path_of(record, "output");
  std::vector<fs::path> parts;
  for (const fs::path& part : fs::path(output).relative_path()) parts.push_back(part);
  std::error_code ec;
  // Tails of at most kMaxTailParts parts, after the last "..": a tail never leaves the library, and a hostile
  // record of 500,000 parts costs 64 lookups, not a quadratic number of them.
  constexpr size_t kMaxTailParts = 64;
  size_t start = parts.size() > kMaxTailParts ? parts.size() - kMaxTailParts : 0;
  for (size_t k = 0; k < parts.size(); ++k)
    if (parts[k] == "..") start = std::max(start, k + 1);
  for (size_t first = start; first < parts.size(); ++first) {
    fs::path tail;
    for (size_t k = first; k < parts.size(); ++k) tail /= parts[k];
    if (fs::is_regular_file(fs::path(library) / tail, ec)) return tail.generic_string();
  }
  // A record with output_from_manifest was located from its manifest (locate_output); an older one's absolute
  // output means the same file from anywhere. A relative output of an older record is from the batch's working
  // directory, unknown here: only its file name is trusted.
  if (!path_of(record, "output_from_manifest").empty() || fs::path(output).is_absolute()) {
    const fs::path below = fs::path(manifest_output_key(output)).lexically_relative(resolved_folder(library));
    if (!below.empty() && *below.begin() != ".." && *below.begin() != "." && below.is_relative())
      return below.generic_string();
  }
  return fs::path(output).filename().string();
}

// The asset's file: in the library when it is there, else the manifest's output as recorded where that lies in
// the library too (a record naming a file elsewhere is not the library's: its card says it is missing).
std::string asset_path(const std::string& library, const std::string& relative, const std::string& output) {
  std::error_code ec;
  const fs::path in_library = fs::path(library) / relative;
  if (fs::is_regular_file(in_library, ec) || output.empty() || !fs::exists(output, ec)) return in_library.string();
  const fs::path root = fs::weakly_canonical(library, ec), recorded = fs::weakly_canonical(output, ec);
  if (ec) return in_library.string();
  const fs::path below = recorded.lexically_relative(root);
  if (below.empty() || *below.begin() == "..") return in_library.string();
  return output;
}

nlohmann::json error_json(const Error& e) { return {{"code", code_name(e.code)}, {"message", e.message}}; }

nlohmann::json issues_json(const std::vector<Issue>& issues) {
  nlohmann::json list = nlohmann::json::array();
  for (const Issue& i : issues) {
    if (list.size() >= kMaxFindings) break;
    list.push_back({{"code", code_name(i.code)},
                    {"severity", severity_name(i.severity)},
                    {"path", i.path},
                    {"message", i.message}});
  }
  return list;
}

// Plain writes, not write_file_atomically: every file goes into the temporary folder, and the folder is what
// is swapped in whole (a flush and rename per file would only add hundreds of syncs).
Status write_text(const fs::path& path, const std::string& text) {
  errno = 0;
  std::ofstream out(path, std::ios::binary);
  out.write(text.data(), std::streamsize(text.size()));
  out.close();
  if (!out) {
    // The system's reason where the stream left one: a full disk or `ulimit -f` says what to do about it.
    const int reason = errno;
    return Error(IssueCode::WriteFailed,
                 path.string() + ": cannot write" +
                     (reason ? ": " + std::error_code(reason, std::generic_category()).message() : std::string()),
                 path.string());
  }
  return Status::success();
}

// A script that hands `value` to the page: as a JSON string for JSON.parse, so that every key is data (in a
// JavaScript object literal, "__proto__" would set the object's prototype instead).
std::string script_value(const nlohmann::json& value) {
  return "JSON.parse(" + dump(nlohmann::json(dump(value))) + ")";
}

// An asset file as read, with the warnings of its read.
struct ReadAsset {
  Result<Asset> asset;
  std::vector<Issue> warnings;
};

ReadAsset read_for_report(const std::string& path, const ReadOptions& read) {
  std::vector<Issue> warnings;
  Result<Asset> asset = read_asset(path, &warnings, read);
  return {std::move(asset), std::move(warnings)};
}

// Everything the report shows of one asset file: `row` gets the small facts (for the table and the card);
// assets/ID.js the large ones (loaded when the card opens), whose path goes into row["detail"].
Status describe_asset(const std::string& path, const ReadAsset& read_result, const fs::path& dir, size_t id,
                      const ReadOptions& read, bool pictures, nlohmann::json& row) {
  const Result<Asset>& asset = read_result.asset;
  const std::vector<Issue>& warnings = read_result.warnings;
  if (!asset) {
    row["asset_error"] = error_json(asset.error());
    // The file's size now (none when it is gone): the manifest's figures are the bake's, not this file's.
    std::error_code ec;
    if (fs::is_regular_file(path, ec))
      if (const uintmax_t size = fs::file_size(path, ec); !ec) row["asset_bytes"] = size;
    const std::vector<Issue> findings = validate_file(path, read);
    row["validation"] = {{"valid", false}, {"findings", issues_json(findings)}, {"count", findings.size()}};
    return Status::success();
  }
  const AssetSummary summary = summarize_asset(path, asset.value());
  nlohmann::json inspect = nlohmann::json::parse(inspect_json(path, asset.value(), summary, warnings), nullptr, false);
  row["validation"] = {{"valid", true}, {"findings", issues_json(warnings)}, {"count", warnings.size()}};
  row["memory_bytes"] = summary.memory_bytes;
  // An asset alone has no manifest record: the card's grid, points and volume come from the file itself.
  for (const char* key : {"voxelmap", "pointshell"})
    if (!row.contains(key) && inspect.contains(key)) row[key] = inspect[key];
  const nlohmann::json mass =
      inspect.is_object() ? inspect.value("mass_properties", nlohmann::json()) : nlohmann::json();
  if (!row.contains("volume") && mass.is_object() && mass.contains("volume")) row["volume"] = mass["volume"];
  // And its bake's warnings and settings from its provenance, as plain `inspect` prints them.
  const nlohmann::json provenance =
      inspect.is_object() ? inspect.value("provenance", nlohmann::json()) : nlohmann::json();
  if (provenance.is_object()) {
    const auto warnings_it = provenance.find("build_warnings");
    if (!row.contains("warnings") && warnings_it != provenance.end() && warnings_it->is_array())
      row["warnings"] = *warnings_it;
    const auto parameters_it = provenance.find("build_parameters");
    if (!row.contains("build_parameters") && parameters_it != provenance.end())
      row["build_parameters"] = *parameters_it;
  }
  nlohmann::json detail = {{"inspect", inspect}};
  const std::string name = std::to_string(id);
  if (pictures) {
    const std::string views = "img/" + name + "-views.png", slice = "img/" + name + "-slice.png";
    if (write_views_png(asset.value(), kViewSize, (dir / views).string())) row["views"] = views;
    if (write_mid_slice_png(asset.value(), kSliceSize, (dir / slice).string())) row["slice"] = slice;
    detail["scene"] = scene_data(asset.value(), kScenePoints, kSceneGrid);
    row["has_3d"] = true;  // the card offers the 3D view only then (--no-pictures writes no scene)
  }
  const std::string script = "assets/" + name + ".js";
  if (Status s = write_text(dir / script, "voxfmtReport.addAsset(" + name + ", " + script_value(detail) + ");\n"); !s)
    return s;
  row["detail"] = script;
  return Status::success();
}

// Runs f(i) for i in [0, n) on `threads` threads.
template <class F>
void parallel_for(size_t n, int threads, F&& f) {
  const size_t workers =
      std::min<size_t>(n, size_t(threads > 0 ? threads : std::max(1u, std::thread::hardware_concurrency())));
  std::atomic<size_t> next{0};
  std::vector<std::thread> pool;
  for (size_t w = 0; w < workers; ++w)
    pool.emplace_back([&] {
      for (size_t i; (i = next++) < n;) f(i);
    });
  for (std::thread& t : pool) t.join();
}

// What a report folder holds: replacing a folder with anything else in it could delete someone's files. Its
// subfolders hold files named by an asset's number only ("12-views.png", "12.js"), so a folder of the same name
// holding a user's files is not one.
bool numbered_file(const std::string& name, std::initializer_list<const char*> suffixes) {
  for (const char* suffix : suffixes) {
    const size_t length = std::strlen(suffix);
    if (name.size() <= length || name.compare(name.size() - length, length, suffix) != 0) continue;
    const std::string number = name.substr(0, name.size() - length);
    if (number.find_first_not_of("0123456789") == std::string::npos) return true;
  }
  return false;
}

bool report_subfolder(const fs::path& folder, std::initializer_list<const char*> suffixes) {
  std::error_code ec;
  if (fs::is_symlink(folder, ec)) return false;
  for (const auto& entry : fs::directory_iterator(folder, ec))
    if (entry.is_symlink(ec) || !entry.is_regular_file(ec) ||
        !numbered_file(entry.path().filename().string(), suffixes))
      return false;
  return !ec;
}

bool report_entry(const fs::directory_entry& entry) {
  std::error_code ec;
  const std::string name = entry.path().filename().string();
  if (entry.is_directory(ec)) {
    if (name == "img") return report_subfolder(entry.path(), {"-views.png", "-slice.png"});
    if (name == "assets") return report_subfolder(entry.path(), {".js"});
    return false;
  }
  if (entry.is_symlink(ec) || !entry.is_regular_file(ec)) return false;
  if (name == "data.js") return true;
  for (size_t r = 0; r < kResourceCount; ++r)
    if (name == kResources[r].name) return true;
  return false;
}

// The first line every report's data.js starts with: what tells a previous report from a folder of someone's that
// happens to hold an index.html or a data.js of its own.
constexpr const char* kDataPrefix = "window.VOXFMT_REPORT = ";

bool report_data_file(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  std::string start(std::strlen(kDataPrefix), '\0');
  in.read(start.data(), std::streamsize(start.size()));
  return in && start == kDataPrefix;
}

// A folder that holds nothing, or a previous report and only what `voxfmt report` writes: safe to replace. Names
// alone are not enough (a site's index.html, someone's data.js): a report's data.js must say it is one.
bool replaceable(const fs::path& out) {
  std::error_code ec;
  if (!fs::exists(out, ec)) return true;
  if (!fs::is_directory(out, ec) || fs::is_symlink(out, ec)) return false;
  bool empty = true;
  for (const auto& entry : fs::directory_iterator(out, ec)) {
    if (!report_entry(entry)) return false;
    empty = false;
  }
  return !ec && (empty || report_data_file(out / "data.js"));
}

// Leftovers of killed runs beside `out` (STEM.partial-PID, STEM.old-PID whose process is gone; temporary_stem).
void remove_stale_leftovers(const fs::path& out) {
  std::error_code ec;
  const std::string name = temporary_stem(out.filename().string());
  for (const auto& entry : fs::directory_iterator(out.parent_path(), ec)) {
    const std::string other = entry.path().filename().string();
    for (const std::string& marker : {name + std::string(kPartialMarker), name + ".old-"}) {
      if (other.rfind(marker, 0) != 0) continue;
      if (process_is_gone(other.substr(marker.size()))) fs::remove_all(entry.path(), ec);
    }
  }
}

// The temporary folder is removed on every failure, an unexpected exception included.
Status fill_or_error(const std::function<Status(const fs::path&)>& fill, const fs::path& temporary) {
  try {
    return fill(temporary);
  } catch (const std::bad_alloc&) {
    return Error(IssueCode::OutOfMemory, temporary.string() + ": out of memory while writing the report");
  } catch (const std::exception& e) {
    return Error(IssueCode::Internal, temporary.string() + ": unexpected error while writing the report: " + e.what());
  }
}

// Builds the report in a temporary folder beside OUT, then swaps it in (OUT moved aside, the new one renamed to
// OUT, the old one removed): a killed run leaves either report whole under OUT's name, never half of one.
// OUT as the report's folder: absolute, and "report/" is "report".
fs::path report_folder(const fs::path& given) {
  std::error_code ec;
  fs::path out = fs::absolute(given, ec).lexically_normal();
  return out.filename().empty() ? out.parent_path() : out;
}

}  // namespace

Status check_report_folder(const std::string& given) {
  const fs::path out = report_folder(given);
  if (out == out.root_path())
    return Error(IssueCode::BadOption, out.string() + ": a report needs a folder of its own", out.string());
  std::error_code ec;
  if (fs::exists(out, ec) && !fs::is_directory(out, ec))
    return Error(IssueCode::BadOption,
                 out.string() + " is a file, not a folder: a report is a folder (choose another path)", out.string());
  if (!replaceable(out))
    return Error(IssueCode::BadOption,
                 out.string() + " exists and holds files a report does not write: not replaced (choose another folder)",
                 out.string());
  return Status::success();
}

namespace {

Result<ReportInfo> write_report_folder(fs::path out, const std::function<Status(const fs::path&)>& fill) {
  std::error_code ec;
  if (Status usable = check_report_folder(out.string()); !usable) return usable.error();
  out = report_folder(out);
  const fs::path parent = out.parent_path();
  fs::create_directories(parent, ec);
  remove_stale_leftovers(out);
  const std::string pid = std::to_string(::getpid());
  const std::string stem = temporary_stem(out.filename().string());
  const fs::path temporary = parent / (stem + std::string(kPartialMarker) + pid);
  const fs::path old = parent / (stem + ".old-" + pid);
  fs::remove_all(temporary, ec);
  if (!fs::create_directories(temporary / "img", ec) || !fs::create_directories(temporary / "assets", ec))
    return Error(IssueCode::WriteFailed, temporary.string() + ": cannot create the folder (" + ec.message() + ")",
                 temporary.string());
  Status filled = fill_or_error(fill, temporary);
  for (size_t r = 0; filled && r < kResourceCount; ++r)
    filled = write_text(temporary / kResources[r].name, std::string(kResources[r].data, kResources[r].size));
  if (!filled) {
    fs::remove_all(temporary, ec);
    return filled.error();
  }
  ReportInfo info;
  for (const auto& entry : fs::recursive_directory_iterator(temporary, ec))
    if (entry.is_regular_file(ec)) info.bytes += entry.file_size(ec);
  const bool had_one = fs::exists(out, ec);
  if (had_one) fs::rename(out, old, ec);
  if (!ec) fs::rename(temporary, out, ec);
  if (ec) {
    const std::string reason = ec.message();
    if (had_one && !fs::exists(out)) fs::rename(old, out, ec);
    fs::remove_all(temporary, ec);
    return Error(IssueCode::WriteFailed, out.string() + ": cannot move the report into place (" + reason + ")",
                 out.string());
  }
  if (had_one) fs::remove_all(old, ec);
  info.index_html = (out / "index.html").string();
  return info;
}

// The fields the comparison needs of each record of the other library. Its assets are not read (that would double
// the report's time), but one the manifest calls built and that is gone is said to be: a mesh whose asset vanished
// there and is back here changed state.
nlohmann::json compact_rows(const std::string& library, const std::vector<nlohmann::json>& records) {
  nlohmann::json rows = nlohmann::json::array();
  for (const nlohmann::json& r : records) {
    const std::string relative = library_relative(library, r), status = text_of(r, "status");
    nlohmann::json row = {{"name", mesh_name(r)}, {"output", utf8_escaped(relative)}, {"status", status}};
    for (const char* key : {"file_size_bytes", "total_s", "error", "warnings", "voxelmap", "tool_version", "unread"})
      if (r.contains(key)) row[key] = r[key];
    std::error_code ec;
    if ((status == "ok" || status == "up_to_date") &&
        !fs::is_regular_file(asset_path(library, relative, path_of(r, "output")), ec))
      row["asset_error"] = {{"code", "FILE_NOT_FOUND"}, {"message", utf8_escaped(relative) + ": not in the library"}};
    rows.push_back(std::move(row));
  }
  return rows;
}

nlohmann::json report_data(const char* kind, const std::string& library, const LibraryReportOptions& options,
                           size_t skipped_lines, nlohmann::json rows, nlohmann::json against) {
  return {{"kind", kind},
          {"library", fs::absolute(library).lexically_normal().string()},
          {"generated_utc", utc_now()},
          {"tool_version", VOXFMT_VERSION_STRING},
          {"skipped_lines", skipped_lines},
          {"thresholds", {{"size", options.size_threshold}, {"time", options.time_threshold}}},
          {"rows", std::move(rows)},
          {"against", std::move(against)}};
}

// One manifest record as the page's row: the report's own keys set (a manifest's never reach the page, which loads
// "detail" as a script and "views" and "slice" as pictures), and a built asset described into `dir`. A file
// system error on a hostile path becomes the row's asset_error; a write error is returned.
Status library_row(const LibraryReportOptions& options, nlohmann::json record, size_t i, const fs::path& dir,
                   nlohmann::json& row) {
  const std::string output = path_of(record, "output");
  const std::string relative = library_relative(options.library, record);
  row = std::move(record);
  row.erase("command");  // the bake's argv: long, and the build parameters say the same
  row.erase("output_mtime_ns");
  row.erase("input_hex");  // the exact bytes of a path that is not UTF-8: "input" and "output" show it escaped
  row.erase("output_hex");
  row.erase("output_from_manifest");  // where the asset is from the manifest: "output" was located by it
  row.erase("output_from_manifest_hex");
  row.erase("unread");  // a folder's asset is read here: its row says what the read found
  for (const char* key : kReportKeys) row.erase(key);
  row["id"] = i;
  row["name"] = mesh_name(row);
  row["output_name"] = utf8_escaped(relative);  // as --against's rows name it: text either way
  const std::string status = text_of(row, "status");
  if (status != "ok" && status != "up_to_date") return Status::success();
  try {
    const std::string path = asset_path(options.library, relative, output);
    return describe_asset(path, read_for_report(path, options.read), dir, i, options.read, options.pictures, row);
  } catch (const std::exception& e) {
    row["asset_error"] = {{"code", "INTERNAL"}, {"message", std::string("cannot describe the asset: ") + e.what()}};
    return Status::success();
  }
}

// The rows of every record, described in parallel, in the manifest's order; the first write error if any.
Result<std::vector<nlohmann::json>> library_rows(const LibraryReportOptions& options,
                                                 std::vector<nlohmann::json>& records, const fs::path& dir) {
  std::vector<nlohmann::json> row_of(records.size());
  std::mutex mutex;  // the progress callback and the first write error
  std::optional<Error> write_error;
  std::atomic<size_t> done{0};
  parallel_for(records.size(), options.threads, [&](size_t i) {
    const Status described = library_row(options, std::move(records[i]), i, dir, row_of[i]);
    std::lock_guard<std::mutex> lock(mutex);
    if (!described && !write_error) write_error = described.error();
    const size_t finished = ++done;
    if (options.progress && (finished % 16 == 0 || finished == records.size()))
      options.progress(finished, records.size());
  });
  if (write_error) return *write_error;
  return row_of;
}

void count_rows(const std::vector<nlohmann::json>& rows, ReportInfo& counts) {
  for (const nlohmann::json& row : rows) {
    const std::string status = text_of(row, "status");
    counts.built += status == "ok";
    counts.up_to_date += status == "up_to_date";
    counts.failed += status == "failed";
    counts.unreadable_assets += row.contains("asset_error");
  }
}

}  // namespace

Result<ReportInfo> write_library_report(const LibraryReportOptions& options) {
  Result<ManifestRecords> manifest = read_manifest(options.library, options.manifest);
  if (!manifest) return manifest.error();
  nlohmann::json against;
  if (!options.against.empty()) {
    Result<ManifestRecords> other = read_manifest(options.against, "");
    if (!other) return other.error();
    against = {{"library", fs::absolute(options.against).lexically_normal().string()},
               {"rows", compact_rows(options.against, other->records)}};
  }
  const fs::path out = options.out.empty() ? fs::path(options.library) / "report" : fs::path(options.out);
  ReportInfo counts;
  counts.meshes = manifest->records.size();
  counts.skipped_lines = manifest->skipped_lines;
  Result<ReportInfo> written = write_report_folder(out, [&](const fs::path& dir) -> Status {
    Result<std::vector<nlohmann::json>> rows = library_rows(options, manifest->records, dir);
    if (!rows) return rows.error();
    count_rows(rows.value(), counts);
    nlohmann::json row_array = nlohmann::json::array();
    for (nlohmann::json& row : rows.value()) row_array.push_back(std::move(row));
    const nlohmann::json data =
        report_data("library", options.library, options, manifest->skipped_lines, std::move(row_array), against);
    return write_text(dir / "data.js", kDataPrefix + script_value(data) + ";\n");
  });
  if (!written) return written.error();
  ReportInfo info = counts;
  info.index_html = written->index_html;
  info.bytes = written->bytes;
  return info;
}

Result<ReportInfo> write_asset_report(const std::string& asset, const std::string& out, const ReadOptions& read) {
  const ReadAsset read_result = read_for_report(asset, read);
  if (!read_result.asset) return read_result.asset.error();  // an unreadable asset is the command's error
  Result<ReportInfo> written = write_report_folder(fs::path(out), [&](const fs::path& dir) -> Status {
    nlohmann::json row = {{"id", 0},
                          {"name", fs::path(asset).filename().string()},
                          {"output", fs::absolute(asset).lexically_normal().string()},
                          {"output_name", fs::path(asset).filename().string()},
                          {"status", "ok"}};
    std::error_code ec;
    row["file_size_bytes"] = fs::file_size(asset, ec);
    if (Status s = describe_asset(asset, read_result, dir, 0, read, true, row); !s) return s;
    LibraryReportOptions defaults;
    // absolute first: a bare file name ("b.vox.h5") has an empty parent, which fs::absolute refuses
    const nlohmann::json data = report_data("asset", fs::absolute(asset).parent_path().string(), defaults, 0,
                                            nlohmann::json::array({row}), nullptr);
    return write_text(dir / "data.js", kDataPrefix + script_value(data) + ";\n");
  });
  if (!written) return written.error();
  ReportInfo info = written.value();
  info.meshes = info.built = 1;
  return info;
}

}  // namespace voxfmt::report
