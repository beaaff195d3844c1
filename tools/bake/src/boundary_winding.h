// The generalized winding number's side of 1/2, decided exactly for every band voxel of an open, non-manifold or
// self-intersecting surface, at a cost that follows the surface's boundary instead of its triangles.
//
// Cap each component of the surface M's boundary (the edges whose faces do not cancel) with a surface C of the
// same boundary: M - C is then closed, so its winding number at q is the signed count I(q) of its crossings on the
// ray from q towards -x, and exactly (up to rounding of the solid angles):
//
//   w(q) = I(q) + w_C(q),   w_C = the caps' solid angles / 4 pi (oriented to cancel M's boundary: "- C" above)
//
// A component's cap is either the strips swept from its edges towards +x (parallel to the rays, so never
// crossed) or a fan of triangles from its centre (crossed like M's triangles), whichever passes near fewer
// voxels that need a sign: strips for the rim of a large sheet, fans for small holes and open ends. The rays of a
// row of voxels lie on one line, whose crossings the bake sorts once. Crossings, the strips' and fans' branches
// (+-2 pi across them) and the side of a plane use exact predicates on one symbolically perturbed point, so that
// the parts agree wherever a line passes through edges and vertices. A closed surface has no boundary: w = I.
//
// Per brick, the caps far from it add up to a smooth (harmonic) function there; it is interpolated from a shared
// lattice 4 voxels apart, within a bound from its third derivatives (the Biot-Savart field of the caps'
// boundaries). A voxel whose interpolated value lies farther from 1/2 than the bound is decided; the rest sum
// every cap.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "voxfmt/asset.h"

namespace voxfmt::bake {

/// An edge of the surface's boundary chain, `multiplicity` times from `a` to `b` (index space).
struct BoundaryEdge {
  Vec3 a, b;
  uint32_t va, vb;
  int32_t multiplicity;
  uint32_t component;
};

/// Where the line {(x, j, k)} crosses a triangle: at `x`, certainly if farther than `slack` from a voxel centre
/// (the exact side test decides nearer). The winding number of the closed M - C changes by `step` from before
/// the crossing to after it. `triangle`: a mesh triangle, or kFanTriangle + a fan triangle.
struct LineCrossing {
  double x, slack;
  int32_t step;
  uint32_t triangle;
};

class BoundaryWinding {
 public:
  static constexpr uint32_t kFanTriangle = 0x80000000u;

  /// `vertices` in index space (voxel centres at integers), the same values the triangles' corners take.
  BoundaryWinding(const std::vector<std::array<uint32_t, 3>>& triangles, const std::vector<Vec3>& vertices);

  bool closed() const { return edges_.empty(); }
  size_t edge_count() const { return edges_.size(); }

  /// Chooses each boundary component's cap and fills the lattice for the bricks that need signs (`bricks`:
  /// ascending linear indices (bk * B1 + bj) * B0 + bi of a grid of `brick_dims` bricks of 8^3 voxels). `caps`
  /// other than Cheaper (the bake's) are for tests: every component capped the same way.
  enum class Caps { Cheaper, Strips, Fans };
  void prepare(const std::vector<int64_t>& bricks, const std::array<int64_t, 3>& brick_dims,
               Caps choice = Caps::Cheaper);

  /// w_C(q): the sum of every cap's solid angle / 4 pi, so that w(q) = I(q) + caps(q).
  double caps(const Vec3& q) const;

  /// The fan triangles (kFanTriangle + index) that may cross a voxel line of the row of bricks (bj, bk).
  void row_fan_triangles(int64_t bj, int64_t bk, std::vector<uint32_t>& out) const;
  /// A fan triangle's corners (its crossings, with multiplicity) as LineCrossing's triangle names it.
  void fan_triangle(uint32_t name, Vec3& a, Vec3& b, Vec3& c, int32_t& multiplicity) const;

  /// The crossing of the line {(x, j, k)} with triangle abc, if the (perturbed) line crosses it (step: +-1).
  static bool line_crossing(const Vec3& a, const Vec3& b, const Vec3& c, double j, double k, LineCrossing& out);
  /// Exactly, for the perturbed point: does p lie past triangle abc's plane in +x (after its crossing)?
  static bool past_plane(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& p);

  /// One brick's caps: those evaluated at each voxel (`near_edges`: strips, `near_fans`), the rest interpolated
  /// (quadratically, from the 27 lattice points of the brick's cell) within `bound`, which prepare_cell brings
  /// below `target` if it can with a bounded amount of work per voxel.
  struct Cell {
    Vec3 lo{};
    double spacing = 0;  // of its 27 lattice points
    std::vector<uint32_t> near_edges, near_fans;
    double far[27] = {};
    double bound = 0;
  };
  void prepare_cell(int64_t bi, int64_t bj, int64_t bk, double target, Cell& cell) const;
  /// caps(q) for q in the cell, within cell.bound (interpolation and rounding).
  double cell_caps(const Cell& cell, const Vec3& q) const;

 private:
  struct Component {
    Vec3 lo, hi, centre;
    double area = 0;  // of its fan, unsigned
    std::vector<uint32_t> edges;
    std::vector<Vec3> corners;                   // its vertices, once each
    std::vector<std::array<uint32_t, 2>> sides;  // each edge's corners (a, b)
    bool fan = false;
  };
  void group_components(size_t vertex_count);
  void place_fan(Component& c) const;
  double strip(const BoundaryEdge& e, const Vec3& q) const;
  double fan(const Component& c, const Vec3& q) const;
  double lattice_value(int64_t x, int64_t y, int64_t z, double& error) const;
  // The caps of a cube of `size` at cell.lo to evaluate exactly, and the bound on interpolating the rest from
  // points cell.spacing apart; then the values to interpolate, from the caps' sums at those points.
  void select_near(double size, double target, size_t max_work, Cell& cell) const;
  // prepare()'s steps: strips or a fan for each boundary component (the cheaper for `bricks`), the strip edges at
  // each vertex, the fan triangles by row of bricks, the caps' sums at the bricks' lattice points.
  void choose_caps(const std::vector<int64_t>& bricks, Caps choice);
  void index_strip_vertices();
  void bin_fan_triangles();
  void prepare_lattice(const std::vector<int64_t>& bricks);
  class NearSelection;  // select_near's greedy choice, for one cell
  void fill_far(const double* values, double value_error, Cell& cell) const;

  std::vector<BoundaryEdge> edges_;
  std::vector<Component> components_;
  std::vector<uint32_t> strip_edges_, fans_;            // edges capped by strips; components capped by fans
  std::vector<uint32_t> fan_triangles_;                 // the edge of each fan triangle
  std::vector<uint32_t> vertex_first_, vertex_edges_;   // the strip edges at each vertex (CSR over vertex ids)
  std::vector<std::pair<int64_t, uint32_t>> row_fans_;  // (row bk * B1 + bj, fan triangle), ascending
  std::array<int64_t, 3> brick_dims_{};
  double total_multiplicity_ = 0;
  std::vector<uint64_t> lattice_keys_;  // ascending
  std::vector<double> lattice_values_, lattice_errors_;
};

}  // namespace voxfmt::bake
