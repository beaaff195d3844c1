// Reduction of a raw contact set to a few well-spread points: a rigid-body solver (Bullet's persistent
// manifold keeps 4) settles on 4 stable points and jitters on hundreds.
#pragma once

#include <array>
#include <cstddef>
#include <vector>

#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {

/// Up to four contact indices, held inline (the reduction runs once per pair and step: no allocation).
struct ReducedContacts {
  std::array<size_t, 4> index{};
  size_t count = 0;
  const size_t* begin() const { return index.data(); }
  const size_t* end() const { return index.data() + count; }
  size_t size() const { return count; }
};

/// Indices of at most `max_points` (<= 4) contacts of `contacts`: the deepest; the one farthest from it; the
/// one spanning the largest triangle with those two; the one adding the most area on the far side of that
/// triangle. Deterministic for a given input order, so the choice is stable from step to step.
ReducedContacts reduce_contacts(const std::vector<Contact>& contacts, size_t max_points = 4);

}  // namespace voxfmt::runtime
