#include "voxfmt/bullet/collision.h"

#include "triangle_distance.h"
#include "triangle_set.h"

#include <BulletCollision/NarrowPhaseCollision/btGjkEpa2.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <iterator>
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
  triangles_.push_back(detail::BoxedTriangle::of(a, b, c));
}

void TriangleGrid::clear() {
  first.clear();
  members.clear();
  ring.clear();
}

Eigen::Vector3i TriangleGrid::cell_of(const Eigen::Vector3f& x) const {
  Eigen::Vector3i c;
  for (int a = 0; a < 3; ++a) {
    // Clamped as a float first: a coordinate far away (or NaN, taken as 0) does not fit an int.
    const float f = std::floor((x[a] - lo[a]) / cell);
    c[a] = f >= float(dims[a] - 1) ? dims[a] - 1 : f > 0 ? int(f) : 0;
  }
  return c;
}

float TriangleGrid::unseen_distance(const Eigen::Vector3f& x, const Eigen::Vector3i& c, int r) const {
  float block = std::numeric_limits<float>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (c[a] - r > 0) block = std::min(block, std::max(0.0f, x[a] - (lo[a] + float(c[a] - r) * cell)));
    if (c[a] + r + 1 < dims[a]) block = std::min(block, std::max(0.0f, lo[a] + float(c[a] + r + 1) * cell - x[a]));
  }
  return block;
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

double bound_triangles(const std::vector<detail::BoxedTriangle>& triangles, TriangleGrid& grid) {
  grid.lo = triangles[0].lo;
  grid.hi = triangles[0].hi;
  double edges = 0;
  for (const detail::BoxedTriangle& t : triangles) {
    grid.lo = grid.lo.cwiseMin(t.lo);
    grid.hi = grid.hi.cwiseMax(t.hi);
    edges += double((t.b - t.a).norm() + (t.c - t.b).norm() + (t.a - t.c).norm());
  }
  return edges;
}

Eigen::Vector3f common_normal(const std::vector<detail::BoxedTriangle>& triangles) {
  Eigen::Vector3f mean = Eigen::Vector3f::Zero();
  for (const detail::BoxedTriangle& t : triangles) mean += t.normal;
  if (!(mean.squaredNorm() > 0.0f)) return Eigen::Vector3f::Zero();
  mean.normalize();
  for (const detail::BoxedTriangle& t : triangles)
    if (t.normal.squaredNorm() > 0.0f && !(t.normal.dot(mean) > 0.0f)) return Eigen::Vector3f::Zero();
  return mean;
}

void TriangleSet::clear() {
  solid_below_ = false;
  common_normal_.setZero();
  triangles_.clear();
  grid_.clear();
  clear_columns();
}

bool TriangleSet::same_triangles(const TriangleSet& other) const {
  return std::equal(triangles_.begin(), triangles_.end(), other.triangles_.begin(), other.triangles_.end(),
                    [](const detail::BoxedTriangle& s, const detail::BoxedTriangle& t) {
                      return s.a == t.a && s.b == t.b && s.c == t.c;
                    });
}

void TriangleSet::clear_columns() {
  above_surface_.clear();
  column_tops_.clear();
  column_lowest_.clear();
  column_levels_.clear();
}

void TriangleSet::mark_cells_above_surface() {
  clear_columns();
  if (!(common_normal_.squaredNorm() > 0.0f)) return;
  int up = 0;
  common_normal_.cwiseAbs().maxCoeff(&up);
  const int sign = common_normal_[up] > 0.0f ? 1 : -1;
  // Every proper normal leans up the axis (a terrain's do): a point in a column of cells above its topmost occupied
  // cell is above the surface there, so outside. (A column with no triangle says nothing: a point below a terrain's
  // edge, just beside it, is inside. Nor do columns at the box's sides for points beyond them: lower_bound asks
  // only within the box's footprint.)
  for (const detail::BoxedTriangle& t : triangles_)
    if (t.normal.squaredNorm() > 0.0f && !(float(sign) * t.normal[up] > 0.0f)) return;
  above_surface_.assign(size_t(grid_.dims.prod()), 0);
  up_axis_ = up;
  up_sign_ = float(sign);
  const int a = (up + 1) % 3, b = (up + 2) % 3, n = grid_.dims[up];
  const auto at = [&](Eigen::Vector3i c, int step) {  // the step-th cell of c's column from its top
    c[up] = sign > 0 ? n - 1 - step : step;
    return grid_.cell_index(c);
  };
  Eigen::Vector3i c = Eigen::Vector3i::Zero();
  for (c[a] = 0; c[a] < grid_.dims[a]; ++c[a])
    for (c[b] = 0; c[b] < grid_.dims[b]; ++c[b]) {
      int top = 0;
      while (top < n && grid_.first[at(c, top) + 1] == grid_.first[at(c, top)]) ++top;
      if (top == n) continue;
      for (int step = 0; step < top; ++step) above_surface_[at(c, step)] = 1;
    }
  fill_column_tops();
}

