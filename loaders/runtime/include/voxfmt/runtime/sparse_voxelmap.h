// Bricked, quantised voxelmap for runtime queries: the dense grids of an asset (spec §3) in a few MB.
//
// The grid is cut into 8x8x8 bricks, each described by an 8-byte header. Bricks that touch the band of stored
// distances keep one 16-bit value per voxel: the stored distance in fixed point, or minus the layer where none
// is stored, the lowest bit saying which; a lookup there is one header and one cache line. Other bricks
// keep layers only: within a brick 6-neighbour layers differ by at most 1, so every layer is the brick's
// minimum plus a 4-bit offset (range <= 21 would need 5 bits in theory; bricks that need more are kept with
// 8-bit offsets). Bricks whose voxels are all farther outside than `outer_layers_kept` become one value in the
// header (a lower bound, good for pruning but not for proximity).
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "voxfmt/asset.h"

namespace voxfmt::runtime {

/// What the field says at a point, in voxel units of the map (multiply by voxel_size for metres).
struct FieldSample {
  float distance = 0.0f;  ///< signed distance estimate, negative inside
  bool exact = false;     ///< true: trilinear interpolation of stored distances; false: from layers or bounds
  bool bound = false;     ///< only a lower bound: outside the grid, or far outside where bricks keep no layers
};

class SparseVoxelmap {
 public:
  struct Options {
    /// Outer layers kept voxel by voxel; farther outside a brick keeps only a lower bound of the distance.
    /// Proximity queries are exact up to about this many voxels outside the surface.
    int outer_layers_kept = 8;
  };

  /// What the layers beyond the distance band promise about the exact depth (spec §3), which decides the
  /// bounds used for pruning.
  enum class LayerAccuracy {
    /// Format 1.0 (a 26-neighbour chamfer): at most ~11 % deeper than the exact depth, never shallower.
    Chamfer,
    /// Format 1.1: never shallower than the exact depth - 1/2 voxel, at most 1/2 + sqrt(3) voxels deeper.
    WithinSqrt3,
  };

  SparseVoxelmap() = default;
  /// Compresses `dense` (validated asset grids). `bounds_min/max` is the object's bounding box (asset frame);
  /// points outside the grid get their distance bound from it.
  static SparseVoxelmap from_dense(const voxfmt::Voxelmap& dense, const voxfmt::Vec3& bounds_min,
                                   const voxfmt::Vec3& bounds_max, const Options& options,
                                   LayerAccuracy accuracy = LayerAccuracy::WithinSqrt3);

  /// Grid coordinates (voxel centres at integers) of a point given in the asset frame.
  Eigen::Vector3f to_grid(const Eigen::Vector3d& asset_point) const {
    return ((asset_point - origin_) / voxel_size_).cast<float>();
  }
  /// Signed distance at grid coordinates `u`: trilinear interpolation of the 8 surrounding voxels, each
  /// contributing its stored distance or, where none is stored, minus its layer (spec §3: layer l means a
  /// distance within half a voxel of -l). Outside the grid: the distance to the object's bounding box.
  /// If `gradient` is given it receives the direction of increasing distance (grid axes = asset axes, not
  /// normalised; zero where the field is flat).
  FieldSample sample(const Eigen::Vector3f& u, Eigen::Vector3f* gradient = nullptr) const;
  /// A value the true signed distance at `u` is not below (voxel units). Used to prune sphere-tree clusters.
  float distance_lower_bound(const Eigen::Vector3f& u) const;

  /// Layer of voxel (i, j, k) (clamped bricks report their bound; where a distance is stored, the layer it
  /// implies, spec §3), for tests and inspection.
  int layer_at(int i, int j, int k) const;
  /// Stored distance of voxel (i, j, k) in voxel units, or NaN where the asset stores none.
  float stored_distance_at(int i, int j, int k) const;

  double voxel_size() const { return voxel_size_; }
  const Eigen::Vector3d& origin() const { return origin_; }
  const std::array<int, 3>& dims() const { return dims_; }
  bool empty() const { return bricks_.empty(); }
  /// Heap bytes held (what the map costs in RAM).
  size_t memory_bytes() const;
  size_t brick_count() const { return bricks_.size(); }
  /// Bricks that keep layers only, and bricks that keep a value per voxel (those touching the distance band).
  size_t layer_brick_count() const;
  size_t distance_brick_count() const { return value_pool_.size() / kBrickVoxels; }

  static constexpr int kBrickEdge = 8;
  static constexpr int kBrickVoxels = kBrickEdge * kBrickEdge * kBrickEdge;

 private:
  enum class BrickKind : uint8_t { FarOutside, Nibbles, Bytes, Values };
  struct Brick {
    int16_t layer_base = 0;  ///< Nibbles/Bytes: minimum layer; FarOutside: the layer closest to the surface
    BrickKind kind = BrickKind::FarOutside;
    uint8_t unused = 0;
    uint32_t data = 0;  ///< Nibbles/Bytes: byte offset into layer_pool_; Values: brick index into value_pool_
  };
  static_assert(sizeof(Brick) == 8, "headers stay small enough to live in cache");

  // Voxel fetches; (i, j, k) must lie inside the grid.
  const Brick& brick_of(int i, int j, int k, int& local) const;
  int layer_in(const Brick& brick, int local) const;
  /// A Values brick's voxel: the stored distance (exact) or minus the layer, in voxel units.
  float value_in(const Brick& brick, int local, bool& exact) const;
  /// A voxel's value for interpolation: its stored distance, else minus its layer (clearing `exact`; setting
  /// `bound` where a far brick keeps only a bound).
  float estimate_in(const Brick& brick, int local, bool& exact, bool& bound) const;
  /// The lowest signed distance a voxel of this layer can have (voxel units).
  float layer_lower_bound(float layer) const;
  float bounds_distance(const Eigen::Vector3f& u) const;
  /// True if `u` lies within the grid's voxels (a voxel's cell extends half a voxel around its centre).
  bool covers(const Eigen::Vector3f& u) const;

  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  double voxel_size_ = 1.0;
  std::array<int, 3> dims_{};
  std::array<int, 3> brick_dims_{};
  float value_scale_ = 1.0f;             ///< fixed-point steps per voxel of the Values bricks
  float value_step_ = 1.0f;              ///< 1 / value_scale_
  float decode_step_[2] = {1.0f, 1.0f};  ///< a value's multiplier by its lowest bit: layer 1, distance value_step_
  float value_slack_ = 0.0f;  ///< half a step (and float rounding): how far a decoded distance may be from the file's
  LayerAccuracy layer_accuracy_ = LayerAccuracy::WithinSqrt3;
  Eigen::Vector3f cover_max_ = -Eigen::Vector3f::Ones();  ///< upper end of the grid's voxels, grid coordinates
  Eigen::Vector3f object_min_ = Eigen::Vector3f::Zero();  ///< object bounding box, grid coordinates
  Eigen::Vector3f object_max_ = Eigen::Vector3f::Zero();
  std::vector<Brick> bricks_;
  std::vector<uint8_t> layer_pool_;
  /// (fixed-point distance << 1) | 1 where a distance is stored, (-layer) << 1 elsewhere.
  std::vector<int16_t> value_pool_;
};

}  // namespace voxfmt::runtime
