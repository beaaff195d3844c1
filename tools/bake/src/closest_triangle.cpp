#include "closest_triangle.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include <oneapi/tbb/parallel_for.h>

#include "triangle_closest_point.h"

namespace voxfmt::bake {

namespace {

constexpr uint32_t kLeafSize = 4;
// Splits by the surface-area heuristic above this depth, by the median below it: at most kSurfaceAreaDepth + 32
// levels for any number of triangles, within nearest()'s stack of 64.
constexpr int kSurfaceAreaDepth = 24;
constexpr int kBins = 16;

struct Box {
  double lo[3] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
                  std::numeric_limits<double>::infinity()};
  double hi[3] = {-std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity(),
                  -std::numeric_limits<double>::infinity()};
  void add(const Box& b) {
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], b.lo[a]), hi[a] = std::max(hi[a], b.hi[a]);
  }
  void add(const std::array<Vec3, 2>& b) {
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], b[0][a]), hi[a] = std::max(hi[a], b[1][a]);
  }
  double half_area() const {
    const double x = hi[0] - lo[0], y = hi[1] - lo[1], z = hi[2] - lo[2];
    return x < 0 ? 0 : x * y + y * z + z * x;
  }
};

// Squared distance from p to triangle abc.
double distance2_to_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  Feature feature;
  return distance2(p, closest_on_triangle(p, a, b, c, feature));
}

}  // namespace

struct ClosestTriangle::Inputs {
  std::vector<Vec3> centroids;
  std::vector<std::array<Vec3, 2>> boxes;
};

// A node of the tree's top, split before the subtrees below it are built: each child is another top node
// (its index) or a subtree built on its own (-1 - its index).
struct ClosestTriangle::Top {
  Node node;
  int32_t child[2];
};

ClosestTriangle::ClosestTriangle(const std::vector<std::array<Vec3, 3>>& corners, uint32_t parallel_from) {
  Inputs in{std::vector<Vec3>(corners.size()), std::vector<std::array<Vec3, 2>>(corners.size())};
  tbb::parallel_for(size_t(0), corners.size(), [&](size_t t) {
    for (int a = 0; a < 3; ++a) {
      in.centroids[t][a] = (corners[t][0][a] + corners[t][1][a] + corners[t][2][a]) / 3;
      in.boxes[t][0][a] = std::min({corners[t][0][a], corners[t][1][a], corners[t][2][a]});
      in.boxes[t][1][a] = std::max({corners[t][0][a], corners[t][1][a], corners[t][2][a]});
    }
  });
  order_.resize(corners.size());
  std::iota(order_.begin(), order_.end(), 0u);
  if (!corners.empty()) build_tree(in, parallel_from);
  tris_.reserve(corners.size());
  for (uint32_t t : order_) tris_.push_back(corners[t]);
}

void ClosestTriangle::build_tree(const Inputs& in, uint32_t parallel_from) {
  // The top, split on this thread (a top node always has children: it holds more than a leaf)...
  parallel_from = std::max(parallel_from, kLeafSize + 1);
  std::vector<Top> tops;
  struct Range {
    uint32_t begin, end;
    int depth;
  };
  std::vector<Range> ranges;
  auto split_top = [&](auto& self, uint32_t begin, uint32_t end, int depth) -> int32_t {
    if (end - begin < parallel_from) {
      ranges.push_back({begin, end, depth});
      return -int32_t(ranges.size());
    }
    uint32_t mid = 0;
    const Node node = split(begin, end, in, depth, mid);
    const int32_t id = int32_t(tops.size());
    tops.push_back({node, {0, 0}});
    const int32_t first = self(self, begin, mid, depth + 1);
    tops[size_t(id)].child[0] = first;
    tops[size_t(id)].child[1] = self(self, mid, end, depth + 1);
    return id;
  };
  const int32_t root = split_top(split_top, 0, uint32_t(order_.size()), 0);
  // ... the subtrees below it on all threads (disjoint ranges of order_) ...
  std::vector<std::vector<Node>> subtrees(ranges.size());
  std::vector<int> deepest(ranges.size(), 0);
  tbb::parallel_for(size_t(0), ranges.size(), [&](size_t r) {
    subtrees[r].reserve(2 * (ranges[r].end - ranges[r].begin) / kLeafSize + 2);
    build(ranges[r].begin, ranges[r].end, in, ranges[r].depth, subtrees[r], deepest[r]);
  });
  // ... and all of it laid out depth first, each subtree's inner nodes' child indices moved to where it lands.
  size_t count = tops.size();
  for (const std::vector<Node>& t : subtrees) count += t.size();
  nodes_.reserve(count);
  auto place = [&](auto& self, int32_t code) -> uint32_t {
    const uint32_t at = uint32_t(nodes_.size());
    if (code < 0) {
      std::vector<Node>& subtree = subtrees[size_t(-1 - code)];
      for (Node n : subtree) {
        if (n.count == 0) n.first += at;
        nodes_.push_back(n);
      }
      std::vector<Node>().swap(subtree);
      return at;
    }
    nodes_.push_back({});
    Node node = tops[size_t(code)].node;
    self(self, tops[size_t(code)].child[0]);
    node.first = self(self, tops[size_t(code)].child[1]);
    nodes_[at] = node;
    return at;
  };
  place(place, root);
  depth_ = *std::max_element(deepest.begin(), deepest.end());
}