// Per column of cells along the up axis, the span (along `sign` times the axis) of the triangles whose boxes cover
// it and its lowest triangle, then the tops' maximum over the blocks of 2k + 1 columns a side around each
// (kColumnReach) and the spans' pyramid.
void TriangleSet::fill_column_tops() {
  const int a = (up_axis_ + 1) % 3, b = (up_axis_ + 2) % 3, na = grid_.dims[a], nb = grid_.dims[b];
  const size_t columns = size_t(na) * size_t(nb);
  column_levels_.assign(1, ColumnLevel{na, nb, std::vector<ColumnSpan>(columns)});
  std::vector<ColumnSpan>& spans = column_levels_[0].spans;
  column_lowest_.assign(columns, 0);
  for (size_t i = 0; i < triangles_.size(); ++i) {
    const detail::BoxedTriangle& t = triangles_[i];
    const Eigen::Vector3i c0 = grid_.cell_of(t.lo), c1 = grid_.cell_of(t.hi);
    const float top = up_sign_ > 0.0f ? t.hi[up_axis_] : -t.lo[up_axis_];
    const float bottom = up_sign_ > 0.0f ? t.lo[up_axis_] : -t.hi[up_axis_];
    Eigen::Vector3i cell = c0;
    for (cell[b] = c0[b]; cell[b] <= c1[b]; ++cell[b])
      for (cell[a] = c0[a]; cell[a] <= c1[a]; ++cell[a]) {
        const size_t column = column_index(cell);
        ColumnSpan& span = spans[column];
        span.top = std::max(span.top, top);
        if (bottom < span.bottom) {
          span.bottom = bottom;
          column_lowest_[column] = uint32_t(i);
        }
      }
  }
  column_tops_.assign(columns * std::size(kColumnReach), -std::numeric_limits<float>::infinity());
  // Each reach's map from the last (the first from the columns' own tops) by a separable maximum filter (reaches
  // grow, so each widens the one before).
  std::vector<float> along(columns);
  int before = 0;
  for (size_t level = 0; level < std::size(kColumnReach); ++level) {
    const int grow = kColumnReach[level] - before;
    before = kColumnReach[level];
    const auto from = [&](int column) {
      return level == 0 ? spans[size_t(column)].top : column_tops_[(level - 1) * columns + size_t(column)];
    };
    float* to = &column_tops_[level * columns];
    for (int j = 0; j < nb; ++j)
      for (int i = 0; i < na; ++i) {
        float m = -std::numeric_limits<float>::infinity();
        for (int d = std::max(i - grow, 0); d <= std::min(i + grow, na - 1); ++d) m = std::max(m, from(j * na + d));
        along[size_t(j * na + i)] = m;
      }
    for (int j = 0; j < nb; ++j)
      for (int i = 0; i < na; ++i) {
        float m = -std::numeric_limits<float>::infinity();
        for (int d = std::max(j - grow, 0); d <= std::min(j + grow, nb - 1); ++d)
          m = std::max(m, along[size_t(d * na + i)]);
        to[j * na + i] = m;
      }
  }
  fill_column_pyramid();
}

