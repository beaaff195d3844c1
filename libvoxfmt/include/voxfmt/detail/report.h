// The summary of an asset that `voxfmt inspect --json` prints and Python's `voxfmt.inspect()` returns: one
// builder for both, so their keys cannot drift apart.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/result.h"

namespace voxfmt {

/// Figures of an asset that are not stored in it as such.
struct AssetSummary {
  uint64_t file_size = 0;     ///< bytes of `file` on disk (0 if it cannot be read)
  uint64_t memory_bytes = 0;  ///< the voxelmap and the point shell in memory
  size_t stored_distances = 0;
  int layer_min = 0, layer_max = 0;
  size_t value_bricks = 0, coarse_bricks = 0;
  std::vector<uint32_t> points_per_level;
};

AssetSummary summarize_asset(const std::string& file, const Asset& asset);

/// The inspect summary as a JSON object (file, format_version, bounds, voxelmap, pointshell, mass_properties,
/// provenance, warnings, ...). `warnings` are those read_asset returned.
std::string inspect_json(const std::string& file, const Asset& asset, const AssetSummary& summary,
                         const std::vector<Issue>& warnings);

}  // namespace voxfmt
