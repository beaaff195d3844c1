// `voxfmt report LIBRARY [-o OUT] [--against OLD]`: an HTML report of a baked library.
#include <unistd.h>

#include <iomanip>
#include <iostream>
#include <sstream>

#include "commands.h"
#include "json_report.h"
#include "report.h"

namespace voxfmt::cli {

namespace {

struct Options {
  report::LibraryReportOptions report;
  bool json = false;
};

std::string megabytes(uint64_t bytes) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(1) << double(bytes) / (1 << 20) << " MB";
  return s.str();
}

}  // namespace

nlohmann::json report_summary_json(const report::ReportInfo& info) {
  return {{"index_html", info.index_html},
          {"meshes", info.meshes},
          {"built", info.built},
          {"up_to_date", info.up_to_date},
          {"failed", info.failed},
          {"unreadable_assets", info.unreadable_assets},
          {"skipped_manifest_lines", info.skipped_lines},
          {"bytes", info.bytes}};
}

std::function<void(size_t, size_t)> report_progress() {
  if (!::isatty(STDERR_FILENO)) return {};  // logs get the summary line only
  return [](size_t done, size_t total) {
    std::cerr << "\rreport: " << done << " / " << total << " meshes" << (done == total ? "\r\033[K" : "") << std::flush;
  };
}

void print_report_summary(const report::ReportInfo& info) {
  std::cout << "report: " << terminal_safe(info.index_html) << " (" << info.meshes << " meshes: " << info.built
            << " built, " << info.up_to_date << " up to date, " << info.failed << " failed";
  if (info.unreadable_assets) std::cout << ", " << info.unreadable_assets << " asset(s) unreadable";
  std::cout << "; " << megabytes(info.bytes) << ")\n";
  if (info.skipped_lines) std::cout << "  " << info.skipped_lines << " manifest line(s) were not records: skipped\n";
}

void add_report_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<Options>();
  CLI::App* cmd = app.add_subcommand(
      "report",
      "Write an HTML report of a baked library (a `voxfmt batch` output folder, or any folder of assets): summary, "
      "table, a card with pictures per asset, a 3D view; opens from the file system, no server");
  cmd->add_option("library", options->report.library,
                  "Library folder: a `voxfmt batch` output (its manifest.jsonl), or any folder of *.vox.h5 assets")
      ->required();
  cmd->add_option("-o,--output", options->report.out, "Report folder (default: LIBRARY/report)")->check(output_path());
  cmd->add_option("--manifest", options->report.manifest,
                  "Manifest to read (default: LIBRARY/manifest.jsonl and the shards' manifest.shard-I-of-N.jsonl)")
      ->check(non_empty_path());
  CLI::Option* against =
      cmd->add_option("--against", options->report.against,
                      "Another bake of the library to compare with (assets that appeared, disappeared, changed status, "
                      "grew, shrank or bake more slowly)")
          ->check(non_empty_path());
  cmd->add_option("--size-threshold", options->report.size_threshold,
                  "With --against: relative file-size change that is listed")
      ->capture_default_str()
      ->check(finite_number(true))
      ->check(CLI::Range(0.0, 100.0))
      ->needs(against);
  cmd->add_option("--time-threshold", options->report.time_threshold,
                  "With --against: relative bake-time increase that is listed")
      ->capture_default_str()
      ->check(finite_number(true))
      ->check(CLI::Range(0.0, 100.0))
      ->needs(against);
  cmd->add_option("-j,--jobs", options->report.threads, "Threads reading assets (default: every core)")
      ->transform(whole_number())
      ->check(CLI::Range(1u, kMaxThreads));
  cmd->add_flag(
      "--no-pictures", [options](int64_t) { options->report.pictures = false; },
      "Only the manifest's and the assets' facts: no thumbnails, slices or 3D data");
  cmd->add_flag("--json", options->json, "Print the summary as JSON on stdout");
  add_read_budget_option(cmd, options->report.read);
  cmd->footer(
      "\nExamples:\n"
      "  voxfmt report out/library                        # writes out/library/report/index.html\n"
      "  voxfmt report new/ --against old/ -o diff/       # what changed between two bakes\n"
      "  voxfmt report assets/                            # a folder without a manifest: every *.vox.h5 below it\n"
      "One asset's page: voxfmt inspect ASSET --html OUT.\n"
      "Open index.html in a browser (file://). A damaged asset gets its card with the coded error.\n");
  cmd->callback([options, &exit_code] {
    options->report.progress = report_progress();
    const Result<report::ReportInfo> info = report::write_library_report(options->report);
    if (!info) {
      exit_code = report_error("report", info.error(), options->json, options->report.library);
      return;
    }
    if (options->json)
      std::cout << to_text(report_summary_json(info.value())) << "\n";
    else
      print_report_summary(info.value());
    exit_code = kExitOk;
  });
}

}  // namespace voxfmt::cli
