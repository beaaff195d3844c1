// The signed distance field MuJoCo's SDF collisions ask for, in metres in the asset frame (the geom's frame).
// MuJoCo's search makes thousands of lookups per contacting pair and step, scattered over the object, so the
// voxelmap is re-laid for them at load: each brick near the surface (a value brick, and a coarse brick whose
// cells reach into one) becomes a 9x9x9 block of the runtime's voxel values (SparseVoxelmap::value_at) that
// repeats its neighbours' first layer, so a lookup reads one table entry and one block; every other cell is the
// asset's lattice. Both are interpolated by the query core's functions (core::trilinear, core::coarse_sample), so
// the field is the runtime's. Free of MuJoCo types, so it is tested on its own.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/field.h"
#include "voxfmt/asset.h"
#include "voxfmt/result.h"

namespace voxfmt::runtime {
class CollisionObject;
class SparseVoxelmap;
}  // namespace voxfmt::runtime

namespace voxfmt::mujoco {

class AssetField {
 public:
  /// Reads (in an isolated child process, as every voxfmt read) and validates an asset file of any supported
  /// format version, and builds its field. Errors are the reader's, or INVALID_ASSET for an asset without a
  /// voxelmap.
  static voxfmt::Result<std::shared_ptr<const AssetField>> load(const std::string& path);
  /// The field of an asset in memory (it must pass quick validation).
  static voxfmt::Result<std::shared_ptr<const AssetField>> from_asset(voxfmt::Asset asset);
  /// The field of a loaded object (already validated): its voxelmap's lattice, bricks and voxels as they are.
  static voxfmt::Result<std::shared_ptr<const AssetField>> from_object(const runtime::CollisionObject& object);

  /// Signed distance in metres, negative inside, and in `gradient` (may be null) the unit direction in which it
  /// grows. In the grid: the trilinear interpolation of the voxels' values (exact within the band: the stored
  /// distances), the same field as the runtime's SparseVoxelmap::sample. Beyond the grid: the value at the
  /// nearest grid point plus the distance to it, continuous at the grid's boundary and growing away from it.
  /// The gradient is never zero: where the field is flat (beyond the band, where the lattice underestimates) it
  /// points away from the object's centre, so a descent is never stranded.
  double evaluate(const double point[3], double gradient[3]) const;
  /// The two halves of evaluate, for callers that may not need the gradient: the distance and the gradient's
  /// direction as the field gives it (not normalised, possibly zero), and that direction made the unit gradient.
  double evaluate_raw(const double point[3], Eigen::Vector3f& direction) const;
  void unit_gradient(const Eigen::Vector3f& direction, const double point[3], double gradient[3]) const;

  /// The object's bounding box grown by `margin` (metres), as {centre xyz, half-size xyz}.
  void aabb(double margin, double box[6]) const;

  double voxel_size() const { return voxel_size_; }
  /// Heap bytes of the field (the blocks, the table and the lattice).
  size_t memory_bytes() const;
  /// Blocks built at load (value bricks and their coarse neighbours).
  size_t block_count() const { return blocks_.size() / kBlockValues; }

  // The asset's mass properties at unit density (asset frame), for tools that place the body.
  double volume() const { return volume_; }
  const Eigen::Vector3d& center_of_mass() const { return center_of_mass_; }
  const Eigen::Vector3d& bounds_min() const { return bounds_min_; }
  const Eigen::Vector3d& bounds_max() const { return bounds_max_; }

  static constexpr int kBlockEdge = 9;  ///< a brick's 8 voxels and its + neighbours' first
  static constexpr int kBlockValues = kBlockEdge * kBlockEdge * kBlockEdge;

 private:
  AssetField() = default;
  // The field (voxel units) and its gradient (voxel units per voxel) at grid coordinates inside the box of
  // voxel centres.
  float lookup(const Eigen::Vector3f& u, Eigen::Vector3f& gradient) const;
  // from_object's steps: the grid's geometry and the lattice; the blocks from the runtime's decoded voxels.
  void set_geometry(const runtime::CollisionObject& object);
  void fill_blocks(const voxfmt::runtime::SparseVoxelmap& map);

  double voxel_size_ = 1.0;
  double inverse_voxel_size_ = 1.0;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  Eigen::Vector3f grid_max_ = Eigen::Vector3f::Zero();  ///< the last voxel centre, grid coordinates
  /// The runtime's field: its layout and, in lattice_, its lattice; no brick table or codes (table_ and blocks_
  /// replace them), so only the lattice's functions may read it.
  runtime::core::Field field_;
  /// Per brick: >= 0 the first value of its block in blocks_; core::kCoarseOutside / kCoarseInside: the lattice's.
  std::vector<int32_t> table_;
  std::vector<float> blocks_;      ///< voxel units
  std::vector<uint16_t> lattice_;  ///< the runtime's lattice (field_.lattice)

  double volume_ = 0.0;
  Eigen::Vector3d center_of_mass_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d bounds_min_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d bounds_max_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d centre_ = Eigen::Vector3d::Zero();  ///< of the bounding box: the fallback direction's origin
};

}  // namespace voxfmt::mujoco
