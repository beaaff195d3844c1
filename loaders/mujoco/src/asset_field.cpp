#include "asset_field.h"

#include <algorithm>
#include <cmath>

namespace voxfmt::mujoco {

voxfmt::Result<std::shared_ptr<const AssetField>> AssetField::from_object(
    std::shared_ptr<const voxfmt::runtime::CollisionObject> object) {
  if (!object || !object->has_voxelmap())
    return voxfmt::Error(voxfmt::IssueCode::InvalidAsset, "the asset has no voxelmap: MuJoCo needs its distance field");
  const auto& dims = object->voxelmap().dims();
  if (dims[0] < 2 || dims[1] < 2 || dims[2] < 2)
    return voxfmt::Error(voxfmt::IssueCode::InvalidAsset, "the asset's voxelmap is thinner than two voxels");
  return std::shared_ptr<const AssetField>(new AssetField(std::move(object)));
}

AssetField::AssetField(std::shared_ptr<const voxfmt::runtime::CollisionObject> object)
    : object_(std::move(object)), map_(&object_->voxelmap()) {
  voxel_size_ = map_->voxel_size();
  origin_ = map_->origin();
  for (int a = 0; a < 3; ++a) grid_max_[a] = float(map_->dims()[a] - 1);
  centre_ = 0.5 * (object_->bounds_min() + object_->bounds_max());
}

inline void AssetField::locate(const double point[3], Eigen::Vector3f& u, Eigen::Vector3f& clamped) const {
  const double inverse = 1.0 / voxel_size_;
  for (int a = 0; a < 3; ++a) u[a] = float((point[a] - origin_[a]) * inverse);
  // Beyond the voxel centres the trilinear field would be constant along the clamped axes (a zero gradient that
  // strands a descent); the distance to the box takes over there instead.
  clamped = u.cwiseMax(Eigen::Vector3f::Zero()).cwiseMin(grid_max_);
}

double AssetField::distance(const double point[3]) const {
  Eigen::Vector3f u, c;
  locate(point, u, c);
  const float inside = map_->sample(c).distance;
  return (double(inside) + double((u - c).norm())) * voxel_size_;
}

double AssetField::distance_and_gradient(const double point[3], double gradient[3]) const {
  Eigen::Vector3f u, c, g;
  locate(point, u, c);
  const float inside = map_->sample(c, &g).distance;
  const Eigen::Vector3f out = u - c;
  const float beyond = out.norm();
  // Along an axis where the point is past the box, the distance grows with the offset from it; along the
  // others, with the field at the clamped point.
  Eigen::Vector3f direction;
  for (int a = 0; a < 3; ++a) direction[a] = out[a] != 0.0f ? out[a] / beyond : g[a];
  const float length = direction.norm();
  if (length > 1e-6f) {
    for (int a = 0; a < 3; ++a) gradient[a] = double(direction[a] / length);
  } else {
    Eigen::Vector3d away = Eigen::Vector3d(point[0], point[1], point[2]) - centre_;
    const double n = away.norm();
    if (n > 0)
      away /= n;
    else
      away = Eigen::Vector3d::UnitZ();
    for (int a = 0; a < 3; ++a) gradient[a] = away[a];
  }
  return (double(inside) + double(beyond)) * voxel_size_;
}

void AssetField::aabb(double margin, double box[6]) const {
  const Eigen::Vector3d& lo = object_->bounds_min();
  const Eigen::Vector3d& hi = object_->bounds_max();
  for (int a = 0; a < 3; ++a) {
    box[a] = 0.5 * (lo[a] + hi[a]);
    box[3 + a] = 0.5 * (hi[a] - lo[a]) + margin;
  }
}

}  // namespace voxfmt::mujoco
