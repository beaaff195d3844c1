// voxfmt: the one command-line front end of the toolchain.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <csignal>
#include <exception>
#include <iostream>
#include <new>
#include <string>
#include <utility>
#include <vector>

#include "commands.h"
#include "voxfmt/asset.h"
#include "voxfmt/version.h"

namespace {
const char* command_name(const CLI::App& app) {
  const auto used = app.get_subcommands();
  return used.empty() ? "(no command)" : used.front()->get_name().c_str();
}

// Whether the command line asks for JSON: `--json`, or `--json=V` with V a value CLI11 reads as true (the last
// one counts, as in CLI11). Needed where CLI11 itself refused the line, so that its error is JSON too.
bool json_requested(int argc, char** argv) {
  bool json = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--") break;
    if (arg == "--json") json = true;
    if (arg.rfind("--json=", 0) != 0) continue;
    // CLI11's own reading of a flag's value, so that every spelling it takes as true ("2", "on", ...) asks for JSON.
    bool value = false;
    json = CLI::detail::lexical_cast(arg.substr(7), value) && value;
  }
  return json;
}
}  // namespace

int main(int argc, char** argv) {
  // A file-size limit (ulimit -f) must make a write fail with EFBIG, reported as WRITE_FAILED with the temporary
  // removed, not kill the process with SIGXFSZ and leave the temporary behind. (CPython ignores it too.)
  std::signal(SIGXFSZ, SIG_IGN);
  CLI::App app{"voxfmt — bake, inspect, validate and export Voxmap-PointShell collision assets (.vox.h5)"};
  app.name("voxfmt");  // the help says "voxfmt", not the path it was started by
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("voxfmt ") + VOXFMT_VERSION_STRING + " (asset format " +
                                        std::to_string(voxfmt::kFormatVersion.major) + "." +
                                        std::to_string(voxfmt::kFormatVersion.minor) + ")");
  int exit_code = voxfmt::cli::kExitOk;
  voxfmt::cli::add_build_command(app, exit_code);
  voxfmt::cli::add_batch_command(app, exit_code);
  voxfmt::cli::add_inspect_command(app, exit_code);
  voxfmt::cli::add_validate_command(app, exit_code);
  voxfmt::cli::add_upgrade_command(app, exit_code);
  voxfmt::cli::add_export_command(app, exit_code);
  voxfmt::cli::add_report_command(app, exit_code);
  if (argc < 2) {  // no command: the overview, not CLI11's one line
    std::cerr << app.help();
    return voxfmt::cli::kExitUsageOrIo;
  }
  const std::vector<const CLI::App*> commands = std::as_const(app).get_subcommands(nullptr);
  const auto named = [&](const CLI::App* command) { return command->get_name() == argv[1]; };
  if (argv[1][0] != '-' && std::none_of(commands.begin(), commands.end(), named)) {
    std::cerr << "voxfmt: unknown command '" << voxfmt::terminal_safe(argv[1]) << "' (commands:";
    for (const CLI::App* command : commands) std::cerr << " " << command->get_name();
    std::cerr << "; voxfmt --help)\n";
    return voxfmt::cli::kExitUsageOrIo;
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // CLI11's message with the one error model's code; the help is one option away.
    const std::string command = command_name(app);
    // With --json the error is JSON on stdout too, as every command's own errors are.
    const bool json = json_requested(argc, argv);
    voxfmt::cli::report_error(command.c_str(), {voxfmt::IssueCode::BadOption, e.what()}, json, "");
    std::cerr << "run 'voxfmt " << (command == "(no command)" ? "" : command + " ") << "--help' for the options\n";
    return voxfmt::cli::kExitUsageOrIo;
  } catch (const std::bad_alloc&) {
    return voxfmt::cli::report_error(command_name(app), {voxfmt::IssueCode::OutOfMemory, "out of memory"});
  } catch (const std::exception& e) {
    // Every command returns coded errors; an exception here is our bug, still reported as one coded line.
    return voxfmt::cli::report_error(command_name(app),
                                     {voxfmt::IssueCode::Internal, std::string("unexpected error: ") + e.what()});
  }
  // What was printed must have reached stdout: `--json > report.json` on a full disk is a failure, not an empty
  // report and exit 0.
  if (!std::cout.flush())
    return std::max(exit_code,
                    voxfmt::cli::report_error(command_name(app), {voxfmt::IssueCode::WriteFailed,
                                                                  "standard output: cannot write what was printed"}));
  return exit_code;
}
