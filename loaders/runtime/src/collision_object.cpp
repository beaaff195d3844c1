#include "voxfmt/runtime/collision_object.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <atomic>
#include <cmath>

#include "traversal/eigen.h"
#include "voxfmt/io.h"

namespace voxfmt::runtime {
namespace {

Eigen::Vector3f to_float(const voxfmt::Vec3f& v) { return Eigen::Vector3f(v[0], v[1], v[2]); }
Eigen::Vector3d to_double(const voxfmt::Vec3& v) { return Eigen::Vector3d(v[0], v[1], v[2]); }

// The tree's anchor (PointTree::anchor): zero, or the shell's centre where it lies more than 16 times its size
// from the origin (a float there would round it by more than about 1e-6 of its size).
Eigen::Vector3d anchor_of(const voxfmt::PointShell& shell) {
  if (shell.size() == 0) return Eigen::Vector3d::Zero();
  Eigen::Vector3d lo = to_double(shell.points[0]), hi = lo;
  for (size_t i = 0; i < shell.size(); ++i) {
    lo = lo.cwiseMin(to_double(shell.points[i]));
    hi = hi.cwiseMax(to_double(shell.points[i]));
  }
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  return centre.norm() > 16.0 * (hi - lo).norm() ? centre : Eigen::Vector3d::Zero();
}

PointTree make_tree(const voxfmt::PointShell& shell) {
  PointTree tree;
  const size_t n = shell.size();
  tree.anchor = anchor_of(shell);
  const auto from_anchor = [&](const voxfmt::Vec3& x) -> Eigen::Vector3f {
    return (to_double(x) - tree.anchor).cast<float>();
  };
  tree.points.reserve(n);
  tree.normals.reserve(n);
  tree.nodes.resize(n);
  for (size_t i = 0; i < n; ++i) {
    tree.points.push_back(from_anchor(shell.points[i]));
    tree.normals.push_back(to_float(shell.normals[i]));
  }
  // Single precision moves a centre or a point by up to 2^-24 of its largest coordinate (6e-8 relative): grow
  // radii by that much of the shell's largest coordinate, so a sphere still encloses its subtree at any scale
  // (a micrometre part or a building; a fixed pad in metres would swamp the one and miss the other).
  double largest = 0;
  for (size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a)
      largest = std::max({largest, std::abs(shell.points[i][a] - tree.anchor[a]),
                          std::abs(shell.sphere_centers[i][a] - tree.anchor[a])});
  const float rounding_pad = float(4e-7 * largest);
  for (size_t i = 0; i < n; ++i) {
    PointTree::Node& node = tree.nodes[i];
    node.centre = core::to_core(from_anchor(shell.sphere_centers[i]));
    node.radius = float(shell.sphere_radii[i]) * (1.0f + 1e-6f) + rounding_pad;
    node.first_child = shell.child_begin[i];
    node.child_count = shell.child_count[i];
    if (node.child_count == 0) node.first_child = uint32_t(n);  // no children: an empty range past the end
  }
  tree.level_offsets = shell.level_offsets;
  for (size_t i = 0; i < n; ++i)
    tree.extent = std::max({tree.extent, tree.points[i].norm(), tree.centre(i).norm() + tree.nodes[i].radius});
  tree.extent = tree.extent * (1.0f + 1e-6f) + rounding_pad;
  // How far each child's sphere reaches from its parent's centre (computed in double, rounded up).
  for (size_t parent = 0; parent < n; ++parent)
    for (uint32_t c = 0; c < shell.child_count[parent]; ++c) {
      const size_t child = shell.child_begin[parent] + c;
      double offset = 0;
      for (int a = 0; a < 3; ++a)
        offset += (shell.sphere_centers[child][a] - shell.sphere_centers[parent][a]) *
                  (shell.sphere_centers[child][a] - shell.sphere_centers[parent][a]);
      tree.nodes[child].reach_from_parent =
          float(std::sqrt(offset) + shell.sphere_radii[child]) * (1.0f + 1e-6f) + rounding_pad;
      double from_point = 0;
      for (int a = 0; a < 3; ++a)
        from_point += (shell.sphere_centers[child][a] - shell.points[parent][a]) *
                      (shell.sphere_centers[child][a] - shell.points[parent][a]);
      tree.nodes[child].reach_from_parent_point =
          float(std::sqrt(from_point) + shell.sphere_radii[child]) * (1.0f + 1e-6f) + rounding_pad;
    }
  return tree;
}

}  // namespace

size_t PointTree::memory_bytes() const {
  return nodes.capacity() * sizeof(Node) + (points.capacity() + normals.capacity()) * sizeof(Eigen::Vector3f) +
         level_offsets.capacity() * sizeof(uint32_t);
}

voxfmt::Result<std::shared_ptr<const CollisionObject>> CollisionObject::load(const std::string& path,
                                                                             const LoadOptions& options) {
  voxfmt::Result<voxfmt::Asset> asset = voxfmt::read_asset(path, nullptr, options.read);
  if (!asset) return asset.error();
  // read_asset has checked the file against options.read.level, which includes the quick rules: not again.
  return from_checked_asset(std::move(asset.value()), options);
}

voxfmt::Result<std::shared_ptr<const CollisionObject>> CollisionObject::from_asset(const voxfmt::Asset& asset,
                                                                                   const LoadOptions& options) {
  return from_asset(voxfmt::Asset(asset), options);
}

voxfmt::Result<std::shared_ptr<const CollisionObject>> CollisionObject::from_asset(voxfmt::Asset&& asset,
                                                                                   const LoadOptions& options) {
  const std::vector<voxfmt::Issue> issues = voxfmt::validate_asset(asset, voxfmt::ValidationLevel::Quick);
  for (const voxfmt::Issue& issue : issues)
    if (issue.severity == voxfmt::Severity::Error)
      return voxfmt::Error{issue.code, "asset is not valid: " + issue.path + ": " + issue.message};
  return from_checked_asset(std::move(asset), options);
}

voxfmt::Result<std::shared_ptr<const CollisionObject>> CollisionObject::from_checked_asset(voxfmt::Asset&& asset,
                                                                                           const LoadOptions& options) {
  if (!options.load_voxelmap && !options.load_point_shell)
    return voxfmt::Error{voxfmt::IssueCode::ReadFailed, "LoadOptions asks for neither voxelmap nor point shell"};

  auto object = std::make_shared<CollisionObject>();
  static std::atomic<uint64_t> made{0};
  object->id_ = ++made;
  object->bounds_min_ = to_double(asset.bounds_min);
  object->bounds_max_ = to_double(asset.bounds_max);
  object->distance_band_ = asset.voxelmap.distance_band;
  if (options.load_voxelmap)
    object->voxelmap_ = SparseVoxelmap::from_voxelmap(std::move(asset.voxelmap), asset.bounds_min, asset.bounds_max);
  if (options.load_point_shell) object->tree_ = make_tree(asset.point_shell);

  object->volume_ = asset.mass.volume;
  object->center_of_mass_ = to_double(asset.mass.center_of_mass);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) object->inertia_(r, c) = asset.mass.inertia[size_t(r * 3 + c)];
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(0.5 * (object->inertia_ + object->inertia_.transpose()));
  object->principal_moments_ = eigen.eigenvalues().cwiseMax(0.0);
  object->principal_axes_ = eigen.eigenvectors();
  if (object->principal_axes_.determinant() < 0) object->principal_axes_.col(2) *= -1.0;

  double radius2 = 0.0;
  for (size_t i = 0; i < object->tree_.size(); ++i)
    radius2 = std::max(radius2, (object->tree_.asset_point(i) - object->center_of_mass_).squaredNorm());
  if (object->tree_.size() == 0) {  // a point-less object is bounded by its box
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d c((corner & 1) ? object->bounds_max_.x() : object->bounds_min_.x(),
                              (corner & 2) ? object->bounds_max_.y() : object->bounds_min_.y(),
                              (corner & 4) ? object->bounds_max_.z() : object->bounds_min_.z());
      radius2 = std::max(radius2, (c - object->center_of_mass_).squaredNorm());
    }
  }
  object->bounding_radius_ = std::sqrt(radius2);
  object->point_spacing_ = asset.point_shell.point_spacing.value_or(0.0);
  object->provenance_ = std::move(asset.provenance);
  return std::shared_ptr<const CollisionObject>(std::move(object));
}

}  // namespace voxfmt::runtime