void TriangleSet::fill_column_pyramid() {
  column_pad_ = 1e-5f * grid_.cell + 5e-7f * std::max(grid_.lo.cwiseAbs().maxCoeff(), grid_.hi.cwiseAbs().maxCoeff());
  while (column_levels_.back().count_a > 1 || column_levels_.back().count_b > 1) {
    const ColumnLevel& below = column_levels_.back();
    ColumnLevel up{(below.count_a + 1) / 2, (below.count_b + 1) / 2, {}};
    up.spans.resize(size_t(up.count_a) * size_t(up.count_b));
    for (int j = 0; j < below.count_b; ++j)
      for (int i = 0; i < below.count_a; ++i) {
        ColumnSpan& to = up.spans[size_t(j / 2 * up.count_a + i / 2)];
        const ColumnSpan& from = below.at(i, j);
        to.bottom = std::min(to.bottom, from.bottom);
        to.top = std::max(to.top, from.top);
      }
    column_levels_.push_back(std::move(up));
  }
}

float TriangleSet::nearest_over_columns(const Eigen::Vector3f& x, Eigen::Vector3f& outward) const {
  const int a = (up_axis_ + 1) % 3, b = (up_axis_ + 2) % 3;
  const float height = up_sign_ * x[up_axis_];
  // A node's box: its columns across, its span up (a triangle's point lies in the column under it, whose span holds
  // the triangle's), padded by column_pad_.
  const float pad = column_pad_;
  struct Node {
    float d2;
    int level, i, j;
  };
  detail::NearestTriangle nearest(x);
  thread_local std::vector<Node> heap;
  heap.clear();
  const auto nearer_first = [](const Node& p, const Node& q) { return p.d2 > q.d2; };
  const auto push = [&](int level, int i, int j) {
    const ColumnSpan& span = column_levels_[size_t(level)].at(i, j);
    if (!(span.bottom <= span.top)) return;  // no triangle
    const float side = grid_.cell * float(1 << level);
    const float a0 = grid_.lo[a] + float(i) * side, b0 = grid_.lo[b] + float(j) * side;
    const float da = std::max({a0 - pad - x[a], x[a] - (a0 + side + pad), 0.0f});
    const float db = std::max({b0 - pad - x[b], x[b] - (b0 + side + pad), 0.0f});
    const float dv = std::max({span.bottom - pad - height, height - (span.top + pad), 0.0f});
    const float d2 = da * da + db * db + dv * dv;
    if (!nearest.may_improve(d2)) return;  // nor can any triangle in it
    heap.push_back({d2, level, i, j});
    std::push_heap(heap.begin(), heap.end(), nearer_first);
  };
  push(int(column_levels_.size()) - 1, 0, 0);
  VisitStamps& stamps = VisitStamps::start(triangles_.size());
  while (!heap.empty()) {
    std::pop_heap(heap.begin(), heap.end(), nearer_first);
    const Node node = heap.back();
    heap.pop_back();
    if (!nearest.may_improve(node.d2)) break;  // nor can any node after it
    if (node.level == 0) {
      consider_column(node.i, node.j, stamps, nearest);
      continue;
    }
    const ColumnLevel& below = column_levels_[size_t(node.level - 1)];
    for (int j = 2 * node.j; j < std::min(2 * node.j + 2, below.count_b); ++j)
      for (int i = 2 * node.i; i < std::min(2 * node.i + 2, below.count_a); ++i) push(node.level - 1, i, j);
  }
  outward = nearest.outward;
  return nearest.signed_distance();
}

void TriangleSet::consider_column(int i, int j, VisitStamps& stamps, detail::NearestTriangle& nearest) const {
  const int a = (up_axis_ + 1) % 3, b = (up_axis_ + 2) % 3, up = up_axis_;
  // The column's cells that its triangles reach (the span is up_sign_ times the axis).
  const ColumnSpan& span = column_levels_[0].at(i, j);
  Eigen::Vector3f low = grid_.lo, high = grid_.lo;
  low[up] = up_sign_ > 0.0f ? span.bottom : -span.top;
  high[up] = up_sign_ > 0.0f ? span.top : -span.bottom;
  Eigen::Vector3i c = grid_.cell_of(low);
  const int last = grid_.cell_of(high)[up];
  c[a] = i;
  c[b] = j;
  for (; c[up] <= last; ++c[up]) consider_cell(grid_, triangles_, grid_.cell_index(c), stamps, nearest);
}

