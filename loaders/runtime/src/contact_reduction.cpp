#include "voxfmt/runtime/detail/contact_reduction.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <limits>

namespace voxfmt::runtime {

ReducedContacts reduce_contacts(const std::vector<Contact>& contacts, size_t max_points) {
  ReducedContacts chosen;
  max_points = std::min<size_t>(max_points, 4);
  if (contacts.empty() || max_points == 0) return chosen;
  if (contacts.size() <= max_points) {
    for (size_t i = 0; i < contacts.size(); ++i) chosen.index[chosen.count++] = i;
    return chosen;
  }
  auto argmax = [&](auto&& score) {
    size_t best = 0;  // also when every score is NaN
    double best_score = -std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < contacts.size(); ++i) {
      const double s = score(contacts[i]);
      if (s > best_score) best = i, best_score = s;
    }
    return std::make_pair(best, best_score);
  };
  const size_t deepest = argmax([](const Contact& c) { return c.depth; }).first;
  chosen.index[chosen.count++] = deepest;
  const Eigen::Vector3d p0 = contacts[deepest].point;
  if (max_points == 1) return chosen;
  const auto [far, far_d2] = argmax([&](const Contact& c) { return (c.point - p0).squaredNorm(); });
  if (far_d2 <= 0.0) return chosen;  // all contacts at one point
  chosen.index[chosen.count++] = far;
  const Eigen::Vector3d p1 = contacts[far].point;
  if (max_points == 2) return chosen;
  // Squared (twice the) area: the same order as the area, without a square root per contact.
  const Eigen::Vector3d edge = p1 - p0;
  const auto [third, area2] = argmax([&](const Contact& c) { return edge.cross(c.point - p0).squaredNorm(); });
  if (area2 <= 0.0) return chosen;  // collinear
  chosen.index[chosen.count++] = third;
  const Eigen::Vector3d p2 = contacts[third].point;
  if (max_points == 3) return chosen;
  // The fourth point adds the most area: the largest triangle it forms with an edge it lies beyond.
  const Eigen::Vector3d n = edge.cross(p2 - p0);
  const Eigen::Vector3d corners[3] = {p0, p1, p2};
  const Eigen::Vector3d edge_normals[3] = {(p1 - p0).cross(n), (p2 - p1).cross(n), (p0 - p2).cross(n)};
  const auto [fourth, gain] = argmax([&](const Contact& c) {
    // (b - a) x (c - a) . n == (c - a) . ((b - a) x n) up to sign: < 0 beyond edge ab, its size the area added.
    double best = 0.0;
    for (int e = 0; e < 3; ++e) best = std::max(best, (c.point - corners[e]).dot(edge_normals[e]));
    return best;
  });
  if (gain > 0.0) chosen.index[chosen.count++] = fourth;
  return chosen;
}

}  // namespace voxfmt::runtime
