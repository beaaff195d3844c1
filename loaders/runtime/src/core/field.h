// The distance field of a voxelmap (spec §3), read where it is stored: the brick table, the value bricks' 16-bit
// codes and the lattice, as plain arrays. One definition for the CPU runtime (SparseVoxelmap), its tests and the
// CUDA kernels (VOXFMT_HD): a lookup near the surface is one table entry and one brick's codes, decoded without
// a branch; a coarse brick interpolates the lattice.
#pragma once

#include "hd.h"

namespace voxfmt::runtime::core {

constexpr int kEdge = 8;
constexpr unsigned kEdgeBits = 3;
constexpr int kBrickVoxels = kEdge * kEdge * kEdge;
constexpr int32_t kCoarseOutside = -1;
constexpr int32_t kCoarseInside = -2;
// The lattice interpolated at a voxel is within the sum over the cell's corners of weight x distance of the exact
// distance (the distance is 1-Lipschitz); that sum is largest at a brick's centre: 4 sqrt(3) voxels (spec §3.3).
constexpr float kInterpolationBound = 6.9282032f;

// A value brick with an apron (Field::apron): its 8^3 codes and the first layer of its +x, +y and +z neighbours',
// 9^3 in all, so that a trilinear sample's eight corners are in one brick; then a mask of which of the seven
// neighbours' codes the apron holds (a coarse neighbour has none), padded to whole 16-byte rows.
constexpr int kApronEdge = kEdge + 1;
constexpr int kApronMask = kApronEdge * kApronEdge * kApronEdge;
constexpr int kApronBrickCodes = 736;
static_assert(kApronBrickCodes > kApronMask && kApronBrickCodes * 2 % 16 == 0, "the mask, then whole rows");

/// A voxelmap as the runtime holds it: views of its arrays and how they are read (voxel units throughout).
struct Field : FieldLayout {
  const int32_t* bricks = nullptr;    ///< brick table: >= 0 a value brick, -1 / -2 coarse outside / inside
  const int16_t* codes = nullptr;     ///< value bricks, kBrickVoxels codes each (kApronBrickCodes with an apron)
  const uint16_t* lattice = nullptr;  ///< unsigned distances at the lattice points, in steps of lattice_step
  /// The value bricks carry an apron (apron_codes): what a GPU holds, where one table read and eight loads in one
  /// brick serve every sample whose neighbours are stored. The runtime's own bricks have none.
  bool apron = false;
};

VOXFMT_HD int lattice_coordinate(const Field& f, int a, int axis) { return min_i(a * kEdge, f.dims[axis] - 1); }

/// The brick table entry of voxel (i, j, k).
VOXFMT_HD const int32_t* table_slot(const Field& f, int i, int j, int k) {
  // Voxel indices are never negative: shifts, not signed divisions.
  return &f.bricks[(size_t(unsigned(k) >> kEdgeBits) * unsigned(f.brick_dims[1]) + (unsigned(j) >> kEdgeBits)) *
                       unsigned(f.brick_dims[0]) +
                   (unsigned(i) >> kEdgeBits)];
}

VOXFMT_HD int32_t entry_of(const Field& f, int i, int j, int k) { return *table_slot(f, i, j, k); }

/// The 8 lattice values (in lattice steps) of the cell whose first lattice point is `lower`, x fastest, then y,
/// then z: what interpolating the lattice and bounding by its points read.
VOXFMT_HD void cell_values(const Field& f, const int lower[3], float p[8]) {
  const size_t row = size_t(f.lattice_dims[0]), plane = row * size_t(f.lattice_dims[1]);
  const uint16_t* q = &f.lattice[size_t(lower[2]) * plane + size_t(lower[1]) * row + size_t(lower[0])];
  const size_t offset[8] = {0, 1, row, row + 1, plane, plane + 1, plane + row, plane + row + 1};
  for (int c = 0; c < 8; ++c) p[c] = float(q[offset[c]]);
}

/// Trilinear interpolation of 8 corner values `v` (x fastest, then y, then z) at `t` in [0,1]^3, and if asked its
/// gradient per unit of t: the one interpolation of the voxels, the lattice and the MuJoCo plugin's blocks.
VOXFMT_HD float trilinear(const float v[8], const float t[3], Vec3* gradient) {
  const float x0 = v[0] + t[0] * (v[1] - v[0]), x1 = v[2] + t[0] * (v[3] - v[2]);
  const float x2 = v[4] + t[0] * (v[5] - v[4]), x3 = v[6] + t[0] * (v[7] - v[6]);
  const float y0 = x0 + t[1] * (x1 - x0), y1 = x2 + t[1] * (x3 - x2);
  if (gradient) {
    const float dx0 = v[1] - v[0], dx1 = v[3] - v[2], dx2 = v[5] - v[4], dx3 = v[7] - v[6];
    const float gx = (1 - t[2]) * (dx0 + t[1] * (dx1 - dx0)) + t[2] * (dx2 + t[1] * (dx3 - dx2));
    const float gy = (1 - t[2]) * (x1 - x0) + t[2] * (x3 - x2);
    *gradient = make_vec3(gx, gy, y1 - y0);
  }
  return y0 + t[2] * (y1 - y0);
}

/// The lattice cell voxel (i, j, k) lies in: that of its brick, from the brick's first voxel to the next brick's.
VOXFMT_HD void cell_of(int i, int j, int k, int lower[3]) {
  lower[0] = i >> kEdgeBits, lower[1] = j >> kEdgeBits, lower[2] = k >> kEdgeBits;
}

/// The coarse estimate of a voxel of a coarse brick from its cell's lattice values `p` (cell_values of cell_of):
/// the lattice interpolated, at least the band's edge, signed.
VOXFMT_HD float coarse_value_in(const Field& f, int i, int j, int k, int32_t entry, const float p[8]) {
  const int c[3] = {i, j, k};
  float t[3];
  for (int a = 0; a < 3; ++a) {
    const int x0 = (c[a] >> kEdgeBits) * kEdge, x1 = lattice_coordinate(f, (c[a] >> kEdgeBits) + 1, a);
    t[a] = x1 > x0 ? float(c[a] - x0) / float(x1 - x0) : 0.0f;
  }
  const float magnitude = max_f(trilinear(p, t, nullptr) * f.lattice_step, f.band_edge);
  return entry == kCoarseInside ? -magnitude : magnitude;
}

/// The coarse estimate of a voxel of a coarse brick.
VOXFMT_HD float coarse_value(const Field& f, int i, int j, int k, int32_t entry) {
  int lower[3];
  cell_of(i, j, k, lower);
  float p[8];
  cell_values(f, lower, p);
  return coarse_value_in(f, i, j, k, entry, p);
}

/// The lattice interpolated trilinearly at grid coordinates u (inside the grid), and its gradient if asked.
VOXFMT_HD float lattice_at(const Field& f, const Vec3& u, Vec3* gradient) {
  int lower[3];
  float t[3], inverse[3];
  for (int a = 0; a < 3; ++a) {
    const float c = clamp_f(u[a], 0.0f, float(f.dims[a] - 1));
    lower[a] = min_i(int(c) >> kEdgeBits, max_i(f.lattice_dims[a] - 2, 0));
    const int x0 = lattice_coordinate(f, lower[a], a), x1 = lattice_coordinate(f, lower[a] + 1, a);
    inverse[a] = x1 > x0 ? 1.0f / float(x1 - x0) : 0.0f;
    t[a] = clamp_f((c - float(x0)) * inverse[a], 0.0f, 1.0f);
  }
  float v[8];
  cell_values(f, lower, v);
  for (int c = 0; c < 8; ++c) v[c] *= f.lattice_step;
  const float value = trilinear(v, t, gradient);
  if (gradient) *gradient = make_vec3(gradient->x * inverse[0], gradient->y * inverse[1], gradient->z * inverse[2]);
  return value;
}

/// The field at `u` in a coarse brick (`entry` kCoarseOutside or kCoarseInside): its voxels' values are the
/// lattice's interpolation, which is trilinear across the whole brick, so interpolating the lattice at u directly
/// gives the same field; at least the band's edge (flat there: a zero gradient), signed by the brick.
VOXFMT_HD float coarse_sample(const Field& f, const Vec3& u, int32_t entry, Vec3* gradient) {
  const float magnitude = lattice_at(f, u, gradient);
  const bool clamped = magnitude < f.band_edge;
  const float sign = entry == kCoarseInside ? -1.0f : 1.0f;
  if (gradient) *gradient = clamped ? make_vec3(0, 0, 0) : sign * *gradient;
  return sign * max_f(magnitude, f.band_edge);
}

/// `f` reading its value bricks with an apron from `apron_codes` (apron_codes' layout): never by vector gathers,
/// which assume the runtime's 8^3 bricks.
VOXFMT_HD Field with_apron(Field f, const int16_t* apron_codes) {
  f.codes = apron_codes;
  f.apron = true;
  f.gather_safe = false;
  return f;
}

/// Where voxel (i, j, k) of value brick `entry` keeps its code.
VOXFMT_HD const int16_t* code_of(const Field& f, int i, int j, int k, int32_t entry) {
  if (f.apron) {
    const int local = ((k & (kEdge - 1)) * kApronEdge + (j & (kEdge - 1))) * kApronEdge + (i & (kEdge - 1));
    return &f.codes[size_t(entry) * kApronBrickCodes + size_t(local)];
  }
  const int local = ((k & (kEdge - 1)) * kEdge + (j & (kEdge - 1))) * kEdge + (i & (kEdge - 1));
  return &f.codes[size_t(entry) * kBrickVoxels + size_t(local)];
}

/// Value of voxel (i, j, k) inside the grid, whose brick table entry is `entry`; `exact` is cleared for an
/// estimate.
VOXFMT_HD float entry_value(const Field& f, int i, int j, int k, int32_t entry, bool& exact) {
  if (entry >= 0) {
    const int code = *code_of(f, i, j, k, entry);
    exact &= (code & 1) != 0;
    return float(code >> 1) * f.decode_step[code & 1];
  }
  exact = false;
  return coarse_value(f, i, j, k, entry);
}

/// Value of voxel (i, j, k) inside the grid; `exact` is cleared for an estimate.
VOXFMT_HD float voxel_value(const Field& f, int i, int j, int k, bool& exact) {
  return entry_value(f, i, j, k, entry_of(f, i, j, k), exact);
}

/// The lowest signed distance a voxel whose value is `value` can have; `coarse`: the voxel is in a coarse brick.
VOXFMT_HD float value_lower_bound(const Field& f, float value, bool stored, bool coarse) {
  if (stored) return value - f.stored_slack;
  // A voxel without a stored distance is at least the band's edge from the surface, and its estimate bounds the
  // exact distance both ways (spec §3.1).
  const float slack = coarse ? f.estimate_slack : f.value_estimate_slack;
  return value > 0 ? max_f(f.band_edge, (value - f.estimate_offset) * f.estimate_shrink - slack) : value - slack;
}

/// True if `u` lies within the grid's voxels (a voxel's cell extends half a voxel around its centre).
VOXFMT_HD bool covers(const Field& f, const Vec3& u) {
  // Bitwise, not short-circuit: one branch for the caller instead of six hard-to-predict ones.
  return (u.x > -0.5f) & (u.y > -0.5f) & (u.z > -0.5f) & (u.x < f.cover_max.x) & (u.y < f.cover_max.y) &
         (u.z < f.cover_max.z);
}

VOXFMT_HD float bounds_distance(const Field& f, const Vec3& u) {
  const Vec3 outside = make_vec3(max_f(max_f(f.object_min.x - u.x, u.x - f.object_max.x), 0.0f),
                                 max_f(max_f(f.object_min.y - u.y, u.y - f.object_max.y), 0.0f),
                                 max_f(max_f(f.object_min.z - u.z, u.z - f.object_max.z), 0.0f));
  return hypot_f(outside, 0.0f);
}

/// The 8 corner values of the cell at `base` when they lie in one value brick (one table entry, two cache lines
/// near the surface): true, and `exact` whether all are stored. False where the cell is not in one brick, or the
/// brick is coarse (`entry` then says which).
VOXFMT_HD bool brick_corners(const Field& f, const int base[3], float v[8], bool& exact, int32_t& entry);

/// brick_corners for bricks with an apron: the cell is in one brick wherever its base voxel is, unless it reaches
/// into a neighbour the apron has no codes of.
VOXFMT_HD bool apron_corners(const Field& f, const int base[3], float v[8], bool& exact, int32_t& entry) {
  // The neighbours the cell reaches (bit x | y << 1 | z << 2 of the offset): every nonzero offset within them must
  // be in the apron's mask.
  const int reach = int((base[0] & (kEdge - 1)) == kEdge - 1) | int((base[1] & (kEdge - 1)) == kEdge - 1) << 1 |
                    int((base[2] & (kEdge - 1)) == kEdge - 1) << 2;
  const bool flat = f.dims[0] < 2 || f.dims[1] < 2 || f.dims[2] < 2;
  entry = flat ? 0 : entry_of(f, base[0], base[1], base[2]);
  if (flat) return false;
  if (entry < 0) {
    // As brick_corners: a cell across bricks goes corner by corner (entry 0) even from a coarse brick.
    if (reach != 0) entry = 0;
    return false;
  }
  const int16_t* brick = &f.codes[size_t(entry) * kApronBrickCodes];
  // Byte `reach` of this word: the offsets within `reach` (its nonzero subsets), one bit each; a shift, not a table
  // (a table indexed at run time lands in a GPU thread's local memory).
  constexpr uint64_t kWithin = 0xfe5432100e040200ull;
  const int within = int((kWithin >> (8 * reach)) & 0xff);
  if ((within & ~int(uint16_t(brick[kApronMask]))) != 0) return false;
  const int local =
      ((base[2] & (kEdge - 1)) * kApronEdge + (base[1] & (kEdge - 1))) * kApronEdge + (base[0] & (kEdge - 1));
  constexpr int kRow = kApronEdge, kPlane = kApronEdge * kApronEdge;
  const int offset[8] = {0, 1, kRow, kRow + 1, kPlane, kPlane + 1, kPlane + kRow, kPlane + kRow + 1};
  int flags = 1;
  for (int corner = 0; corner < 8; ++corner) {
    const int value = brick[local + offset[corner]];
    flags &= value;
    v[corner] = float(value >> 1) * f.decode_step[value & 1];
  }
  exact = flags != 0;
  return true;
}

VOXFMT_HD bool brick_corners(const Field& f, const int base[3], float v[8], bool& exact, int32_t& entry) {
  if (f.apron) return apron_corners(f, base, v, exact, entry);
  const bool in_one_brick = (base[0] & (kEdge - 1)) < kEdge - 1 && (base[1] & (kEdge - 1)) < kEdge - 1 &&
                            (base[2] & (kEdge - 1)) < kEdge - 1 && f.dims[0] > 1 && f.dims[1] > 1 && f.dims[2] > 1;
  entry = in_one_brick ? entry_of(f, base[0], base[1], base[2]) : 0;
  if (!in_one_brick || entry < 0) return false;
  const int local = ((base[2] & (kEdge - 1)) * kEdge + (base[1] & (kEdge - 1))) * kEdge + (base[0] & (kEdge - 1));
  const int16_t* q = &f.codes[size_t(entry) * kBrickVoxels + size_t(local)];
  const int offset[8] = {
      0, 1, kEdge, kEdge + 1, kEdge * kEdge, kEdge * kEdge + 1, kEdge * kEdge + kEdge, kEdge * kEdge + kEdge + 1};
  int flags = 1;
  for (int corner = 0; corner < 8; ++corner) {
    const int value = q[offset[corner]];
    flags &= value;
    v[corner] = float(value >> 1) * f.decode_step[value & 1];
  }
  exact = flags != 0;
  return true;
}

/// The trilinear field at a point the grid covers.
VOXFMT_HD Sample sample_grid(const Field& f, const Vec3& u, Vec3* gradient) {
  Sample result;
  // The cell whose corners surround u, clamped so that all 8 corners exist.
  int base[3];
  float t[3];
  for (int a = 0; a < 3; ++a) {
    const float c = clamp_f(u[a], 0.0f, float(f.dims[a] - 1));
    base[a] = min_i(int(c), max_i(f.dims[a] - 2, 0));
    t[a] = c - float(base[a]);
  }
  bool exact = true;
  float v[8];
  int32_t entry = 0;
  if (!brick_corners(f, base, v, exact, entry)) {
    if (entry < 0) {
      result.distance = coarse_sample(f, u, entry, gradient);
      return result;
    }
    for (int corner = 0; corner < 8; ++corner) {  // across bricks: corner by corner
      const int x = min_i(base[0] + (corner & 1), f.dims[0] - 1),
                y = min_i(base[1] + ((corner >> 1) & 1), f.dims[1] - 1),
                z = min_i(base[2] + (corner >> 2), f.dims[2] - 1);
      v[corner] = voxel_value(f, x, y, z, exact);
    }
  }
  result.distance = trilinear(v, t, gradient);
  result.exact = exact;
  return result;
}

/// sample() at a point the grid covers: the trilinear field, and where that is an estimate outside the object,
/// at least the distance to the object's bounding box (a bound the estimate may fall below near the grid's
/// faces; the same bound outside the grid, so the two meet without a step).
VOXFMT_HD Sample sample_inside(const Field& f, const Vec3& u, Vec3* gradient) {
  Sample result = sample_grid(f, u, gradient);
  if (result.exact || result.distance <= 0.0f) return result;
  const float box = bounds_distance(f, u);
  if (box > result.distance) {
    result.distance = box;
    if (gradient)
      *gradient =
          u - make_vec3(clamp_f(u.x, f.object_min.x, f.object_max.x), clamp_f(u.y, f.object_min.y, f.object_max.y),
                        clamp_f(u.z, f.object_min.z, f.object_max.z));
  }
  return result;
}

/// Signed distance at grid coordinates `u`: trilinear interpolation of the 8 surrounding voxels' values (stored
/// distances, or estimates where none is stored). Outside the grid, the field continued as a lower bound: with q
/// the grid's nearest point and d the field there, sqrt(|u - q|^2 + d^2) -- the surface lies inside the grid, a
/// convex box, so its nearest point s to u satisfies |u - s|^2 >= |u - q|^2 + |q - s|^2: a lower bound wherever d
/// is one, above the exact distance by no more than d is at q -- and at least the distance to the object's
/// bounding box. It meets the field at the grid's faces (no cliff) and changes no faster than the distance
/// travelled or the field along the faces. `gradient`, if given, receives the direction of increasing distance
/// (not normalised; zero where flat).
VOXFMT_HD Sample sample(const Field& f, const Vec3& u, Vec3* gradient) {
  if (covers(f, u)) return sample_inside(f, u, gradient);
  Sample result;
  result.bound = true;
  if (!(u.x == u.x && u.y == u.y && u.z == u.z)) {  // NaN (a blown-up simulation): clamping keeps it, int() of it
    result.distance = u.x + u.y + u.z;              // is undefined; so no voxel is read, and the distance is NaN
    if (gradient) *gradient = make_vec3(0, 0, 0);
    return result;
  }
  const Vec3 q = make_vec3(clamp_f(u.x, -0.5f, f.cover_max.x), clamp_f(u.y, -0.5f, f.cover_max.y),
                           clamp_f(u.z, -0.5f, f.cover_max.z));
  Vec3 face_gradient = make_vec3(0, 0, 0);
  const float d = sample_inside(f, q, gradient ? &face_gradient : nullptr).distance;
  const Vec3 away = u - q;
  const float box = bounds_distance(f, u);
  const float continued = d > 0.0f ? hypot_f(away, d) : 0.0f;
  result.distance = max_f(box, continued);
  if (gradient) {
    if (continued >= box) {
      // d/du of the bound: the way out of the grid, plus d times the field's slope along the faces u is beyond.
      const Vec3 along = make_vec3(away.x == 0.0f ? face_gradient.x : 0.0f, away.y == 0.0f ? face_gradient.y : 0.0f,
                                   away.z == 0.0f ? face_gradient.z : 0.0f);
      *gradient = away + d * along;
    } else {
      *gradient = u - 0.5f * (f.object_min + f.object_max);
    }
  }
  return result;
}

/// Catmull-Rom weights of the four voxels around a coordinate (offsets -1, 0, 1, 2 from the voxel below it) at
/// `t` in [0, 1), and their derivatives in t. The kernel reproduces quadratics exactly: a curved surface's
/// distance, which trilinear weights overestimate on its convex side by about t (1 - t) / 2 times its curvature.
VOXFMT_HD void catmull_rom(float t, float w[4], float dw[4]) {
  const float t2 = t * t, t3 = t2 * t;
  w[0] = 0.5f * (-t3 + 2.0f * t2 - t);
  w[1] = 0.5f * (3.0f * t3 - 5.0f * t2 + 2.0f);
  w[2] = 0.5f * (-3.0f * t3 + 4.0f * t2 + t);
  w[3] = 0.5f * (t3 - t2);
  dw[0] = 0.5f * (-3.0f * t2 + 4.0f * t - 1.0f);
  dw[1] = 0.5f * (9.0f * t2 - 10.0f * t);
  dw[2] = 0.5f * (-9.0f * t2 + 8.0f * t + 1.0f);
  dw[3] = 0.5f * (3.0f * t2 - 2.0f * t);
}

/// The tricubic (Catmull-Rom) field at a point the grid covers, where the 4^3 voxels around it all lie in the grid
/// and hold stored distances (false otherwise: nothing is written). `gradient` per voxel, as trilinear's.
VOXFMT_HD bool tricubic_stored(const Field& f, const Vec3& u, float& distance, Vec3* gradient) {
  int base[3];
  float w[3][4], dw[3][4];
  for (int a = 0; a < 3; ++a) {
    const float c = u[a];
    base[a] = int(c + 1.0f) - 1;  // floor: c > -1 where the grid covers u
    if (base[a] < 1 || base[a] + 2 > f.dims[a] - 1) return false;
    catmull_rom(c - float(base[a]), w[a], dw[a]);
  }
  // Along x for each of the 16 rows, then along y for each of the 4 planes, then along z.
  float row[16], row_dx[16];
  for (int r = 0; r < 16; ++r) {
    const int j = base[1] - 1 + (r & 3), k = base[2] - 1 + (r >> 2);
    float sum = 0.0f, sum_dx = 0.0f;
    for (int i = 0; i < 4; ++i) {
      bool exact = true;
      const float v = voxel_value(f, base[0] - 1 + i, j, k, exact);
      if (!exact) return false;
      sum += w[0][i] * v;
      sum_dx += dw[0][i] * v;
    }
    row[r] = sum;
    row_dx[r] = sum_dx;
  }
  float value = 0.0f, gx = 0.0f, gy = 0.0f, gz = 0.0f;
  for (int k = 0; k < 4; ++k) {
    float plane = 0.0f, plane_dx = 0.0f, plane_dy = 0.0f;
    for (int j = 0; j < 4; ++j) {
      plane += w[1][j] * row[k * 4 + j];
      plane_dx += w[1][j] * row_dx[k * 4 + j];
      plane_dy += dw[1][j] * row[k * 4 + j];
    }
    value += w[2][k] * plane;
    gx += w[2][k] * plane_dx;
    gy += w[2][k] * plane_dy;
    gz += dw[2][k] * plane;
  }
  distance = value;
  if (gradient) *gradient = make_vec3(gx, gy, gz);
  return true;
}

/// sample() read tricubically where it can be (tricubic_stored: near the surface; the stencil reaches up to 2
/// voxels along each axis, 3.5 diagonally, so with a band of 3 nearly every point on the surface, three in four half
/// a voxel deep and one in four a voxel deep), else as sample() reads it. Exact distances at voxel centres interpolated
/// by a cubic follow a curved surface's distance far closer than trilinearly: a bunny's shallow contact forces within 2
/// % of the exact model's in every step, against 89 % of steps (bench/force_quality.py). Costs 64 voxel reads a sample.
VOXFMT_HD Sample sample_tricubic(const Field& f, const Vec3& u, Vec3* gradient) {
  Sample result;
  if (covers(f, u) && tricubic_stored(f, u, result.distance, gradient)) {
    result.exact = true;
    return result;
  }
  return sample(f, u, gradient);
}

/// The voxel nearest `u`, a point that covers() (every coordinate above -1/2, so truncation rounds).
VOXFMT_HD void nearest_voxel(const Vec3& u, int v[3]) {
  v[0] = int(u.x + 0.5f), v[1] = int(u.y + 0.5f), v[2] = int(u.z + 0.5f);
}

/// What lattice value `l` (voxels, as the runtime holds it) says of its lattice point: the surface is at least
/// this far (spec §3.3: l >= u >= (l - e0) / (1 + e1) before the runtime's rounding to half a step, less a
/// margin for this float arithmetic).
VOXFMT_HD float lattice_point_bound(const Field& f, float l) {
  return (l - 0.5f * f.lattice_step - f.estimate_offset) * f.estimate_shrink - (1e-3f + 1e-6f * l);
}

/// A lower bound at `u`, outside the object, from the 8 lattice points of lattice cell `lower` (cell_of), whose
/// values are `p` (cell_values): the best of each point's own bound less u's distance to it. Near a lattice point
/// this is far tighter than the interpolated estimate, which must allow for interpolation anywhere in the cell
/// (4 sqrt(3) voxels).
VOXFMT_HD float lattice_corners_bound(const Field& f, const Vec3& u, const int lower[3], const float p[8]) {
  float x0[3], x1[3];
  for (int a = 0; a < 3; ++a) {
    x0[a] = float(lower[a] * kEdge);
    x1[a] = float(lattice_coordinate(f, lower[a] + 1, a));
  }
  float best = -__builtin_huge_valf();
  for (int c = 0; c < 8; ++c) {
    const Vec3 corner = make_vec3(c & 1 ? x1[0] : x0[0], c & 2 ? x1[1] : x0[1], c & 4 ? x1[2] : x0[2]);
    best = max_f(best, lattice_point_bound(f, p[c] * f.lattice_step) - length(u - corner));
  }
  return best;
}

/// lower_bound at a covered `u` from its nearest voxel `v`, whose brick table entry is `entry`.
VOXFMT_HD float nearest_voxel_bound(const Field& f, const Vec3& u, const int v[3], int32_t entry) {
  // A coarse voxel's value and the lattice-point bounds read the same cell: once.
  int lower[3];
  cell_of(v[0], v[1], v[2], lower);
  float p[8];
  bool stored = entry >= 0;
  float value;
  if (stored) {
    value = entry_value(f, v[0], v[1], v[2], entry, stored);
  } else {
    cell_values(f, lower, p);
    value = coarse_value_in(f, v[0], v[1], v[2], entry, p);
  }
  // The distance is 1-Lipschitz: u is no nearer the surface than the voxel's bound less u's offset from it.
  const float offset = length(u - make_vec3(float(v[0]), float(v[1]), float(v[2])));
  const float bound = value_lower_bound(f, value, stored, entry < 0) - offset;
  // A voxel without a stored distance is at least the band's edge from the surface: where its value says outside
  // and u is nearer to it than that, u is outside too, and the lattice points of the voxel's cell bound u's
  // distance directly.
  if (stored || !(value > 0 && offset < f.band_edge)) return bound;
  if (entry >= 0) cell_values(f, lower, p);
  return max_f(bound, lattice_corners_bound(f, u, lower, p));
}

/// A value the true signed distance at `u` is not below (voxel units): what prunes sphere-tree clusters.
VOXFMT_HD_OUTLINE float lower_bound(const Field& f, const Vec3& u) {
  // Outside the grid the object is at least as far as its bounding box; inside, the nearest voxel says more.
  if (!covers(f, u)) return bounds_distance(f, u);
  int v[3];
  nearest_voxel(u, v);
  return nearest_voxel_bound(f, u, v, entry_of(f, v[0], v[1], v[2]));
}

#if !defined(__CUDACC__)
/// lower_bound at the n `points`, the same values, for the CPU (the scalar kernel of field_simd.h). In batches of 64:
/// first every point's brick table entry is fetched, then every value brick's code, then the bounds are computed. A
/// lookup is two dependent cache misses (the table, then the codes); this way the misses of a batch overlap
/// instead of queueing one by one.
inline void lower_bounds(const Field& f, const Vec3* points, size_t n, float* out) {
  constexpr size_t kBatch = 64;
  int v[kBatch][3];
  int32_t entry[kBatch];
  bool covered[kBatch];
  for (size_t begin = 0; begin < n; begin += kBatch) {
    const size_t count = n - begin < kBatch ? n - begin : kBatch;
    const Vec3* u = points + begin;
    for (size_t p = 0; p < count; ++p) {
      covered[p] = covers(f, u[p]);
      if (!covered[p]) continue;
      nearest_voxel(u[p], v[p]);
      __builtin_prefetch(table_slot(f, v[p][0], v[p][1], v[p][2]));
    }
    for (size_t p = 0; p < count; ++p) {
      if (!covered[p]) continue;
      entry[p] = entry_of(f, v[p][0], v[p][1], v[p][2]);
      if (entry[p] >= 0) __builtin_prefetch(code_of(f, v[p][0], v[p][1], v[p][2], entry[p]));
    }
    for (size_t p = 0; p < count; ++p)
      out[begin + p] = covered[p] ? nearest_voxel_bound(f, u[p], v[p], entry[p]) : bounds_distance(f, u[p]);
  }
}
#endif

}  // namespace voxfmt::runtime::core

#if !defined(__CUDACC__)
#include <vector>

namespace voxfmt::runtime {
class SparseVoxelmap;
/// The core's view of a runtime voxelmap (sparse_voxelmap.cpp): pointers into it, valid while it lives.
core::Field field_of(const SparseVoxelmap& map);
namespace core {
/// `field`'s value bricks with an apron (kApronBrickCodes codes each, in the brick table's order): for a Field
/// whose `codes` point there and whose `apron` is set, every lookup gives the same values, bit for bit.
std::vector<int16_t> apron_codes(const Field& field, size_t value_bricks);
}  // namespace core
}  // namespace voxfmt::runtime
#endif
