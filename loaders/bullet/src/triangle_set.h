// The triangles of a static mesh or terrain near a VPS body, and the uniform grid that searches them: private to
// the Bullet integration (the collision algorithm and the static mesh index).
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <vector>

#include "triangle_distance.h"

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
  /// A triangle not yet seen after ring r around cell c lies in no cell of the block within r rings of c (every
  /// cell its box covers lists it), so it is at least as far from x as the block's faces inside the grid.
  float unseen_distance(const Eigen::Vector3f& x, const Eigen::Vector3i& c, int r) const;

 private:
  void fill_rings(int rings);
};

/// A stamp per triangle and thread: a search looks at each triangle once, though the grid lists it in every cell its
/// box covers (a triangle passed over stays out of reach, as the nearest only gets nearer).
class VisitStamps {
 public:
  /// This thread's stamps, ready for a search over `count` triangles.
  static VisitStamps& start(size_t count) {
    thread_local VisitStamps stamps;
    if (stamps.seen_.size() < count) stamps.seen_.resize(count, 0);
    if (++stamps.search_ == 0) {
      std::fill(stamps.seen_.begin(), stamps.seen_.end(), 0u);
      stamps.search_ = 1;
    }
    return stamps;
  }
  /// Whether this search has not looked at triangle `id` yet (and marks it looked at).
  bool first_visit(uint32_t id) {
    if (seen_[id] == search_) return false;
    seen_[id] = search_;
    return true;
  }

 private:
  std::vector<uint32_t> seen_;
  uint32_t search_ = 0;
};

/// Offers `nearest` the triangles `grid` lists in `cell` that this search has not looked at and whose boxes could
/// hold a nearer one.
inline void consider_cell(const TriangleGrid& grid, const std::vector<detail::BoxedTriangle>& triangles, size_t cell,
                          VisitStamps& stamps, detail::NearestTriangle& nearest) {
  for (uint32_t m = grid.first[cell]; m < grid.first[cell + 1]; ++m) {
    const uint32_t id = grid.members[m];
    if (!stamps.first_visit(id)) continue;
    const detail::BoxedTriangle& t = triangles[id];
    if (!nearest.may_improve((t.lo - nearest.x).cwiseMax(nearest.x - t.hi).cwiseMax(0.0f).squaredNorm())) continue;
    nearest.consider(t.a, t.b, t.c, t.normal);
  }
}

/// The nearest of `triangles` (listed in `grid`) to x, offered to `nearest`: rings of cells around c (x's cell)
/// from `first_ring` on, skipping cells and triangles whose boxes cannot hold a nearer one and looking at each
/// triangle once, until no unseen triangle can be nearer than the nearest (nearest.settled_within(reach)) or every
/// unseen one lies beyond `limit`. `box`: x's distance to the grid's box, which no triangle is
/// nearer than. Returns the reach: the distance every unseen triangle is at least.
inline float nearest_by_rings(const TriangleGrid& grid, const std::vector<detail::BoxedTriangle>& triangles,
                              const Eigen::Vector3f& x, const Eigen::Vector3i& c, int first_ring, float box,
                              float limit, detail::NearestTriangle& nearest) {
  VisitStamps& stamps = VisitStamps::start(triangles.size());
  for (int r = first_ring;; ++r) {
    for (int k = std::max(c.z() - r, 0); k <= std::min(c.z() + r, grid.dims.z() - 1); ++k) {
      for (int j = std::max(c.y() - r, 0); j <= std::min(c.y() + r, grid.dims.y() - 1); ++j) {
        const bool face = std::abs(k - c.z()) == r || std::abs(j - c.y()) == r;
        const int step = (face || r == 0) ? 1 : 2 * r;
        for (int i = c.x() - r; i <= c.x() + r; i += step) {
          if (i < 0 || i >= grid.dims.x()) continue;
          const Eigen::Vector3f cell_lo = grid.lo + grid.cell * Eigen::Vector3f(float(i), float(j), float(k));
          const Eigen::Vector3f off = (cell_lo - x).cwiseMax(x - cell_lo - Eigen::Vector3f::Constant(grid.cell));
          if (!nearest.may_improve(off.cwiseMax(0.0f).squaredNorm())) continue;
          consider_cell(grid, triangles, grid.cell_index(i, j, k), stamps, nearest);
        }
      }
    }
    const float reach = std::max(box, grid.unseen_distance(x, c, r));
    if (nearest.settled_within(reach) || reach > limit) return reach;
  }
}

