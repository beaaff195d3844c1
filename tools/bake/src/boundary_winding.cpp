#include "boundary_winding.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/parallel_sort.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include "vec3_math.h"

namespace voxfmt::bake {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
constexpr double kPi = 3.14159265358979323846;
constexpr double kEpsilon = std::numeric_limits<double>::epsilon() / 2;  // unit roundoff
// Shewchuk's bound on the rounding error of a 2x2 orientation determinant computed in doubles.
constexpr double kOrientBound = (3 + 16 * kEpsilon) * kEpsilon;

// A brick (8 voxels) is interpolated from a lattice 4 voxels apart; each of its points from its block (32 voxels,
// points 16 apart, where the caps are summed exactly) within kBlockTarget, evaluating the caps near the block
// (at most max(kBlockWork, boundary edges / kBlockWorkShare) evaluations a point), or exactly where the caps
// crowd the block too much for that.
constexpr int64_t kBrick = 8, kSpacing = 4;
constexpr int64_t kBlock = 32, kBlockSpacing = 16;
constexpr double kBlockTarget = 1e-4;
constexpr size_t kBlockWork = 256, kBlockWorkShare = 2;
// Caps passing within this many voxels of a cell are always evaluated per voxel. Farther ones join them, the most
// bound per unit of work first (a strip is one evaluation per voxel, a fan one per edge), until the cell's bound
// is below the target asked for or the work reaches max(kMaxWork, boundary edges / kMaxWorkShare).
constexpr double kNearStrip = 4.0;
constexpr size_t kMaxWork = 64, kMaxWorkShare = 8;
// Tensor-product quadratic interpolation on nodes 0, H, 2H errs by at most 0.0642 H^3 (1 + 1.25 + 1.25^2)
// times the largest third derivative along an axis (Lebesgue constant 1.25); the third derivatives of a cap's
// solid angle / 4 pi are the Biot-Savart kernel's second ones, at most 6 / (4 pi r^4) per unit length of its
// boundary. Errors in the 27 values pass through weights summing in magnitude to at most 1.25^3 < 2.
constexpr double interpolation_error(double spacing) {
  return 0.06415 * 3.8125 * spacing * spacing * spacing * 6 / (4 * kPi);
}
constexpr double kValueErrorGain = 1.953125;

// atan2 to within 1e-11 (a polynomial on [-tan(pi/8), tan(pi/8)], fitted to 4.2e-12, after the usual octant
// reduction), about three times as fast as libm's: the strips are the bake's inner loop. Their sums err by at most
// kAtanError / 2 pi per strip, which the decisions below allow for.
constexpr double kAtanError = 1e-11;
inline double fast_atan2(double y, double x) {
  const double ax = std::abs(x), ay = std::abs(y);
  const double hi = std::max(ax, ay), lo = std::min(ax, ay);
  // Past tan(pi/8), atan(lo / hi) = pi/4 + atan((lo - hi) / (lo + hi)): one division either way.
  const bool upper = lo > 0.41421356237309503 * hi;
  const double t = upper ? (lo - hi) / (lo + hi) : hi > 0 ? lo / hi : 0.0;
  const double offset = upper ? kPi / 4 : 0.0;
  const double u = t * t;
  double r = 0.0455126675776084;
  r = r * u - 0.08368926998702557;
  r = r * u + 0.11021713290473542;
  r = r * u - 0.14279648253446;
  r = r * u + 0.1999978626534891;
  r = r * u - 0.3333332999109862;
  r = r * u + 0.999999999848195;
  r = offset + t * r;
  if (ay > ax) r = kPi / 2 - r;
  if (x < 0) r = kPi - r;
  return std::copysign(r, y);
}

// Sign of (a_y - p_y)(b_z - p_z) - (a_z - p_z)(b_y - p_y), for the line through p along x moved by (e, e^2) in
// (y, z) for an infinitesimal e: never 0 unless a and b coincide in (y, z). Exact: a float filter, then CGAL.
int orient_yz(const Vec3& p, const Vec3& a, const Vec3& b) {
  const double l = (a[1] - p[1]) * (b[2] - p[2]), r = (a[2] - p[2]) * (b[1] - p[1]);
  const double det = l - r, error = kOrientBound * (std::abs(l) + std::abs(r));
  if (det > error) return 1;
  if (det < -error) return -1;
  const CGAL::Orientation o =
      CGAL::orientation(Kernel::Point_2(p[1], p[2]), Kernel::Point_2(a[1], a[2]), Kernel::Point_2(b[1], b[2]));
  if (o != CGAL::COLLINEAR) return o == CGAL::LEFT_TURN ? 1 : -1;
  // The determinant is affine in p: d/dp_y = a_z - b_z, d/dp_z = b_y - a_y.
  if (a[2] != b[2]) return a[2] > b[2] ? 1 : -1;
  if (a[1] != b[1]) return b[1] > a[1] ? 1 : -1;
  return 0;
}

// Exact sign of the component `axis` of triangle abc's normal (b - a) x (c - a): its orientation projected onto
// the other two axes in cyclic order (x: (y, z), y: (z, x), z: (x, y)).
int normal_sign(const Vec3& a, const Vec3& b, const Vec3& c, int axis) {
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;
  const double l = (b[u] - a[u]) * (c[v] - a[v]), r = (b[v] - a[v]) * (c[u] - a[u]);
  const double det = l - r, error = kOrientBound * (std::abs(l) + std::abs(r));
  if (det > error) return 1;
  if (det < -error) return -1;
  const CGAL::Orientation o =
      CGAL::orientation(Kernel::Point_2(a[u], a[v]), Kernel::Point_2(b[u], b[v]), Kernel::Point_2(c[u], c[v]));
  return o == CGAL::COLLINEAR ? 0 : o == CGAL::LEFT_TURN ? 1 : -1;
}

// Sign of n . (p' - a), n = (b - a) x (c - a), for p' = p + (e^3, e, e^2) with an infinitesimal e: the point that
// every predicate here moves the same way (the line through p by (e, e^2) in (y, z), then p along it by e^3).
int side_of_plane(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& p) {
  const CGAL::Orientation side =
      CGAL::orientation(Kernel::Point_3(a[0], a[1], a[2]), Kernel::Point_3(b[0], b[1], b[2]),
                        Kernel::Point_3(c[0], c[1], c[2]), Kernel::Point_3(p[0], p[1], p[2]));
  if (side != CGAL::COPLANAR) return side == CGAL::POSITIVE ? 1 : -1;
  for (const int axis : {1, 2, 0})
    if (const int s = normal_sign(a, b, c, axis)) return s;
  return 0;  // a degenerate triangle
}

// Distance between two axis-aligned boxes (0 if they meet).
double box_distance(const Vec3& lo1, const Vec3& hi1, const Vec3& lo2, const Vec3& hi2) {
  double s = 0;
  for (int a = 0; a < 3; ++a) {
    const double gap = std::max({0.0, lo1[a] - hi2[a], lo2[a] - hi1[a]});
    s += gap * gap;
  }
  return std::sqrt(s);
}

double point_segment_distance(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double len2 = dot(ab, ab);
  const double t = len2 > 0 ? std::clamp(dot(p - a, ab) / len2, 0.0, 1.0) : 0.0;
  return length(p - (a + ab * t));
}

// Bounds on the integrals of 1/r^4 along a segment and along a ray, at least d from every point of the cell:
// r >= max(d, |t - t0|) along the line gives 2/d^3 + 2/(3 d^3).
double segment_term(double length, double d) {
  if (!(d > 0)) return std::numeric_limits<double>::infinity();
  return std::min(length / (d * d * d * d), 8.0 / (3 * d * d * d));
}
double ray_term(double d) {
  if (!(d > 0)) return std::numeric_limits<double>::infinity();
  return 8.0 / (3 * d * d * d);
}

// Points of a lattice of `spacing` (non-negative multiples of it), 21 bits an axis.
uint64_t lattice_key(int64_t x, int64_t y, int64_t z, int64_t spacing) {
  return uint64_t(x / spacing) | uint64_t(y / spacing) << 21 | uint64_t(z / spacing) << 42;
}
std::array<int64_t, 3> lattice_point(uint64_t key, int64_t spacing) {
  return {int64_t(key & 0x1fffff) * spacing, int64_t(key >> 21 & 0x1fffff) * spacing,
          int64_t(key >> 42 & 0x1fffff) * spacing};
}

}  // namespace

