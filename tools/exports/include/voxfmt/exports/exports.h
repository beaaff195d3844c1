// voxfmt::exports — an asset's structures in the files other tools read: a voxelmap slice as a PNG picture,
// the point shell as PLY (MeshLab, Blender, CloudCompare), the voxelmap as OpenVDB grids (Houdini, Blender,
// vdb_view). Every file is written atomically (a temporary beside it, renamed over it). OpenVDB and libpng stay inside
// this library: no header here includes them.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/result.h"

namespace voxfmt::exports {

// ---- A small RGB raster with a built-in 5x7 bitmap font, written as PNG (libpng): inspect's slice pictures and the
// examples' scene pictures.

struct Rgb {
  uint8_t r = 0, g = 0, b = 0;
};

class RasterImage {
 public:
  RasterImage(int width, int height, Rgb background);
  int width() const { return width_; }
  int height() const { return height_; }
  /// Pixels outside the image are ignored (drawing clips).
  void set(int x, int y, Rgb colour);
  Rgb get(int x, int y) const;
  void fill_rect(int x, int y, int w, int h, Rgb colour);
  /// Draws text with the built-in font (upper case, digits, - . , = + ( ) : / ? and space; lower case is drawn
  /// as upper case, anything else as '?'), each font pixel `scale` x `scale`. Returns the width drawn.
  int text(int x, int y, const std::string& text, int scale, Rgb colour);
  static int text_width(const std::string& text, int scale) {
    return int(text.size()) * 6 * scale - (text.empty() ? 0 : scale);
  }
  static int text_height(int scale) { return 7 * scale; }

  /// Writes 8-bit RGB PNG atomically; WRITE_FAILED naming the path on failure.
  Status write_png(const std::string& path) const;

 private:
  int width_, height_;
  std::vector<uint8_t> rgb_;
};

// ---- Asset exports.

// ---- slice picture

struct SliceSpec {
  int axis = 2;  ///< 0 = x, 1 = y, 2 = z: the slice is the plane of voxels with this index
  int64_t index = 0;
  bool distances = false;  ///< colour by stored distance (grey where none) instead of by layer
  int zoom = 0;            ///< pixels per voxel; 0 = automatic (the map ~900 px on its long side, 1..16)
};
/// Parses "z=40" (axis x, y or z, case-insensitive); BAD_OPTION with a message otherwise.
Result<SliceSpec> parse_slice(const std::string& text);

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
/// from the stored distances; a colour bar with tick labels) and writes it as PNG. BAD_OPTION for an index
/// outside the grid, WRITE_FAILED when the file cannot be written.
Result<SliceInfo> write_slice_png(const Asset& asset, const SliceSpec& spec, const std::string& path);

// ---- point shell

struct PlyInfo {
  uint32_t level = 0, levels = 0;
  uint64_t points = 0;
};
/// Writes points [0, level_offsets[level + 1]) (the tree down to `level`; -1 = the finest) as binary
/// little-endian PLY with float x y z nx ny nz. Normals are written outward (flipped from the asset's inward
/// normals) as viewers expect, unless `inward`. BAD_OPTION for a level the tree does not have, WRITE_FAILED.
Result<PlyInfo> write_point_shell_ply(const Asset& asset, int level, bool inward, const std::string& path);

// ---- OpenVDB

struct VdbInfo {
  uint64_t distance_voxels = 0;  ///< active voxels of the "distance" grid: the stored band
  uint64_t layer_voxels = 0;     ///< voxels of the "layers" grid (the whole voxelmap)
};
/// Writes two grids in metres, asset voxel (i, j, k) being VDB voxel (i, j, k) with its centre at
/// origin + voxel_size * (i, j, k): "distance", a level set (class GRID_LEVEL_SET) whose active voxels are the
/// stored signed distances and whose background is distance_band * voxel_size, negative inside; and "layers",
/// every voxel's layer (int32; constant regions become tiles). WRITE_FAILED naming the path on failure.
Result<VdbInfo> write_voxelmap_vdb(const Asset& asset, const std::string& path);

}  // namespace voxfmt::exports
