// `voxfmt validate FILE... [--json]`: check assets against the spec. Exit 0 valid, 1 invalid, 2 unreadable or over
// the read budget.
#include <algorithm>
#include <iostream>

#include "commands.h"
#include "json_report.h"
#include "voxfmt/io.h"

namespace voxfmt::cli {

namespace {
struct Options {
  std::vector<std::string> files;
  bool json = false;
  std::string level = "full";
  size_t max_issues = 100;
  ReadOptions read;
};
// One file's findings as a person reads them: the verdict and counts of all, the first `shown` of them listed.
void print_findings(const std::string& file, const std::vector<Issue>& issues, size_t shown) {
  bool unreadable = false, over_budget = false;
  size_t errors = 0, warnings = 0;
  for (const Issue& issue : issues) {
    errors += issue.severity == Severity::Error;
    warnings += issue.severity == Severity::Warning;
    unreadable |= issue.code == IssueCode::FileNotFound;
    over_budget |= issue.code == IssueCode::OutOfMemory;
  }
  std::cout << terminal_safe(file) << ": "
            << (!has_errors(issues) ? "valid"
                : unreadable        ? "UNREADABLE"
                : over_budget       ? "NOT JUDGED (over the read budget: --max-memory)"
                                    : "INVALID")
            << " (" << errors << " error(s), " << warnings << " warning(s))\n";
  if (issues.size() > shown) std::cout << "  (showing " << shown << " of " << issues.size() << " findings)\n";
  for (const Issue& issue : std::vector<Issue>(issues.begin(), issues.begin() + std::min(shown, issues.size())))
    std::cout << "  " << severity_name(issue.severity) << " " << code_name(issue.code) << " "
              << terminal_safe(issue.path) << ": " << terminal_safe(issue.message) << "\n";
}

int run(const Options& options) {
  nlohmann::json report = {{"files", nlohmann::json::array()}};
  int worst = kExitOk;  // the highest exit status of any file's first error
  for (const std::string& file : options.files) {
    ReadOptions read = options.read;
    read.level = options.level == "full" ? ValidationLevel::Full : ValidationLevel::Quick;
    std::vector<Issue> issues = validate_file(file, read);
    // The verdict and the exit status are the whole file's; --max-issues only limits what is listed, errors first.
    for (const Issue& issue : issues)
      if (issue.severity == Severity::Error) {
        worst = std::max(worst, exit_status(issue.code));
        break;
      }
    if (issues.size() > options.max_issues)
      std::stable_partition(issues.begin(), issues.end(),
                            [](const Issue& issue) { return issue.severity == Severity::Error; });
    const size_t shown = std::min(options.max_issues, issues.size());
    if (options.json)
      report["files"].push_back({{"file", file},
                                 {"valid", !has_errors(issues)},
                                 {"issues", issues_json({issues.begin(), issues.begin() + shown})},
                                 {"issues_found", issues.size()}});
    else
      print_findings(file, issues, shown);
  }
  if (options.json) std::cout << to_text(report) << "\n";
  return worst;
}

}  // namespace

void add_validate_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<Options>();
  CLI::App* cmd =
      app.add_subcommand("validate", "Check assets against the format spec (exit 0 valid, 1 invalid, 2 unreadable)");
  cmd->add_option("files", options->files, "Asset files (.vox.h5)")->required();
  cmd->add_flag("--json", options->json, "Print findings as JSON on stdout");
  cmd->add_option("--level", options->level,
                  "quick: structure, types, shapes, ranges, tree; full: also the semantic rules")
      ->capture_default_str()
      ->check(CLI::IsMember({"quick", "full"}));
  cmd->add_option("--max-issues", options->max_issues,
                  "List at most this many findings per file, errors first (the verdict and the exit status are "
                  "every finding's)")
      ->capture_default_str()
      ->transform(whole_number())
      ->check(finite_number());
  add_read_budget_option(cmd, options->read);
  cmd->footer(
      "\nExamples:\n"
      "  voxfmt validate bunny.vox.h5                      # every rule of the spec, every voxel (full)\n"
      "  voxfmt validate --level quick assets/*.vox.h5     # the structure only, quicker\n"
      "  voxfmt validate --json bunny.vox.h5 | jq '.files[].issues'  # findings for a script\n");
  cmd->callback([options, &exit_code] { exit_code = run(*options); });
}

}  // namespace voxfmt::cli