BoundaryWinding::BoundaryWinding(const std::vector<std::array<uint32_t, 3>>& triangles,
                                 const std::vector<Vec3>& vertices) {
  // Each undirected edge's net count of faces running from its lower to its higher vertex id.
  std::unordered_map<uint64_t, int32_t> net;
  net.reserve(triangles.size() * 2);
  for (const auto& t : triangles)
    for (int c = 0; c < 3; ++c) {
      const uint32_t u = t[c], v = t[(c + 1) % 3];
      if (u == v) continue;
      if (u < v)
        ++net[uint64_t(u) << 32 | v];
      else
        --net[uint64_t(v) << 32 | u];
    }
  for (const auto& [key, n] : net)
    if (n != 0) {
      const uint32_t u = uint32_t(key >> 32), v = uint32_t(key);
      edges_.push_back({vertices[u], vertices[v], u, v, n, 0});
    }
  // Deterministic order (the map's is not): sums come out the same in every run.
  std::sort(edges_.begin(), edges_.end(),
            [](const BoundaryEdge& x, const BoundaryEdge& y) { return x.va != y.va ? x.va < y.va : x.vb < y.vb; });
  for (const BoundaryEdge& e : edges_) total_multiplicity_ += std::abs(e.multiplicity);

  group_components(vertices.size());
  for (Component& c : components_) place_fan(c);
}

// Components: edges sharing a vertex. Each is a closed chain (every vertex balanced), so it can be capped alone.
void BoundaryWinding::group_components(size_t vertex_count) {
  std::vector<uint32_t> parent(vertex_count);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](uint32_t v) {
    while (parent[v] != v) v = parent[v] = parent[parent[v]];
    return v;
  };
  for (const BoundaryEdge& e : edges_) parent[find(e.va)] = find(e.vb);
  std::unordered_map<uint32_t, uint32_t> component_of_root;
  for (uint32_t n = 0; n < edges_.size(); ++n) {
    BoundaryEdge& e = edges_[n];
    const auto [it, added] = component_of_root.emplace(find(e.va), uint32_t(components_.size()));
    if (added) components_.push_back({e.a, e.a, {}, 0.0, {}, {}, {}, false});
    Component& c = components_[it->second];
    e.component = it->second;
    c.edges.push_back(n);
    for (int a = 0; a < 3; ++a) {
      c.lo[a] = std::min({c.lo[a], e.a[a], e.b[a]});
      c.hi[a] = std::max({c.hi[a], e.a[a], e.b[a]});
    }
  }
}