/// The mean of the proper normals if every one of them leans its way (n . mean > 0: a floor, a terrain), else zero.
/// Degenerate triangles (zero normals) lie among their neighbours and do not count.
Eigen::Vector3f common_normal(const std::vector<detail::BoxedTriangle>& triangles);

/// Sets `grid`'s box to the one around every triangle (at least one) and returns the sum of their edge lengths:
/// a grid's cell is sized on the mean edge.
double bound_triangles(const std::vector<detail::BoxedTriangle>& triangles, TriangleGrid& grid);

/// A set of triangles (a static mesh or terrain near a VPS body), world frame, each oriented counter-clockwise
/// seen from outside. The distance is to the nearest triangle; its sign is the side of the nearest triangle
/// whose plane is most nearly perpendicular to the direction to the point (at an edge or vertex several
/// triangles are equally near; the one facing the point decides), so a closed or one-sided surface (a floor,
/// a terrain) has negative distances below it. A uniform grid over the set finds the nearest triangle by
/// searching rings of cells outward; points farther than `kMaxRings` cells beyond the first ring that holds a
/// triangle, on a grid more cells across than those rings reach, get a lower bound (the larger of the rings'
/// distance and the distance to the set's bounding box), enough to prune (under a solid set, a terrain, the same
/// size inside, and exact below every triangle of the point's column: set_solid_below); elsewhere the distance is
/// exact.
class TriangleSet {
 public:
  static constexpr int kMaxRings = 8;

  void clear();
  void add(const Eigen::Vector3f& a, const Eigen::Vector3f& b, const Eigen::Vector3f& c);
  /// Builds the search grid; call after the last add() and before distance().
  void build();
  size_t size() const { return triangles_.size(); }
  /// Whether `other` holds the same triangles, corner for corner, in the same order.
  bool same_triangles(const TriangleSet& other) const;
  bool empty() const { return triangles_.empty(); }
  /// A terrain is solid below its surface: a point over the set's box and below every triangle of its column is
  /// searched to its nearest triangle however deep (over a pyramid of the columns' spans), and one below the top of
  /// its column's triangles and farther than the ring search reaches from every triangle is inside, at least that
  /// deep, pushed up the set's up axis, rather than counted as tunnelled through (a floor or other open surface, by
  /// default, may be passed through). Cleared by clear().
  void set_solid_below(bool solid) { solid_below_ = solid; }
  /// The vertices of triangle i.
  const Eigen::Vector3f& corner(size_t i, int k) const {
    const detail::BoxedTriangle& t = triangles_[i];
    return k == 0 ? t.a : k == 1 ? t.b : t.c;
  }
  float distance(const Eigen::Vector3f& x, Eigen::Vector3f& outward) const;
  /// A value the signed distance at x is not below, cheap far above a floor or terrain: for a set whose normals
  /// all lean one way, a point beyond the set's box on that side is outside by at least its distance to the box;
  /// for a set whose normals all lean up a grid axis, a point over the box, above every triangle of its column of
  /// cells, whose cell has no triangle within r rings is outside by at least r - 1 cells, and nearer by its height
  /// over the tops of the columns around it (column_bound); under a solid set, below every triangle of its column,
  /// minus its distance to one of them (depth_bound: cheap, and the point is inside, so its cluster opens either way;
  /// behind an open floor the search's +reach prunes it instead).
  /// Elsewhere (beside the surface, near a triangle, or a set with no up) distance(): a bound must not hide a point
  /// that is inside. (Beyond the search's reach distance() is a value of the right size, not a bound; a negative one
  /// never prunes.)
  float lower_bound(const Eigen::Vector3f& x) const;

