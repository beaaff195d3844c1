#include "winding_number.h"

#include "vec3_math.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace voxfmt::bake {

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr size_t kLeafSize = 8;

}  // namespace

struct WindingNumber::Impl {
  struct Node {
    Vec3 centre{};  // area-weighted centroid
    Vec3 dipole{};  // sum of area vectors (area * unit normal)
    double radius = 0;
    uint32_t begin = 0, end = 0;  // triangle range (in `order`)
    int32_t left = -1, right = -1;
  };
  std::vector<Vec3> corners;  // 3 per triangle, in `order`
  std::vector<Node> nodes;

  int32_t build(std::vector<uint32_t>& order, const std::vector<Vec3>& centroid, uint32_t begin, uint32_t end,
                const TriangleMesh& mesh) {
    const int32_t id = int32_t(nodes.size());
    nodes.push_back({});
    Node n;
    n.begin = begin;
    n.end = end;
    double area_sum = 0;
    Vec3 lo = centroid[order[begin]], hi = lo;
    for (uint32_t i = begin; i < end; ++i) {
      const auto& t = mesh.triangles[order[i]];
      const Vec3 a{mesh.vertices[t[0]][0], mesh.vertices[t[0]][1], mesh.vertices[t[0]][2]};
      const Vec3 b{mesh.vertices[t[1]][0], mesh.vertices[t[1]][1], mesh.vertices[t[1]][2]};
      const Vec3 c{mesh.vertices[t[2]][0], mesh.vertices[t[2]][1], mesh.vertices[t[2]][2]};
      const Vec3 area_vector = cross(b - a, c - a);
      const double area = 0.5 * length(area_vector);
      n.dipole = {n.dipole[0] + 0.5 * area_vector[0], n.dipole[1] + 0.5 * area_vector[1],
                  n.dipole[2] + 0.5 * area_vector[2]};
      const Vec3& g = centroid[order[i]];
      n.centre = {n.centre[0] + area * g[0], n.centre[1] + area * g[1], n.centre[2] + area * g[2]};
      area_sum += area;
      lo = {std::min(lo[0], g[0]), std::min(lo[1], g[1]), std::min(lo[2], g[2])};
      hi = {std::max(hi[0], g[0]), std::max(hi[1], g[1]), std::max(hi[2], g[2])};
    }
    if (area_sum > 0)
      n.centre = {n.centre[0] / area_sum, n.centre[1] / area_sum, n.centre[2] / area_sum};
    else
      n.centre = {(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2};
    for (uint32_t i = begin; i < end; ++i)
      for (int k = 0; k < 3; ++k) {
        const Vec3& v = mesh.vertices[mesh.triangles[order[i]][k]];
        n.radius = std::max(n.radius, length(v - n.centre));
      }
    if (end - begin > kLeafSize) {
      const Vec3 extent = hi - lo;
      const int axis = extent[0] >= extent[1] && extent[0] >= extent[2] ? 0 : extent[1] >= extent[2] ? 1 : 2;
      auto key = [&](uint32_t t) { return axis == 0 ? centroid[t][0] : axis == 1 ? centroid[t][1] : centroid[t][2]; };
      const uint32_t mid = begin + (end - begin) / 2;
      std::nth_element(order.begin() + begin, order.begin() + mid, order.begin() + end,
                       [&](uint32_t a, uint32_t b) { return key(a) < key(b) || (key(a) == key(b) && a < b); });
      n.left = build(order, centroid, begin, mid, mesh);
      n.right = build(order, centroid, mid, end, mesh);
    }
    nodes[size_t(id)] = n;
    return id;
  }

  // Solid angle of a triangle seen from q (Van Oosterom & Strackee 1983), signed by orientation.
  static double solid_angle(const Vec3& q, const Vec3& A, const Vec3& B, const Vec3& C) {
    const Vec3 a = A - q, b = B - q, c = C - q;
    const double la = length(a), lb = length(b), lc = length(c);
    const double numerator = dot(a, cross(b, c));
    const double denominator = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
    return 2 * std::atan2(numerator, denominator);
  }

  // Far field when the query is farther than beta node radii (Barill et al.: 2).
  double evaluate(int32_t id, const Vec3& q, double beta) const {
    const Node& n = nodes[size_t(id)];
    const Vec3 r = n.centre - q;
    const double distance = length(r);
    if (distance > beta * n.radius) return dot(n.dipole, r) / (distance * distance * distance) / (4 * kPi);
    if (n.left < 0) {
      double omega = 0;
      for (uint32_t i = n.begin; i < n.end; ++i)
        omega += solid_angle(q, corners[3 * i], corners[3 * i + 1], corners[3 * i + 2]);
      return omega / (4 * kPi);
    }
    return evaluate(n.left, q, beta) + evaluate(n.right, q, beta);
  }
};

WindingNumber::WindingNumber(const TriangleMesh& mesh) : impl_(std::make_unique<Impl>()) {
  std::vector<Vec3> centroid(mesh.triangles.size());
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    Vec3 g{0, 0, 0};
    for (int k = 0; k < 3; ++k) {
      const Vec3& v = mesh.vertices[mesh.triangles[t][k]];
      g = {g[0] + v[0] / 3, g[1] + v[1] / 3, g[2] + v[2] / 3};
    }
    centroid[t] = g;
  }
  std::vector<uint32_t> order(mesh.triangles.size());
  std::iota(order.begin(), order.end(), 0u);
  if (!order.empty()) impl_->build(order, centroid, 0, uint32_t(order.size()), mesh);
  impl_->corners.reserve(3 * order.size());
  for (uint32_t t : order)
    for (int k = 0; k < 3; ++k) {
      const Vec3& v = mesh.vertices[mesh.triangles[t][k]];
      impl_->corners.push_back({v[0], v[1], v[2]});
    }
}

WindingNumber::~WindingNumber() = default;

double WindingNumber::evaluate(const Vec3& point, double beta) const {
  if (impl_->nodes.empty()) return 0;
  return impl_->evaluate(0, point, beta);
}

}  // namespace voxfmt::bake