// A component's fan: its corners and sides, its apex (the mean of its edge midpoints) and its area.
void BoundaryWinding::place_fan(Component& c) const {
  std::unordered_map<uint32_t, uint32_t> corner_of;
  Vec3 sum{0, 0, 0};
  auto corner = [&](uint32_t v, const Vec3& p) {
    const auto [it, added] = corner_of.emplace(v, uint32_t(c.corners.size()));
    if (added) c.corners.push_back(p);
    return it->second;
  };
  for (uint32_t n : c.edges) {
    sum = sum + (edges_[n].a + edges_[n].b) * 0.5;
    c.sides.push_back({corner(edges_[n].va, edges_[n].a), corner(edges_[n].vb, edges_[n].b)});
  }
  // Off the voxel lines, so that no line runs through the apex or along a spoke (a plane of voxel centres
  // through a flat loop, a ring of a lathed part, would put the apex on one).
  c.centre = sum * (1.0 / double(c.edges.size())) + Vec3{0, 1e-3 * std::sqrt(2.0), 1e-3 * std::sqrt(3.0)};
  c.area = 0;
  for (uint32_t n : c.edges)
    c.area += std::abs(edges_[n].multiplicity) * length(cross(edges_[n].a - c.centre, edges_[n].b - c.centre)) / 2;
}

double BoundaryWinding::strip(const BoundaryEdge& e, const Vec3& q) const {
  // An edge parallel to x sweeps no area (its strip's rays overlap it).
  if (e.a[1] == e.b[1] && e.a[2] == e.b[2]) return 0;
  // Solid angle of the triangle (a, b, a + infinity x) (Van Oosterom & Strackee 1983, one vertex at infinity):
  // numerator a'.(b' x X) = a'_y b'_z - a'_z b'_y.
  const Vec3 a = e.a - q, b = e.b - q;
  const double la = length(a), lb = length(b);
  if ((a[1] == 0 && a[2] == 0 && a[0] < 0) || (b[1] == 0 && b[2] == 0 && b[0] < 0)) {
    // q's line runs through an end of the edge behind q: the strip's side ray passes through q, where its angle
    // winds (the neighbouring strip's winds back). Its limit along the perturbed line: the numerator and the
    // denominator to first (and, where that vanishes, second) order in e, q moved by (0, e, e^2).
    const bool at_a = a[1] == 0 && a[2] == 0;
    const Vec3& o = at_a ? a : b;  // the end q's line runs through
    const Vec3& f = at_a ? b : a;  // the other end
    const double lf = at_a ? lb : la;
    const double sign = at_a ? 1 : -1;  // the numerator a_y b_z - a_z b_y changes sign with the roles
    const double n1 = -sign * f[2], n2 = sign * f[1];
    const double d1 = -f[1], d2 = -f[2] + (lf + f[0]) / (2 * std::abs(o[0]));
    // A vanishing first order keeps the second's sign: on the -x side it decides between the +-pi branches.
    const double angle = d1 != 0   ? std::atan2(n1 != 0 ? n1 : std::copysign(0.0, n2), d1)
                         : n1 != 0 ? std::atan2(n1, 0.0)
                                   : std::atan2(n2, d2);
    return e.multiplicity * angle / (2 * kPi);
  }
  const double l = a[1] * b[2], r = a[2] * b[1];
  double numerator = l - r;
  const double denominator = la * lb + dot(a, b) + b[0] * la + a[0] * lb;
  if (!(std::abs(numerator) > kOrientBound * (std::abs(l) + std::abs(r)))) {
    // In (or next to) the strip's plane the angle jumps by 4 pi across it: the perturbed line's side, as the
    // crossings take it.
    numerator = orient_yz(q, e.a, e.b) >= 0 ? 0.0 : -0.0;
  }
  return e.multiplicity * fast_atan2(numerator, denominator) / (2 * kPi);
}

double BoundaryWinding::fan(const Component& c, const Vec3& q) const {
  // Solid angles of the triangles (centre, a, b) (Van Oosterom & Strackee 1983); each corner's vector once.
  static thread_local std::vector<Vec3> corner;
  static thread_local std::vector<double> corner_length;
  corner.resize(c.corners.size());
  corner_length.resize(c.corners.size());
  for (size_t n = 0; n < c.corners.size(); ++n) {
    corner[n] = c.corners[n] - q;
    corner_length[n] = length(corner[n]);
  }
  const Vec3 o = c.centre - q;
  const double lo = length(o);
  double sum = 0;
  for (size_t n = 0; n < c.sides.size(); ++n) {
    const Vec3 &a = corner[c.sides[n][0]], &b = corner[c.sides[n][1]];
    const double la = corner_length[c.sides[n][0]], lb = corner_length[c.sides[n][1]];
    double numerator = dot(o, cross(a, b));
    const double denominator = lo * la * lb + dot(o, a) * lb + dot(o, b) * la + dot(a, b) * lo;
    // Shewchuk's bound for a 3x3 determinant of rounded differences, its permanent at most sqrt(3) |o| |a| |b|: on
    // or next to the triangle's plane the angle jumps by 4 pi across it, so the sign comes from the exact,
    // perturbed side (the crossings' test).
    if (!(std::abs(numerator) > 2e-15 * lo * la * lb)) {
      const BoundaryEdge& e = edges_[c.edges[n]];
      numerator = side_of_plane(c.centre, e.a, e.b, q) <= 0 ? 0.0 : -0.0;  // numerator = -n . (q - centre)
    }
    sum += edges_[c.edges[n]].multiplicity * fast_atan2(numerator, denominator);
  }
  return sum / (2 * kPi);
}

