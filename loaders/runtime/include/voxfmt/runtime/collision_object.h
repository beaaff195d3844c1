// A loaded asset in runtime form: bricked voxelmap, compact point-sphere tree, mass properties.
// Immutable after loading, so many bodies (and threads) can share one object.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/io.h"
#include "voxfmt/result.h"
#include "voxfmt/runtime/core_types.h"

namespace voxfmt::runtime {

// ---- The runtime's view of an asset's voxelmap (spec §3): the file's own arrays, read as they are. Value bricks
// (8x8x8 voxels near the surface) hold a 16-bit code per voxel — a stored distance in fixed point, or the coarse
// estimate of a voxel without one, the lowest bit saying which — so a lookup near the surface is one brick-table
// entry and one cache line, decoded without a branch. Every other brick is one table entry whose voxels are
// interpolated from the lattice of unsigned distances at the brick corners. Memory follows the surface.

namespace core {
struct Field;
}

class SparseVoxelmap {
 public:
  SparseVoxelmap() = default;
  /// Takes over the voxelmap's arrays (validated asset). `bounds_min/max` is the object's bounding box (asset
  /// frame); points outside the grid get their distance bound from it.
  static SparseVoxelmap from_voxelmap(voxfmt::Voxelmap voxelmap, const voxfmt::Vec3& bounds_min,
                                      const voxfmt::Vec3& bounds_max);

  /// Grid coordinates (voxel centres at integers) of a point given in the asset frame.
  Eigen::Vector3f to_grid(const Eigen::Vector3d& asset_point) const {
    return ((asset_point - origin_) / voxel_size_).cast<float>();
  }
  /// Signed distance at grid coordinates `u`: trilinear interpolation of the 8 surrounding voxels' values
  /// (stored distances, or estimates where none is stored). Outside the grid a lower bound (`bound` set) that
  /// continues the field: sqrt(|u - q|^2 + d(q)^2) with q the grid's nearest point, at least the distance to the
  /// object's bounding box; no jump where the grid ends. If `gradient` is given it receives the direction of
  /// increasing distance (grid axes = asset axes, not normalised; zero where the field is flat).
  FieldSample sample(const Eigen::Vector3f& u, Eigen::Vector3f* gradient = nullptr) const;
  /// A value the true signed distance at `u` is not below (voxel units). Used to prune sphere-tree clusters.
  float distance_lower_bound(const Eigen::Vector3f& u) const;

  /// Layer of voxel (i, j, k): floor(-d + 1/2) of its value d in voxels (spec §3), for tests and inspection;
  /// INT_MIN outside the grid (or on an empty map).
  int layer_at(int i, int j, int k) const;
  /// Stored distance of voxel (i, j, k) in voxel units, or NaN where the asset stores none or outside the grid.
  float stored_distance_at(int i, int j, int k) const;
  /// Value of voxel (i, j, k) in voxel units: its stored distance or its estimate; NaN outside the grid.
  float value_at(int i, int j, int k) const;
  /// Whether voxel (i, j, k) is one of the grid's (never on an empty map).
  bool in_grid(int i, int j, int k) const;

  double voxel_size() const { return voxel_size_; }
  const Eigen::Vector3d& origin() const { return origin_; }
  std::array<int, 3> dims() const { return {layout_.dims[0], layout_.dims[1], layout_.dims[2]}; }
  bool empty() const { return bricks_.empty(); }
  /// Heap bytes held (what the map costs in RAM).
  size_t memory_bytes() const;
  size_t brick_count() const { return bricks_.size(); }
  /// Bricks with a code per voxel (those near the surface); the others are read from the lattice.
  size_t value_brick_count() const { return codes_.size() / kBrickVoxels; }
  /// How far an estimate m (voxels; a voxel without a stored distance) may be from the exact distance u:
  /// u <= m + estimate_slack() and u >= (m - estimate_offset()) / (1 + estimate_relative()) - estimate_slack().
  float estimate_slack() const { return layout_.estimate_slack; }
  float estimate_offset() const { return layout_.estimate_offset; }
  float estimate_relative() const { return 1.0f / layout_.estimate_shrink - 1.0f; }

