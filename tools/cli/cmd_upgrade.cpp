// `voxfmt upgrade IN... -o OUT`: rewrite assets of an older format in the current one (1.x: the dense grids read as
// bricks, spec §3.4; 2.0 and 2.1: the estimates settled, §3.1). One file to a file, or files and folders (searched for
// *.vox.h5) into a folder, keeping their relative paths. Each output is validated like any written asset and replaces
// its target atomically.
#include <unistd.h>

#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>

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

bool is_asset_name(const fs::path& p) {
  const std::string name = p.filename().string();
  return name.size() > 7 && name.compare(name.size() - 7, 7, ".vox.h5") == 0;
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
    } else if (fs::is_regular_file(input, ec)) {
      items.push_back({input, (fs::path(o.output) / fs::path(input).filename()).string()});
    } else {
      const std::string kind = not_a_regular_file(input);
      return Error{IssueCode::FileNotFound, input + ": " + (kind.empty() ? "no such file or folder" : kind), input};
    }
  }
  std::sort(items.begin(), items.end(), [](const Item& a, const Item& b) { return a.input < b.input; });
  std::map<fs::path, const Item*> by_output;
  for (const Item& item : items) {
    const auto [it, added] = by_output.emplace(place(item.output), &item);
    if (!added)
      return Error{IssueCode::BadOption,
                   "two inputs would write the same output " + item.output + ": " + it->second->input + " and " +
                       item.input + " (upgrade them into different folders)",
                   item.output};
  }
  return items;
}

// Counts of a run, and the exit status of its worst failure.
struct Tally {
  size_t upgraded = 0, current = 0, failed = 0;
  int worst = kExitOk;
};

// One file: read, and rewritten in the current format unless it is already (or --force). Its entry in the JSON
// report; the line a person reads.
nlohmann::json upgrade_one(const Options& o, const Item& item, bool progress, Tally& tally) {
  nlohmann::json entry = {{"input", item.input}, {"output", item.output}};
  std::vector<Issue> warnings;
  Result<Asset> asset = read_asset(item.input, &warnings, o.read);
  Status written = Status::success();
  const auto current = [](const FormatVersion& v) {
    return v.major == kFormatVersion.major && v.minor >= kFormatVersion.minor;
  };
  if (asset && current(asset.value().version) && !o.force) {
    ++tally.current;
    entry["status"] = "current";
    entry["format_version"] = {asset.value().version.major, asset.value().version.minor};
  } else if (asset) {
    const FormatVersion from = asset.value().version;
    std::error_code ec;
    if (fs::path(item.output).has_parent_path()) fs::create_directories(fs::path(item.output).parent_path(), ec);
    // 2.0 and 2.1 estimates are the lattice interpolated; 2.2 settles them from the same stored data.
    Voxelmap& vm = asset.value().voxelmap;
    if (vm.estimates != Voxelmap::Estimates::Settled) fill_estimates(vm);
    written = write_asset(item.output, asset.value());
    if (written) {
      ++tally.upgraded;
      entry["status"] = "upgraded";
      entry["from"] = {from.major, from.minor};
      entry["bytes_before"] = fs::file_size(item.input, ec);
      entry["bytes_after"] = fs::file_size(item.output, ec);
      if (!o.json && !o.quiet) {
        if (progress) std::cerr << "\r\033[K";
        std::cout << item.input << " (" << from.major << "." << from.minor << ", " << std::fixed << std::setprecision(1)
                  << double(fs::file_size(item.input, ec)) / 1e6 << " MB) -> " << item.output << " ("
                  << kFormatVersion.major << "." << kFormatVersion.minor << ", "
                  << double(fs::file_size(item.output, ec)) / 1e6 << " MB)\n";
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
  if (!planned) return report_error("upgrade", planned.error());
  const std::vector<Item>& items = planned.value();
  const bool progress = !o.quiet && !o.json && isatty(STDERR_FILENO) && items.size() > 1;
  nlohmann::json report = {{"files", nlohmann::json::array()}};
  Tally tally;
  for (size_t n = 0; n < items.size(); ++n) {
    if (progress) std::cerr << "\r\033[K[" << n + 1 << "/" << items.size() << "] " << items[n].input << std::flush;
    report["files"].push_back(upgrade_one(o, items[n], progress, tally));
  }
  if (progress) std::cerr << "\r\033[K" << std::flush;
  report["upgraded"] = tally.upgraded;
  report["current"] = tally.current;
  report["failed"] = tally.failed;
  if (o.json) {
    std::cout << to_text(report) << "\n";
  } else if (!o.quiet) {
    std::cout << tally.upgraded << " upgraded to format " << kFormatVersion.major << "." << kFormatVersion.minor << ", "
              << tally.current << " already current" << (o.force ? "" : " (left alone; --force rewrites them)") << ", "
              << tally.failed << " failed\n";
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
      ->check(non_empty_path())
      ->required();
  cmd->add_flag("--force", o->force, "Rewrite assets that are already of the current format too");
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
