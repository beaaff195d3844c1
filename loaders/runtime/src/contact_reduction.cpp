#include "voxfmt/runtime/contact_reduction.h"

#include <Eigen/Geometry>

#include <algorithm>

namespace voxfmt::runtime {

std::vector<size_t> reduce_contacts(const std::vector<Contact>& contacts, size_t max_points) {
  std::vector<size_t> chosen;
  max_points = std::min<size_t>(max_points, 4);
  if (contacts.empty() || max_points == 0) return chosen;
  if (contacts.size() <= max_points) {
    for (size_t i = 0; i < contacts.size(); ++i) chosen.push_back(i);
    return chosen;
  }
  auto argmax = [&](auto&& score) {
    size_t best = 0;
    double best_score = -1.0;
    for (size_t i = 0; i < contacts.size(); ++i) {
      const double s = score(contacts[i]);
      if (s > best_score) best = i, best_score = s;
    }
    return std::make_pair(best, best_score);
  };
  const size_t deepest = argmax([](const Contact& c) { return c.depth; }).first;
  chosen.push_back(deepest);
  const Eigen::Vector3d p0 = contacts[deepest].point;
  if (max_points == 1) return chosen;
  const auto [far, far_d2] = argmax([&](const Contact& c) { return (c.point - p0).squaredNorm(); });
  if (far_d2 <= 0.0) return chosen;  // all contacts at one point
  chosen.push_back(far);
  const Eigen::Vector3d p1 = contacts[far].point;
  if (max_points == 2) return chosen;
  const auto [third, twice_area] = argmax([&](const Contact& c) { return (p1 - p0).cross(c.point - p0).norm(); });
  if (twice_area <= 0.0) return chosen;  // collinear
  chosen.push_back(third);
  const Eigen::Vector3d p2 = contacts[third].point;
  if (max_points == 3) return chosen;
  // The fourth point adds the most area: the largest triangle it forms with an edge it lies beyond.
  const Eigen::Vector3d n = (p1 - p0).cross(p2 - p0);
  const Eigen::Vector3d corners[3] = {p0, p1, p2};
  const auto [fourth, gain] = argmax([&](const Contact& c) {
    double best = 0.0;
    for (int e = 0; e < 3; ++e) {
      const Eigen::Vector3d& a = corners[e];
      const Eigen::Vector3d& b = corners[(e + 1) % 3];
      const double side = (b - a).cross(c.point - a).dot(n);  // < 0: beyond edge ab
      if (side < 0.0) best = std::max(best, -side);
    }
    return best;
  });
  if (gain > 0.0) chosen.push_back(fourth);
  return chosen;
}

}  // namespace voxfmt::runtime