bool ClosestTriangle::operator==(const ClosestTriangle& other) const {
  auto same = [](const Node& a, const Node& b) {
    return std::equal(a.lo, a.lo + 3, b.lo) && std::equal(a.hi, a.hi + 3, b.hi) && a.first == b.first &&
           a.count == b.count;
  };
  return order_ == other.order_ && depth_ == other.depth_ &&
         std::equal(nodes_.begin(), nodes_.end(), other.nodes_.begin(), other.nodes_.end(), same);
}

// The binned surface-area split of order_[begin, end) (Wald 2007): the plane between two of kBins bins along an
// axis of the centroids' box that least sums each side's box area times its triangles. The first index of the
// second half after partitioning, or `end` when every split leaves a side empty.
uint32_t ClosestTriangle::surface_area_split(uint32_t begin, uint32_t end, const Inputs& in, const Vec3& centroid_lo,
                                             const Vec3& centroid_hi) {
  const std::vector<Vec3>& centroids = in.centroids;
  const std::vector<std::array<Vec3, 2>>& boxes = in.boxes;
  double best_cost = std::numeric_limits<double>::infinity();
  int best_axis = -1, best_bin = 0;
  auto bin_of = [&](uint32_t t, int axis) {
    const double extent = centroid_hi[axis] - centroid_lo[axis];
    return std::min(kBins - 1, int(kBins * ((centroids[t][axis] - centroid_lo[axis]) / extent)));
  };
  for (int axis = 0; axis < 3; ++axis) {
    if (!(centroid_hi[axis] > centroid_lo[axis])) continue;
    Box bins[kBins];
    uint32_t counts[kBins] = {};
    for (uint32_t i = begin; i < end; ++i) {
      const int b = bin_of(order_[i], axis);
      bins[b].add(boxes[order_[i]]);
      ++counts[b];
    }
    double right_area[kBins];  // of bins b .. kBins - 1
    uint32_t right_count[kBins];
    Box right;
    uint32_t count = 0;
    for (int b = kBins - 1; b > 0; --b) {
      right.add(bins[b]);
      count += counts[b];
      right_area[b] = right.half_area();
      right_count[b] = count;
    }
    Box left;
    count = 0;
    for (int b = 0; b + 1 < kBins; ++b) {  // the plane after bin b
      left.add(bins[b]);
      count += counts[b];
      if (count == 0 || right_count[b + 1] == 0) continue;
      const double cost = left.half_area() * count + right_area[b + 1] * right_count[b + 1];
      if (cost < best_cost) best_cost = cost, best_axis = axis, best_bin = b;
    }
  }
  if (best_axis < 0) return end;
  return uint32_t(std::partition(order_.begin() + begin, order_.begin() + end,
                                 [&](uint32_t t) { return bin_of(t, best_axis) <= best_bin; }) -
                  order_.begin());
}

ClosestTriangle::Node ClosestTriangle::split(uint32_t begin, uint32_t end, const Inputs& in, int depth, uint32_t& mid) {
  const std::vector<Vec3>& centroids = in.centroids;
  Node node{};
  Vec3 centroid_lo{}, centroid_hi{};
  for (int a = 0; a < 3; ++a) {
    node.lo[a] = centroid_lo[a] = std::numeric_limits<double>::infinity();
    node.hi[a] = centroid_hi[a] = -std::numeric_limits<double>::infinity();
  }
  for (uint32_t i = begin; i < end; ++i) {
    const uint32_t t = order_[i];
    for (int a = 0; a < 3; ++a) {
      node.lo[a] = std::min(node.lo[a], in.boxes[t][0][a]);
      node.hi[a] = std::max(node.hi[a], in.boxes[t][1][a]);
      centroid_lo[a] = std::min(centroid_lo[a], centroids[t][a]);
      centroid_hi[a] = std::max(centroid_hi[a], centroids[t][a]);
    }
  }
  if (end - begin <= kLeafSize) {
    node.first = begin;
    node.count = end - begin;
    return node;
  }
  mid = depth < kSurfaceAreaDepth ? surface_area_split(begin, end, in, centroid_lo, centroid_hi) : end;
  if (mid == begin || mid == end) {  // deep, or no split separates the centroids: the median along the longest axis
    const Vec3 extent = centroid_hi - centroid_lo;
    const int axis = extent[0] >= extent[1] && extent[0] >= extent[2] ? 0 : extent[1] >= extent[2] ? 1 : 2;
    mid = begin + (end - begin) / 2;
    std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end, [&](uint32_t a, uint32_t b) {
      return centroids[a][axis] < centroids[b][axis] || (centroids[a][axis] == centroids[b][axis] && a < b);
    });
  }
  node.count = 0;
  return node;
}

uint32_t ClosestTriangle::build(uint32_t begin, uint32_t end, const Inputs& in, int depth, std::vector<Node>& out,
                                int& deepest) {
  const uint32_t id = uint32_t(out.size());
  out.push_back({});
  uint32_t mid = 0;
  Node node = split(begin, end, in, depth, mid);
  if (node.count == 0) {
    build(begin, mid, in, depth + 1, out, deepest);
    node.first = build(mid, end, in, depth + 1, out, deepest);
  } else {
    deepest = std::max(deepest, depth);
  }
  out[id] = node;
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
    if (top + 2 > 64) continue;  // deeper than any tree build() makes (kSurfaceAreaDepth + 32 levels)
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