double BoundaryWinding::caps(const Vec3& q) const {
  double sum = 0;
  for (uint32_t n : strip_edges_) sum += strip(edges_[n], q);
  for (uint32_t c : fans_) sum += fan(components_[c], q);
  return sum;
}

bool BoundaryWinding::line_crossing(const Vec3& a, const Vec3& b, const Vec3& c, double j, double k,
                                    LineCrossing& out) {
  // A triangle parallel to the line (no area in projection) is never crossed by the perturbed line.
  const int o = normal_sign(a, b, c, 0);
  if (o == 0) return false;
  const Vec3 p{0, j, k};
  if (orient_yz(p, a, b) != o || orient_yz(p, b, c) != o || orient_yz(p, c, a) != o) return false;
  const Vec3 n = cross(b - a, c - a);
  const double lo = std::min({a[0], b[0], c[0]}), hi = std::max({a[0], b[0], c[0]});
  const double numerator = n[1] * (j - a[1]) + n[2] * (k - a[2]);
  double x = n[0] != 0 ? a[0] - numerator / n[0] : (lo + hi) / 2;
  x = std::clamp(x, lo, hi);
  // Rounding of the normal and of the plane equation; large for triangles nearly parallel to x, where the exact
  // side test decides instead.
  const double edge = std::max({length(b - a), length(c - a), 1e-300});
  const double nx = std::abs(n[0]);
  double slack = 1e-9 + 64 * kEpsilon *
                            (std::abs(a[0]) + edge * edge * edge / std::max(nx, 1e-300) +
                             length(n) * edge * edge * edge / std::max(nx * nx, 1e-300));
  slack = std::min(slack, hi - lo + 1e-9);
  out.x = x;
  out.slack = slack;
  out.step = -o;  // crossing a face whose normal points to +x leaves its inside
  return true;
}

bool BoundaryWinding::past_plane(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& p) {
  return side_of_plane(a, b, c, p) == normal_sign(a, b, c, 0);
}

void BoundaryWinding::prepare(const std::vector<int64_t>& bricks, const std::array<int64_t, 3>& brick_dims,
                              Caps choice) {
  brick_dims_ = brick_dims;
  strip_edges_.clear();
  fans_.clear();
  fan_triangles_.clear();
  row_fans_.clear();
  lattice_keys_.clear();
  lattice_values_.clear();
  lattice_errors_.clear();
  if (edges_.empty()) return;
  choose_caps(bricks, choice);
  index_strip_vertices();
  bin_fan_triangles();
  prepare_lattice(bricks);
}

void BoundaryWinding::choose_caps(const std::vector<int64_t>& bricks, Caps choice) {
  const int64_t B0 = brick_dims_[0], B1 = brick_dims_[1];
  // Bricks that need signs within a box of voxels grown by kNearStrip: where a cap there costs an evaluation per
  // voxel (the box may run to +infinity in x).
  auto bricks_near = [&](const Vec3& lo, const Vec3& hi) {
    int64_t first[3], last[3];
    for (int a = 0; a < 3; ++a) {
      const int64_t n = brick_dims_[size_t(a)];
      first[a] = std::clamp<int64_t>(int64_t(std::floor((lo[a] - kNearStrip) / kBrick)), 0, n);
      last[a] = std::isinf(hi[a]) ? n - 1
                                  : std::clamp<int64_t>(int64_t(std::floor((hi[a] + kNearStrip) / kBrick)), -1, n - 1);
    }
    double count = 0;
    for (int64_t bk = first[2]; bk <= last[2]; ++bk)
      for (int64_t bj = first[1]; bj <= last[1]; ++bj) {
        const int64_t row = (bk * B1 + bj) * B0;
        count += double(std::upper_bound(bricks.begin(), bricks.end(), row + last[0]) -
                        std::lower_bound(bricks.begin(), bricks.end(), row + first[0]));
      }
    return count;
  };
  for (uint32_t c = 0; c < components_.size(); ++c) {
    Component& component = components_[c];
    double strip_cost = 0;
    for (uint32_t n : component.edges) {
      const BoundaryEdge& e = edges_[n];
      if (e.a[1] == e.b[1] && e.a[2] == e.b[2]) continue;
      Vec3 lo, hi;
      for (int a = 0; a < 3; ++a) lo[a] = std::min(e.a[a], e.b[a]), hi[a] = std::max(e.a[a], e.b[a]);
      hi[0] = std::numeric_limits<double>::infinity();
      strip_cost += bricks_near(lo, hi);
    }
    const double fan_cost = double(component.edges.size()) * bricks_near(component.lo, component.hi);
    component.fan = choice == Caps::Cheaper ? fan_cost < strip_cost : choice == Caps::Fans;
    if (component.fan) {
      fans_.push_back(c);
      for (uint32_t n : component.edges) fan_triangles_.push_back(n);
    } else {
      strip_edges_.insert(strip_edges_.end(), component.edges.begin(), component.edges.end());
    }
  }
}

