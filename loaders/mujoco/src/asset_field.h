// The signed distance field MuJoCo's SDF collisions ask for, in metres in the asset frame (the geom's frame),
// read from a loaded asset's voxelmap. Free of MuJoCo types, so it is tested on its own.
#pragma once

#include <Eigen/Core>

#include <memory>

#include "voxfmt/result.h"
#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::mujoco {

class AssetField {
 public:
  /// The field of an object that has a voxelmap (BAD_OPTION otherwise: a point-shell-only asset has no field).
  static voxfmt::Result<std::shared_ptr<const AssetField>> from_object(
      std::shared_ptr<const voxfmt::runtime::CollisionObject> object);

  /// Signed distance in metres, negative inside. In the grid: the voxelmap's trilinear field (exact within the
  /// band: the stored distances interpolated). Beyond the grid: the value at the nearest grid point plus the
  /// distance to it, so the field is continuous at the grid's boundary and still grows away from the object.
  double distance(const double point[3]) const;
  /// The distance, and in `gradient` the unit direction in which it grows (never zero: where the field is flat
  /// it points away from the object's centre, so a descent is never stranded).
  double distance_and_gradient(const double point[3], double gradient[3]) const;

  /// The box MuJoCo samples for the geom's mesh and seeds its searches in: the object's bounding box grown by
  /// `margin` (metres), as {centre xyz, half-size xyz}.
  void aabb(double margin, double box[6]) const;

  const voxfmt::runtime::CollisionObject& object() const { return *object_; }
  double voxel_size() const { return voxel_size_; }

 private:
  explicit AssetField(std::shared_ptr<const voxfmt::runtime::CollisionObject> object);
  // Grid coordinates of a point and of the nearest point of the grid's box of voxel centres.
  void locate(const double point[3], Eigen::Vector3f& u, Eigen::Vector3f& clamped) const;

  std::shared_ptr<const voxfmt::runtime::CollisionObject> object_;
  const voxfmt::runtime::SparseVoxelmap* map_ = nullptr;
  double voxel_size_ = 1.0;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  Eigen::Vector3f grid_max_ = Eigen::Vector3f::Zero();  ///< the last voxel centre, grid coordinates
  Eigen::Vector3d centre_ = Eigen::Vector3d::Zero();    ///< of the bounding box: the fallback direction's origin
};

}  // namespace voxfmt::mujoco
