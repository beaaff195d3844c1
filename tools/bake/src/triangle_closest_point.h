// The closest point of a triangle to a point, for every triangle a repaired mesh may still hold: slivers, and
// triangles whose corners coincide or lie on one line (a soup's copies of one vertex). Shared by the voxel band,
// the lattice and the nearest-triangle hierarchy, so that all of them measure one distance.
#pragma once

#include <algorithm>
#include <cstdint>

#include "vec3_math.h"

namespace voxfmt::bake {

/// The part of triangle abc a closest point lies on: a corner, an edge (named by its first corner, as in the
/// bake's pseudonormals) or the face.
enum class Feature : uint8_t { kCornerA, kCornerB, kCornerC, kEdgeAB, kEdgeBC, kEdgeCA, kFace };

namespace detail {

// Closest point on segment ab (a zero-length one is its corner a) and its squared distance to p.
inline Vec3 closest_on_segment(const Vec3& p, const Vec3& a, const Vec3& b, Feature corner_a, Feature corner_b,
                               Feature edge, Feature& feature, double& d2) {
  const Vec3 ab = b - a;
  const double length2 = dot(ab, ab);
  const double t = length2 > 0 ? std::clamp(dot(p - a, ab) / length2, 0.0, 1.0) : 0.0;
  feature = t <= 0 ? corner_a : t >= 1 ? corner_b : edge;
  const Vec3 q = t <= 0 ? a : t >= 1 ? b : a + ab * t;
  d2 = distance2(p, q);
  return q;
}

// The nearest of the three edges' closest points: where the face's barycentric coordinates cannot be trusted (out
// of line, so that the searches' loops keep their fast path small).
[[gnu::noinline, gnu::cold]] inline Vec3 closest_on_edges(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c,
                                                          Feature& feature) {
  double best2, d2;
  Vec3 best = closest_on_segment(p, a, b, Feature::kCornerA, Feature::kCornerB, Feature::kEdgeAB, feature, best2);
  Feature f;
  Vec3 q = closest_on_segment(p, b, c, Feature::kCornerB, Feature::kCornerC, Feature::kEdgeBC, f, d2);
  if (d2 < best2) best = q, best2 = d2, feature = f;
  q = closest_on_segment(p, c, a, Feature::kCornerC, Feature::kCornerA, Feature::kEdgeCA, f, d2);
  if (d2 < best2) best = q, feature = f;
  return best;
}

}  // namespace detail

/// Closest point on triangle abc to p and its feature: the Voronoi-region tests of Ericson's "Real-Time Collision
/// Detection" (5.1.5), made safe for degenerate triangles. An edge's test divides by its squared length (d1 - d3,
/// d2 - d6, (d4 - d3) + (d5 - d6)), so a zero-length edge is skipped (0/0 made a corner-sharing segment NaN, and
/// the bake then missed it); the tests left find the segment or point such a triangle is. A triangle nearly on one
/// line (where rounding makes the face's barycentric coordinates meaningless) takes the nearest point of its edges.
inline Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, Feature& feature) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) {
    feature = Feature::kCornerA;
    return a;
  }
  const Vec3 bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) {
    feature = Feature::kCornerB;
    return b;
  }
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0 && d1 - d3 > 0) {
    feature = Feature::kEdgeAB;
    return a + ab * (d1 / (d1 - d3));
  }
  const Vec3 cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) {
    feature = Feature::kCornerC;
    return c;
  }
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0 && d2 - d6 > 0) {
    feature = Feature::kEdgeCA;
    return a + ac * (d2 / (d2 - d6));
  }
  const double va = d3 * d6 - d5 * d4, along_b = d4 - d3, along_c = d5 - d6;
  if (va <= 0 && along_b >= 0 && along_c >= 0 && along_b + along_c > 0) {
    feature = Feature::kEdgeBC;
    return b + (c - b) * (along_b / (along_b + along_c));
  }
  // The face's coordinates are va, vb, vc over their sum |ab x ac|^2 = |ab|^2 |ac|^2 sin^2(angle at a): never
  // negative for a proper triangle here. Under a sine of 1e-5 rounding can put them anywhere in the triangle, and its
  // edges are within its width (that sine times its length) of it. (For a point farther than about 100 triangle
  // sizes, rounding can also move a proper triangle's point across it: an error under its size, 1 % of the
  // distance, as the far lattice allows.)
  const double area2 = va + vb + vc;
  if (va >= 0 && vb >= 0 && vc >= 0 && area2 > 1e-10 * dot(ab, ab) * dot(ac, ac)) {
    const double denom = 1 / area2;
    feature = Feature::kFace;
    return a + ab * (vb * denom) + ac * (vc * denom);
  }
  return detail::closest_on_edges(p, a, b, c, feature);
}

}  // namespace voxfmt::bake