void BoundaryWinding::index_strip_vertices() {  // for the junctions of select_near
  uint32_t vertices = 0;
  for (const BoundaryEdge& e : edges_) vertices = std::max({vertices, e.va + 1, e.vb + 1});
  vertex_first_.assign(vertices + 1, 0);
  for (uint32_t n : strip_edges_) ++vertex_first_[edges_[n].va + 1], ++vertex_first_[edges_[n].vb + 1];
  for (uint32_t v = 0; v < vertices; ++v) vertex_first_[v + 1] += vertex_first_[v];
  vertex_edges_.resize(vertex_first_.back());
  std::vector<uint32_t> fill(vertex_first_.begin(), vertex_first_.end() - 1);
  for (uint32_t n : strip_edges_) {
    vertex_edges_[fill[edges_[n].va]++] = n;
    vertex_edges_[fill[edges_[n].vb]++] = n;
  }
}

// Each fan triangle under the rows of bricks whose voxel lines its projection may cover.
void BoundaryWinding::bin_fan_triangles() {
  const int64_t B1 = brick_dims_[1], B2 = brick_dims_[2];
  for (uint32_t t = 0; t < fan_triangles_.size(); ++t) {
    Vec3 a, b, c;
    int32_t multiplicity;
    fan_triangle(kFanTriangle + t, a, b, c, multiplicity);
    const int64_t j0 = std::max<int64_t>(0, int64_t(std::ceil(std::min({a[1], b[1], c[1]}))));
    const int64_t j1 = std::min<int64_t>(B1 * kBrick - 1, int64_t(std::floor(std::max({a[1], b[1], c[1]}))));
    const int64_t k0 = std::max<int64_t>(0, int64_t(std::ceil(std::min({a[2], b[2], c[2]}))));
    const int64_t k1 = std::min<int64_t>(B2 * kBrick - 1, int64_t(std::floor(std::max({a[2], b[2], c[2]}))));
    for (int64_t bk = k0 / kBrick; k0 <= k1 && bk <= k1 / kBrick; ++bk)
      for (int64_t bj = j0 / kBrick; j0 <= j1 && bj <= j1 / kBrick; ++bj) row_fans_.push_back({bk * B1 + bj, t});
  }
  std::sort(row_fans_.begin(), row_fans_.end());
}

namespace {

// Keys of the lattice points of the bricks' cells (kSpacing apart, 27 a brick, shared by up to 8), ascending, once.
std::vector<uint64_t> brick_lattice_keys(const std::vector<int64_t>& bricks, const std::array<int64_t, 3>& dims) {
  std::vector<uint64_t> keys;
  keys.reserve(bricks.size() * 27);
  for (const int64_t brick : bricks) {
    const int64_t bi = brick % dims[0], bj = brick / dims[0] % dims[1], bk = brick / (dims[0] * dims[1]);
    for (int n = 0; n < 27; ++n)
      keys.push_back(lattice_key(bi * kBrick + kSpacing * (n % 3), bj * kBrick + kSpacing * (n / 3 % 3),
                                 bk * kBrick + kSpacing * (n / 9), kSpacing));
  }
  tbb::parallel_sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  return keys;
}

// The lattice points grouped by the block (kBlock voxels) they lie in: (block key, point) sorted, and where each
// block's run begins (plus the end).
struct PointsByBlock {
  std::vector<std::pair<uint64_t, uint32_t>> points;
  std::vector<size_t> first;
  std::array<int64_t, 3> block_lo(size_t b) const { return lattice_point(points[first[b]].first, kBlock); }
};

PointsByBlock points_by_block(const std::vector<uint64_t>& keys) {
  PointsByBlock blocks;
  blocks.points.resize(keys.size());
  for (size_t n = 0; n < keys.size(); ++n) {
    const auto p = lattice_point(keys[n], kSpacing);
    blocks.points[n] = {lattice_key(p[0] / kBlock * kBlock, p[1] / kBlock * kBlock, p[2] / kBlock * kBlock, kBlock),
                        uint32_t(n)};
  }
  tbb::parallel_sort(blocks.points.begin(), blocks.points.end());
  for (size_t n = 0; n < blocks.points.size(); ++n)
    if (n == 0 || blocks.points[n].first != blocks.points[n - 1].first) blocks.first.push_back(n);
  blocks.first.push_back(blocks.points.size());
  return blocks;
}

// The 27 points (kBlockSpacing apart) of a block's cell whose lower corner is `lo`.
uint64_t block_point_key(const std::array<int64_t, 3>& lo, int n) {
  return lattice_key(lo[0] + kBlockSpacing * (n % 3), lo[1] + kBlockSpacing * (n / 3 % 3),
                     lo[2] + kBlockSpacing * (n / 9), kBlockSpacing);
}

}  // namespace

