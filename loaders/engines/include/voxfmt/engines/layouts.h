// voxfmt::engines — a loaded asset's distance field in the layouts other engines read, built from the runtime's own
// field so that every value they sample is the runtime's:
//
// - the *texture SDF* of Newton (and, nearly, PhysX's PxSDFDesc): a float coarse grid at brick corners, bricks of
//   8 cells stored as 9^3 samples (a one-voxel apron, so a trilinear sample stays in one brick) packed into one 3D
//   texture, a slot per brick, values quantised over one global range;
// - NanoVDB grids (Warp's wp.Volume, NanoVDB's own tools): the distance as a float level set whose leaves are the
//   value bricks (NanoVDB's leaves are 8^3, like the bricks) and a coarse grid of the lattice for the far field.
//
// Both place sample (i, j, k) at the asset's voxel centre origin + voxel_size * (i, j, k). A sample past the grid's
// last voxel along an axis (the layouts round the grid up to whole bricks) is the nearest voxel's value plus the
// distance to it: beyond the grid is outside the object's bounding box.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "voxfmt/result.h"
#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::engines {

// ---- Texture SDF (Newton's layout)

enum class TextureFormat { Float32, Uint16, Uint8 };

struct TextureSdfOptions {
  TextureFormat format = TextureFormat::Uint16;
  /// A brick without codes is stored as a brick (not interpolated from the coarse grid) where the coarse grid's
  /// interpolation would differ from the runtime's value by more than this (voxels) at one of its samples inside
  /// the grid; negative: the asset's estimate quantum (1/16 voxel from `voxfmt build`), the step in which the asset
  /// itself stores estimates. Bricks with codes are always stored: near the surface the texture is the runtime's
  /// field within the texture's quantum.
  double coarse_tolerance_voxels = -1;
};

struct TextureSdf {
  static constexpr int kCells = 8;    ///< cells per brick along an axis
  static constexpr int kSamples = 9;  ///< samples per brick along an axis (the apron repeats the next brick's first)
  static constexpr uint32_t kEmpty = 0xFFFFFFFFu;  ///< a brick read from the coarse grid

  std::array<double, 3> lower{};  ///< sample (0, 0, 0): the asset's voxel (0, 0, 0), metres
  double cell = 0;                ///< sample spacing: the voxel size, metres
  std::array<int, 3> bricks{};    ///< per axis: ceil((dims - 1) / 8), at least 1; the coarse grid has one more
  /// Signed distances (metres) at brick corners, (bricks + 1) per axis, x fastest then y then z.
  std::vector<float> coarse;
  /// Per brick, x fastest: the brick's block in the packed texture, (bz << 20) | (by << 10) | bx, or kEmpty.
  std::vector<uint32_t> slots;
  int blocks_per_side = 0;  ///< the packed texture holds blocks_per_side^3 blocks of 9^3 samples
  int texture_side = 0;     ///< samples per side of the packed texture (blocks_per_side * 9; 1 when empty)
  TextureFormat format = TextureFormat::Uint16;
  /// The packed texture, texture_side^3 samples x fastest, each a float32, uint16 or uint8 (native byte order).
  std::vector<uint8_t> texels;
  /// A sample's metres: value_min + value_range * code / max_code (uint16: 65535, uint8: 255); float32 texels are
  /// metres themselves (value_min 0, value_range 1).
  float value_min = 0, value_range = 1;
  size_t value_bricks = 0;   ///< bricks stored because the asset keeps codes there (near the surface)
  size_t coarse_stored = 0;  ///< coarse bricks stored because the coarse grid would not reproduce them
  /// Largest difference between a stored sample's decoded value and the runtime's (metres): the quantisation.
  double max_quantisation_error = 0;
};

/// The texture SDF of a loaded asset's voxelmap. INVALID_ASSET for an object without one; OUT_OF_MEMORY when the
/// packed texture would need more than 1024 blocks along a side (Newton's 10-bit block coordinates).
Result<TextureSdf> texture_sdf(const runtime::CollisionObject& object, const TextureSdfOptions& options = {});

// ---- NanoVDB grids (Warp's volumes)

struct NanoVdbOptions {
  /// Half-width of the "distance" level set, voxels (up to 32767; negative: BAD_OPTION): every brick with a voxel
  /// nearer than that is a leaf, its values clamped to +-(width + √3) (tiles hold +-width); 0 = the band the asset
  /// stores completely,
  /// distance_band - 1/2 (2.5 voxels from `voxfmt build`'s default band): the leaves are then the asset's value bricks,
  /// and every voxel within the width holds its exact distance.
  double width_voxels = 0;
  bool compress = true;  ///< ZIP codec (Warp and NanoVDB's tools read it); off: uncompressed
};

struct NanoVdbGrids {
  std::string file;  ///< the two grids as one .nvdb file's bytes ("distance", then "coarse")
  double width = 0;  ///< the level set's half-width, metres (its background)
  uint64_t distance_leaves = 0, distance_active_voxels = 0;
  uint64_t coarse_voxels = 0;       ///< samples of the "coarse" grid: the lattice, one every 8 voxels
  uint64_t uncompressed_bytes = 0;  ///< the grids' size in memory (what a loaded wp.Volume holds)
};

/// Two float32 NanoVDB grids in metres, index (i, j, k) at origin + voxel_size * (i, j, k):
/// - "distance", class LevelSet: the value bricks (and any coarse brick with a voxel nearer than the width) as
///   leaves, every voxel active, values the runtime's clamped to +-(width + √3 voxels), so that a cell with a
///   corner within the width is the runtime's at every corner; elsewhere tiles of -width inside and
///   +width outside (the signs of the asset's brick table, not a flood fill, so open meshes keep theirs);
/// - "coarse", class Unknown, voxel size 8 * voxel_size, index (a, b, c) at the lattice point of voxel (8a, 8b, 8c):
///   the asset's lattice, unsigned distances (every point active). Beyond the level set's width the runtime's
///   value is this grid interpolated, at least the band's edge, with the sign the level set's tiles carry: one
///   coarse grid cannot hold that sign itself where the inside changes without a surface (across a hole's cap).
/// Each grid carries, as its blind data named "voxfmt", a JSON object: the grid's meaning, units (metres), the
/// asset's provenance (source file and SHA-256, generator, build parameters, time), voxel size, band and width
/// (grid_metadata_json). INVALID_ASSET for an object without a voxelmap.
Result<NanoVdbGrids> nanovdb_grids(const runtime::CollisionObject& object, const NanoVdbOptions& options = {});

/// The JSON object the grids carry: `grid` is "distance" or "coarse", `width` the level set's half-width (m).
std::string grid_metadata_json(const runtime::CollisionObject& object, const std::string& grid, double width);

}  // namespace voxfmt::engines
