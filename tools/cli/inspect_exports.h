// Files `voxfmt inspect` can write besides its summary: a picture of one voxelmap slice, the point shell as PLY.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>

#include "voxfmt/asset.h"

namespace voxfmt::cli {

/// A request the asset cannot satisfy (slice or level out of range): a usage error.
struct ExportRangeError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// ---- slice picture

struct SliceSpec {
  int axis = 2;          ///< 0 = x, 1 = y, 2 = z: the slice is the plane of voxels with this index
  int64_t index = 0;
  bool distances = false;  ///< colour by stored distance (grey where none) instead of by layer
  int zoom = 0;            ///< pixels per voxel; 0 = automatic (the map ~900 px on its long side, 1..16)
};
/// Parses "z=40" (axis x, y or z, case-insensitive); throws std::invalid_argument with a message.
SliceSpec parse_slice(const std::string& text);

// Picture layout: margin 10 px, a title line, the map (P x P pixels per voxel), a legend panel on the right.
// So the PNG is (P * columns + 200) x (max(P * rows, 240) + 42) pixels, where the slice z=k has columns x
// (left to right) and rows y (bottom to top), y=j: x and z, x=i: y and z.
constexpr int kSliceExtraWidth = 200, kSliceExtraHeight = 42, kSliceMinMapHeight = 240;

struct SliceInfo {
  int width = 0, height = 0;  ///< of the PNG, pixels
  int zoom = 0;
  uint32_t columns = 0, rows = 0;  ///< voxels
  bool has_surface = false;        ///< the zero contour of the stored distances crosses this slice
};
/// Renders the slice (diverging colour map, inside red, outside blue; the surface d = 0 as a black contour
/// from the stored distances; a colour bar with tick labels) and writes it as PNG. Throws ExportRangeError for
/// an index outside the grid and std::runtime_error when the file cannot be written.
SliceInfo write_slice_png(const Asset& asset, const SliceSpec& spec, const std::string& path);

// ---- point shell

struct PlyInfo {
  uint32_t level = 0, levels = 0;
  uint64_t points = 0;
};
/// Writes points [0, level_offsets[level + 1]) (the tree down to `level`; -1 = the finest) as binary
/// little-endian PLY with float x y z nx ny nz. Normals are written outward (flipped from the asset's inward
/// normals) as viewers expect, unless `inward`. Throws ExportRangeError / std::runtime_error.
PlyInfo write_point_shell_ply(const Asset& asset, int level, bool inward, const std::string& path);

}  // namespace voxfmt::cli
