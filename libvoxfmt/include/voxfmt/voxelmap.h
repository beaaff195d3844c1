// The layered distance-field voxelmap of an asset (spec §3), held as the file stores it and the runtime reads
// it: 8x8x8 bricks. Bricks near the surface ("value bricks") keep a 16-bit code per voxel; every other brick is
// one entry of the brick table, its voxels estimated from a coarse lattice of unsigned distances at the brick
// corners. Memory grows with the surface, not the volume. Read it through the accessors (voxel(), layer(),
// read_block()); nothing outside libvoxfmt and the runtime needs to know the codes.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <vector>

namespace voxfmt {

using Vec3 = std::array<double, 3>;
using Vec3f = std::array<float, 3>;

/// What one voxel holds.
struct VoxelValue {
  double distance = 0.0;  ///< signed distance at the voxel centre (m, negative inside): stored, or the estimate
  bool stored = false;    ///< true: a stored band distance (exact within distance_quantum / 2)
};

struct Voxelmap {
  static constexpr uint32_t kBrickEdge = 8;
  static constexpr uint32_t kBrickVoxels = kBrickEdge * kBrickEdge * kBrickEdge;
  /// Brick table entries of bricks without per-voxel codes (spec §3.2).
  static constexpr int32_t kCoarseOutside = -1, kCoarseInside = -2;
  /// Largest |code >> 1| of a value-brick code: 15 bits of magnitude.
  static constexpr int kMaxSteps = 16383;

  // ---- geometry (as in format 1.x)
  Vec3 origin{};                   ///< centre of voxel (0,0,0), metres
  double voxel_size = 0.0;         ///< voxel edge h, metres
  std::array<uint32_t, 3> dims{};  ///< W, H, D (voxels along x, y, z)
  double distance_band = 3.0;      ///< half-width of the stored-distance band, in voxels
  std::optional<uint32_t> margin;  ///< outer voxels around the bounding box (optional in the file)
  /// Shell mode (format 1.1): the object is the solid shell of this thickness (metres) around the surface, its
  /// signed distance the unsigned distance to the surface minus half of it. Absent: the surface's inside.
  std::optional<double> shell_thickness;

  // ---- encoding (format 2.0)
  double distance_quantum = 0.0;  ///< metres per step of a stored distance (odd codes)
  double estimate_quantum = 0.0;  ///< metres per step of an estimate (even codes)
  /// How far a lattice value may exceed the exact unsigned distance u (it is never below it): at most
  /// lattice_error[0] voxels + lattice_error[1] x u.
  std::array<double, 2> lattice_error{0.0, 0.0};
  /// Brick table, [BD][BH][BW] (x fastest): >= 0 the index of a value brick, else kCoarseOutside/kCoarseInside.
  std::vector<int32_t> bricks;
  /// Value bricks, kBrickVoxels codes each (x fastest within the brick). Odd code c: a stored distance
  /// (c >> 1) * distance_quantum; even code: the estimate (c >> 1) * estimate_quantum of a voxel without one.
  std::vector<int16_t> brick_values;
  /// Unsigned distance (metres) at the lattice points, [BD+1][BH+1][BW+1]; lattice point (a, b, c) is voxel
  /// (min(8a, W-1), min(8b, H-1), min(8c, D-1)).
  std::vector<float> lattice;
  /// The rule the value bricks' estimates follow (spec §3.1): the lattice interpolated at the voxel (formats 2.0 and
  /// 2.1), or settled (2.2): the least of the lattice's paths and the neighbours' values plus their step. A writer
  /// writes the format version of its rule.
  enum class Estimates : uint8_t { Interpolated, Settled };
  Estimates estimates = Estimates::Settled;

  // ---- sizes and positions
  std::array<uint32_t, 3> brick_dims() const {
    return {(dims[0] + kBrickEdge - 1) / kBrickEdge, (dims[1] + kBrickEdge - 1) / kBrickEdge,
            (dims[2] + kBrickEdge - 1) / kBrickEdge};
  }
  std::array<uint32_t, 3> lattice_dims() const {
    const auto b = brick_dims();
    return {b[0] + 1, b[1] + 1, b[2] + 1};
  }
  uint64_t voxel_count() const { return uint64_t(dims[0]) * dims[1] * dims[2]; }
  size_t brick_count() const {
    const auto b = brick_dims();
    return size_t(b[0]) * b[1] * b[2];
  }
  size_t lattice_count() const {
    const auto l = lattice_dims();
    return size_t(l[0]) * l[1] * l[2];
  }
  size_t value_brick_count() const { return brick_values.size() / kBrickVoxels; }
  size_t brick_index(uint32_t bi, uint32_t bj, uint32_t bk) const {
    const auto b = brick_dims();
    return (size_t(bk) * b[1] + bj) * b[0] + bi;
  }
  size_t lattice_index(uint32_t a, uint32_t b, uint32_t c) const {
    const auto l = lattice_dims();
    return (size_t(c) * l[1] + b) * l[0] + a;
  }
  /// Voxel coordinate of lattice point `a` along an axis of `n` voxels.
  static uint32_t lattice_coordinate(uint32_t a, uint32_t n) { return std::min(a * kBrickEdge, n - 1); }
  static uint32_t local_index(uint32_t li, uint32_t lj, uint32_t lk) {
    return (lk * kBrickEdge + lj) * kBrickEdge + li;
  }
  Vec3 voxel_center(uint32_t i, uint32_t j, uint32_t k) const {
    return {origin[0] + voxel_size * i, origin[1] + voxel_size * j, origin[2] + voxel_size * k};
  }
  /// Centre of lattice point (a, b, c)'s voxel (spec §3.3), metres.
  Vec3 lattice_point_center(uint32_t a, uint32_t b, uint32_t c) const {
    return voxel_center(lattice_coordinate(a, dims[0]), lattice_coordinate(b, dims[1]), lattice_coordinate(c, dims[2]));
  }

