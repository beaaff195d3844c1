// Bullet collision shapes backed by a VPS asset: voxelmap, point shell, or mixed (both), as in the DLR seed.
//
// The shape's local frame is the asset's principal frame: origin at the centre of mass, axes along the
// principal axes of inertia, so a btRigidBody built on it rotates correctly with a diagonal inertia.
// `asset_to_shape()` maps asset coordinates (e.g. a render mesh) into that frame.
#pragma once

#include <BulletCollision/CollisionShapes/btConcaveShape.h>

#include <memory>

#include "voxfmt/runtime/collision_object.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::bullet {

class VpsShape : public btConcaveShape {
 public:
  /// Which structures the shape uses in collisions.
  enum class Role {
    Voxelmap,    ///< only hit by others' points (static environment)
    PointShell,  ///< only probes others' voxelmaps (haptic probe)
    Mixed,       ///< both: either side of a pair can carry the points
  };
  /// Bullet's dispatcher looks up algorithms by this type. Bullet itself never uses it (CUSTOM_CONCAVE_SHAPE_TYPE
  /// would be taken for an SDF shape by Bullet's own convex-concave algorithm).
  static constexpr int kShapeType = FAST_CONCAVE_MESH_PROXYTYPE;

  /// `object` must have the structures `role` needs (checked: std::invalid_argument otherwise).
  VpsShape(std::shared_ptr<const runtime::CollisionObject> object, Role role);

  const runtime::CollisionObject& object() const { return *object_; }
  Role role() const { return role_; }
  bool uses_points() const { return role_ != Role::Voxelmap; }
  bool uses_voxelmap() const { return role_ != Role::PointShell; }
  /// Uniform scale (Bullet's local scaling; a non-uniform one is refused).
  double scale() const { return scale_; }

  /// Points tested per query when this shape carries the points: whole tree levels up to this budget
  /// (e.g. ~800 for the seed's coarse shell). Default: all.
  void set_point_budget(size_t budget) { point_budget_ = budget; }
  size_t point_budget() const { return point_budget_; }
  /// Deepest point-sphere tree level tested when this shape carries the points (0 = the root only; a fixed
  /// coarse level instead of a budget). Default: all levels.
  void set_max_level(uint32_t level) { max_level_ = level; }
  uint32_t max_level() const { return max_level_; }
  /// Points of this shape closer than this (metres) to a partner become speculative contacts; the pair uses the
  /// largest of both shapes', the collision settings' and Bullet's contact threshold. Default 0.
  void set_proximity(double metres) { proximity_ = metres; }
  double proximity() const { return proximity_; }

  /// Asset frame -> shape frame (unscaled).
  const btTransform& asset_to_shape() const { return asset_to_shape_; }
  /// Pose of the asset frame for a body whose shape frame is at `world_from_shape` (includes the scale).
  runtime::Pose asset_pose(const btTransform& world_from_shape) const;

  // btCollisionShape
  void getAabb(const btTransform& t, btVector3& aabb_min, btVector3& aabb_max) const override;
  /// Uniform only. Throws std::invalid_argument unless x is finite and > 0 and y and z equal it (within 1e-5 of it).
  void setLocalScaling(const btVector3& scaling) override;
  const btVector3& getLocalScaling() const override { return local_scaling_; }
  /// Principal moments of the asset's mass properties for `mass` (uniform density), scaled.
  void calculateLocalInertia(btScalar mass, btVector3& inertia) const override;
  const char* getName() const override;
  /// btConcaveShape: a VPS shape has no triangles, but Bullet's ray tests and convex sweeps (the sweeps of its
  /// continuous collision detection) ask for them. It hands out one small triangle per point-shell point in the
  /// box (shape frame), in the point's tangent plane and facing out, large enough (inradius = the point
  /// spacing) that together they cover the surface: rays and CCD sweeps stop at the surface within about a
  /// point spacing. Contacts never come from these: they come from the VPS algorithm.
  void processAllTriangles(btTriangleCallback* callback, const btVector3& aabb_min,
                           const btVector3& aabb_max) const override;

 private:
  std::shared_ptr<const runtime::CollisionObject> object_;
  Role role_;
  double scale_ = 1.0;
  btVector3 local_scaling_{1, 1, 1};
  size_t point_budget_ = std::numeric_limits<size_t>::max();
  uint32_t max_level_ = std::numeric_limits<uint32_t>::max();
  double proximity_ = 0.0;
  btTransform asset_to_shape_;
  btVector3 local_min_, local_max_;  // unscaled bounds in the shape frame
};

class VpsVoxelmapShape : public VpsShape {
 public:
  explicit VpsVoxelmapShape(std::shared_ptr<const runtime::CollisionObject> object)
      : VpsShape(std::move(object), Role::Voxelmap) {}
};
class VpsPointShellShape : public VpsShape {
 public:
  explicit VpsPointShellShape(std::shared_ptr<const runtime::CollisionObject> object)
      : VpsShape(std::move(object), Role::PointShell) {}
};
class VpsMixedShape : public VpsShape {
 public:
  explicit VpsMixedShape(std::shared_ptr<const runtime::CollisionObject> object)
      : VpsShape(std::move(object), Role::Mixed) {}
};

}  // namespace voxfmt::bullet
