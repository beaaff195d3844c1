// The runtime's field read the way the engine layouts sample it: a voxel's value at any index (past the grid: the
// nearest voxel's plus the distance to it), and the signed coarse value at a brick corner, whose trilinear
// interpolation across a brick without codes is the runtime's own there.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "core/field.h"

namespace voxfmt::engines::detail {

namespace core = runtime::core;

class FieldSamples {
 public:
  explicit FieldSamples(const core::Field& field) : f_(field) {}

  const core::Field& field() const { return f_; }
  int dims(int axis) const { return f_.dims[axis]; }

  /// Value of voxel (i, j, k), voxels; past the grid, the nearest voxel's plus the distance to it.
  float value(int i, int j, int k) const {
    const int c[3] = {std::clamp(i, 0, f_.dims[0] - 1), std::clamp(j, 0, f_.dims[1] - 1),
                      std::clamp(k, 0, f_.dims[2] - 1)};
    bool exact = true;
    const float inside = core::voxel_value(f_, c[0], c[1], c[2], exact);
    if (c[0] == i && c[1] == j && c[2] == k) return inside;
    const float dx = float(i - c[0]), dy = float(j - c[1]), dz = float(k - c[2]);
    return inside + std::sqrt(dx * dx + dy * dy + dz * dz);
  }

  /// The values of brick (a, b, c)'s 512 voxels, x fastest (a value brick's decoded from its codes at once).
  void brick_values(int a, int b, int c, float* out) const {
    const int32_t entry = brick(a, b, c);
    const bool whole = (a + 1) * core::kEdge <= f_.dims[0] && (b + 1) * core::kEdge <= f_.dims[1] &&
                       (c + 1) * core::kEdge <= f_.dims[2];
    if (entry >= 0 && whole) {
      const int16_t* codes = &f_.codes[size_t(entry) * core::kBrickVoxels];
      for (int n = 0; n < core::kBrickVoxels; ++n) out[n] = float(codes[n] >> 1) * f_.decode_step[codes[n] & 1];
      return;
    }
    for (int z = 0, n = 0; z < core::kEdge; ++z)
      for (int y = 0; y < core::kEdge; ++y)
        for (int x = 0; x < core::kEdge; ++x, ++n)
          out[n] = value(a * core::kEdge + x, b * core::kEdge + y, c * core::kEdge + z);
  }

  /// The least lattice value (voxels) at the corners of brick (a, b, c): the interpolation inside is a convex
  /// combination of them, so no voxel of a brick without codes has a value below it (or the band's edge).
  float least_corner(int a, int b, int c) const {
    const int lower[3] = {a, b, c};
    float p[8];
    core::cell_values(f_, lower, p);
    return *std::min_element(p, p + 8) * f_.lattice_step;
  }

  bool in_grid(int i, int j, int k) const {
    return i >= 0 && j >= 0 && k >= 0 && i < f_.dims[0] && j < f_.dims[1] && k < f_.dims[2];
  }

  /// The brick table entry of brick (a, b, c), or 0 (a value brick: no sign of its own) past the grid.
  int32_t brick(int a, int b, int c) const {
    if (a < 0 || b < 0 || c < 0 || a >= f_.brick_dims[0] || b >= f_.brick_dims[1] || c >= f_.brick_dims[2]) return 0;
    return f_.bricks[(size_t(c) * size_t(f_.brick_dims[1]) + size_t(b)) * size_t(f_.brick_dims[0]) + size_t(a)];
  }

  /// The signed value (voxels) at the corner of bricks (8a, 8b, 8c): the lattice there, signed as the bricks
  /// without codes around it are. Where the corner lies past the grid's last voxel along an axis, the lattice's
  /// last cell is extended linearly, so that interpolating the corners of a brick without codes over 8 voxels gives
  /// the runtime's interpolation over the shorter last cell.
  float coarse_corner(int a, int b, int c) const { return corner_sign(a, b, c) * lattice_corner(a, b, c); }

  /// The lattice's unsigned distance (voxels) at the corner of bricks (8a, 8b, 8c), extended linearly past the
  /// grid's last voxel as coarse_corner is.
  float lattice_corner(int a, int b, int c) const {
    const int corner[3] = {a, b, c};
    int index[3][2];
    float weight[3][2];
    for (int axis = 0; axis < 3; ++axis) {
      const int last = f_.dims[axis] - 1, x = corner[axis] * core::kEdge;
      if (x <= last || corner[axis] == 0) {
        index[axis][0] = index[axis][1] = corner[axis];
        weight[axis][0] = 1, weight[axis][1] = 0;
        continue;
      }
      // The lattice's last cell runs from voxel 8 (a - 1) to the last voxel.
      const int x0 = (corner[axis] - 1) * core::kEdge;
      index[axis][0] = corner[axis] - 1, index[axis][1] = corner[axis];
      const float t = last > x0 ? float(x - x0) / float(last - x0) : 0.0f;
      weight[axis][0] = 1 - t, weight[axis][1] = t;
    }
    const size_t row = size_t(f_.lattice_dims[0]), plane = row * size_t(f_.lattice_dims[1]);
    float unsigned_value = 0;
    for (int n = 0; n < 8; ++n) {
      const int ia = index[0][n & 1], ib = index[1][(n >> 1) & 1], ic = index[2][n >> 2];
      const float w = weight[0][n & 1] * weight[1][(n >> 1) & 1] * weight[2][n >> 2];
      if (w != 0) unsigned_value += w * float(f_.lattice[size_t(ic) * plane + size_t(ib) * row + size_t(ia)]);
    }
    return unsigned_value * f_.lattice_step;
  }

 private:
  /// The sign of the bricks without codes that share the corner; where none does (or both signs do: across a hole
  /// of an open mesh), the sign of the corner's voxel.
  float corner_sign(int a, int b, int c) const {
    bool inside = false, outside = false;
    for (int n = 0; n < 8; ++n) {
      const int32_t entry = brick(a - (n & 1), b - ((n >> 1) & 1), c - (n >> 2));
      inside |= entry == core::kCoarseInside;
      outside |= entry == core::kCoarseOutside;
    }
    if (inside != outside) return inside ? -1.0f : 1.0f;
    return value(a * core::kEdge, b * core::kEdge, c * core::kEdge) < 0 ? -1.0f : 1.0f;
  }

  core::Field f_;
};

}  // namespace voxfmt::engines::detail
