#include "winding_number.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace voxfmt::bake {

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr double kBeta = 2.0;  // far field when the query is farther than kBeta * node radius (Barill: 2)
constexpr size_t kLeafSize = 8;

struct P { double x, y, z; };
P sub(const P& a, const P& b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
double dot(const P& a, const P& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
P cross(const P& a, const P& b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
double len(const P& a) { return std::sqrt(dot(a, a)); }
}  // namespace

struct WindingNumber::Impl {
  struct Node {
    P centre{};       // area-weighted centroid
    P dipole{};       // sum of area vectors (area * unit normal)
    double radius = 0;
    uint32_t begin = 0, end = 0;  // triangle range (in `order`)
    int32_t left = -1, right = -1;
  };
  std::vector<P> corners;  // 3 per triangle, in `order`
  std::vector<Node> nodes;

  int32_t build(std::vector<uint32_t>& order, const std::vector<P>& centroid, uint32_t begin, uint32_t end,
                const TriangleMesh& mesh) {
    const int32_t id = int32_t(nodes.size());
    nodes.push_back({});
    Node n;
    n.begin = begin;
    n.end = end;
    double area_sum = 0;
    P lo = centroid[order[begin]], hi = lo;
    for (uint32_t i = begin; i < end; ++i) {
      const auto& t = mesh.triangles[order[i]];
      const P a{mesh.vertices[t[0]][0], mesh.vertices[t[0]][1], mesh.vertices[t[0]][2]};
      const P b{mesh.vertices[t[1]][0], mesh.vertices[t[1]][1], mesh.vertices[t[1]][2]};
      const P c{mesh.vertices[t[2]][0], mesh.vertices[t[2]][1], mesh.vertices[t[2]][2]};
      const P area_vector = cross(sub(b, a), sub(c, a));
      const double area = 0.5 * len(area_vector);
      n.dipole = {n.dipole.x + 0.5 * area_vector.x, n.dipole.y + 0.5 * area_vector.y, n.dipole.z + 0.5 * area_vector.z};
      const P& g = centroid[order[i]];
      n.centre = {n.centre.x + area * g.x, n.centre.y + area * g.y, n.centre.z + area * g.z};
      area_sum += area;
      lo = {std::min(lo.x, g.x), std::min(lo.y, g.y), std::min(lo.z, g.z)};
      hi = {std::max(hi.x, g.x), std::max(hi.y, g.y), std::max(hi.z, g.z)};
    }
    if (area_sum > 0) n.centre = {n.centre.x / area_sum, n.centre.y / area_sum, n.centre.z / area_sum};
    else n.centre = {(lo.x + hi.x) / 2, (lo.y + hi.y) / 2, (lo.z + hi.z) / 2};
    for (uint32_t i = begin; i < end; ++i)
      for (int k = 0; k < 3; ++k) {
        const Vec3& v = mesh.vertices[mesh.triangles[order[i]][k]];
        n.radius = std::max(n.radius, len(sub(P{v[0], v[1], v[2]}, n.centre)));
      }
    if (end - begin > kLeafSize) {
      const P extent = sub(hi, lo);
      const int axis = extent.x >= extent.y && extent.x >= extent.z ? 0 : extent.y >= extent.z ? 1 : 2;
      auto key = [&](uint32_t t) { return axis == 0 ? centroid[t].x : axis == 1 ? centroid[t].y : centroid[t].z; };
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
  static double solid_angle(const P& q, const P& A, const P& B, const P& C) {
    const P a = sub(A, q), b = sub(B, q), c = sub(C, q);
    const double la = len(a), lb = len(b), lc = len(c);
    const double numerator = dot(a, cross(b, c));
    const double denominator = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
    return 2 * std::atan2(numerator, denominator);
  }

  double evaluate(int32_t id, const P& q) const {
    const Node& n = nodes[size_t(id)];
    const P r = sub(n.centre, q);
    const double distance = len(r);
    if (distance > kBeta * n.radius) return dot(n.dipole, r) / (distance * distance * distance) / (4 * kPi);
    if (n.left < 0) {
      double omega = 0;
      for (uint32_t i = n.begin; i < n.end; ++i) omega += solid_angle(q, corners[3 * i], corners[3 * i + 1], corners[3 * i + 2]);
      return omega / (4 * kPi);
    }
    return evaluate(n.left, q) + evaluate(n.right, q);
  }
};

WindingNumber::WindingNumber(const TriangleMesh& mesh) : impl_(std::make_unique<Impl>()) {
  std::vector<P> centroid(mesh.triangles.size());
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    P g{0, 0, 0};
    for (int k = 0; k < 3; ++k) {
      const Vec3& v = mesh.vertices[mesh.triangles[t][k]];
      g = {g.x + v[0] / 3, g.y + v[1] / 3, g.z + v[2] / 3};
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

double WindingNumber::operator()(const Vec3& point) const {
  if (impl_->nodes.empty()) return 0;
  return impl_->evaluate(0, P{point[0], point[1], point[2]});
}

}  // namespace voxfmt::bake
