// Private: the nearest-triangle search step shared by TriangleSet (partners.cpp) and StaticMeshIndex
// (static_mesh.cpp), so that both sign and tie-break their distances the same way.
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>

namespace voxfmt::bullet::detail {

/// A triangle as the nearest-triangle searches keep it: its corners, its unit normal (zero when it is degenerate)
/// and its bounding box (a triangle no nearer than its box is not looked at).
struct BoxedTriangle {
  Eigen::Vector3f a, b, c, normal, lo, hi;
  static BoxedTriangle of(const Eigen::Vector3f& a, const Eigen::Vector3f& b, const Eigen::Vector3f& c) {
    const Eigen::Vector3f n = (b - a).cross(c - a);
    const float length = n.norm();
    return {a,
            b,
            c,
            length > 0.0f ? Eigen::Vector3f(n / length) : Eigen::Vector3f::Zero(),
            a.cwiseMin(b).cwiseMin(c),
            a.cwiseMax(b).cwiseMax(c)};
  }
};

/// Closest point on segment ab to p (a zero-length one: a).
inline Eigen::Vector3f closest_on_segment(const Eigen::Vector3f& p, const Eigen::Vector3f& a,
                                          const Eigen::Vector3f& b) {
  const Eigen::Vector3f ab = b - a;
  const float length2 = ab.squaredNorm();
  return length2 > 0.0f ? Eigen::Vector3f(a + ab * std::clamp(ab.dot(p - a) / length2, 0.0f, 1.0f)) : a;
}

/// For a sliver, whose face coordinates float rounding spoils: the nearest of its edges' closest points and of
/// `face` (the face's point, where its coordinates came out not negative; else null). All lie on the triangle, so
/// the nearest is never worse than any. Out of line, so that the searches' loops keep their fast path small.
[[gnu::noinline, gnu::cold]] inline Eigen::Vector3f closest_on_sliver(const Eigen::Vector3f& p,
                                                                      const Eigen::Vector3f& a,
                                                                      const Eigen::Vector3f& b,
                                                                      const Eigen::Vector3f& c,
                                                                      const Eigen::Vector3f* face) {
  Eigen::Vector3f best = closest_on_segment(p, a, b);
  for (const Eigen::Vector3f& q : {closest_on_segment(p, b, c), closest_on_segment(p, c, a)})
    if ((q - p).squaredNorm() < (best - p).squaredNorm()) best = q;
  if (face && (*face - p).squaredNorm() < (best - p).squaredNorm()) best = *face;
  return best;
}

/// Closest point on triangle abc to p (barycentric region test, Ericson 5.1.5), safe for degenerate triangles as
/// the bake's is (tools/bake/src/triangle_closest_point.h): an edge's test divides by its squared length, so a
/// zero-length edge (a mesh's triangle naming one vertex twice) is skipped rather than made NaN. The face's
/// coordinates are va, vb, vc over their sum |ab x ac|^2 = |ab|^2 |ac|^2 sin^2(angle at a), never negative for a
/// proper triangle there; on a sliver (a sine under 1e-2, corners nearly on one line) float rounding reaches them
/// (about 2e-5 |ab|^2 |ac|^2 for points within a few triangle sizes) and would put the point anywhere on it, so a
/// sliver takes closest_on_sliver.
inline Eigen::Vector3f closest_on_triangle(const Eigen::Vector3f& p, const Eigen::Vector3f& a, const Eigen::Vector3f& b,
                                           const Eigen::Vector3f& c) {
  const Eigen::Vector3f ab = b - a, ac = c - a, ap = p - a;
  const float d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Eigen::Vector3f bp = p - b;
  const float d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const float vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0 && d1 - d3 > 0) return a + ab * (d1 / (d1 - d3));
  const Eigen::Vector3f cp = p - c;
  const float d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const float vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0 && d2 - d6 > 0) return a + ac * (d2 / (d2 - d6));
  const float va = d3 * d6 - d5 * d4, along_b = d4 - d3, along_c = d5 - d6;
  if (va <= 0 && along_b >= 0 && along_c >= 0 && along_b + along_c > 0)
    return b + (c - b) * (along_b / (along_b + along_c));
  const float area2 = va + vb + vc;
  if (!(va >= 0 && vb >= 0 && vc >= 0 && area2 > 0)) return closest_on_sliver(p, a, b, c, nullptr);
  const float denom = 1.0f / area2;
  const Eigen::Vector3f face = a + ab * (vb * denom) + ac * (vc * denom);
  if (!(area2 > 1e-4f * ab.squaredNorm() * ac.squaredNorm())) return closest_on_sliver(p, a, b, c, &face);
  return face;
}

/// The nearest of the triangles offered to it, with the sign of the side of the nearest triangle whose plane is
/// most nearly perpendicular to the direction to the point (at a shared edge or vertex several are equally near;
/// the one facing the point decides).
struct NearestTriangle {
  Eigen::Vector3f x;
  float best2 = std::numeric_limits<float>::infinity();
  float best_alignment = -1.0f, side = 1.0f;
  Eigen::Vector3f outward = Eigen::Vector3f::UnitY();

  explicit NearestTriangle(const Eigen::Vector3f& point) : x(point) {}
  /// The tolerance within which two squared distances count as a tie (float precision at a shared edge).
  float tie(float d2) const {
    return 1e-6f * std::max(best2 < std::numeric_limits<float>::infinity() ? best2 : d2, 1e-12f);
  }
  /// Whether a triangle at least sqrt(d2_low) away can change the result.
  bool may_improve(float d2_low) const { return !(d2_low > best2 + tie(d2_low)); }
  void consider(const Eigen::Vector3f& a, const Eigen::Vector3f& b, const Eigen::Vector3f& c,
                const Eigen::Vector3f& normal) {
    const Eigen::Vector3f v = x - closest_on_triangle(x, a, b, c);
    const float d2 = v.squaredNorm();
    const float t = tie(d2);
    if (d2 > best2 + t) return;
    const float length = std::sqrt(d2);
    const float along = length > 0.0f ? normal.dot(v) / length : 1.0f;
    if (d2 < best2 - t || std::abs(along) > best_alignment) {
      best_alignment = std::abs(along);
      side = along < 0.0f ? -1.0f : 1.0f;
      best2 = std::min(best2, d2);
      outward = length > 0.0f ? Eigen::Vector3f(side * v / length) : normal;
    }
  }
  float signed_distance() const { return side * std::sqrt(best2); }
  /// Whether no triangle at least `reach` away can be nearer (the search is settled), within float rounding.
  bool settled_within(float reach) const { return best2 <= reach * reach * (1 + 1e-6f); }
};

}  // namespace voxfmt::bullet::detail