 private:
  /// Drops what mark_cells_above_surface fills (a set with no up axis has none of it).
  void clear_columns();
  void mark_cells_above_surface();
  void fill_column_tops();
  /// Index of cell c's column (along the up axis) in column_tops_' maps and column_levels_[0].
  size_t column_index(const Eigen::Vector3i& c) const;
  /// Whether x lies within the set's box across the up axis (over it or under it).
  bool over_the_box(const Eigen::Vector3f& x) const;
  /// A point above the top of its own column: the largest of, over each block of columns around it, the lesser of
  /// its height over the block's top and its distance across to the block's side (a triangle is either in the
  /// block, no higher than its top, or beyond its side). Not above it: -infinity. `c`: x's cell.
  float column_bound(const Eigen::Vector3f& x, const Eigen::Vector3i& c) const;
  /// Whether x (in cell c) lies below every triangle of its own column, one that has some.
  bool below_own_column(const Eigen::Vector3f& x, const Eigen::Vector3i& c) const;
  /// Whether x lies over the set's box across the up axis and below the top of its own column's triangles.
  bool below_column_top(const Eigen::Vector3f& x) const;
  /// A value the signed distance at x is not below: minus x's distance to t (the nearest triangle is no farther).
  static float depth_bound(const Eigen::Vector3f& x, const detail::BoxedTriangle& t);
  /// distance() of a point below its column under a solid set: a best-first search over column_levels_, exact at any
  /// depth (against the set's triangles).
  float nearest_over_columns(const Eigen::Vector3f& x, Eigen::Vector3f& outward) const;
  /// Offers `nearest` the triangles of column (i, j) (across the up axis: (up + 1) % 3, (up + 2) % 3) not yet looked
  /// at.
  void consider_column(int i, int j, VisitStamps& stamps, detail::NearestTriangle& nearest) const;
  void fill_column_pyramid();
  /// distance() of a point no triangle lies within `reach` of (`box`: its distance to the set's box): inside by
  /// that much under a solid set, else outside.
  float beyond_reach(const Eigen::Vector3f& x, float box, float reach, Eigen::Vector3f& outward) const;

  std::vector<detail::BoxedTriangle> triangles_;
  TriangleGrid grid_;
  Eigen::Vector3f common_normal_ = Eigen::Vector3f::Zero();  ///< zero unless every normal has n . c > 0
  /// Per cell, 1 where the cell lies above every triangle of its column along an axis every normal leans up
  /// (so a point there is outside); empty when no axis does.
  std::vector<uint8_t> above_surface_;
  int up_axis_ = 1;       ///< that axis, when above_surface_ is filled
  float up_sign_ = 1.0f;  ///< +1 if the normals lean up that axis, -1 down it
  /// When above_surface_ is filled: per k in kColumnReach, per column of cells along the up axis, the top (up_sign_
  /// times) of the triangles covering the block of 2k + 1 columns a side around it (a column's own top: its span in
  /// column_levels_[0]).
  std::vector<float> column_tops_;
  static constexpr int kColumnReach[] = {1, 2, 4, 8};
  /// The lowest and highest point (up_sign_ times) of the triangles covering some columns (none: bottom +infinity,
  /// top -infinity).
  struct ColumnSpan {
    float bottom = std::numeric_limits<float>::infinity(), top = -std::numeric_limits<float>::infinity();
  };
  /// A level of the columns' pyramid: count_a x count_b nodes across the up axis ((up + 1) % 3, (up + 2) % 3).
  struct ColumnLevel {
    int count_a = 0, count_b = 0;
    std::vector<ColumnSpan> spans;
    const ColumnSpan& at(int i, int j) const { return spans[size_t(j) * size_t(count_a) + size_t(i)]; }
  };
  /// With column_tops_: the pyramid over the columns, level 0 each column, each next level 2 x 2 nodes of the one
  /// below (what bounds the distance to all of a node's triangles in nearest_over_columns); and per column the
  /// triangle that reaches lowest.
  std::vector<ColumnLevel> column_levels_;
  std::vector<uint32_t> column_lowest_;
  /// How far a pyramid node's box is padded: the rounding in cell_of, relative to the cell and to the coordinates.
  float column_pad_ = 0.0f;
  bool solid_below_ = false;
  static constexpr int kEmptyRings = 64;  ///< rings the grid's map covers: a lower bound that costs one read
};

}  // namespace voxfmt::bullet