size_t TriangleSet::column_index(const Eigen::Vector3i& c) const {
  const int a = (up_axis_ + 1) % 3, b = (up_axis_ + 2) % 3;
  return size_t(c[b]) * size_t(grid_.dims[a]) + size_t(c[a]);
}

bool TriangleSet::over_the_box(const Eigen::Vector3f& x) const {
  for (int a = 0; a < 3; ++a)
    if (a != up_axis_ && !(x[a] >= grid_.lo[a] && x[a] <= grid_.hi[a])) return false;
  return true;
}

bool TriangleSet::below_own_column(const Eigen::Vector3f& x, const Eigen::Vector3i& c) const {
  const ColumnSpan& span = column_levels_[0].at(c[(up_axis_ + 1) % 3], c[(up_axis_ + 2) % 3]);
  return span.bottom <= span.top && up_sign_ * x[up_axis_] < span.bottom;
}

bool TriangleSet::below_column_top(const Eigen::Vector3f& x) const {
  if (column_levels_.empty() || !over_the_box(x)) return false;
  return up_sign_ * x[up_axis_] < column_levels_[0].spans[column_index(grid_.cell_of(x))].top;
}

float TriangleSet::column_bound(const Eigen::Vector3f& x, const Eigen::Vector3i& c) const {
  const int a = (up_axis_ + 1) % 3, b = (up_axis_ + 2) % 3;
  const size_t columns = size_t(grid_.dims[a]) * size_t(grid_.dims[b]), column = column_index(c);
  const float height = up_sign_ * x[up_axis_];
  // Above every triangle of its own column (a graph over the up axis): outside. A column no triangle covers says
  // nothing (beside the set's edge, or over a gap in it, a point may be inside).
  const float own_top = column_levels_[0].spans[column].top;
  if (!(own_top > -std::numeric_limits<float>::infinity()) || !(height > own_top))
    return -std::numeric_limits<float>::infinity();
  // How far x is inside its own column across the up axis: a block of 2k + 1 columns around it reaches k cells
  // beyond that.
  const float inside =
      std::min({x[a] - (grid_.lo[a] + float(c[a]) * grid_.cell), grid_.lo[a] + float(c[a] + 1) * grid_.cell - x[a],
                x[b] - (grid_.lo[b] + float(c[b]) * grid_.cell), grid_.lo[b] + float(c[b] + 1) * grid_.cell - x[b]});
  float bound = 0.0f;
  for (size_t level = 0; level < std::size(kColumnReach); ++level) {
    // A triangle within the block is no higher than its top; one beyond it is farther across than the block's side.
    const float across = std::max(inside, 0.0f) + float(kColumnReach[level]) * grid_.cell;
    const float above = height - column_tops_[level * columns + column];
    bound = std::max(bound, std::min(across, above));
    if (above <= across) break;  // wider blocks are no lower: their bounds are no larger than `above`
  }
  return bound;
}

void TriangleSet::build() {
  grid_.clear();
  if (empty()) return;
  const double edges = bound_triangles(triangles_, grid_);
  // A one-sided set (every triangle faces within 90 degrees of the mean normal) allows the cheap lower bound.
  common_normal_ = common_normal(triangles_);
  // Cells about the size of a triangle (a few triangles each), at most 64 along an axis.
  const Eigen::Vector3f extent = grid_.hi - grid_.lo;
  grid_.cell = std::max({float(edges / double(3 * size())), extent.maxCoeff() / 64.0f, 1e-30f});  // relative: any scale
  for (int a = 0; a < 3; ++a) grid_.dims[a] = std::clamp(int(std::ceil(extent[a] / grid_.cell)), 1, 64);
  grid_.fill(
      size(), [&](size_t t) -> const Eigen::Vector3f& { return triangles_[t].lo; },
      [&](size_t t) -> const Eigen::Vector3f& { return triangles_[t].hi; }, kEmptyRings);
  mark_cells_above_surface();
}

