// The sphere-tree walk as host/device code: one object's point shell against another's distance field, depth
// first with a stack of child ranges, for one pose at a time on one thread (the batched CUDA kernel runs one per
// environment; the CPU runs the very same function for the batch's CPU path and its tests). Its pruning is
// LevelTraversal's (traversal.h) node for node, so it reports the same points with the same distances; only the
// order differs (depth first, not level by level).
#pragma once

#include "field.h"
#include "frame.h"
#include "prune.h"

namespace voxfmt::runtime::core {

/// A point-sphere tree (spec §4) in the runtime's form: node n is point n, breadth first.
struct Shell {
  const Node* nodes = nullptr;
  const Vec3* points = nullptr;   ///< asset frame, metres
  const Vec3* normals = nullptr;  ///< inward unit normals
  uint32_t count = 0;
  uint32_t levels = 0;  ///< tree depth: the walk's stack holds at most one range per level
};

/// Deepest tree the walk takes (a stack of this many ranges per thread); a loader refuses deeper ones up front.
constexpr uint32_t kMaxWalkLevels = 48;

/// Walks `shell` in the grid of `field` (`frame`), calling emit(node, distance, exact, &gradient) for every point
/// nearer than frame.proximity (grid units). Returns the nodes visited, or -1 for a tree deeper than kMaxWalkLevels.
template <class Emit>
VOXFMT_HD int walk(const Field& field, const Shell& shell, const Frame& frame, Emit& emit) {
  // A node is examined when the bounds its parent carried (from the parent's centre and point) do not rule it
  // out; then its sphere is culled on the bound at its centre, its point tested, its children pushed as a range.
  struct Range {
    uint32_t next, end;
    float bound, point_bound;  // the parent's
  };
  Range stack[kMaxWalkLevels + 1];
  int top = 0;
  const float infinity = __builtin_huge_valf();
  stack[top++] = {0, shell.count > 0 ? 1u : 0u, -infinity, -infinity};
  const float scale = frame.radius_scale, proximity = frame.proximity;
  int visited = 0;
  while (top > 0) {
    Range& range = stack[top - 1];
    if (range.next == range.end) {
      --top;
      continue;
    }
    const uint32_t node = range.next++;
    const Node& n = shell.nodes[node];
    if (carried_bound(range.bound, range.point_bound, n.reach_from_parent, n.reach_from_parent_point, scale) >
        proximity)
      continue;
    ++visited;
    const float bound = lower_bound(field, frame.to_grid.apply(n.centre));
    if (!sphere_in_reach(bound, n.radius, scale, proximity)) continue;
    const Vec3 u = frame.to_grid.apply(shell.points[node]);
    // An inner node's point is tested on its own bound before its distance (one voxel against up to eight).
    float point_bound = -infinity;
    if (n.child_count > 0) point_bound = lower_bound(field, u);
    if (point_bound < proximity) {
      // The gradient comes with the distance's corners: a contact's normal needs no second sample.
      Vec3 gradient = make_vec3(0, 0, 0);
      const Sample s = sample(field, u, &gradient);
      if (s.distance < proximity) emit(node, s.distance, s.exact, &gradient);
    }
    if (n.child_count == 0) continue;
    if (top > int(kMaxWalkLevels)) return -1;
    stack[top++] = {n.first_child, n.first_child + n.child_count, bound, point_bound};
  }
  return visited;
}

}  // namespace voxfmt::runtime::core
