// `voxfmt upgrade IN... -o OUT`: rewrite assets of an older format in the current one (1.x: the dense grids read as
// bricks, spec §3.4; 2.0 and 2.1: the estimates settled, §3.1). One file to a file, or files and folders (searched for
// *.vox.h5) into a folder, keeping their relative paths. Each output is validated like any written asset and replaces
// its target atomically.
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>

#include "batch_manifest.h"
#include "commands.h"
#include "json_report.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/io.h"

namespace voxfmt::cli {

namespace {

namespace fs = std::filesystem;

struct Options {
  std::vector<std::string> inputs;
  std::string output;
  ReadOptions read;
  bool force = false;
  bool json = false;
  bool quiet = false;
};

struct Item {
  std::string input, output;
};

// *.vox.h5, in any case (a library copied from a case-insensitive file system may hold BUNNY.VOX.H5).
bool is_asset_name(const fs::path& p) {
  const std::string name = p.filename().string();
  if (name.size() <= 7) return false;
  std::string suffix = name.substr(name.size() - 7);
  for (char& c : suffix) c = char(std::tolower(static_cast<unsigned char>(c)));
  return suffix == ".vox.h5";
}

// Where a path lies, as the plan compares them: a folder as what it is (an alias of OUT is OUT), a file by its
// own name in its resolved folder (a link upgraded in place is an output of its own, not refused as the file it
// names; writing it goes through the link to that file, as every output does).
fs::path place(const fs::path& path) {
  std::error_code ec;
  fs::path normal = fs::absolute(path, ec).lexically_normal();
  if (!normal.has_filename()) normal = normal.parent_path();  // "out/" is "out"
  if (fs::is_directory(normal, ec)) return fs::weakly_canonical(normal, ec);
  return fs::weakly_canonical(normal.parent_path(), ec) / normal.filename();
}

// The files to upgrade and where each goes. A single file input with an output that is not an existing folder
// is a file-to-file upgrade; otherwise the output is a folder.
Result<std::vector<Item>> plan(const Options& o) {
  std::vector<Item> items;
  std::error_code ec;
  const bool single_file = o.inputs.size() == 1 && fs::is_regular_file(o.inputs[0], ec) &&
                           !fs::is_directory(o.output, ec) &&
                           (o.output.empty() || o.output.back() != '/');  // "new/": a folder to make
  if (single_file) return std::vector<Item>{{o.inputs[0], o.output}};
  const fs::path output_folder = place(o.output);
  for (const std::string& input : o.inputs) {
    const size_t found_before = items.size();
    if (fs::is_directory(input, ec)) {
      for (auto it = fs::recursive_directory_iterator(input, ec); !ec && it != fs::recursive_directory_iterator();
           it.increment(ec)) {
        if (it->is_directory(ec) && place(it->path()) == output_folder) {
          it.disable_recursion_pending();  // our own output inside the input: not an input
          continue;
        }
        // The path as listed, not resolved: a link to a file elsewhere is written under OUTPUT by its own name,
        // never through the link to where it points.
        if (it->is_regular_file(ec) && is_asset_name(it->path()))
          items.push_back({it->path().string(), (fs::path(o.output) / it->path().lexically_relative(input)).string()});
      }
      if (ec) return Error{IssueCode::FileNotFound, input + ": cannot list the folder: " + ec.message(), input};
      if (items.size() == found_before)
        return Error{IssueCode::FileNotFound, input + ": the folder holds no asset (*.vox.h5) to upgrade", input};
    } else if (fs::is_regular_file(input, ec)) {
      items.push_back({input, (fs::path(o.output) / fs::path(input).filename()).string()});
    } else {
      const std::string kind = not_a_regular_file(input);
      return Error{IssueCode::FileNotFound, input + ": " + (kind.empty() ? "no such file or folder" : kind), input};
    }
  }
  std::sort(items.begin(), items.end(), [](const Item& a, const Item& b) { return a.input < b.input; });
  // Items run one after another: an output whose write lands on another item's input (by name, or through this
  // user's links, as writes follow them) would replace it before it is read. Compared as files, links resolved.
  const auto landing = [&ec](const std::string& path) {
    const Result<std::string> target = output_target(path);
    return fs::weakly_canonical(fs::absolute(target ? target.value() : path, ec), ec);
  };
  std::map<fs::path, const Item*> by_output, by_input;
  for (const Item& item : items) by_input.emplace(fs::weakly_canonical(fs::absolute(item.input, ec), ec), &item);
  std::vector<Item> unique;
  for (const Item& item : items) {
    const auto input = by_input.find(landing(item.output));
    if (input != by_input.end() && !fs::equivalent(input->second->input, item.input, ec))
      return Error{IssueCode::BadOption,
                   item.output + " (the upgrade of " + item.input + ") is also an input: it would be replaced " +
                       "before it is read (upgrade into another folder)",
                   item.output};
    const auto [it, added] = by_output.emplace(place(item.output), &item);
    if (!added && fs::equivalent(it->second->input, item.input, ec)) continue;  // one file named twice: once
    if (!added)
      return Error{IssueCode::BadOption,
                   "two inputs would write the same output " + item.output + ": " + it->second->input + " and " +
                       item.input + " (upgrade them into different folders)",
                   item.output};
    unique.push_back(item);
  }
  return unique;
}

// Counts of a run, and the exit status of its worst failure.
struct Tally {
  size_t upgraded = 0, current = 0, newer = 0, failed = 0;
  int worst = kExitOk;
};

// The folder `output` goes in, made where missing: WRITE_FAILED with the reason (a permission, a file in the way).
Status make_parent(const std::string& output) {
  const fs::path parent = fs::path(output).parent_path();
  std::error_code ec;
  if (parent.empty() || fs::is_directory(parent, ec)) return Status::success();
  if (fs::create_directories(parent, ec); ec)
    return Error{IssueCode::WriteFailed, output + ": cannot make the folder " + parent.string() + ": " + ec.message(),
                 output};
  return Status::success();
}

// A file left as it is (current, or newer than this voxfmt), copied byte for byte where the output is elsewhere,
// so that a library's upgraded copy holds every asset of it.
Status copy_unchanged(const Item& item) {
  if (place(item.output) == place(item.input)) return Status::success();
  if (Status made = make_parent(item.output); !made) return made;
  return write_file_atomically(
      item.output, AtomicWrite{[&](const std::string& temporary) -> Status {
                                 std::error_code ec;
                                 fs::copy_file(item.input, temporary, fs::copy_options::overwrite_existing, ec);
                                 if (ec)
                                   return Error{IssueCode::WriteFailed,
                                                item.output + ": cannot copy " + item.input + ": " + ec.message(),
                                                item.output};
                                 return Status::success();
                               },
                               {}});
}

// The upgraded asset written to the item's output; its entry's sizes (the input's measured before a write in place
// replaces it).
Status write_upgraded(Asset& asset, const Item& item, nlohmann::json& entry) {
  std::error_code ec;
  const uintmax_t before = fs::file_size(item.input, ec);
  if (Status made = make_parent(item.output); !made) return made;
  // 2.0 and 2.1 estimates are the lattice interpolated; 2.2 settles them from the same stored data.
  if (asset.voxelmap.estimates != Voxelmap::Estimates::Settled) fill_estimates(asset.voxelmap);
  const Status written = write_asset(item.output, asset);
  if (written) {
    entry["bytes_before"] = before;
    entry["bytes_after"] = fs::file_size(item.output, ec);
  }
  return written;
}

// One file: read, and rewritten in the current format unless it is already (or --force: a file of a newer minor
// version is never rewritten, which would drop what this voxfmt does not know). Its entry in the JSON report; the
// line a person reads.
nlohmann::json upgrade_one(const Options& o, const Item& item, bool progress, Tally& tally) {
  nlohmann::json entry = {{"input", item.input}, {"output", item.output}};
  std::vector<Issue> warnings;
  Result<Asset> asset = read_asset(item.input, &warnings, o.read);
  Status written = Status::success();
  const FormatVersion from = asset ? asset.value().version : FormatVersion{};
  // Newer than this voxfmt knows (a 2.x or a 1.x minor): the reader says so, and ignores what it does not know.
  const bool newer = std::any_of(warnings.begin(), warnings.end(),
                                 [](const Issue& issue) { return issue.code == IssueCode::VersionNewerMinor; });
  if (asset && !warnings.empty()) {
    entry["warnings"] = issues_json(warnings);
    if (!o.json && !o.quiet)
      for (const Issue& issue : warnings)
        if (issue.severity != Severity::Info)
          std::cerr << (progress ? "\r\033[K" : "") << "voxfmt upgrade: " << terminal_safe(item.input) << ": "
                    << severity_name(issue.severity) << ": " << code_name(issue.code) << ": "
                    << terminal_safe(issue.message) << "\n";
  }
  if (asset && (newer || (from.major == kFormatVersion.major && from.minor == kFormatVersion.minor && !o.force))) {
    written = copy_unchanged(item);
    if (written) {
      ++(newer ? tally.newer : tally.current);
      entry["status"] = newer ? "newer" : "current";
      entry["format_version"] = {from.major, from.minor};
    }
  } else if (asset) {
    written = write_upgraded(asset.value(), item, entry);
    if (written) {
      ++tally.upgraded;
      entry["status"] = "upgraded";
      entry["from"] = {from.major, from.minor};
      if (!o.json && !o.quiet) {
        if (progress) std::cerr << "\r\033[K";
        std::cout << terminal_safe(item.input) << " (" << from.major << "." << from.minor << ", " << std::fixed
                  << std::setprecision(1) << double(entry["bytes_before"].get<uintmax_t>()) / 1e6 << " MB) -> "
                  << terminal_safe(item.output) << " (" << kFormatVersion.major << "." << kFormatVersion.minor << ", "
                  << double(entry["bytes_after"].get<uintmax_t>()) / 1e6 << " MB)\n";
      }
    }
  }
  const Error* error = !asset ? &asset.error() : !written ? &written.error() : nullptr;
  if (error) {
    ++tally.failed;
    tally.worst = std::max(tally.worst, exit_status(error->code));
    entry["status"] = "failed";
    entry["error"] = {{"code", code_name(error->code)}, {"message", error->message}};
    if (!o.json) {
      if (progress) std::cerr << "\r\033[K";
      std::cerr << "voxfmt upgrade: error: " << code_name(error->code) << ": " << terminal_safe(error->message) << "\n";
    }
  }
  return entry;
}

int run(const Options& o) {
  const Result<std::vector<Item>> planned = plan(o);
  if (!planned) return report_error("upgrade", planned.error(), o.json, o.inputs.empty() ? "" : o.inputs[0]);
  const std::vector<Item>& items = planned.value();
  {
    // What killed upgrades left beside these outputs (a dead process's NAME.partial-PID-N), once per folder.
    std::vector<std::string> outputs;
    for (const Item& item : items) outputs.push_back(item.output);
    remove_stale_partials(outputs);
  }
  const bool progress = !o.quiet && !o.json && isatty(STDERR_FILENO) && items.size() > 1;
  nlohmann::json report = {{"files", nlohmann::json::array()}};
  Tally tally;
  for (size_t n = 0; n < items.size(); ++n) {
    if (progress)
      std::cerr << "\r\033[K[" << n + 1 << "/" << items.size() << "] " << terminal_safe(items[n].input) << std::flush;
    report["files"].push_back(upgrade_one(o, items[n], progress, tally));
  }
  if (progress) std::cerr << "\r\033[K" << std::flush;
  report["upgraded"] = tally.upgraded;
  report["current"] = tally.current;
  report["newer"] = tally.newer;
  report["failed"] = tally.failed;
  if (o.json) {
    std::cout << to_text(report) << "\n";
  } else if (!o.quiet) {
    std::cout << tally.upgraded << " upgraded to format " << kFormatVersion.major << "." << kFormatVersion.minor << ", "
              << tally.current << " already current" << (o.force ? "" : " (--force rewrites them)") << ", "
              << tally.newer << " of a newer format (never rewritten), " << tally.failed
              << " failed; those left as they are were copied where the output is elsewhere\n";
  }
  return tally.worst;
}

}  // namespace

void add_upgrade_command(CLI::App& app, int& exit_code) {
  auto o = std::make_shared<Options>();
  CLI::App* cmd = app.add_subcommand(
      "upgrade",
      "Rewrite assets of an older format version in the current one (1.x: dense grids to bricks; 2.0, 2.1: "
      "estimates settled)");
  cmd->add_option("inputs", o->inputs, "Asset files, or folders searched for *.vox.h5")->required();
  cmd->add_option("-o,--output", o->output,
                  "Output file (one input file), or folder (several inputs, or a folder: relative paths are kept)")
      ->check(output_path())
      ->required();
  cmd->add_flag("--force", o->force,
                "Rewrite assets that are already of the current format too (never those of a newer minor version)");
  cmd->add_flag("--json", o->json, "Print a JSON report on stdout");
  cmd->add_flag("-q,--quiet", o->quiet, "Print nothing but errors");
  add_read_budget_option(cmd, o->read);
  cmd->footer(
      "\nExamples:\n"
      "  voxfmt upgrade old/bunny.vox.h5 -o bunny.vox.h5     # one file\n"
      "  voxfmt upgrade assets/ -o assets-2.2/               # a library, folder structure kept\n");
  cmd->callback([o, &exit_code] { exit_code = run(*o); });
}

}  // namespace voxfmt::cli
