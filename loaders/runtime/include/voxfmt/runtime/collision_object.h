// A loaded asset in runtime form: bricked voxelmap, compact point-sphere tree, mass properties.
// Immutable after loading, so many bodies (and threads) can share one object.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/io.h"
#include "voxfmt/result.h"
#include "voxfmt/runtime/sparse_voxelmap.h"

namespace voxfmt::runtime {

/// The point-sphere tree of spec §4 in single precision, breadth-first: node n is point n, its children are
/// [nodes[n].first_child, nodes[n].first_child + nodes[n].child_count), level l is
/// [level_offsets[l], level_offsets[l + 1]).
struct PointTree {
  /// What a traversal reads of a node before it knows whether the node's point is needed, packed so that a
  /// visit touches one cache line (two nodes per line) and a node's children are contiguous.
  struct alignas(32) Node {
    Eigen::Vector3f centre;  ///< centre of the sphere around the node's point and its descendants (asset frame)
    float radius = 0;        ///< metres
    /// |centre - parent's centre| + radius (metres; 0 for the root): a parent's distance bound minus this bounds
    /// the node's, so a child out of reach is dropped without a lookup of its own.
    float reach_from_parent = 0;
    /// |centre - parent's point| + radius: the same from the parent's point, whose bound is known too.
    float reach_from_parent_point = 0;
    uint32_t first_child = 0;
    uint32_t child_count = 0;
  };
  static_assert(sizeof(Node) == 32, "two nodes per cache line");

  std::vector<Node> nodes;
  std::vector<Eigen::Vector3f> points;   ///< asset frame, metres
  std::vector<Eigen::Vector3f> normals;  ///< inward unit normals
  std::vector<uint32_t> level_offsets;
  /// The largest |x| of any point or sphere of the tree (asset frame, metres): how far a rigid motion can move
  /// any of them at most, for coherent queries.
  float extent = 0;

  size_t size() const { return points.size(); }
  size_t level_count() const { return level_offsets.empty() ? 0 : level_offsets.size() - 1; }
  /// Number of points in levels [0, level]: the coarse point shell that stops at `level`.
  size_t points_up_to_level(size_t level) const {
    return level + 1 < level_offsets.size() ? level_offsets[level + 1] : points.size();
  }
  size_t memory_bytes() const;
};

struct LoadOptions {
  bool load_voxelmap = true;     ///< false: a point-shell-only object (a probe that never gets hit)
  bool load_point_shell = true;  ///< false: a voxelmap-only object (static environment)
  /// How the file is read: its memory budget and the rules it must pass (by default every rule of
  /// `voxfmt validate`, so no loader accepts what validate refuses).
  voxfmt::ReadOptions read;
};

class CollisionObject {
 public:
  /// Reads and validates an asset file (options.read), then converts it. Errors name the file and the reason.
  static voxfmt::Result<std::shared_ptr<const CollisionObject>> load(const std::string& path,
                                                                     const LoadOptions& options = {});
  /// Converts an asset already in memory (it must pass quick validation); the rvalue overload takes over its
  /// voxelmap's arrays instead of copying them.
  static voxfmt::Result<std::shared_ptr<const CollisionObject>> from_asset(const voxfmt::Asset& asset,
                                                                           const LoadOptions& options = {});
  static voxfmt::Result<std::shared_ptr<const CollisionObject>> from_asset(voxfmt::Asset&& asset,
                                                                           const LoadOptions& options = {});

  bool has_voxelmap() const { return !voxelmap_.empty(); }
  bool has_point_shell() const { return tree_.size() > 0; }
  const SparseVoxelmap& voxelmap() const { return voxelmap_; }
  const PointTree& point_tree() const { return tree_; }

  /// Unit-density mass properties in the asset frame (spec §5).
  double volume() const { return volume_; }
  const Eigen::Vector3d& center_of_mass() const { return center_of_mass_; }
  const Eigen::Matrix3d& inertia_unit_density() const { return inertia_; }
  /// Principal axes of the inertia tensor (columns, right-handed) and the moments about them (unit density).
  const Eigen::Matrix3d& principal_axes() const { return principal_axes_; }
  const Eigen::Vector3d& principal_moments() const { return principal_moments_; }

  /// Object bounding box in the asset frame.
  const Eigen::Vector3d& bounds_min() const { return bounds_min_; }
  const Eigen::Vector3d& bounds_max() const { return bounds_max_; }
  /// Radius of the sphere about the centre of mass that holds every point of the shell (or the bounding box).
  double bounding_radius() const { return bounding_radius_; }
  /// Mean distance between neighbouring points of the finest shell, metres (0 if unknown).
  double point_spacing() const { return point_spacing_; }

  /// Heap bytes of the runtime structures.
  size_t memory_bytes() const { return voxelmap_.memory_bytes() + tree_.memory_bytes(); }

 private:
  /// Converts an asset that has passed at least quick validation (each load validates once).
  static voxfmt::Result<std::shared_ptr<const CollisionObject>> from_checked_asset(voxfmt::Asset&& asset,
                                                                                   const LoadOptions& options);

  SparseVoxelmap voxelmap_;
  PointTree tree_;
  double volume_ = 0.0;
  Eigen::Vector3d center_of_mass_ = Eigen::Vector3d::Zero();
  Eigen::Matrix3d inertia_ = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d principal_axes_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d principal_moments_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d bounds_min_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d bounds_max_ = Eigen::Vector3d::Zero();
  double bounding_radius_ = 0.0;
  double point_spacing_ = 0.0;
};

}  // namespace voxfmt::runtime
