// The options of one bake, shared by `voxfmt build` (which runs it) and `voxfmt batch` (which forwards them to
// a `voxfmt build` child per mesh): one registration, one canonical form.
#pragma once

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <string>
#include <vector>

#include "voxfmt/bake/bake.h"

namespace voxfmt::cli {

/// Registers --resolution, --voxel-size, --points, ..., --deflate, --threads on `cmd`.
void add_bake_options(CLI::App& cmd, bake::Settings& settings);

/// The same settings as `voxfmt build` arguments (every option spelled out, numbers round-trip exactly), so a
/// child process bakes with exactly these settings.
std::vector<std::string> bake_option_args(const bake::Settings& settings);

/// What an asset's provenance records as `build_parameters` for these settings (bake::build_parameters_json).
nlohmann::json build_parameters(const bake::Settings& settings);

}  // namespace voxfmt::cli
