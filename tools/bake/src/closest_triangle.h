// The nearest triangle to a point: a bounding-volume hierarchy over a mesh's triangles, for the voxelmap lattice's
// exact distances. CGAL's AABB tree answers the same query but took 10-20 us per lattice point of the bunny; this
// one, given the upper bound the lattice propagation already has, visits only the boxes within it (~1 us).
#pragma once

#include <cstdint>
#include <vector>

#include "voxfmt/asset.h"

namespace voxfmt::bake {

class ClosestTriangle {
 public:
  /// `corners`: three corners per triangle (any frame; queries use the same one). Ranges of at least
  /// `parallel_from` triangles are split first and the subtrees below them built on all threads: the same tree
  /// whatever the threads or `parallel_from`.
  explicit ClosestTriangle(const std::vector<std::array<Vec3, 3>>& corners, uint32_t parallel_from = 1u << 15);
  /// Squared distance to the nearest triangle and its index, searching only closer than sqrt(`bound2`); if none
  /// is, returns {bound2, `hint`}. With `slack` > 0 the result may be up to (1 + slack) times the nearest
  /// distance: boxes that could only improve it by less are not opened (far from the surface that is most).
  std::pair<double, uint32_t> nearest(const Vec3& p, double bound2, uint32_t hint, double slack = 0) const;
  /// Levels below the root of the deepest leaf (the search's stack holds 64 nodes, so at most 62).
  int depth() const { return depth_; }
  /// The same nodes and triangle order.
  bool operator==(const ClosestTriangle& other) const;

 private:
  struct Node {
    double lo[3], hi[3];  // box of the node's triangles
    uint32_t first;       // inner: index of the second child (the first follows the node); leaf: first triangle
    uint32_t count;       // 0 for an inner node
  };
  struct Inputs;  // centroids and boxes (lowest, highest corner) by triangle
  struct Top;
  // The tree over order_: its top split on this thread, the subtrees below it built on all threads.
  void build_tree(const Inputs& in, uint32_t parallel_from);
  // The node over order_[begin, end): a leaf, or an inner node and the first index of its second half (`mid`).
  Node split(uint32_t begin, uint32_t end, const Inputs& in, int depth, uint32_t& mid);
  uint32_t surface_area_split(uint32_t begin, uint32_t end, const Inputs& in, const Vec3& centroid_lo,
                              const Vec3& centroid_hi);
  // The subtree over order_[begin, end) appended to `out` in depth-first order; returns its root's index in `out`.
  uint32_t build(uint32_t begin, uint32_t end, const Inputs& in, int depth, std::vector<Node>& out, int& deepest);
  std::vector<Node> nodes_;
  int depth_ = 0;
  std::vector<uint32_t> order_;            // triangle indices in leaf order
  std::vector<std::array<Vec3, 3>> tris_;  // corners in leaf order
};

}  // namespace voxfmt::bake
