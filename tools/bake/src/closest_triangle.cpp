#include "closest_triangle.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "vec3_math.h"

namespace voxfmt::bake {

namespace {

constexpr uint32_t kLeafSize = 4;

// Squared distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
double distance2_to_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return dot(ap, ap);
  const Vec3 bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return dot(bp, bp);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return distance2(p, a + ab * (d1 / (d1 - d3)));
  const Vec3 cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return dot(cp, cp);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return distance2(p, a + ac * (d2 / (d2 - d6)));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return distance2(p, b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
  const double denom = 1 / (va + vb + vc);
  return distance2(p, a + ab * (vb * denom) + ac * (vc * denom));
}

}  // namespace

ClosestTriangle::ClosestTriangle(const std::vector<std::array<Vec3, 3>>& corners) {
  std::vector<Vec3> centroids(corners.size());
  for (size_t t = 0; t < corners.size(); ++t)
    for (int a = 0; a < 3; ++a) centroids[t][a] = (corners[t][0][a] + corners[t][1][a] + corners[t][2][a]) / 3;
  order_.resize(corners.size());
  std::iota(order_.begin(), order_.end(), 0u);
  tris_ = corners;  // indexed by triangle until the tree is built
  nodes_.reserve(2 * corners.size() / kLeafSize + 2);
  if (!corners.empty()) build(0, uint32_t(corners.size()), centroids);
  std::vector<std::array<Vec3, 3>> ordered;
  ordered.reserve(corners.size());
  for (uint32_t t : order_) ordered.push_back(corners[t]);
  tris_.swap(ordered);
}

uint32_t ClosestTriangle::build(uint32_t begin, uint32_t end, const std::vector<Vec3>& centroids) {
  const uint32_t id = uint32_t(nodes_.size());
  nodes_.push_back({});
  Node node{};
  Vec3 centroid_lo{}, centroid_hi{};
  for (int a = 0; a < 3; ++a) {
    node.lo[a] = centroid_lo[a] = std::numeric_limits<double>::infinity();
    node.hi[a] = centroid_hi[a] = -std::numeric_limits<double>::infinity();
  }
  for (uint32_t i = begin; i < end; ++i) {
    const uint32_t t = order_[i];
    for (int a = 0; a < 3; ++a) {
      for (const Vec3& corner : tris_[t]) {
        node.lo[a] = std::min(node.lo[a], corner[a]);
        node.hi[a] = std::max(node.hi[a], corner[a]);
      }
      centroid_lo[a] = std::min(centroid_lo[a], centroids[t][a]);
      centroid_hi[a] = std::max(centroid_hi[a], centroids[t][a]);
    }
  }
  if (end - begin <= kLeafSize) {
    node.first = begin;
    node.count = end - begin;
    nodes_[id] = node;
    return id;
  }
  // Median split along the longest axis of the centroids' box.
  const Vec3 extent = centroid_hi - centroid_lo;
  const int axis = extent[0] >= extent[1] && extent[0] >= extent[2] ? 0 : extent[1] >= extent[2] ? 1 : 2;
  const uint32_t mid = begin + (end - begin) / 2;
  std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end, [&](uint32_t a, uint32_t b) {
    return centroids[a][axis] < centroids[b][axis] || (centroids[a][axis] == centroids[b][axis] && a < b);
  });
  build(begin, mid, centroids);
  node.first = build(mid, end, centroids);
  node.count = 0;
  nodes_[id] = node;
  return id;
}

std::pair<double, uint32_t> ClosestTriangle::nearest(const Vec3& p, double bound2, uint32_t hint, double slack) const {
  const double shrink = 1 / ((1 + slack) * (1 + slack));  // a box must be this much nearer than the best to open
  double best = bound2;
  uint32_t best_triangle = hint;
  if (nodes_.empty()) return {best, best_triangle};
  auto box_distance2 = [&](const Node& n) {
    double d2 = 0;
    for (int a = 0; a < 3; ++a) {
      const double below = n.lo[a] - p[a], above = p[a] - n.hi[a];
      const double out = std::max({below, above, 0.0});
      d2 += out * out;
    }
    return d2;
  };
  // Depth-first, nearer child first; a box no nearer than the best so far is skipped.
  uint32_t stack[64];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& n = nodes_[stack[--top]];
    if (box_distance2(n) >= best * shrink) continue;
    if (n.count > 0) {
      for (uint32_t i = n.first; i < n.first + n.count; ++i) {
        const double d2 = distance2_to_triangle(p, tris_[i][0], tris_[i][1], tris_[i][2]);
        if (d2 < best || (d2 == best && order_[i] < best_triangle)) {
          best = d2;
          best_triangle = order_[i];
        }
      }
      continue;
    }
    const uint32_t left = uint32_t(&n - nodes_.data()) + 1, right = n.first;
    const double dl = box_distance2(nodes_[left]), dr = box_distance2(nodes_[right]);
    if (top + 2 > 64) continue;  // deeper than any median-split tree of 2^32 triangles
    const double open_below = best * shrink;
    if (dl <= dr) {
      if (dr < open_below) stack[top++] = right;
      if (dl < open_below) stack[top++] = left;
    } else {
      if (dl < open_below) stack[top++] = left;
      if (dr < open_below) stack[top++] = right;
    }
  }
  return {best, best_triangle};
}

}  // namespace voxfmt::bake