float TriangleSet::lower_bound(const Eigen::Vector3f& x) const {
  if (grid_.built() && common_normal_.squaredNorm() > 0.0f) {
    const Eigen::Vector3f off_box = x - x.cwiseMax(grid_.lo).cwiseMin(grid_.hi);
    // Beyond the box on the side every triangle faces: above a surface that is a graph over that direction,
    // so outside, and no triangle is nearer than the box.
    if (off_box.dot(common_normal_) > 0.0f) return off_box.norm();
  }
  if (!above_surface_.empty() && over_the_box(x)) {
    // No triangle within `ring` - 1 rings of x's cell (x's projection onto the box lies in it, and projecting
    // onto a convex set brings nothing of it nearer): at least that many cells, and the box's distance, away;
    // and above the surface, so outside. Nearer, the columns' tops around x bound it from below.
    const Eigen::Vector3i c = grid_.cell_of(x);
    const size_t cell = grid_.cell_index(c);
    const int ring = grid_.ring[cell];
    if (ring > 1 && above_surface_[cell]) return std::max(grid_.box_distance(x), float(ring - 1) * grid_.cell);
    const float column = column_bound(x, c);
    if (column > 0.0f) return column;
    // Below every triangle of its own column: most likely inside, where the exact distance (a search as deep as
    // the point) would only open the cluster. Any triangle's distance bounds the depth.
    if (solid_below_ && below_own_column(x, c)) return depth_bound(x, triangles_[column_lowest_[column_index(c)]]);
  }
  Eigen::Vector3f outward;
  return distance(x, outward);
}

float TriangleSet::depth_bound(const Eigen::Vector3f& x, const detail::BoxedTriangle& t) {
  // The searches' nearest is no farther than t (computed alike); the margin is for rounding, and costs nothing:
  // the cluster opens either way.
  return -(x - detail::closest_on_triangle(x, t.a, t.b, t.c)).norm() * (1.0f + 1e-5f);
}

float TriangleSet::beyond_reach(const Eigen::Vector3f& x, float box, float reach, Eigen::Vector3f& outward) const {
  if (solid_below_ && below_column_top(x)) {  // under a terrain: inside, pushed up its axis
    outward = Eigen::Vector3f::Unit(up_axis_) * up_sign_;
    return -reach;
  }
  // Behind an open surface (a floor): it has tunnelled through, so outside.
  outward =
      box > 0.0f ? Eigen::Vector3f((x - x.cwiseMax(grid_.lo).cwiseMin(grid_.hi)) / box) : Eigen::Vector3f::UnitY();
  return reach;
}

float TriangleSet::distance(const Eigen::Vector3f& x, Eigen::Vector3f& outward) const {
  if (empty()) return std::numeric_limits<float>::infinity();
  detail::NearestTriangle nearest(x);
  if (!grid_.built()) {  // not built: every triangle
    for (const detail::BoxedTriangle& t : triangles_) nearest.consider(t.a, t.b, t.c, t.normal);
    outward = nearest.outward;
    return nearest.signed_distance();
  }
  const Eigen::Vector3i c = grid_.cell_of(x);
  // Under a terrain, below every triangle of its column: searched over the columns, exact at any depth.
  if (solid_below_ && !column_levels_.empty() && over_the_box(x) && below_own_column(x, c))
    return nearest_over_columns(x, outward);
  const float box = grid_.box_distance(x);
  // The rings before the nearest occupied one hold nothing: the search starts there.
  const int first_ring = grid_.ring.empty() ? 0 : int(grid_.ring[grid_.cell_index(c)]);
  if (first_ring >= kEmptyRings)  // no triangle within the rings the map covers
    return beyond_reach(x, box, std::max(box, float(kEmptyRings - 1) * grid_.cell), outward);
  // Rings past the grid's size cover all of it: the search is then exact wherever x is.
  const float limit = first_ring + kMaxRings > grid_.dims.maxCoeff() ? std::numeric_limits<float>::infinity()
                                                                     : float(first_ring + kMaxRings) * grid_.cell;
  const float reach = nearest_by_rings(grid_, triangles_, x, c, first_ring, box, limit, nearest);
  if (nearest.settled_within(reach)) {
    outward = nearest.outward;
    return nearest.signed_distance();
  }
  // Not settled within kMaxRings of the first occupied ring: every triangle is farther than that and than the box.
  return beyond_reach(x, box, std::max(box, limit), outward);
}

}  // namespace voxfmt::bullet
