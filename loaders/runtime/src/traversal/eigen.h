// Between the runtime's Eigen types and the query core's plain ones (host only).
#pragma once

#include <Eigen/Core>

#include <cstddef>

#include "../core/batch.h"
#include "voxfmt/runtime/collision_object.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime::core {

inline Vec3 to_core(const Eigen::Vector3f& v) { return make_vec3(v.x(), v.y(), v.z()); }
inline Eigen::Vector3f to_eigen(const Vec3& v) { return Eigen::Vector3f(v.x, v.y, v.z); }

/// u = M x + m as the core's Affine (row-major).
inline Affine to_core(const Eigen::Matrix3f& M, const Eigen::Vector3f& m) {
  Affine a;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) a.M[3 * r + c] = M(r, c);
  a.m = to_core(m);
  return a;
}

/// The map's matrix as Eigen's.
inline Eigen::Matrix3f to_eigen(const Affine& a) {
  Eigen::Matrix3f M;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) M(r, c) = a.M[3 * r + c];
  return M;
}

/// A traversal's frame from a map u = M x + m into a target whose lengths are the shell's times `radius_scale`
/// (an analytic partner's: metres).
inline Frame frame_from(const Eigen::Matrix3f& M, const Eigen::Vector3f& m, float radius_scale, float proximity) {
  Frame f;
  f.to_grid = to_core(M, m);
  f.radius_scale = radius_scale;
  f.proximity = proximity;
  return f;
}

/// The runtime's tree as the core's plain arrays: the same memory.
inline Shell shell_of(const PointTree& tree) {
  static_assert(sizeof(Eigen::Vector3f) == sizeof(Vec3), "points and normals are read as the core's Vec3");
  Shell s;
  s.nodes = tree.nodes.data();
  s.points = reinterpret_cast<const Vec3*>(tree.points.data());
  s.normals = reinterpret_cast<const Vec3*>(tree.normals.data());
  s.count = uint32_t(tree.size());
  s.levels = uint32_t(tree.level_count());
  for (int a = 0; a < 3; ++a) s.anchor[a] = tree.anchor[a];
  return s;
}

/// A loaded asset as the batch reads it: views of the object's own arrays (valid while it lives).
inline Body body_of(const CollisionObject& object) {
  Body b;
  b.has_field = object.has_voxelmap();
  b.has_shell = object.has_point_shell();
  if (b.has_field) {
    b.field = field_of(object.voxelmap());
    for (int a = 0; a < 3; ++a) b.origin[a] = object.voxelmap().origin()[a];
    b.voxel_size = object.voxelmap().voxel_size();
  }
  if (b.has_shell) b.shell = shell_of(object.point_tree());
  b.bounding_radius = object.bounding_radius();
  for (int a = 0; a < 3; ++a) b.center_of_mass[a] = object.center_of_mass()[a];
  return b;
}

/// A runtime pose as the core's (row-major, double).
inline RigidPose to_core(const Pose& pose) {
  RigidPose p;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) p.R[3 * r + c] = pose.rotation(r, c);
    p.t[r] = pose.translation[r];
  }
  p.scale = pose.scale;
  return p;
}

/// The core's pose as a runtime one, exactly (no arithmetic).
inline Pose to_eigen(const RigidPose& p) {
  Pose pose;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) pose.rotation(r, c) = p.R[3 * r + c];
    pose.translation[r] = p.t[r];
  }
  pose.scale = p.scale;
  return pose;
}

/// `pose` acting on `tree`'s points and sphere centres, which are relative to its anchor (core::anchored).
inline Pose anchored(const Pose& pose, const PointTree& tree) {
  const double anchor[3] = {tree.anchor[0], tree.anchor[1], tree.anchor[2]};
  return to_eigen(anchored(to_core(pose), anchor));
}

}  // namespace voxfmt::runtime::core