// The caps' sum at every lattice point of the bricks' cells. Each point from its block's cell (kBlock voxels, points
// kBlockSpacing apart, summed exactly), where the block can bound its far caps below kBlockTarget; at low
// resolutions, where caps crowd every block, exactly.
void BoundaryWinding::prepare_lattice(const std::vector<int64_t>& bricks) {
  std::vector<uint64_t> keys = brick_lattice_keys(bricks, brick_dims_);
  const PointsByBlock blocks = points_by_block(keys);
  std::vector<uint64_t> coarse;
  for (size_t b = 0; b + 1 < blocks.first.size(); ++b)
    for (int n = 0; n < 27; ++n) coarse.push_back(block_point_key(blocks.block_lo(b), n));
  tbb::parallel_sort(coarse.begin(), coarse.end());
  coarse.erase(std::unique(coarse.begin(), coarse.end()), coarse.end());
  std::vector<double> coarse_values(coarse.size());
  tbb::parallel_for(size_t(0), coarse.size(), [&](size_t n) {
    const auto p = lattice_point(coarse[n], kBlockSpacing);
    coarse_values[n] = caps(Vec3{double(p[0]), double(p[1]), double(p[2])});
  });
  lattice_values_.resize(keys.size());
  lattice_errors_.resize(keys.size());
  const double rounding = kAtanError / (2 * kPi) * total_multiplicity_;  // of a sum over every cap
  tbb::parallel_for(size_t(0), blocks.first.size() - 1, [&](size_t b) {
    const auto lo = blocks.block_lo(b);
    Cell block;
    block.lo = {double(lo[0]), double(lo[1]), double(lo[2])};
    block.spacing = double(kBlockSpacing);
    select_near(double(kBlock), kBlockTarget / 2, std::max(kBlockWork, edges_.size() / kBlockWorkShare), block);
    double values[27];
    for (int n = 0; n < 27; ++n)
      values[n] = coarse_values[size_t(std::lower_bound(coarse.begin(), coarse.end(), block_point_key(lo, n)) -
                                       coarse.begin())];
    fill_far(values, rounding, block);
    const bool interpolate = block.bound <= kBlockTarget;
    for (size_t n = blocks.first[b]; n < blocks.first[b + 1]; ++n) {
      const uint32_t point = blocks.points[n].second;
      const auto p = lattice_point(keys[point], kSpacing);
      const Vec3 q{double(p[0]), double(p[1]), double(p[2])};
      lattice_values_[point] = interpolate ? cell_caps(block, q) : caps(q);
      lattice_errors_[point] = interpolate ? block.bound : rounding;
    }
  });
  lattice_keys_ = std::move(keys);
}

void BoundaryWinding::row_fan_triangles(int64_t bj, int64_t bk, std::vector<uint32_t>& out) const {
  out.clear();
  const int64_t row = bk * brick_dims_[1] + bj;
  auto it = std::lower_bound(row_fans_.begin(), row_fans_.end(), std::pair<int64_t, uint32_t>(row, 0));
  for (; it != row_fans_.end() && it->first == row; ++it) out.push_back(kFanTriangle + it->second);
}

void BoundaryWinding::fan_triangle(uint32_t name, Vec3& a, Vec3& b, Vec3& c, int32_t& multiplicity) const {
  const BoundaryEdge& e = edges_[fan_triangles_[name - kFanTriangle]];
  // M - C is closed: the fan enters the crossings reversed, (centre, b, a).
  a = components_[e.component].centre;
  b = e.b;
  c = e.a;
  multiplicity = e.multiplicity;
}

double BoundaryWinding::lattice_value(int64_t x, int64_t y, int64_t z, double& error) const {
  const uint64_t key = lattice_key(x, y, z, kSpacing);
  const auto it = std::lower_bound(lattice_keys_.begin(), lattice_keys_.end(), key);
  if (it != lattice_keys_.end() && *it == key) {
    error = lattice_errors_[size_t(it - lattice_keys_.begin())];
    return lattice_values_[size_t(it - lattice_keys_.begin())];
  }
  error = kAtanError / (2 * kPi) * total_multiplicity_;  // a brick prepare() was not told about
  return caps(Vec3{double(x), double(y), double(z)});
}

void BoundaryWinding::prepare_cell(int64_t bi, int64_t bj, int64_t bk, double target, Cell& cell) const {
  cell.lo = {double(bi * kBrick), double(bj * kBrick), double(bk * kBrick)};
  cell.spacing = kSpacing;
  select_near(double(2 * kSpacing), target, std::max(kMaxWork, edges_.size() / kMaxWorkShare), cell);
  double values[27], error = 0;
  for (int n = 0; n < 27; ++n) {
    double e;
    values[n] = lattice_value(bi * kBrick + kSpacing * (n % 3), bj * kBrick + kSpacing * (n / 3 % 3),
                              bk * kBrick + kSpacing * (n / 9), e);
    error = std::max(error, e);
  }
  fill_far(values, error, cell);
}

void BoundaryWinding::fill_far(const double* values, double value_error, Cell& cell) const {
  for (int n = 0; n < 27; ++n) {
    const Vec3 q{cell.lo[0] + cell.spacing * (n % 3), cell.lo[1] + cell.spacing * (n / 3 % 3),
                 cell.lo[2] + cell.spacing * (n / 9)};
    double f = values[n];
    for (uint32_t e : cell.near_edges) f -= strip(edges_[e], q);
    for (uint32_t c : cell.near_fans) f -= fan(components_[c], q);
    cell.far[n] = f;
  }
  cell.bound += kValueErrorGain * value_error;
}

