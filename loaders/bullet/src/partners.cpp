#include "voxfmt/bullet/collision.h"

#include "triangle_distance.h"
#include "triangle_set.h"

#include <BulletCollision/NarrowPhaseCollision/btGjkEpa2.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>

namespace voxfmt::bullet {

float plane_distance(const Eigen::Vector3f& normal, float constant, const Eigen::Vector3f& x,
                     Eigen::Vector3f& outward) {
  outward = normal;
  return normal.dot(x) - constant;
}

float box_distance(const Eigen::Matrix3f& rotation, const Eigen::Vector3f& centre, const Eigen::Vector3f& half,
                   const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
  const Eigen::Vector3f local = rotation.transpose() * (x - centre);
  const Eigen::Vector3f q = local.cwiseAbs() - half;
  const Eigen::Vector3f sign = local.unaryExpr([](float v) { return v < 0.0f ? -1.0f : 1.0f; });
  if ((q.array() > 0.0f).any()) {
    const Eigen::Vector3f out = q.cwiseMax(0.0f).cwiseProduct(sign);
    const float d = out.norm();
    outward = rotation * (out / d);
    return d;
  }
  int axis = 0;
  q.maxCoeff(&axis);
  Eigen::Vector3f n = Eigen::Vector3f::Zero();
  n[axis] = sign[axis];
  outward = rotation * n;
  return q[axis];
}

float sphere_distance(const Eigen::Vector3f& centre, float radius, const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
  const Eigen::Vector3f v = x - centre;
  const float length = v.norm();
  outward = length > 0.0f ? Eigen::Vector3f(v / length) : Eigen::Vector3f::UnitZ();
  return length - radius;
}

float capsule_distance(const Eigen::Vector3f& a, const Eigen::Vector3f& b, float radius, const Eigen::Vector3f& x,
                       Eigen::Vector3f& outward) {
  const Eigen::Vector3f axis = b - a;
  const float length2 = axis.squaredNorm();
  const float t = length2 > 0.0f ? std::clamp((x - a).dot(axis) / length2, 0.0f, 1.0f) : 0.0f;
  return sphere_distance(a + t * axis, radius, x, outward);
}

float cylinder_distance(const Eigen::Vector3f& centre, const Eigen::Vector3f& axis, float radius, float half_height,
                        const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
  const Eigen::Vector3f v = x - centre;
  const float along = v.dot(axis);
  const Eigen::Vector3f across = v - along * axis;
  const float r = across.norm();
  const Eigen::Vector3f radial = r > 0.0f ? Eigen::Vector3f(across / r) : Eigen::Vector3f(axis.unitOrthogonal());
  const Eigen::Vector3f axial = along < 0.0f ? Eigen::Vector3f(-axis) : axis;
  const float dr = r - radius, da = std::abs(along) - half_height;
  if (dr <= 0.0f && da <= 0.0f) {  // inside: the nearer of the side and the cap
    outward = dr > da ? radial : axial;
    return std::max(dr, da);
  }
  const Eigen::Vector3f out = std::max(dr, 0.0f) * radial + std::max(da, 0.0f) * axial;
  const float d = out.norm();
  outward = out / d;
  return d;
}

bool polyhedron_inside_distance(const std::vector<Eigen::Vector4f>& planes, float margin, const Eigen::Vector3f& x,
                                float& distance, Eigen::Vector3f& outward) {
  float best = -std::numeric_limits<float>::infinity();
  for (const Eigen::Vector4f& p : planes) {
    const float value = p.head<3>().dot(x) + p[3];
    if (value > best) {
      best = value;
      outward = p.head<3>();
    }
  }
  if (!(best <= 0.0f)) return false;
  distance = best - margin;
  return true;
}

float convex_distance(const btConvexShape& shape, const btTransform& world_from_shape, const Eigen::Vector3f& x,
                      Eigen::Vector3f& outward) {
  btGjkEpaSolver2::sResults results;
  const btVector3 point(x.x(), x.y(), x.z());
  const btScalar d = btGjkEpaSolver2::SignedDistance(point, 0, &shape, world_from_shape, results);
  if (!(d < SIMD_INFINITY)) return std::numeric_limits<float>::infinity();
  // witnesses[0] is the nearest point of the shape's surface (margin included), inside or out.
  const btVector3 to_point = point - results.witnesses[0];
  const btScalar length = to_point.length();
  btVector3 n = length > SIMD_EPSILON ? to_point / length : results.normal;
  if (d < 0) n = -n;  // inside: the surface is ahead of the point
  outward = Eigen::Vector3f(float(n.x()), float(n.y()), float(n.z()));
  return float(d);
}

void TriangleSet::add(const Eigen::Vector3f& a, const Eigen::Vector3f& b, const Eigen::Vector3f& c) {
  corners_.push_back(a);
  corners_.push_back(b);
  corners_.push_back(c);
  const Eigen::Vector3f n = (b - a).cross(c - a);
  const float length = n.norm();
  normals_.push_back(length > 0.0f ? Eigen::Vector3f(n / length) : Eigen::Vector3f::Zero());
}

void TriangleGrid::clear() {
  first.clear();
  members.clear();
  ring.clear();
}

Eigen::Vector3i TriangleGrid::cell_of(const Eigen::Vector3f& x) const {
  Eigen::Vector3i c;
  for (int a = 0; a < 3; ++a) c[a] = std::clamp(int(std::floor((x[a] - lo[a]) / cell)), 0, dims[a] - 1);
  return c;
}

// Rings to the nearest occupied cell: a breadth-first search over the 26 neighbours from every occupied cell (a
// step to any of them is one Chebyshev ring).
void TriangleGrid::fill_rings(int rings) {
  max_rings = rings;
  const size_t cells = size_t(dims.prod());
  ring.assign(cells, uint8_t(rings));
  std::vector<uint32_t> wave, next_wave;
  for (size_t c = 0; c < cells; ++c)
    if (first[c + 1] > first[c]) {
      ring[c] = 0;
      wave.push_back(uint32_t(c));
    }
  for (int r = 1; r < rings && !wave.empty(); ++r) {
    next_wave.clear();
    for (const uint32_t c : wave) {
      const int i = int(c % uint32_t(dims.x())), j = int(c / uint32_t(dims.x()) % uint32_t(dims.y())),
                k = int(c / uint32_t(dims.x() * dims.y()));
      for (int dk = -1; dk <= 1; ++dk)
        for (int dj = -1; dj <= 1; ++dj)
          for (int di = -1; di <= 1; ++di) {
            const int ni = i + di, nj = j + dj, nk = k + dk;
            if (ni < 0 || nj < 0 || nk < 0 || ni >= dims.x() || nj >= dims.y() || nk >= dims.z()) continue;
            const size_t n = cell_index(ni, nj, nk);
            if (ring[n] > r) {
              ring[n] = uint8_t(r);
              next_wave.push_back(uint32_t(n));
            }
          }
    }
    wave.swap(next_wave);
  }
}

Eigen::Vector3f common_normal(const std::vector<Eigen::Vector3f>& normals) {
  Eigen::Vector3f mean = Eigen::Vector3f::Zero();
  for (const Eigen::Vector3f& n : normals) mean += n;
  if (!(mean.squaredNorm() > 0.0f)) return Eigen::Vector3f::Zero();
  mean.normalize();
  for (const Eigen::Vector3f& n : normals)
    if (n.squaredNorm() > 0.0f && !(n.dot(mean) > 0.0f)) return Eigen::Vector3f::Zero();
  return mean;
}

void TriangleSet::clear() {
  common_normal_.setZero();
  corners_.clear();
  normals_.clear();
  grid_.clear();
}

void TriangleSet::build() {
  grid_.clear();
  if (empty()) return;
  grid_.lo = grid_.hi = corners_[0];
  float edges = 0;
  for (size_t t = 0; t < size(); ++t)
    for (int k = 0; k < 3; ++k) {
      grid_.lo = grid_.lo.cwiseMin(corner(t, k));
      grid_.hi = grid_.hi.cwiseMax(corner(t, k));
      edges += (corner(t, (k + 1) % 3) - corner(t, k)).norm();
    }
  // A one-sided set (every triangle faces within 90 degrees of the mean normal) allows the cheap lower bound.
  common_normal_ = common_normal(normals_);
  // Cells about the size of a triangle (a few triangles each), at most 64 along an axis.
  const Eigen::Vector3f extent = grid_.hi - grid_.lo;
  grid_.cell = std::max({edges / float(3 * size()), extent.maxCoeff() / 64.0f, 1e-30f});  // relative: any scale
  for (int a = 0; a < 3; ++a) grid_.dims[a] = std::clamp(int(std::ceil(extent[a] / grid_.cell)), 1, 64);
  grid_.fill(
      size(), [&](size_t t) -> Eigen::Vector3f { return corner(t, 0).cwiseMin(corner(t, 1)).cwiseMin(corner(t, 2)); },
      [&](size_t t) -> Eigen::Vector3f { return corner(t, 0).cwiseMax(corner(t, 1)).cwiseMax(corner(t, 2)); },
      kEmptyRings);
}

float TriangleSet::lower_bound(const Eigen::Vector3f& x) const {
  if (grid_.built() && common_normal_.squaredNorm() > 0.0f) {
    const Eigen::Vector3f off_box = x - x.cwiseMax(grid_.lo).cwiseMin(grid_.hi);
    // Beyond the box on the side every triangle faces: above a surface that is a graph over that direction,
    // so outside, and no triangle is nearer than the box.
    if (off_box.dot(common_normal_) > 0.0f) return off_box.norm();
  }
  if (!grid_.ring.empty()) {
    // No triangle within `ring` - 1 rings of x's cell (x's projection onto the box lies in it, and projecting
    // onto a convex set brings nothing of it nearer): at least that many cells, and the box's distance, away.
    const int ring = grid_.ring[grid_.cell_index(grid_.cell_of(x))];
    if (ring > 1) return std::max(grid_.box_distance(x), float(ring - 1) * grid_.cell);
  }
  Eigen::Vector3f outward;
  return distance(x, outward);
}

float TriangleSet::distance(const Eigen::Vector3f& x, Eigen::Vector3f& outward) const {
  detail::NearestTriangle nearest(x);
  auto consider = [&](size_t t) {
    nearest.consider(corners_[3 * t], corners_[3 * t + 1], corners_[3 * t + 2], normals_[t]);
    outward = nearest.outward;
  };
  const float& best2 = nearest.best2;
  const float& side = nearest.side;
  if (empty()) return std::numeric_limits<float>::infinity();
  if (!grid_.built()) {  // not built: every triangle
    for (size_t t = 0; t < size(); ++t) consider(t);
    return side * std::sqrt(best2);
  }
  // Rings of cells around the cell nearest x (x's projection onto the grid's box lies in it; projecting onto a
  // convex set brings no point of the set nearer, so after ring r every unvisited triangle is >= r cells away).
  const Eigen::Vector3i c = grid_.cell_of(x);
  const float box = grid_.box_distance(x);
  // The rings before the nearest occupied one hold nothing: the search starts there.
  const int first_ring = grid_.ring.empty() ? 0 : int(grid_.ring[grid_.cell_index(c)]);
  if (first_ring >= kEmptyRings) {  // no triangle within the rings the map covers
    outward =
        box > 0.0f ? Eigen::Vector3f((x - x.cwiseMax(grid_.lo).cwiseMin(grid_.hi)) / box) : Eigen::Vector3f::UnitY();
    return std::max(box, float(kEmptyRings - 1) * grid_.cell);
  }
  for (int r = first_ring; r <= first_ring + kMaxRings; ++r) {
    for (int k = c.z() - r; k <= c.z() + r; ++k) {
      if (k < 0 || k >= grid_.dims.z()) continue;
      for (int j = c.y() - r; j <= c.y() + r; ++j) {
        if (j < 0 || j >= grid_.dims.y()) continue;
        const bool face = std::abs(k - c.z()) == r || std::abs(j - c.y()) == r;
        for (int i = c.x() - r; i <= c.x() + r; i += (face || r == 0) ? 1 : 2 * r) {
          if (i < 0 || i >= grid_.dims.x()) continue;
          const size_t cell = grid_.cell_index(i, j, k);
          for (uint32_t m = grid_.first[cell]; m < grid_.first[cell + 1]; ++m) consider(grid_.members[m]);
        }
      }
    }
    // Every unvisited triangle is at least this far (and none is nearer than the set's box: above a floor the
    // triangle straight below settles the search at once).
    const float reach = std::max(float(r) * grid_.cell, box);
    if (best2 <= reach * reach * (1 + 1e-6f)) return side * std::sqrt(best2);
    if (r > grid_.dims.maxCoeff()) return side * std::sqrt(best2);  // every cell visited: exact
  }
  // Not settled within kMaxRings of the first occupied ring: every triangle is farther than the rings reach and
  // than the box. Such a point counts as outside (a point that deep behind a floor has tunnelled through it).
  const float bound = std::max(box, float(first_ring + kMaxRings) * grid_.cell);
  outward =
      box > 0.0f ? Eigen::Vector3f((x - x.cwiseMax(grid_.lo).cwiseMin(grid_.hi)) / box) : Eigen::Vector3f::UnitY();
  return bound;
}

}  // namespace voxfmt::bullet
