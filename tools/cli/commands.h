// Subcommands of the one `voxfmt` CLI. Each registers itself on the app and sets the process exit code.
#pragma once

#include <CLI/CLI.hpp>

#include "voxfmt/result.h"

namespace voxfmt::cli {

/// Exit codes shared by every subcommand.
enum ExitCode : int { kExitOk = 0, kExitInvalid = 1, kExitUsageOrIo = 2 };

/// The exit code for an error: one table for every subcommand (exit_status.cpp).
int exit_status(IssueCode code);
/// Prints "voxfmt COMMAND: error: CODE: message" on stderr and returns exit_status(error.code).
int report_error(const char* command, const Error& error);

void add_build_command(CLI::App& app, int& exit_code);
void add_batch_command(CLI::App& app, int& exit_code);
void add_inspect_command(CLI::App& app, int& exit_code);
void add_validate_command(CLI::App& app, int& exit_code);
void add_upgrade_command(CLI::App& app, int& exit_code);

}  // namespace voxfmt::cli