// select_near's choice for one cell: the caps far from it are interpolated within a bound, the near ones evaluated;
// caps move from far to near, largest share of the bound per unit of work first, until the bound meets the target
// or the work its limit. A far cap's share: a fan's, its edges' (or its area's); a strip's, its edge's — the rays
// of the strips cancel along the chain except at junctions, the vertices where far strips meet near ones, which
// add the far strips' net multiplicity there times their ray's term.
class BoundaryWinding::NearSelection {
 public:
  NearSelection(const BoundaryWinding& w, double size, Cell& cell)
      : w_(w),
        cell_(cell),
        s_(scratch()),
        lo_(cell.lo),
        hi_{lo_[0] + size, lo_[1] + size, lo_[2] + size},
        centre_{lo_[0] + size / 2, lo_[1] + size / 2, lo_[2] + size / 2},
        half_diagonal_(size / 2 * std::sqrt(3.0)),
        interpolation_(interpolation_error(cell.spacing)) {
    const size_t caps = w.edges_.size() + w.components_.size();
    if (s_.term.size() != caps) {
      s_.term.assign(caps, 0.0);
      s_.near.assign(caps, 0);
    }
    if (s_.net.size() != w.vertex_first_.size()) {
      s_.net.assign(w.vertex_first_.size(), 0);
      s_.ray.assign(w.vertex_first_.size(), 0.0);
    }
    s_.candidates.clear();
    s_.junctions.clear();
  }

  void add_strips();
  void add_fans();
  void grow(double target, size_t max_work);
  /// The bound, from scratch (the running sums subtract), with the near caps' own rounding; the scratch is reset
  /// for the next cell.
  double finish();

 private:
  static constexpr uint32_t kFan = 0x80000000u;  // candidate names: a strip edge, or kFan + a fan
  // Per thread: each far cap's share of the bound (strip edges, then fans), whether it is near, the far strips'
  // net multiplicity at each junction (minus the near ones' there) and its ray's term, as max-heaps.
  struct Scratch {
    std::vector<double> term;
    std::vector<uint8_t> near;
    std::vector<int32_t> net;
    std::vector<double> ray;
    std::vector<uint32_t> touched;
    std::vector<std::pair<double, uint32_t>> candidates, junctions;
  };
  static Scratch& scratch() {
    static thread_local Scratch s;
    return s;
  }
  size_t slot(uint32_t name) const { return name >= kFan ? w_.edges_.size() + (name - kFan) : size_t(name); }
  double junction_term(uint32_t v) const { return s_.net[v] == 0 ? 0.0 : std::abs(s_.net[v]) * s_.ray[v]; }
  void add_junction(uint32_t v, int sign) {
    const double term = junction_term(v);
    if (std::isinf(term))
      open_junctions_ += sign;
    else
      junction_sum_ += sign * term;
  }
  void touch(uint32_t v, const Vec3& p, int32_t change);
  void make_near(uint32_t name);
  void add_candidate(uint32_t name, double term) {  // ranked by term per unit of work
    s_.term[slot(name)] = term;
    s_.candidates.push_back(
        {name >= kFan ? term / double(w_.components_[w_.fans_[name - kFan]].edges.size()) : term, name});
    far_sum_ += term;
  }

  const BoundaryWinding& w_;
  Cell& cell_;
  Scratch& s_;
  const Vec3 lo_, hi_, centre_;
  const double half_diagonal_, interpolation_;
  size_t work_ = 0;
  double far_sum_ = 0, junction_sum_ = 0;  // junction_sum_: the finite terms; open_junctions_: the infinite ones
  int64_t open_junctions_ = 0;
};

void BoundaryWinding::NearSelection::touch(uint32_t v, const Vec3& p, int32_t change) {
  if (s_.net[v] == 0 && s_.ray[v] == 0) {
    Vec3 ray_hi = p;
    ray_hi[0] = std::numeric_limits<double>::infinity();
    s_.ray[v] = ray_term(box_distance(p, ray_hi, lo_, hi_));
    s_.touched.push_back(v);
  }
  add_junction(v, -1);
  s_.net[v] += change;
  add_junction(v, 1);
  if (s_.net[v] != 0) {
    s_.junctions.push_back({junction_term(v), v});
    std::push_heap(s_.junctions.begin(), s_.junctions.end());
  }
}

void BoundaryWinding::NearSelection::make_near(uint32_t name) {
  s_.near[slot(name)] = 1;
  far_sum_ -= s_.term[slot(name)];
  s_.term[slot(name)] = 0;
  if (name >= kFan) {
    cell_.near_fans.push_back(w_.fans_[name - kFan]);
    work_ += w_.components_[w_.fans_[name - kFan]].edges.size();
    return;
  }
  cell_.near_edges.push_back(name);
  ++work_;
  const BoundaryEdge& edge = w_.edges_[name];
  touch(edge.va, edge.a, -edge.multiplicity);
  touch(edge.vb, edge.b, edge.multiplicity);
}

void BoundaryWinding::NearSelection::add_strips() {
  for (const uint32_t e : w_.strip_edges_) {
    const BoundaryEdge& edge = w_.edges_[e];
    Vec3 elo, ehi;
    for (int a = 0; a < 3; ++a) elo[a] = std::min(edge.a[a], edge.b[a]), ehi[a] = std::max(edge.a[a], edge.b[a]);
    Vec3 strip_hi = ehi;
    strip_hi[0] = std::numeric_limits<double>::infinity();
    if (box_distance(elo, strip_hi, lo_, hi_) < kNearStrip) {
      make_near(e);
      continue;
    }
    const double d =
        std::max(box_distance(elo, ehi, lo_, hi_), point_segment_distance(centre_, edge.a, edge.b) - half_diagonal_);
    add_candidate(e, std::abs(edge.multiplicity) * segment_term(length(edge.b - edge.a), d));
  }
}

