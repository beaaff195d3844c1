// Subcommands of the one `voxfmt` CLI. Each registers itself on the app and sets the process exit code.
#pragma once

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <string>

#include "report.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/detail/utf8.h"
#include "voxfmt/io.h"
#include "voxfmt/result.h"

namespace voxfmt::cli {

/// Exit codes shared by every subcommand.
enum ExitCode : int { kExitOk = 0, kExitInvalid = 1, kExitUsageOrIo = 2 };

/// The exit code for an error: one table for every subcommand (exit_status.cpp).
int exit_status(IssueCode code);
/// Prints "voxfmt COMMAND: error: CODE: message" on stderr and returns exit_status(error.code).
int report_error(const char* command, const Error& error);
/// The same and, with `json` (the command's --json), the error on stdout too as `build --json` prints it
/// ({"status": "error", "input", "code", "message"}): a script reading stdout sees the failure.
int report_error(const char* command, const Error& error, bool json, const std::string& input);

/// A count written in decimal digits only (MiB, points): "1e3", "0x10", "-1" or "2.5" are refused as not a whole
/// number, where the integer conversion would read some of them its own way or call them out of range. Leading
/// zeros are dropped (CLI11 reads "010" as octal 8), and a count beyond 2^64 - 1 is refused (it would be clamped).
inline CLI::Validator whole_number() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        if (text.empty() || text.find_first_not_of("0123456789") != std::string::npos)
          return "must be a whole number in decimal digits, not '" + text + "'";
        text.erase(0, std::min(text.find_first_not_of('0'), text.size() - 1));
        if (text.size() > 20 || (text.size() == 20 && text > "18446744073709551615"))
          return "must be at most 18446744073709551615, not " + text;
        return "";
      },
      "");
}

/// `--max-memory MiB`: the read budget of a command that reads assets (voxfmt/io.h ReadOptions), into `options`.
inline void add_read_budget_option(CLI::App* cmd, ReadOptions& options) {
  cmd->add_option_function<uint64_t>(
         "--max-memory", [&options](uint64_t mib) { options.max_memory_bytes = mib << 20; },
         "MiB a read may use, decided from the file's metadata before anything is read (beyond: OUT_OF_MEMORY, "
         "exit 2; default " +
             std::to_string(ReadOptions::kDefaultReadMemoryBytes >> 20) + ", enough for a 2048^3 asset)")
      ->transform(whole_number())
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 40));
}

/// Refuses an empty path given explicitly (`--html ''`), which would otherwise read as "not asked for" and
/// silently write nothing.
inline CLI::Validator non_empty_path() {
  return CLI::Validator(
      [](std::string& path) { return path.empty() ? std::string("an empty path names no file or folder") : ""; }, "");
}

/// An output's path: non-empty, and not "-", which other tools read as standard output but would here be a file
/// named "-" (outputs are files or folders: an HDF5 asset, a NanoVDB file, a report are written and renamed into
/// place). `./-` still names that file.
inline CLI::Validator output_path() {
  return CLI::Validator(
      [](std::string& path) -> std::string {
        if (path.empty()) return "an empty path names no file or folder";
        if (path == "-") return "'-' (standard output) is not supported: outputs are written to a file (./- names one)";
        return "";
      },
      "");
}

/// A number that must be finite and above 0 (`at_least_zero`: or 0): NaN and infinity are refused, and the message
/// says so (CLI11's PositiveNumber names a range up to 1.8e308 that seems to hold 0).
inline CLI::Validator finite_number(bool at_least_zero = false) {
  return CLI::Validator(
      [at_least_zero](std::string& text) -> std::string {
        char* end = nullptr;
        const double value = std::strtod(text.c_str(), &end);
        // strtod also reads hexadecimal ("0x10" is 16): a decimal number only.
        const bool number = !text.empty() && end && *end == '\0' && text.find_first_of("xXpP") == std::string::npos;
        if (number && std::isfinite(value) && (value > 0 || (at_least_zero && value == 0))) return "";
        return "must be a finite number " + std::string(at_least_zero ? ">= 0" : "> 0") + ", not '" + text + "'";
      },
      at_least_zero ? "NUMBER >= 0" : "NUMBER > 0");
}

using bake::kMaxThreads;  // worker threads: 0 (every core) up to this

void add_build_command(CLI::App& app, int& exit_code);
void add_batch_command(CLI::App& app, int& exit_code);
void add_inspect_command(CLI::App& app, int& exit_code);
void add_validate_command(CLI::App& app, int& exit_code);
void add_upgrade_command(CLI::App& app, int& exit_code);
void add_export_command(CLI::App& app, int& exit_code);
void add_report_command(CLI::App& app, int& exit_code);

/// The report's one-line summary (`voxfmt report`, `batch --report`).
void print_report_summary(const report::ReportInfo& info);
/// The same as `report --json` prints it (and `batch --report --json` puts it under "report").
nlohmann::json report_summary_json(const report::ReportInfo& info);
/// "report: 120 / 143 meshes" on stderr when it is a terminal (nothing otherwise).
std::function<void(size_t, size_t)> report_progress();

}  // namespace voxfmt::cli
