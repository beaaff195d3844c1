#include "voxfmt/bullet/shape.h"

#include <LinearMath/btAabbUtil2.h>

#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "bt_eigen.h"

namespace voxfmt::bullet {

VpsShape::VpsShape(std::shared_ptr<const runtime::CollisionObject> object, Role role)
    : object_(std::move(object)), role_(role) {
  if (!object_) throw std::invalid_argument("VpsShape: no collision object");
  if (uses_points() && !object_->has_point_shell())
    throw std::invalid_argument("VpsShape: the role needs a point shell, the object has none");
  if (uses_voxelmap() && !object_->has_voxelmap())
    throw std::invalid_argument("VpsShape: the role needs a voxelmap, the object has none");
  m_shapeType = kShapeType;
  // x_shape = Q^T (x_asset - com), Q = principal axes.
  const Eigen::Matrix3d qt = object_->principal_axes().transpose();
  asset_to_shape_ = btTransform(to_bt_matrix(qt), to_bt_vector(-(qt * object_->center_of_mass())));
  // Bounds in the shape frame: the points if any (they lie on the surface), else the asset's box corners.
  local_min_ = btVector3(BT_LARGE_FLOAT, BT_LARGE_FLOAT, BT_LARGE_FLOAT);
  local_max_ = -local_min_;
  if (object_->has_point_shell()) {
    const runtime::PointTree& tree = object_->point_tree();
    for (size_t i = 0; i < tree.size(); ++i) {
      const btVector3 q = asset_to_shape_(to_bt_vector(tree.asset_point(i)));
      local_min_.setMin(q);
      local_max_.setMax(q);
    }
    // Points sample the surface: the surface may bulge out between them by a fraction of their spacing.
    const btScalar pad = btScalar(0.5 * object_->point_spacing());
    local_min_ -= btVector3(pad, pad, pad);
    local_max_ += btVector3(pad, pad, pad);
  } else {
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3d corner((c & 1) ? object_->bounds_max().x() : object_->bounds_min().x(),
                                   (c & 2) ? object_->bounds_max().y() : object_->bounds_min().y(),
                                   (c & 4) ? object_->bounds_max().z() : object_->bounds_min().z());
      const btVector3 q = asset_to_shape_(to_bt_vector(corner));
      local_min_.setMin(q);
      local_max_.setMax(q);
    }
  }
  setMargin(0);
}

runtime::Pose VpsShape::asset_pose(const btTransform& world_from_shape) const {
  // world = R_ws * s * (Q^T (x - com)) + t_ws
  runtime::Pose pose;
  const Eigen::Matrix3d r_ws = to_eigen(world_from_shape.getBasis());
  pose.rotation = r_ws * object_->principal_axes().transpose();
  pose.scale = scale_;
  pose.translation = to_eigen(world_from_shape.getOrigin()) - pose.rotation * (scale_ * object_->center_of_mass());
  return pose;
}

void VpsShape::getAabb(const btTransform& t, btVector3& aabb_min, btVector3& aabb_max) const {
  const btScalar s = btScalar(scale_);
  btTransformAabb(local_min_ * s, local_max_ * s, getMargin(), t, aabb_min, aabb_max);
}

void VpsShape::setLocalScaling(const btVector3& scaling) {
  // Uniform scaling only: distances and normals of the asset stay valid under it. A scale of 0 made every point a
  // contact, a negative one turned the box inside out (never paired), NaN or inf made the box and inertia NaN.
  if (!(std::isfinite(double(scaling.x())) && scaling.x() > 0))
    throw std::invalid_argument("VpsShape::setLocalScaling: the scale (x) must be a finite number > 0, got " +
                                std::to_string(double(scaling.x())));
  // A non-uniform scale (given, or a compound's passed on to its children) taken as x collided with a body of
  // another shape than the one simulated: refused, as a bad scale is.
  const double x = double(scaling.x()), tolerance = 1e-5 * x;
  if (!(std::abs(double(scaling.y()) - x) <= tolerance && std::abs(double(scaling.z()) - x) <= tolerance))
    throw std::invalid_argument("VpsShape::setLocalScaling: only uniform scaling is supported, got (" +
                                std::to_string(x) + ", " + std::to_string(double(scaling.y())) + ", " +
                                std::to_string(double(scaling.z())) + ")");
  scale_ = double(scaling.x());
  local_scaling_ = btVector3(scaling.x(), scaling.x(), scaling.x());
}

void VpsShape::calculateLocalInertia(btScalar mass, btVector3& inertia) const {
  const double volume = object_->volume();
  const Eigen::Vector3d moments =
      object_->principal_moments() * (volume > 0 ? double(mass) / volume : 0.0) * scale_ * scale_;
  inertia = to_bt_vector(moments);
}

void VpsShape::processAllTriangles(btTriangleCallback* callback, const btVector3& aabb_min,
                                   const btVector3& aabb_max) const {
  if (!object_->has_point_shell()) return;
  const runtime::PointTree& tree = object_->point_tree();
  const double s = scale_;
  // Asset frame -> shape frame (scaled): x_shape = s * (Q^T (x - com)).
  const Eigen::Matrix3d qt = object_->principal_axes().transpose();
  const Eigen::Vector3d com = object_->center_of_mass();
  const double inradius = s * object_->point_spacing();
  const double circumradius = 2.0 * inradius;
  const Eigen::Vector3d lo = to_eigen(aabb_min), hi = to_eigen(aabb_max);
  // The tree's points and centres are from its anchor.
  const Eigen::Vector3d from = com - tree.anchor;
  auto to_shape = [&](const Eigen::Vector3f& p) { return Eigen::Vector3d(s * (qt * (p.cast<double>() - from))); };
  auto box_distance2 = [&](const Eigen::Vector3d& p) { return (p - p.cwiseMax(lo).cwiseMin(hi)).squaredNorm(); };
  thread_local std::vector<uint32_t> stack;
  stack.assign(1, 0);
  btVector3 triangle[3];
  while (!stack.empty()) {
    const uint32_t node = stack.back();
    stack.pop_back();
    // A node's sphere holds its point and its subtree's; splats reach one circumradius beyond their points.
    const double reach = s * double(tree.nodes[node].radius) + circumradius;
    if (box_distance2(to_shape(tree.centre(node))) > reach * reach) continue;
    const Eigen::Vector3d p = to_shape(tree.points[node]);
    if (box_distance2(p) <= circumradius * circumradius) {
      // Outward normal (the stored one points inward) and a tangent frame around it.
      const Eigen::Vector3d n = -(qt * tree.normals[node].cast<double>()).normalized();
      const Eigen::Vector3d t1 = n.unitOrthogonal(), t2 = n.cross(t1);
      for (int k = 0; k < 3; ++k) {  // counter-clockwise seen from outside
        const double angle = 2.0 * M_PI * k / 3.0;
        triangle[k] = to_bt_vector(p + circumradius * (std::cos(angle) * t1 + std::sin(angle) * t2));
      }
      callback->processTriangle(triangle, 0, int(node));
    }
    for (uint32_t c = 0; c < tree.nodes[node].child_count; ++c) stack.push_back(tree.nodes[node].first_child + c);
  }
}

const char* VpsShape::getName() const {
  switch (role_) {
    case Role::Voxelmap:
      return "VpsVoxelmap";
    case Role::PointShell:
      return "VpsPointShell";
    case Role::Mixed:
      break;
  }
  return "VpsMixed";
}

}  // namespace voxfmt::bullet
