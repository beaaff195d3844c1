// The triangles of a static mesh or terrain near a VPS body, and the uniform grid that searches them: private to
// the Bullet integration (the collision algorithm and the static mesh index).
#pragma once

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <vector>

namespace voxfmt::bullet {

/// A uniform grid over triangles, shared by the searches for a nearest triangle (TriangleSet, the static mesh
/// index): cell (i, j, k) lists the triangles whose bounding boxes cover it, members[first[c] .. first[c + 1]),
/// and holds the ring (Chebyshev distance in cells) of the nearest cell that lists one, at most max_rings: a
/// search from the cell starts there, and a point in it is at least (ring - 1) cells from every triangle.
struct TriangleGrid {
  Eigen::Vector3f lo = Eigen::Vector3f::Zero(), hi = Eigen::Vector3f::Zero();  ///< the triangles' box
  float cell = 1.0f;
  Eigen::Vector3i dims = Eigen::Vector3i::Ones();
  std::vector<uint32_t> first, members;
  std::vector<uint8_t> ring;
  int max_rings = 0;

  bool built() const { return !first.empty(); }
  void clear();
  Eigen::Vector3i cell_of(const Eigen::Vector3f& x) const;
  size_t cell_index(int i, int j, int k) const { return size_t((k * dims.y() + j) * dims.x() + i); }
  size_t cell_index(const Eigen::Vector3i& c) const { return cell_index(c.x(), c.y(), c.z()); }
  /// Distance from x to the triangles' box (0 inside it).
  float box_distance(const Eigen::Vector3f& x) const { return (x - x.cwiseMax(lo).cwiseMin(hi)).norm(); }
  /// With lo, hi, cell and dims set: lists `count` triangles in the cells their boxes (`box_lo(t)`, `box_hi(t)`)
  /// cover, then the rings up to `max_rings` (at most 255).
  template <class BoxLo, class BoxHi>
  void fill(size_t count, BoxLo&& box_lo, BoxHi&& box_hi, int rings) {
    const size_t cells = size_t(dims.prod());
    first.assign(cells + 1, 0);
    std::vector<uint32_t> next;
    for (int pass = 0; pass < 2; ++pass) {  // a counting sort: count, then place
      if (pass == 1) {
        for (size_t c = 0; c < cells; ++c) first[c + 1] += first[c];
        members.resize(first[cells]);
        next.assign(first.begin(), first.end() - 1);
      }
      for (size_t t = 0; t < count; ++t) {
        const Eigen::Vector3i c0 = cell_of(box_lo(t)), c1 = cell_of(box_hi(t));
        for (int k = c0.z(); k <= c1.z(); ++k)
          for (int j = c0.y(); j <= c1.y(); ++j)
            for (int i = c0.x(); i <= c1.x(); ++i) {
              if (pass == 0)
                ++first[cell_index(i, j, k) + 1];
              else
                members[next[cell_index(i, j, k)]++] = uint32_t(t);
            }
      }
    }
    fill_rings(rings);
  }

 private:
  void fill_rings(int rings);
};

/// The mean of the proper normals if every one of them leans its way (n . mean > 0: a floor, a terrain), else zero.
/// Degenerate triangles (zero normals) lie among their neighbours and do not count.
Eigen::Vector3f common_normal(const std::vector<Eigen::Vector3f>& normals);

/// A set of triangles (a static mesh or terrain near a VPS body), world frame, each oriented counter-clockwise
/// seen from outside. The distance is to the nearest triangle; its sign is the side of the nearest triangle
/// whose plane is most nearly perpendicular to the direction to the point (at an edge or vertex several
/// triangles are equally near; the one facing the point decides), so a closed or one-sided surface (a floor,
/// a terrain) has negative distances below it. A uniform grid over the set finds the nearest triangle by
/// searching rings of cells outward; points farther than `kMaxRings` cells from every triangle get a lower
/// bound (the larger of the ring distance and the distance to the set's bounding box), enough to prune.
class TriangleSet {
 public:
  static constexpr int kMaxRings = 8;

  void clear();
  void add(const Eigen::Vector3f& a, const Eigen::Vector3f& b, const Eigen::Vector3f& c);
  /// Builds the search grid; call after the last add() and before distance().
  void build();
  size_t size() const { return corners_.size() / 3; }
  bool empty() const { return corners_.empty(); }
  /// The vertices of triangle i.
  const Eigen::Vector3f& corner(size_t i, int k) const { return corners_[3 * i + size_t(k)]; }
  float distance(const Eigen::Vector3f& x, Eigen::Vector3f& outward) const;
  /// A value the signed distance at x is not below, cheap far from the triangles: for a set whose normals all
  /// lean one way (a floor, a terrain patch), a point beyond the set's box on that side is outside by at least
  /// its distance to the box; a point whose cell has no triangle within r rings is at least r - 1 cells from
  /// every triangle. Elsewhere (a cell with a triangle) the exact distance.
  float lower_bound(const Eigen::Vector3f& x) const;

 private:
  std::vector<Eigen::Vector3f> corners_;
  std::vector<Eigen::Vector3f> normals_;
  TriangleGrid grid_;
  Eigen::Vector3f common_normal_ = Eigen::Vector3f::Zero();  ///< zero unless every normal has n . c > 0
  static constexpr int kEmptyRings = 64;  ///< rings the grid's map covers: a lower bound that costs one read
};

}  // namespace voxfmt::bullet