void BoundaryWinding::NearSelection::add_fans() {
  for (uint32_t f = 0; f < w_.fans_.size(); ++f) {
    const Component& c = w_.components_[w_.fans_[f]];
    const double d = box_distance(c.lo, c.hi, lo_, hi_);  // the fan lies in its edges' box
    if (d < kNearStrip) {
      make_near(kFan + f);
      continue;
    }
    // A fan's boundary is its edges (no rays, no junctions); far away, its area bounds it better: the third
    // derivatives of n.(x - q) / |x - q|^3 are at most 24 / r^5, that is 6 times 4 / r^5.
    double edge_sum = 0;
    for (uint32_t n : c.edges) {
      const BoundaryEdge& edge = w_.edges_[n];
      Vec3 elo, ehi;
      for (int a = 0; a < 3; ++a) elo[a] = std::min(edge.a[a], edge.b[a]), ehi[a] = std::max(edge.a[a], edge.b[a]);
      edge_sum += std::abs(edge.multiplicity) * segment_term(length(edge.b - edge.a), box_distance(elo, ehi, lo_, hi_));
    }
    add_candidate(kFan + f, std::min(edge_sum, 4 * c.area / (d * d * d * d * d)));
  }
  std::make_heap(s_.candidates.begin(), s_.candidates.end());
}

void BoundaryWinding::NearSelection::grow(double target, size_t max_work) {
  for (;;) {
    if ((open_junctions_ == 0 && interpolation_ * (far_sum_ + junction_sum_) <= target) || work_ >= max_work) return;
    while (!s_.candidates.empty() && s_.near[slot(s_.candidates.front().second)]) {
      std::pop_heap(s_.candidates.begin(), s_.candidates.end());
      s_.candidates.pop_back();
    }
    // Heap entries go stale as multiplicities change: the current term decides.
    while (!s_.junctions.empty() && s_.junctions.front().first != junction_term(s_.junctions.front().second)) {
      std::pop_heap(s_.junctions.begin(), s_.junctions.end());
      s_.junctions.pop_back();
    }
    const double candidate_top = s_.candidates.empty() ? 0 : s_.candidates.front().first;
    const double junction_top = s_.junctions.empty() ? 0 : s_.junctions.front().first;
    if (candidate_top == 0 && junction_top == 0) return;
    if (candidate_top >= junction_top) {
      make_near(s_.candidates.front().second);
      continue;
    }
    // The ray leaving this vertex passes close: the far strips meeting there join the near ones.
    const uint32_t v = s_.junctions.front().second;
    bool moved = false;
    for (uint32_t n = w_.vertex_first_[v]; n < w_.vertex_first_[v + 1]; ++n)
      if (!s_.near[w_.vertex_edges_[n]]) {
        make_near(w_.vertex_edges_[n]);
        moved = true;
      }
    if (!moved) return;  // cannot happen: a vertex with net multiplicity has a far strip
  }
}

double BoundaryWinding::NearSelection::finish() {
  double far_sum = 0;
  for (const auto& c : s_.candidates) {
    if (!s_.near[slot(c.second)]) far_sum += s_.term[slot(c.second)];
    s_.term[slot(c.second)] = 0;
  }
  double junction_sum = 0;
  for (uint32_t v : s_.touched) {
    junction_sum += junction_term(v);
    s_.net[v] = 0;
    s_.ray[v] = 0;
  }
  s_.touched.clear();
  double near_multiplicity = 0;
  for (uint32_t e : cell_.near_edges) {
    s_.near[e] = 0;
    near_multiplicity += std::abs(w_.edges_[e].multiplicity);
  }
  for (uint32_t f = 0; f < w_.fans_.size(); ++f) s_.near[w_.edges_.size() + f] = 0;
  for (uint32_t c : cell_.near_fans)
    for (uint32_t n : w_.components_[c].edges) near_multiplicity += std::abs(w_.edges_[n].multiplicity);
  return interpolation_ * (far_sum + junction_sum) + kAtanError / (2 * kPi) * near_multiplicity;
}

void BoundaryWinding::select_near(double size, double target, size_t max_work, Cell& cell) const {
  cell.near_edges.clear();
  cell.near_fans.clear();
  cell.bound = 0;
  std::fill(cell.far, cell.far + 27, 0.0);
  if (edges_.empty()) return;
  NearSelection selection(*this, size, cell);
  selection.add_strips();
  selection.add_fans();
  selection.grow(target, max_work);
  cell.bound = selection.finish();
}

double BoundaryWinding::cell_caps(const Cell& cell, const Vec3& q) const {
  double weight[3][3];
  for (int a = 0; a < 3; ++a) {
    const double t = (q[a] - cell.lo[a]) / cell.spacing;
    weight[a][0] = (t - 1) * (t - 2) / 2;
    weight[a][1] = -t * (t - 2);
    weight[a][2] = t * (t - 1) / 2;
  }
  double sum = 0;
  for (int n = 0; n < 27; ++n) sum += cell.far[n] * weight[0][n % 3] * weight[1][n / 3 % 3] * weight[2][n / 9];
  for (uint32_t e : cell.near_edges) sum += strip(edges_[e], q);
  for (uint32_t c : cell.near_fans) sum += fan(components_[c], q);
  return sum;
}

}  // namespace voxfmt::bake
