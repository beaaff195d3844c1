#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <thread>

#include "asset_views.h"
#include "report.h"
#include "report_resources.h"
#include "voxfmt/detail/atomic_file.h"
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
constexpr const char* kReportKeys[] = {"id",    "name",        "output_name", "detail",      "views",
                                       "slice", "asset_error", "validation",  "memory_bytes"};

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

// The manifest's records, last one per output, in output order; lines that are not JSON objects with an
// "output" are counted, not fatal (a hand-edited or torn manifest still gets its report).
struct ManifestRecords {
  std::vector<nlohmann::json> records;
  size_t skipped_lines = 0;
};

// The manifest files of a library: manifest.jsonl and the shards' manifest.shard-I-of-N.jsonl.
std::vector<fs::path> manifest_files(const std::string& library) {
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(library, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("manifest", 0) == 0 && entry.path().extension() == ".jsonl" && entry.is_regular_file(ec))
      files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

Result<ManifestRecords> read_manifest(const std::string& library) {
  const std::vector<fs::path> files = manifest_files(library);
  if (files.empty())
    return Error(IssueCode::FileNotFound,
                 library + ": no manifest.jsonl here (a library is the output folder of `voxfmt batch`)", library);
  ManifestRecords m;
  std::map<std::string, nlohmann::json> last;
  for (const fs::path& file : files) {
    std::ifstream in(file);
    std::string line;
    while (std::getline(in, line)) {
      if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
      nlohmann::json record = nlohmann::json::parse(line, nullptr, false);
      if (!record.is_object() || !record.contains("output") || !record["output"].is_string()) {
        ++m.skipped_lines;
        continue;
      }
      const std::string output = record["output"].get<std::string>();
      last[output] = std::move(record);
    }
  }
  for (auto& [output, record] : last) m.records.push_back(std::move(record));
  return m;
}

std::string text_of(const nlohmann::json& record, const char* key) {
  const auto it = record.find(key);
  return it != record.end() && it->is_string() ? it->get<std::string>() : std::string();
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

// The asset's path: the manifest's output when it exists, else the same name inside the library (a library
// moved or copied after its bake).
std::string asset_path(const std::string& library, const nlohmann::json& record) {
  const std::string output = text_of(record, "output");
  if (!output.empty() && fs::exists(output)) return output;
  return (fs::path(library) / fs::path(output).filename()).string();
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

// Everything the report shows of one asset file. `row` gets the small facts (for the table and the card),
// the returned script the large ones (loaded when the card opens).
std::string describe_asset(const std::string& path, const std::string& dir, size_t id, const ReadOptions& read,
                           bool pictures, nlohmann::json& row) {
  std::vector<Issue> warnings;
  Result<Asset> asset = read_asset(path, &warnings, read);
  if (!asset) {
    row["asset_error"] = error_json(asset.error());
    const std::vector<Issue> findings = validate_file(path, read);
    row["validation"] = {{"valid", false}, {"findings", issues_json(findings)}, {"count", findings.size()}};
    return {};
  }
  const AssetSummary summary = summarize_asset(path, asset.value());
  nlohmann::json inspect = nlohmann::json::parse(inspect_json(path, asset.value(), summary, warnings), nullptr, false);
  row["validation"] = {{"valid", true}, {"findings", issues_json(warnings)}, {"count", warnings.size()}};
  row["memory_bytes"] = summary.memory_bytes;
  nlohmann::json detail = {{"inspect", inspect}};
  if (pictures) {
    const std::string views = "img/" + std::to_string(id) + "-views.png";
    const std::string slice = "img/" + std::to_string(id) + "-slice.png";
    if (write_views_png(asset.value(), kViewSize, (fs::path(dir) / views).string())) row["views"] = views;
    if (write_mid_slice_png(asset.value(), kSliceSize, (fs::path(dir) / slice).string())) row["slice"] = slice;
    detail["scene"] = scene_data(asset.value(), kScenePoints, kSceneGrid);
  }
  return "voxfmtReport.addAsset(" + std::to_string(id) + ", " + dump(detail) + ");\n";
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

Status write_text(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out.write(text.data(), std::streamsize(text.size()));
  out.close();
  if (!out) return Error(IssueCode::WriteFailed, path.string() + ": cannot write", path.string());
  return Status::success();
}

// A folder earlier `voxfmt report` runs wrote (index.html and data.js), or an empty one: safe to replace.
bool replaceable(const fs::path& out) {
  std::error_code ec;
  if (!fs::exists(out, ec)) return true;
  if (!fs::is_directory(out, ec)) return false;
  if (fs::is_empty(out, ec)) return true;
  return fs::exists(out / "index.html", ec) && fs::exists(out / "data.js", ec) &&
         fs::exists(out / "voxfmt-report.js", ec);
}

// Builds the report in a temporary folder beside OUT and renames it over OUT: a killed run never leaves half a
// report under OUT's name.
Result<ReportInfo> write_report_folder(const fs::path& out, const std::function<Status(const fs::path&)>& fill) {
  if (!replaceable(out))
    return Error(IssueCode::BadOption, out.string() + " exists and is not a voxfmt report: not replaced", out.string());
  std::error_code ec;
  const fs::path parent = out.parent_path().empty() ? fs::path(".") : out.parent_path();
  fs::create_directories(parent, ec);
  const fs::path temporary =
      parent / (out.filename().string() + std::string(kPartialMarker) + std::to_string(::getpid()));
  fs::remove_all(temporary, ec);
  if (!fs::create_directories(temporary / "img", ec) || !fs::create_directories(temporary / "assets", ec))
    return Error(IssueCode::WriteFailed, temporary.string() + ": cannot create the folder (" + ec.message() + ")",
                 temporary.string());
  Status filled = fill(temporary);
  for (size_t r = 0; filled && r < kResourceCount; ++r)
    filled = write_text(temporary / kResources[r].name, std::string(kResources[r].data, kResources[r].size));
  if (!filled) {
    fs::remove_all(temporary, ec);
    return filled.error();
  }
  ReportInfo info;
  for (const auto& entry : fs::recursive_directory_iterator(temporary, ec))
    if (entry.is_regular_file(ec)) info.bytes += entry.file_size(ec);
  fs::remove_all(out, ec);
  fs::rename(temporary, out, ec);
  if (ec) {
    fs::remove_all(temporary, ec);
    return Error(IssueCode::WriteFailed, out.string() + ": cannot move the report into place", out.string());
  }
  info.index_html = (out / "index.html").string();
  return info;
}

// The fields the comparison needs of each record of the other library.
nlohmann::json compact_rows(const std::vector<nlohmann::json>& records) {
  nlohmann::json rows = nlohmann::json::array();
  for (const nlohmann::json& r : records) {
    nlohmann::json row = {{"name", mesh_name(r)},
                          {"output", fs::path(text_of(r, "output")).filename().string()},
                          {"status", text_of(r, "status")}};
    for (const char* key : {"file_size_bytes", "total_s", "error", "warnings", "voxelmap", "tool_version"})
      if (r.contains(key)) row[key] = r[key];
    rows.push_back(std::move(row));
  }
  return rows;
}

}  // namespace

Result<ReportInfo> write_library_report(const LibraryReportOptions& options) {
  Result<ManifestRecords> manifest = read_manifest(options.library);
  if (!manifest) return manifest.error();
  nlohmann::json against;
  if (!options.against.empty()) {
    Result<ManifestRecords> other = read_manifest(options.against);
    if (!other) return other.error();
    against = {{"library", fs::absolute(options.against).lexically_normal().string()},
               {"rows", compact_rows(other->records)}};
  }
  const fs::path out = options.out.empty() ? fs::path(options.library) / "report" : fs::path(options.out);
  std::vector<nlohmann::json>& records = manifest->records;
  ReportInfo counts;
  counts.meshes = records.size();
  counts.skipped_lines = manifest->skipped_lines;
  Result<ReportInfo> written = write_report_folder(out, [&](const fs::path& dir) -> Status {
    std::vector<nlohmann::json> rows(records.size());
    std::vector<std::string> scripts(records.size());
    std::mutex progress_mutex;
    std::atomic<size_t> done{0};
    parallel_for(records.size(), options.threads, [&](size_t i) {
      nlohmann::json& row = rows[i];
      row = records[i];
      row.erase("command");  // the bake's argv: long, and the build parameters say the same
      row.erase("output_mtime_ns");
      // The keys the report sets are the report's: a manifest's own (hand-edited, hostile) never reach the page,
      // which loads "detail" as a script and "views" and "slice" as pictures.
      for (const char* key : kReportKeys) row.erase(key);
      row["id"] = i;
      row["name"] = mesh_name(records[i]);
      row["output_name"] = fs::path(text_of(records[i], "output")).filename().string();
      const std::string status = text_of(records[i], "status");
      if (status == "ok" || status == "up_to_date")
        scripts[i] = describe_asset(asset_path(options.library, records[i]), dir.string(), i, options.read,
                                    options.pictures, row);
      const size_t finished = ++done;
      if (options.progress && (finished % 16 == 0 || finished == records.size())) {
        std::lock_guard<std::mutex> lock(progress_mutex);
        options.progress(finished, records.size());
      }
    });
    for (size_t i = 0; i < rows.size(); ++i) {
      const std::string status = text_of(rows[i], "status");
      counts.built += status == "ok";
      counts.up_to_date += status == "up_to_date";
      counts.failed += status == "failed";
      counts.unreadable_assets += rows[i].contains("asset_error");
      if (scripts[i].empty()) continue;
      rows[i]["detail"] = "assets/" + std::to_string(i) + ".js";
      if (Status s = write_text(dir / "assets" / (std::to_string(i) + ".js"), scripts[i]); !s) return s;
    }
    const nlohmann::json data = {{"kind", "library"},
                                 {"library", fs::absolute(options.library).lexically_normal().string()},
                                 {"generated_utc", utc_now()},
                                 {"tool_version", VOXFMT_VERSION_STRING},
                                 {"skipped_lines", manifest->skipped_lines},
                                 {"thresholds", {{"size", options.size_threshold}, {"time", options.time_threshold}}},
                                 {"rows", rows},
                                 {"against", against}};
    return write_text(dir / "data.js", "window.VOXFMT_REPORT = " + dump(data) + ";\n");
  });
  if (!written) return written.error();
  ReportInfo info = counts;
  info.index_html = written->index_html;
  info.bytes = written->bytes;
  return info;
}

Result<ReportInfo> write_asset_report(const std::string& asset, const std::string& out, const ReadOptions& read) {
  std::vector<Issue> warnings;
  {
    Result<Asset> readable = read_asset(asset, &warnings, read);  // an unreadable asset is the command's error
    if (!readable) return readable.error();
  }
  Result<ReportInfo> written = write_report_folder(fs::path(out), [&](const fs::path& dir) -> Status {
    nlohmann::json row = {{"id", 0},
                          {"name", fs::path(asset).filename().string()},
                          {"output", fs::absolute(asset).lexically_normal().string()},
                          {"output_name", fs::path(asset).filename().string()},
                          {"status", "ok"}};
    const std::string script = describe_asset(asset, dir.string(), 0, read, true, row);
    std::error_code ec;
    row["file_size_bytes"] = fs::file_size(asset, ec);
    row["detail"] = "assets/0.js";
    if (Status s = write_text(dir / "assets" / "0.js", script); !s) return s;
    const nlohmann::json data = {{"kind", "asset"},
                                 {"library", fs::absolute(asset).parent_path().lexically_normal().string()},
                                 {"generated_utc", utc_now()},
                                 {"tool_version", VOXFMT_VERSION_STRING},
                                 {"skipped_lines", 0},
                                 {"thresholds", {{"size", 0.1}, {"time", 0.25}}},
                                 {"rows", {row}},
                                 {"against", nullptr}};
    return write_text(dir / "data.js", "window.VOXFMT_REPORT = " + dump(data) + ";\n");
  });
  if (!written) return written.error();
  ReportInfo info = written.value();
  info.meshes = info.built = 1;
  return info;
}

}  // namespace voxfmt::report
