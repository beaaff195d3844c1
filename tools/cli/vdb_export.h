// The voxelmap as OpenVDB grids, for tools that read .vdb (Houdini, Blender, vdb_view, OpenVDB's own tools).
#pragma once

#include <cstdint>
#include <string>

#include "voxfmt/asset.h"

namespace voxfmt::cli {

struct VdbInfo {
  uint64_t distance_voxels = 0;  ///< active voxels of the "distance" grid: the stored band
  uint64_t layer_voxels = 0;     ///< voxels of the "layers" grid (the whole voxelmap)
};

/// Writes two grids in metres, asset voxel (i, j, k) being VDB voxel (i, j, k) with its centre at
/// origin + voxel_size * (i, j, k): "distance", a level set (class GRID_LEVEL_SET) whose active voxels are the
/// stored signed distances and whose background is distance_band * voxel_size, negative inside; and "layers",
/// every voxel's layer (int32; constant regions become tiles). Written to a temporary file and renamed into
/// place; throws std::runtime_error naming the path when that fails.
VdbInfo write_voxelmap_vdb(const Asset& asset, const std::string& path);

}  // namespace voxfmt::cli
