// The sphere-tree walk as host/device code: one object's point shell against another's distance field. A node is
// examined one way (visit_node), LevelTraversal's (traversal.h) node for node, so every walk reports the same points
// with the same distances; walk() takes them depth first with a stack of child ranges on one thread, the block walk
// (block_walk.h) level by level on a block's lanes.
#pragma once

#include "field.h"
#include "frame.h"
#include "prune.h"

namespace voxfmt::runtime::core {

/// A point-sphere tree (spec §4) in the runtime's form: node n is point n, breadth first.
struct Shell {
  const Node* nodes = nullptr;
  const Vec3* points = nullptr;   ///< metres, relative to `anchor`
  const Vec3* normals = nullptr;  ///< inward unit normals
  uint32_t count = 0;
  uint32_t levels = 0;           ///< tree depth: the walk's stack holds at most one range per level
  double anchor[3] = {0, 0, 0};  ///< PointTree::anchor: the asset-frame point the points and centres are from
};

/// Deepest tree the walk takes (a stack of this many ranges per thread); a loader refuses deeper ones up front.
constexpr uint32_t kMaxWalkLevels = 48;

/// What examining one node found (visit_node).
struct NodeVisit {
  bool in_reach = false;  ///< false: its sphere is culled, with everything below it
  bool hit = false;       ///< its point is nearer than the proximity: `distance`, `exact`, `gradient` are its
  float distance = 0;
  bool exact = false;
  Vec3 gradient;
  float bound = 0, point_bound = 0;  ///< what it carries to its children (carried_bound)
};

/// Examines `node` of `shell` in the grid of `field` (`frame`), given the bounds its parent carried (-inf for the
/// root): false where they rule it out (not examined); else its sphere is culled on the bound at its centre and,
/// in reach, its point tested. Every walk of the batch examines nodes so, whatever order it takes them in.
VOXFMT_HD bool visit_node(const Field& field, const Shell& shell, const Frame& frame, uint32_t node, float parent_bound,
                          float parent_point_bound, NodeVisit& v) {
  const Node& n = shell.nodes[node];
  const float scale = frame.radius_scale, proximity = frame.proximity;
  if (carried_bound(parent_bound, parent_point_bound, n.reach_from_parent, n.reach_from_parent_point, scale) >
      proximity)
    return false;
  v.bound = lower_bound(field, frame.to_grid.apply(n.centre));
  v.in_reach = sphere_in_reach(v.bound, n.radius, scale, proximity);
  if (!v.in_reach) return true;
  const Vec3 u = frame.to_grid.apply(shell.points[node]);
  // An inner node's point is tested on its own bound before its distance (one voxel against up to eight).
  v.point_bound = -__builtin_huge_valf();
  if (n.child_count > 0) v.point_bound = lower_bound(field, u);
  if (v.point_bound < proximity) {
    // The gradient comes with the distance's corners: a contact's normal needs no second sample.
    v.gradient = make_vec3(0, 0, 0);
    const Sample s = sample(field, u, &v.gradient);
    v.hit = s.distance < proximity;
    v.distance = s.distance;
    v.exact = s.exact;
  }
  return true;
}

/// Walks `shell` in the grid of `field` (`frame`), calling emit(node, distance, exact, &gradient) for every point
/// nearer than frame.proximity (grid units). Returns the nodes visited, or -1 for a tree deeper than kMaxWalkLevels.
template <class Emit>
VOXFMT_HD int walk(const Field& field, const Shell& shell, const Frame& frame, Emit& emit) {
  // Depth first: each node examined is pushed as its children's range, with the bounds it carries to them.
  struct Range {
    uint32_t next, end;
    float bound, point_bound;  // the parent's
  };
  Range stack[kMaxWalkLevels + 1];
  int top = 0;
  const float infinity = __builtin_huge_valf();
  stack[top++] = {0, shell.count > 0 ? 1u : 0u, -infinity, -infinity};
  int visited = 0;
  while (top > 0) {
    Range& range = stack[top - 1];
    if (range.next == range.end) {
      --top;
      continue;
    }
    const uint32_t node = range.next++;
    NodeVisit v;
    if (!visit_node(field, shell, frame, node, range.bound, range.point_bound, v)) continue;
    ++visited;
    if (!v.in_reach) continue;
    if (v.hit) emit(node, v.distance, v.exact, &v.gradient);
    const Node& n = shell.nodes[node];
    if (n.child_count == 0) continue;
    if (top > int(kMaxWalkLevels)) return -1;
    stack[top++] = {n.first_child, n.first_child + n.child_count, v.bound, v.point_bound};
  }
  return visited;
}

}  // namespace voxfmt::runtime::core
