#include "voxfmt/detail/estimate_transform.h"

#include <cmath>
#include <cstring>
#include <stdexcept>

namespace voxfmt::detail {

// ---- BrickRounds

BrickRounds::BrickRounds(const Voxelmap& vm)
    : vm_(vm), pending_(std::make_unique<std::atomic<uint8_t>[]>(vm.value_brick_count())) {
  const auto b = vm.brick_dims();
  for (int a = 0; a < 3; ++a) bricks_[a] = int(b[size_t(a)]);
  for (size_t e = 0; e < vm.value_brick_count(); ++e) pending_[e].store(1, std::memory_order_relaxed);
}

bool BrickRounds::awake_neighbours(int bi, int bj, int bk, int32_t (&neighbour)[3][3][3]) const {
  bool any = false;
  for (int dk = -1; dk <= 1; ++dk)
    for (int dj = -1; dj <= 1; ++dj)
      for (int di = -1; di <= 1; ++di) {
        int32_t& n = neighbour[dk + 1][dj + 1][di + 1];
        const int i = bi + di, j = bj + dj, k = bk + dk;
        n = -1;
        if ((di | dj | dk) == 0 || i < 0 || j < 0 || k < 0 || i >= bricks_[0] || j >= bricks_[1] || k >= bricks_[2])
          continue;
        n = vm_.bricks[vm_.brick_index(uint32_t(i), uint32_t(j), uint32_t(k))];
        if (n >= 0 && pending_[size_t(n)].load(std::memory_order_relaxed)) n = -1;
        any |= n >= 0;
      }
  return any;
}

std::vector<std::pair<int, int>> BrickRounds::balanced_slabs(unsigned threads) const {
  const int layers = bricks_[2];
  threads = std::max(1u, std::min<unsigned>(threads, unsigned(layers / 3)));
  std::vector<size_t> below(size_t(layers) + 1, 0);  // value bricks in the layers below each
  for (int bk = 0; bk < layers; ++bk) {
    size_t here = 0;
    for (int bj = 0; bj < bricks_[1]; ++bj)
      for (int bi = 0; bi < bricks_[0]; ++bi)
        here += vm_.bricks[vm_.brick_index(uint32_t(bi), uint32_t(bj), uint32_t(bk))] >= 0;
    below[size_t(bk) + 1] = below[size_t(bk)] + here;
  }
  std::vector<std::pair<int, int>> slabs;
  int lo = 0;
  for (unsigned t = 0; t + 1 < threads; ++t) {
    const size_t target = below[size_t(layers)] * (t + 1) / threads;
    int hi = lo + 3;
    while (hi < layers - 3 * int(threads - 1 - t) && below[size_t(hi)] < target) ++hi;
    slabs.push_back({lo, hi});
    lo = hi;
  }
  slabs.push_back({lo, layers});
  return slabs;
}

// ---- EstimateTransform

EstimateTransform::EstimateTransform(const Voxelmap& vm, std::vector<int16_t>& codes)
    : EstimateTransform(vm, static_cast<const std::vector<int16_t>&>(codes)) {
  writable_ = &codes;
}

EstimateTransform::EstimateTransform(const Voxelmap& vm, const std::vector<int16_t>& codes)
    : vm_(vm), codes_(codes), writable_(nullptr), rounds_(vm) {
  const auto b = vm.brick_dims();
  for (int a = 0; a < 3; ++a) bricks_[a] = int(b[size_t(a)]), dims_[a] = int(vm.dims[size_t(a)]);
  const double per_voxel = vm.voxel_size / vm.estimate_quantum;
  for (int k = 0; k < 4; ++k) axis_step_[k] = int(std::ceil(std::sqrt(double(k)) * per_voxel - 1e-9));
  for (int dk = -1; dk <= 1; ++dk)
    for (int dj = -1; dj <= 1; ++dj)
      for (int dx = -1; dx <= 1; ++dx)
        step_[dk + 1][dj + 1][dx + 1] = int16_t(axis_step_[(dx != 0) + (dj != 0) + (dk != 0)]);
  stored_.resize(Voxelmap::kMaxSteps + 2);
  for (int x = 0; x <= Voxelmap::kMaxSteps + 1; ++x)
    stored_[size_t(x)] =
        int16_t(std::min<double>(Voxelmap::kMaxSteps, std::ceil(x * vm.distance_quantum / vm.estimate_quantum - 1e-9)));
  reversed_.resize(17 * 17 * 17);
  for (int z = 0; z < 17; ++z)
    for (int y = 0; y < 17; ++y)
      for (int x = 0; x < 17; ++x)
        reversed_[size_t((z * 17 + y) * 17 + 16 - x)] =
            int16_t(std::min(path_steps(x - 8, y - 8, z - 8), int(Voxelmap::kMaxSteps)));
}

void EstimateTransform::seed(unsigned threads) {
  if (!writable_) throw std::logic_error("EstimateTransform: seed() on codes given read-only");
  for_each_value_brick_shared(vm_, threads, [&](size_t b) { seed_brick(b); });
}

std::vector<BrickRound> EstimateTransform::settle(unsigned threads) {
  if (!writable_) throw std::logic_error("EstimateTransform: settle() on codes given read-only");
  return rounds_.run(threads, [this](size_t e, int bi, int bj, int bk) { return visit(e, bi, bj, bk); });
}

size_t EstimateTransform::count_unsettled(unsigned threads) const {
  std::atomic<size_t> wrong{0};
  for_each_value_brick_shared(vm_, threads, [&](size_t b) {
    const auto [bi, bj, bk] = brick_coordinates(vm_, b);
    wrong += count_unsettled(bi, bj, bk);
  });
  return wrong;
}

size_t EstimateTransform::count_unsettled(int bi, int bj, int bk) const {
  Block block;
  fill(bi, bj, bk, block);
  int16_t seeds[kEdge][kEdge][kEdge];
  seed_values(bi, bj, bk, seeds);
  size_t wrong = 0;
  for (int z = 1; z <= kEdge; ++z)
    for (int y = 1; y <= kEdge; ++y) {
      const int16_t* from[26];
      int16_t steps[26];
      int r = 0;
      for (int dk = -1; dk <= 1; ++dk)
        for (int dj = -1; dj <= 1; ++dj)
          for (int dx = -1; dx <= 1; ++dx)
            if ((dx | dj | dk) != 0)
              from[r] = &block.v[z + dk][y + dj][1 + dx], steps[r++] = step_[dk + 1][dj + 1][dx + 1];
      int16_t best[kEdge];
      least_of_rows(seeds[z - 1][y - 1], from, steps, best, 26);
      for (int x = 0; x < kEdge; ++x) wrong += !block.fixed[z - 1][y - 1][x] && best[x] != block.v[z][y][x + 1];
    }
  return wrong;
}

/// The length, in steps of q, of the shortest path of voxel steps along (a, b, c).
int EstimateTransform::path_steps(int a, int b, int c) const {
  std::array<int, 3> s = {std::abs(a), std::abs(b), std::abs(c)};
  std::sort(s.begin(), s.end());
  return s[0] * axis_step_[3] + (s[1] - s[0]) * axis_step_[2] + (s[2] - s[1]) * axis_step_[1];
}

inline int16_t EstimateTransform::magnitude(int16_t code) const {
  const int m = std::abs(code >> 1);
  const int16_t as_stored = stored_[size_t(m)];  // loaded either way: a select, not a branch
  return Voxelmap::code_is_stored(code) ? as_stored : int16_t(m);
}

/// The seeds of brick (bi, bj, bk)'s voxels: the least over the cell's lattice points p of ceil(l_p / q) plus the
/// path to p, at most kMaxSteps.
void EstimateTransform::seed_values(int bi, int bj, int bk, int16_t (&seeds)[kEdge][kEdge][kEdge]) const {
  int cx[2], cy[2], cz[2];
  int16_t corner[8];
  for (int q = 0; q < 2; ++q) {
    cx[q] = int(Voxelmap::lattice_coordinate(uint32_t(bi + q), vm_.dims[0]));
    cy[q] = int(Voxelmap::lattice_coordinate(uint32_t(bj + q), vm_.dims[1]));
    cz[q] = int(Voxelmap::lattice_coordinate(uint32_t(bk + q), vm_.dims[2]));
  }
  for (int q = 0; q < 8; ++q) {
    const double l =
        vm_.lattice[vm_.lattice_index(uint32_t(bi + (q & 1)), uint32_t(bj + (q >> 1 & 1)), uint32_t(bk + (q >> 2)))];
    corner[q] =
        int16_t(std::max(0.0, std::min<double>(Voxelmap::kMaxSteps, std::ceil(l / vm_.estimate_quantum - 1e-9))));
  }
  int16_t far[kEdge];
  std::fill(far, far + kEdge, int16_t(Voxelmap::kMaxSteps));
  for (int lk = 0; lk < kEdge; ++lk)
    for (int lj = 0; lj < kEdge; ++lj) {
      const int j = bj * kEdge + lj, k = bk * kEdge + lk;
      // 16-bit sums (both terms at most kMaxSteps, then capped): SSE2's minimum of 16-bit lanes.
      const int16_t* lengths[8];
      for (int q = 0; q < 8; ++q)
        lengths[q] = &reversed_[size_t(((cz[q >> 2] - k + 8) * 17 + cy[q >> 1 & 1] - j + 8) * 17 + 8 -
                                       (cx[q & 1] - bi * kEdge))];
      least_of_rows(far, lengths, corner, seeds[lk][lj], 8);
    }
}

void EstimateTransform::seed_brick(size_t b) {
  const auto [bi, bj, bk] = brick_coordinates(vm_, b);
  int16_t seeds[kEdge][kEdge][kEdge];
  seed_values(bi, bj, bk, seeds);
  int16_t* codes = &(*writable_)[size_t(vm_.bricks[b]) * Voxelmap::kBrickVoxels];
  for (int l = 0; l < int(Voxelmap::kBrickVoxels); ++l) {
    const int x = l & 7, y = l >> 3 & 7, z = l >> 6;
    if (Voxelmap::code_is_stored(codes[l]) || !in_grid(bi * kEdge + x, bj * kEdge + y, bk * kEdge + z)) continue;
    codes[l] = int16_t((codes[l] < 0 ? -2 : 2) * seeds[z][y][x]);
  }
}

inline const int16_t* EstimateTransform::brick_at(int bi, int bj, int bk) const {
  if (bi < 0 || bj < 0 || bk < 0 || bi >= bricks_[0] || bj >= bricks_[1] || bk >= bricks_[2]) return nullptr;
  const int32_t e = vm_.bricks[vm_.brick_index(uint32_t(bi), uint32_t(bj), uint32_t(bk))];
  return e < 0 ? nullptr : &codes_[size_t(e) * Voxelmap::kBrickVoxels];
}

/// Brick (bi, bj, bk)'s magnitudes and a one-voxel apron of its value-brick neighbours' (far elsewhere and past the
/// grid), and which of its voxels are fixed.
inline void EstimateTransform::fill(int bi, int bj, int bk, Block& block) const {
  std::fill(&block.v[0][0][0], &block.v[0][0][0] + (kEdge + 2) * (kEdge + 2) * (kEdge + 2), kFar);
  for (int dk = -1; dk <= 1; ++dk)
    for (int dj = -1; dj <= 1; ++dj)
      for (int di = -1; di <= 1; ++di)
        if (const int16_t* src = brick_at(bi + di, bj + dj, bk + dk)) fill_from(src, {di, dj, dk}, bi, bj, bk, block);
  const int16_t* own = brick_at(bi, bj, bk);
  for (int l = 0; l < int(Voxelmap::kBrickVoxels); ++l) {
    const int x = l & 7, y = l >> 3 & 7, z = l >> 6;
    block.fixed[z][y][x] = Voxelmap::code_is_stored(own[l]) || !in_grid(bi * kEdge + x, bj * kEdge + y, bk * kEdge + z);
  }
}

/// The part of the block that brick (bi, bj, bk) + d, whose codes are `src`, covers.
inline void EstimateTransform::fill_from(const int16_t* src, const int (&d)[3], int bi, int bj, int bk,
                                         Block& block) const {
  // Along each axis the block's range [lo, lo + n) reads the neighbour's local coordinates from `from`.
  int lo[3], n[3], from[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = d[a] < 0 ? 0 : d[a] == 0 ? 1 : kEdge + 1;
    n[a] = d[a] == 0 ? kEdge : 1;
    from[a] = d[a] < 0 ? kEdge - 1 : 0;
  }
  const int i0 = (bi + d[0]) * kEdge + from[0], j0 = (bj + d[1]) * kEdge + from[1], k0 = (bk + d[2]) * kEdge + from[2];
  if (in_grid(i0 + n[0] - 1, j0 + n[1] - 1, k0 + n[2] - 1)) {  // all of it (most bricks): no test a voxel
    for (int z = 0; z < n[2]; ++z)
      for (int y = 0; y < n[1]; ++y) {
        const int16_t* row = src + ((from[2] + z) * kEdge + from[1] + y) * kEdge + from[0];
        int16_t* to = &block.v[lo[2] + z][lo[1] + y][lo[0]];
        for (int x = 0; x < n[0]; ++x) to[x] = magnitude(row[x]);
      }
    return;
  }
  for (int z = 0; z < n[2]; ++z)
    for (int y = 0; y < n[1]; ++y)
      for (int x = 0; x < n[0]; ++x)
        if (in_grid(i0 + x, j0 + y, k0 + z))
          block.v[lo[2] + z][lo[1] + y][lo[0] + x] =
              magnitude(src[((from[2] + z) * kEdge + from[1] + y) * kEdge + from[0] + x]);
}

size_t EstimateTransform::visit(size_t e, int bi, int bj, int bk) {
  Block block;
  fill(bi, bj, bk, block);
  int16_t before[kEdge][kEdge][kEdge];
  for (int z = 0; z < kEdge; ++z)
    for (int y = 0; y < kEdge; ++y) std::memcpy(before[z][y], &block.v[z + 1][y + 1][1], kEdge * sizeof(int16_t));
  // The first sweep after one that lowers nothing proves the brick settled.
  for (int n = 0;; ++n)
    if (!sweep(block, n % 2 == 0 ? 1 : -1) && n >= 1) break;
  int32_t neighbour[3][3][3];
  const bool any_awake = rounds_.awake_neighbours(bi, bj, bk, neighbour);
  int16_t* codes = &(*writable_)[e * Voxelmap::kBrickVoxels];
  size_t lowered = 0;
  for (int z = 0; z < kEdge; ++z)
    for (int y = 0; y < kEdge; ++y)
      for (int x = 0; x < kEdge; ++x) {
        const int16_t now = block.v[z + 1][y + 1][x + 1];
        if (now == before[z][y][x]) continue;
        int16_t& code = codes[(z * kEdge + y) * kEdge + x];
        code = int16_t((code < 0 ? -2 : 2) * now);
        ++lowered;
        if (any_awake && (x == 0 || y == 0 || z == 0 || x == kEdge - 1 || y == kEdge - 1 || z == kEdge - 1))
          wake_lowerable(block, x, y, z, neighbour);
      }
  return lowered;
}

/// Wakes each settled neighbour whose voxel next to (x, y, z) the value there would lower.
inline void EstimateTransform::wake_lowerable(const Block& block, int x, int y, int z, int32_t (&neighbour)[3][3][3]) {
  const int v = block.v[z + 1][y + 1][x + 1];
  for (int ez = -1; ez <= 1; ++ez)
    for (int ey = -1; ey <= 1; ++ey)
      for (int ex = -1; ex <= 1; ++ex) {
        int32_t& n = neighbour[brick_side(z + ez) + 1][brick_side(y + ey) + 1][brick_side(x + ex) + 1];
        if (n < 0) continue;
        if (v + step_[ez + 1][ey + 1][ex + 1] < block.v[z + 1 + ez][y + 1 + ey][x + 1 + ex]) rounds_.wake(n), n = -1;
      }
}

/// One sweep over the brick's voxels, forward (dir 1) or back; whether it lowered any. Fixed voxels keep their values
/// (and pass them on).
inline bool EstimateTransform::sweep(Block& block, int dir) const {
  bool changed = false;
  for (int n = 0; n < kEdge; ++n) {
    const int z = dir > 0 ? n + 1 : kEdge - n;
    for (int m = 0; m < kEdge; ++m) {
      const int y = dir > 0 ? m + 1 : kEdge - m;
      // The 9 neighbours in the layer before and the 3 in the row before (steps depend only on how many axes a
      // step moves along, so the forward ones serve both directions); the row's own run along x last.
      const int16_t* from[12];
      int16_t steps[12];
      int r = 0;
      for (int dj = -1; dj <= 1; ++dj)
        for (int dx = -1; dx <= 1; ++dx, ++r)
          from[r] = &block.v[z - dir][y + dj][1 + dx], steps[r] = step_[2][dj + 1][dx + 1];
      for (int dx = -1; dx <= 1; ++dx, ++r) from[r] = &block.v[z][y - dir][1 + dx], steps[r] = step_[1][2][dx + 1];
      int16_t best[kEdge];
      least_of_rows(&block.v[z][y][1], from, steps, best);
      int16_t* row = block.v[z][y];
      const bool* fixed = block.fixed[z - 1][y - 1];
      int run = row[dir > 0 ? 0 : kEdge + 1];
      for (int s = 0; s < kEdge; ++s) {
        const int x = dir > 0 ? s : kEdge - 1 - s;
        if (!fixed[x]) {
          const int16_t v = int16_t(std::min<int>(best[x], run + axis_step_[1]));
          changed |= v < row[x + 1];
          row[x + 1] = v;
        }
        run = row[x + 1];
      }
    }
  }
  return changed;
}

}  // namespace voxfmt::detail