  static constexpr int kBrickEdge = int(voxfmt::Voxelmap::kBrickEdge);
  static constexpr int kBrickVoxels = int(voxfmt::Voxelmap::kBrickVoxels);

 private:
  /// The query core's view of this map (private to the runtime): its arrays and the numbers that decode them.
  /// The lookups themselves live there, shared by this class, the traversal and the CUDA kernels.
  friend core::Field field_of(const SparseVoxelmap& map);

  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  double voxel_size_ = 1.0;
  core::FieldLayout layout_;     ///< the arrays' shapes and how their codes decode, fixed at load
  std::vector<int32_t> bricks_;  ///< the brick table (>= 0: value brick; -1 / -2: coarse outside / inside)
  std::vector<int16_t> codes_;   ///< value bricks, 512 codes each
  /// Unsigned distances at the lattice points in steps of lattice_step_ voxels (16 bits: half a float's memory; the
  /// far field needs no more, and the step's half is in estimate_slack_).
  std::vector<uint16_t> lattice_;
};

// ---- The loaded object.

/// The point-sphere tree of spec §4 in single precision, breadth-first: node n is point n, its children are
/// [nodes[n].first_child, nodes[n].first_child + nodes[n].child_count), level l is
/// [level_offsets[l], level_offsets[l + 1]).
struct PointTree {
  /// A node: its sphere (centre in the asset frame, radius in metres), what its children's reach from it is, and
  /// where they are, packed two to a cache line (core_types.h).
  using Node = core::Node;

  std::vector<Node> nodes;
  std::vector<Eigen::Vector3f> points;   ///< metres, relative to `anchor` (asset_point() gives the asset frame's)
  std::vector<Eigen::Vector3f> normals;  ///< inward unit normals
  std::vector<uint32_t> level_offsets;
  /// The asset-frame point the points and sphere centres are relative to: zero, unless the shell lies far from
  /// its frame's origin (more than 16 times its own size), where it is the shell's centre, so that single
  /// precision keeps a voxel's fraction (a part in a plant's or a map's coordinates, 1e6 m out, was rounded to
  /// decimetres). Queries fold it into the pose in double (anchored()).
  Eigen::Vector3d anchor = Eigen::Vector3d::Zero();
  /// The largest |x| of any point or sphere of the tree (relative to `anchor`, metres): how far a rigid motion
  /// can move any of them at most, for coherent queries.
  float extent = 0;

  size_t size() const { return points.size(); }
  /// Centre of node n's sphere (metres, relative to `anchor`).
  Eigen::Vector3f centre(size_t n) const { return {nodes[n].centre.x, nodes[n].centre.y, nodes[n].centre.z}; }
  /// Point n in the asset frame.
  Eigen::Vector3d asset_point(size_t n) const { return points[n].cast<double>() + anchor; }
  size_t level_count() const { return level_offsets.empty() ? 0 : level_offsets.size() - 1; }
  /// Number of points in levels [0, level]: the coarse point shell that stops at `level`.
  size_t points_up_to_level(size_t level) const {
    return level < level_count() ? level_offsets[level + 1] : points.size();
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
  /// Who made the asset, from what and how (spec §6): what exports of it record.
  const voxfmt::Provenance& provenance() const { return provenance_; }
  /// Half-width of the band of stored distances, voxels (spec §3.2).
  double distance_band() const { return distance_band_; }
  /// A number no other object this runtime made has (a copy shares its original's; a second copy of the runtime
  /// in the process, linked statically into another library, counts on its own): what a QueryState knows its pair
  /// by, as an address may be reused by an object loaded after another was destroyed.
  uint64_t id() const { return id_; }

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
  voxfmt::Provenance provenance_;
  double distance_band_ = 0.0;
  uint64_t id_ = 0;
};

}  // namespace voxfmt::runtime
