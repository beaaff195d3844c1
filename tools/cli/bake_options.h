// The options of one bake, shared by `voxfmt build` (which runs it) and `voxfmt batch` (which forwards them to
// a `voxfmt build` child per mesh): one registration, one canonical form.
#pragma once

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <string>
#include <vector>

#include "bake.h"

namespace voxfmt::cli {

struct BakeSettings {
  bake::BuildOptions build;
  int deflate = 4;      ///< gzip level of the voxel grids
  bool verify = true;   ///< run the full validator on the asset before writing it
};

/// Registers --resolution, --voxel-size, --points, ..., --threads, --no-verify on `cmd`.
void add_bake_options(CLI::App& cmd, BakeSettings& settings);

/// The same settings as `voxfmt build` arguments (every option spelled out, numbers round-trip exactly), so a
/// child process bakes with exactly these settings.
std::vector<std::string> bake_option_args(const BakeSettings& settings);

/// What an asset's provenance records as `build_parameters` for these settings (the options that change the
/// data; not --deflate, --threads or --no-verify).
nlohmann::json build_parameters(const BakeSettings& settings);

}  // namespace voxfmt::cli
