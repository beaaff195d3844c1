// The pruning rule of every walk of the point-sphere tree — the batch's walk (walk.h), the runtime's level
// traversal (traversal.h) and its coherent traversal (coherent_traversal.h) — written once. Lengths are in the
// target's units; `scale` takes the shell's lengths there. Host and device code.
#pragma once

#include "hd.h"

namespace voxfmt::runtime::core {

/// The lower bound a child inherits from its parent: the parent's bounds at its sphere's centre and at its point,
/// less how far the child's sphere reaches from each. A child whose carried bound exceeds the proximity holds no
/// point within it and is not examined.
VOXFMT_HD float carried_bound(float parent_bound, float parent_point_bound, float reach_from_parent,
                              float reach_from_parent_point, float scale) {
  return max_f(parent_bound - reach_from_parent * scale, parent_point_bound - reach_from_parent_point * scale);
}

/// Whether a sphere whose centre has the lower bound `bound` may hold a point within `proximity` (false for a NaN
/// bound). A sphere out of reach is culled with everything below it.
VOXFMT_HD bool sphere_in_reach(float bound, float radius, float scale, float proximity) {
  return bound <= radius * scale + proximity;
}

}  // namespace voxfmt::runtime::core
