// The chamfer transform of value-brick estimates (voxfmt/detail/estimate_transform.h) against a plain relaxation
// written here from its rule, on an exact sphere: the same codes, whatever the threads; every estimate an upper
// bound of the exact distance; a damaged estimate found.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "voxfmt/detail/estimate_transform.h"

namespace voxfmt {
namespace {

constexpr double kRadius = 0.25, kVoxel = 0.01;

Voxelmap sphere_voxelmap() {
  Voxelmap grid;
  grid.voxel_size = kVoxel;
  grid.distance_band = 3.0;
  grid.margin = 4;
  const uint32_t n = 59;  // not a multiple of 8: the last bricks reach past the grid
  grid.dims = {n, n, n};
  const double half = 0.5 * (n - 1) * kVoxel;
  grid.origin = {-half, -half, -half};
  return make_voxelmap(grid, [](const Vec3& p) { return std::hypot(p[0], p[1], p[2]) - kRadius; });
}

double exact(const Voxelmap& vm, uint32_t i, uint32_t j, uint32_t k) {
  const Vec3 p = vm.voxel_center(i, j, k);
  return std::hypot(p[0], p[1], p[2]) - kRadius;
}

/// The rule, relaxed plainly over a dense grid: each estimate starts at its seed (the least over its cell's lattice
/// points of ceil(l / q) plus the path to it) and takes the least of its value-brick neighbours' magnitudes plus the
/// step until nothing changes; stored distances are ceil(|d| / q) and fixed. Codes in vm.brick_values' layout.
std::vector<int16_t> relaxed_plainly(const Voxelmap& vm) {
  const int n[3] = {int(vm.dims[0]), int(vm.dims[1]), int(vm.dims[2])};
  const double per_voxel = vm.voxel_size / vm.estimate_quantum;
  int step[4];
  for (int a = 0; a < 4; ++a) step[a] = int(std::ceil(std::sqrt(double(a)) * per_voxel - 1e-9));
  auto path = [&](int a, int b, int c) {
    std::array<int, 3> s = {std::abs(a), std::abs(b), std::abs(c)};
    std::sort(s.begin(), s.end());
    return s[0] * step[3] + (s[1] - s[0]) * step[2] + (s[2] - s[1]) * step[1];
  };
  auto at = [&](int i, int j, int k) { return (size_t(k) * size_t(n[1]) + size_t(j)) * size_t(n[0]) + size_t(i); };
  std::vector<int> value(size_t(n[0]) * size_t(n[1]) * size_t(n[2]), -1);  // -1: not in a value brick
  std::vector<char> fixed(value.size(), 0);
  auto code_at = [&](int i, int j, int k) -> const int16_t* {
    const int32_t e = vm.bricks[vm.brick_index(uint32_t(i / 8), uint32_t(j / 8), uint32_t(k / 8))];
    if (e < 0) return nullptr;
    return &vm.brick_values[size_t(e) * 512 + size_t(((k % 8) * 8 + j % 8) * 8 + i % 8)];
  };
  for (int k = 0; k < n[2]; ++k)
    for (int j = 0; j < n[1]; ++j)
      for (int i = 0; i < n[0]; ++i) {
        const int16_t* code = code_at(i, j, k);
        if (!code) continue;
        if (Voxelmap::code_is_stored(*code)) {
          const double steps = std::abs(*code >> 1) * vm.distance_quantum / vm.estimate_quantum;
          value[at(i, j, k)] = std::min(Voxelmap::kMaxSteps, int(std::ceil(steps - 1e-9)));
          fixed[at(i, j, k)] = 1;
          continue;
        }
        int seed = Voxelmap::kMaxSteps;
        for (int q = 0; q < 8; ++q) {
          const uint32_t a = uint32_t(i / 8 + (q & 1)), b = uint32_t(j / 8 + (q >> 1 & 1)),
                         c = uint32_t(k / 8 + (q >> 2));
          const int l = std::min(Voxelmap::kMaxSteps,
                                 int(std::ceil(vm.lattice[vm.lattice_index(a, b, c)] / vm.estimate_quantum - 1e-9)));
          seed = std::min(seed, l + path(int(Voxelmap::lattice_coordinate(a, vm.dims[0])) - i,
                                         int(Voxelmap::lattice_coordinate(b, vm.dims[1])) - j,
                                         int(Voxelmap::lattice_coordinate(c, vm.dims[2])) - k));
        }
        value[at(i, j, k)] = seed;
      }
  for (bool changed = true; changed;) {
    changed = false;
    for (int k = 0; k < n[2]; ++k)
      for (int j = 0; j < n[1]; ++j)
        for (int i = 0; i < n[0]; ++i) {
          int& v = value[at(i, j, k)];
          if (v < 0 || fixed[at(i, j, k)]) continue;
          for (int dk = -1; dk <= 1; ++dk)
            for (int dj = -1; dj <= 1; ++dj)
              for (int di = -1; di <= 1; ++di) {
                const int a = i + di, b = j + dj, c = k + dk;
                if (a < 0 || b < 0 || c < 0 || a >= n[0] || b >= n[1] || c >= n[2]) continue;
                const int w = value[at(a, b, c)];
                const int via = w + step[(di != 0) + (dj != 0) + (dk != 0)];
                if (w >= 0 && via < v) v = via, changed = true;
              }
        }
  }
  std::vector<int16_t> codes = vm.brick_values;
  for (int k = 0; k < n[2]; ++k)
    for (int j = 0; j < n[1]; ++j)
      for (int i = 0; i < n[0]; ++i) {
        const int16_t* code = code_at(i, j, k);
        if (!code || Voxelmap::code_is_stored(*code)) continue;
        int16_t& out = codes[size_t(code - vm.brick_values.data())];
        out = int16_t((*code < 0 ? -2 : 2) * value[at(i, j, k)]);
      }
  return codes;
}

std::vector<int16_t> transformed(const Voxelmap& vm, unsigned threads) {
  std::vector<int16_t> codes = vm.brick_values;
  detail::EstimateTransform transform(vm, codes);
  transform.seed(threads);
  const auto rounds = transform.settle(threads);
  EXPECT_FALSE(rounds.empty());
  EXPECT_EQ(transform.count_unsettled(threads), 0u);
  return codes;
}

TEST(EstimateTransform, EqualsAPlainRelaxationOfItsRuleOnEveryThreadCount) {
  const Voxelmap vm = sphere_voxelmap();
  ASSERT_GT(vm.value_brick_count(), 100u);
  const std::vector<int16_t> expected = relaxed_plainly(vm);
  const std::vector<int16_t> one = transformed(vm, 1);
  EXPECT_TRUE(one == expected);
  EXPECT_TRUE(transformed(vm, 2) == one);
  EXPECT_TRUE(transformed(vm, 3) == one);
  EXPECT_TRUE(one == vm.brick_values);  // make_voxelmap settles its estimates (format 2.2)
  // The transform does something: 2.1's interpolated estimates are not the least paths.
  Voxelmap interpolated = vm;
  fill_interpolated_estimates(interpolated);
  size_t changed = 0;
  for (size_t v = 0; v < one.size(); ++v) changed += one[v] != interpolated.brick_values[v];
  EXPECT_GT(changed, 1000u);
}

TEST(EstimateTransform, KeepsStoredCodesAndSignsAndBoundsTheExactDistanceFromAbove) {
  const Voxelmap vm = sphere_voxelmap();
  const std::vector<int16_t> codes = transformed(vm, 2);
  size_t estimates = 0;
  double worst_over = 0;  // voxels
  for (size_t n = 0; n < vm.bricks.size(); ++n) {
    if (vm.bricks[n] < 0) continue;
    const auto [bi, bj, bk] = detail::brick_coordinates(vm, n);
    for (uint32_t l = 0; l < Voxelmap::kBrickVoxels; ++l) {
      const uint32_t i = uint32_t(bi) * 8 + l % 8, j = uint32_t(bj) * 8 + l / 8 % 8, k = uint32_t(bk) * 8 + l / 64;
      if (i >= vm.dims[0] || j >= vm.dims[1] || k >= vm.dims[2]) continue;
      const size_t at = size_t(vm.bricks[n]) * Voxelmap::kBrickVoxels + l;
      const int16_t before = vm.brick_values[at], after = codes[at];
      if (Voxelmap::code_is_stored(before)) {
        EXPECT_EQ(after, before);
        continue;
      }
      ++estimates;
      ASSERT_FALSE(Voxelmap::code_is_stored(after));
      EXPECT_EQ(after < 0, before < 0);
      const double d = std::abs(exact(vm, i, j, k)), magnitude = std::abs(vm.decode(after));
      EXPECT_GE(magnitude, d - vm.distance_quantum) << i << " " << j << " " << k;
      worst_over = std::max(worst_over, (magnitude - d) / vm.voxel_size);
    }
  }
  EXPECT_GT(estimates, 10000u);
  // A path of voxel steps is at most 8 % longer than the straight line, and the seed's lattice point is within a
  // brick: on a 25-voxel sphere, well within 3 voxels.
  EXPECT_LT(worst_over, 3.0);
}

TEST(EstimateTransform, FindsADamagedEstimateInItsBrick) {
  const Voxelmap vm = sphere_voxelmap();
  std::vector<int16_t> codes = transformed(vm, 1);
  detail::EstimateTransform check(vm, codes);
  // The first estimate of the first value brick holding one, raised or lowered by a step.
  for (const int delta : {+2, -2}) {
    for (size_t n = 0; n < vm.bricks.size(); ++n) {
      if (vm.bricks[n] < 0) continue;
      const size_t first = size_t(vm.bricks[n]) * Voxelmap::kBrickVoxels;
      size_t l = 0;
      while (l < Voxelmap::kBrickVoxels &&
             (Voxelmap::code_is_stored(codes[first + l]) || codes[first + l] == 0 || std::abs(codes[first + l]) < 8))
        ++l;
      if (l == Voxelmap::kBrickVoxels) continue;
      int16_t& code = codes[first + l];
      const int16_t kept = code;
      code = int16_t(code + (code < 0 ? -delta : delta));
      const auto [bi, bj, bk] = detail::brick_coordinates(vm, n);
      EXPECT_GE(check.count_unsettled(bi, bj, bk), 1u) << delta;
      EXPECT_GE(check.count_unsettled(2), 1u) << delta;
      code = kept;
      EXPECT_EQ(check.count_unsettled(bi, bj, bk), 0u);
      break;
    }
  }
}

}  // namespace
}  // namespace voxfmt
