// Reduction of a raw contact set to a few well-spread points: a rigid-body solver (Bullet's persistent
// manifold keeps 4) settles on 4 stable points and jitters on hundreds.
#pragma once

#include <cstddef>
#include <vector>

#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {

/// Indices of at most `max_points` (<= 4) contacts of `contacts`: the deepest; the one farthest from it; the
/// one spanning the largest triangle with those two; the one adding the most area on the far side of that
/// triangle. Deterministic for a given input order, so the choice is stable from step to step.
std::vector<size_t> reduce_contacts(const std::vector<Contact>& contacts, size_t max_points = 4);

}  // namespace voxfmt::runtime
