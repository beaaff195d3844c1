// voxfmt: the one command-line front end of the toolchain.
#include <CLI/CLI.hpp>

#include <csignal>
#include <iostream>

#include "commands.h"
#include "voxfmt/asset.h"
#include "voxfmt/version.h"

int main(int argc, char** argv) {
  // A file-size limit (ulimit -f) must make a write fail with EFBIG, reported as WRITE_FAILED with the temporary
  // removed, not kill the process with SIGXFSZ and leave the temporary behind. (CPython ignores it too.)
  std::signal(SIGXFSZ, SIG_IGN);
  CLI::App app{"voxfmt — bake, inspect, validate and export Voxmap-PointShell collision assets (.vox.h5)"};
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
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return voxfmt::cli::kExitUsageOrIo;
  }
  return exit_code;
}