  // ---- codes
  static bool code_is_stored(int16_t code) { return (code & 1) != 0; }
  double decode(int16_t code) const {
    return double(code >> 1) * (code_is_stored(code) ? distance_quantum : estimate_quantum);
  }
  /// Code of a stored distance (metres), the nearest step.
  int16_t encode_stored(double distance) const;
  /// Code of an estimate (metres) of a voxel without a stored distance, the nearest step (never 0: the sign
  /// is kept).
  int16_t encode_estimate(double distance) const;

  // ---- reading voxels (i, j, k inside the grid)
  VoxelValue voxel(uint32_t i, uint32_t j, uint32_t k) const;
  /// floor(-d/h + 1/2) of the voxel's distance d (stored or estimate), clamped to [-32767, 32767].
  int layer(uint32_t i, uint32_t j, uint32_t k) const;
  /// The coarse estimate's magnitude (metres): the lattice interpolated trilinearly at the voxel, at least
  /// (distance_band - 1/2) h. Its sign is the voxel's (brick table or code).
  double coarse_magnitude(uint32_t i, uint32_t j, uint32_t k) const;
  /// Voxels: how far the interpolated lattice may be from the exact unsigned distance at the voxel, besides the
  /// lattice's own error: sum over the 8 lattice corners of weight x distance (at most 4 sqrt(3)).
  double interpolation_bound(uint32_t i, uint32_t j, uint32_t k) const;
  /// The block of voxels [first, first + size) in x-fastest order: distances (metres, NaN where none is stored)
  /// and layers. Either output may be null.
  void read_block(const std::array<uint32_t, 3>& first, const std::array<uint32_t, 3>& size, float* distances,
                  int16_t* layers) const;
  /// Number of voxels with a stored distance.
  size_t stored_count() const;
  /// Lowest and highest layer of any voxel (from the value bricks and the lattice).
  std::pair<int, int> layer_range() const;
  /// Bytes the arrays hold.
  size_t memory_bytes() const {
    return bricks.size() * sizeof(int32_t) + brick_values.size() * sizeof(int16_t) + lattice.size() * sizeof(float);
  }
  /// Visits the value bricks in table order: f(bi, bj, bk, const int16_t* codes).
  template <class F>
  void for_each_value_brick(F&& f) const {
    const auto b = brick_dims();
    size_t n = 0;
    for (uint32_t bk = 0; bk < b[2]; ++bk)
      for (uint32_t bj = 0; bj < b[1]; ++bj)
        for (uint32_t bi = 0; bi < b[0]; ++bi, ++n)
          if (bricks[n] >= 0 && size_t(bricks[n]) < value_brick_count())
            f(bi, bj, bk, brick_values.data() + size_t(bricks[n]) * kBrickVoxels);
  }
  /// Quantum steps a producer uses: distance_band h spread over 15 bits, and h/16 for estimates.
  void choose_quanta() {
    distance_quantum = distance_band * voxel_size / kMaxSteps;
    estimate_quantum = voxel_size / 16.0;
  }
};

/// A signed distance function of a point in the asset frame (metres, negative inside).
using SignedDistanceFunction = std::function<double(const Vec3&)>;

/// Authoring: fills the bricks and the lattice of `geometry` (origin, voxel size, dims, band, margin, shell
/// thickness set; arrays empty) from an exact signed distance function, evaluated at every voxel and lattice
/// point. For small grids made in code (analytic test shapes, examples); the bake builds large ones sparsely.
Voxelmap make_voxelmap(const Voxelmap& geometry, const SignedDistanceFunction& signed_distance);

/// Fills the estimate codes of every voxel of the value bricks that has no stored distance, settled (spec §3.1,
/// 2.2), keeping each code's sign, on `threads` threads (0: the usable cores), and sets vm.estimates. The brick
/// table, the stored codes and the lattice must be complete.
void fill_estimates(Voxelmap& vm, unsigned threads = 0);
/// Format 2.1's estimates: the lattice interpolated at every value-brick voxel without a stored distance, keeping
/// each code's sign; sets vm.estimates (what a 1.x file reads as, spec §3.4).
void fill_interpolated_estimates(Voxelmap& vm);
/// The same for one value brick (bi, bj, bk) whose codes are `codes`.
void fill_brick_estimates(const Voxelmap& vm, uint32_t bi, uint32_t bj, uint32_t bk, int16_t* codes);
/// The interpolated estimate magnitudes (metres, before rounding to a step; format 2.1) of the voxels of brick
/// (bi, bj, bk), x fastest, kBrickVoxels of them (positions past the grid: 0).
void brick_estimate_magnitudes(const Voxelmap& vm, uint32_t bi, uint32_t bj, uint32_t bk, double* magnitudes);

}  // namespace voxfmt
