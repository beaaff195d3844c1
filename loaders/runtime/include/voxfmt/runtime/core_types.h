// The one definition of the data a loaded asset is made of, as plain structs: SparseVoxelmap and PointTree hold
// these, and the query core's host/device functions (the CPU runtime and the CUDA kernels alike) read them. No
// Eigen, no allocation, nothing nvcc cannot compile. Use them through SparseVoxelmap and PointTree.
#pragma once

#include <cstdint>

#if defined(__CUDACC__)
#define VOXFMT_HD __host__ __device__ __forceinline__
// A device function called from several places of a kernel, kept out of line there: inlined at each, the batch
// kernel's code outgrew the instruction cache (measured: docs/gpu.md). Inlined in what the C++ compiler builds (the
// CPU runtime), as VOXFMT_HD.
#define VOXFMT_HD_OUTLINE __host__ __device__ __noinline__ inline
#else
#define VOXFMT_HD [[gnu::always_inline]] inline
#define VOXFMT_HD_OUTLINE VOXFMT_HD
#endif

namespace voxfmt::runtime {

/// What the field says at a point, in voxel units of the map (multiply by voxel_size for metres).
struct FieldSample {
  float distance = 0.0f;  ///< signed distance estimate, negative inside
  bool exact = false;     ///< true: interpolated from stored distances only; false: estimates or bounds
  bool bound = false;     ///< only a lower bound: outside the grid (core::sample says which)
};

namespace core {

struct Vec3 {
  float x = 0, y = 0, z = 0;
  VOXFMT_HD float operator[](int a) const { return a == 0 ? x : a == 1 ? y : z; }
};

using Sample = FieldSample;

/// How a voxelmap's arrays are read (voxel units throughout): their shapes and the numbers that decode them,
/// fixed at load. The arrays themselves are the voxelmap's; core::Field adds views of them.
struct FieldLayout {
  /// codes and lattice hold kGatherPadding elements more and their indices fit 31 bits (field_simd.h): vector
  /// gathers may read them. A runtime voxelmap's field is; one built by hand is not.
  bool gather_safe = false;
  int dims[3] = {0, 0, 0};
  int brick_dims[3] = {0, 0, 0};
  int lattice_dims[3] = {0, 0, 0};
  float decode_step[2] = {1, 1};  ///< a code's multiplier by its lowest bit: estimate, stored distance
  float stored_slack = 0;         ///< how far a decoded stored distance may be from the file's exact one
  // An estimate m bounds the exact distance u (spec §3.3): u <= m + slack, u >= (m - offset) * shrink - slack, with
  // slack the interpolation's reach (4 sqrt(3)) and half an estimate step, offset the lattice's absolute error and
  // shrink 1 / (1 + its relative error).
  float estimate_slack = 0;
  float estimate_offset = 0;
  float estimate_shrink = 1;
  /// The slack of a value brick's estimate: estimate_slack where it is interpolated (2.1); where it is settled (2.2),
  /// the reach of the paths to the nearest lattice point and back (8 sqrt(3)) and their rounding.
  float value_estimate_slack = 0;
  float band_edge = 0;             ///< distance_band - 1/2: voxels without a stored distance are at least this far
  float lattice_step = 1.0f / 16;  ///< the lattice's unit (16-bit unsigned distances), voxels
  Vec3 cover_max{-1, -1, -1};      ///< upper end of the grid's voxels, grid coordinates (an empty grid: none)
  Vec3 object_min, object_max;     ///< the object's bounding box, grid coordinates
};

/// A node of the point-sphere tree (spec §4), what a traversal reads of it before it knows whether the node's
/// point is needed: one cache line holds two, and a node's children are contiguous. A 16-byte node of quantised
/// values was measured no faster (bench/results/sampled-gradient): the floats stay.
struct alignas(32) Node {
  Vec3 centre;       ///< centre of the sphere around the node's point and its descendants (metres, from the anchor)
  float radius = 0;  ///< metres
  /// |centre - parent's centre| + radius (metres; 0 for the root): a parent's distance bound minus this bounds
  /// the node's, so a child out of reach is dropped without a lookup of its own.
  float reach_from_parent = 0;
  /// |centre - parent's point| + radius: the same from the parent's point, whose bound is known too.
  float reach_from_parent_point = 0;
  uint32_t first_child = 0;
  uint32_t child_count = 0;
};
static_assert(sizeof(Node) == 32, "two nodes per cache line");

}  // namespace core
}  // namespace voxfmt::runtime
