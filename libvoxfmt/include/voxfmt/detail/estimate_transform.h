// The chamfer transform of a voxelmap's value-brick estimates, in place on their 16-bit codes: format 2.2's settled
// estimates (spec §3.1), which fill_estimates writes and validation checks (bench/estimate_transform measures it).
// Brick by brick: a brick and a one-voxel apron of its neighbours are swept in a 10^3 block until settled, and a
// neighbour is woken only where a voxel it could lower was lowered. The least path lengths do not depend on the order
// the relaxations run in, so the codes are the same whatever the threads.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "voxfmt/detail/cores.h"
#include "voxfmt/voxelmap.h"

namespace voxfmt::detail {

/// Brick coordinates (bi, bj, bk) of entry b of a brick table.
inline std::array<int, 3> brick_coordinates(const Voxelmap& vm, size_t b) {
  const auto d = vm.brick_dims();
  return {int(b % d[0]), int(b / d[0] % d[1]), int(b / (size_t(d[0]) * d[1]))};
}

/// body(b) for every value brick b of the brick table, on `threads` threads each taking every threads-th one.
template <class Body>
void for_each_value_brick_shared(const Voxelmap& vm, unsigned threads, const Body& body) {
  threads = std::max(1u, threads);
  run_workers(threads, [&](unsigned first) {
    for (size_t b = first; b < vm.bricks.size(); b += threads)
      if (vm.bricks[b] >= 0) body(b);
  });
}

/// best[x] = the least of own[x] and from[r][x] + step[r] over the `rows` rows r, x = 0 .. 7. For 16-bit values the
/// sums saturate at 32767, so a far value plus a step stays far.
inline void least_of_rows(const float* own, const float* const* from, const float* step, float* best, int rows = 12) {
#if defined(__SSE2__)
  __m128 lo = _mm_loadu_ps(own), hi = _mm_loadu_ps(own + 4);
  for (int r = 0; r < rows; ++r) {
    const __m128 s = _mm_set1_ps(step[r]);
    lo = _mm_min_ps(_mm_add_ps(_mm_loadu_ps(from[r]), s), lo);
    hi = _mm_min_ps(_mm_add_ps(_mm_loadu_ps(from[r] + 4), s), hi);
  }
  _mm_storeu_ps(best, lo);
  _mm_storeu_ps(best + 4, hi);
#else
  for (int x = 0; x < 8; ++x) {
    float v = own[x];
    for (int r = 0; r < rows; ++r) v = std::min(v, from[r][x] + step[r]);
    best[x] = v;
  }
#endif
}
inline void least_of_rows(const int16_t* own, const int16_t* const* from, const int16_t* step, int16_t* best,
                          int rows = 12) {
#if defined(__SSE2__)
  __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(own));
  for (int r = 0; r < rows; ++r)
    v = _mm_min_epi16(
        v, _mm_adds_epi16(_mm_loadu_si128(reinterpret_cast<const __m128i*>(from[r])), _mm_set1_epi16(step[r])));
  _mm_storeu_si128(reinterpret_cast<__m128i*>(best), v);
#else
  for (int x = 0; x < 8; ++x) {
    int v = own[x];
    for (int r = 0; r < rows; ++r) v = std::min(v, std::min(32767, int(from[r][x]) + int(step[r])));
    best[x] = int16_t(v);
  }
#endif
}

/// A round of a brick-wise transform.
struct BrickRound {
  double s = 0;
  size_t visits = 0;   ///< bricks swept
  size_t lowered = 0;  ///< voxels lowered
};

/// Which brick along an axis a local coordinate -1 .. 8 lies in: -1, 0 (this one) or 1.
inline int brick_side(int local) { return local < 0 ? -1 : local >= int(Voxelmap::kBrickEdge) ? 1 : 0; }

/// What brick-wise transforms share: which value bricks are pending, and rounds that visit them in raster order,
/// forward then back, until none is. With threads, each takes a slab of brick layers holding about as many value
/// bricks, and a round sweeps the slabs' inner layers, then their first, then their last, so that no two threads
/// touch neighbouring bricks at once.
class BrickRounds {
 public:
  explicit BrickRounds(const Voxelmap& vm);

  /// Rounds until no brick is pending (each round lowers a value, so they end): visit(e, bi, bj, bk) sweeps value brick
  /// e (its flag already cleared) and returns the voxels it lowered.
  template <class Visit>
  std::vector<BrickRound> run(unsigned threads, const Visit& visit);

  /// The 26 neighbours of brick (bi, bj, bk) that are value bricks not pending, by offset + 1 (-1 for the others and
  /// the brick itself): those a lowered voxel next to them may have to wake. Whether there is any.
  bool awake_neighbours(int bi, int bj, int bk, int32_t (&neighbour)[3][3][3]) const;

  /// Value brick e is to be swept again.
  void wake(int32_t e) { pending_[size_t(e)].store(1, std::memory_order_relaxed); }

 private:
  /// Up to `threads` slabs [lo, hi) of brick layers, each of at least three layers, holding about as many value
  /// bricks each.
  std::vector<std::pair<int, int>> balanced_slabs(unsigned threads) const;

  /// Visits the pending value bricks of brick layer bk in raster order (reversed for dir < 0).
  template <class Visit>
  void sweep_layer(int bk, int dir, BrickRound& round, const Visit& visit);

  const Voxelmap& vm_;
  int bricks_[3];
  std::unique_ptr<std::atomic<uint8_t>[]> pending_;  ///< per value brick: to be swept again
};

/// The transform on value-brick codes, in steps of the estimate quantum q, all in integers. Stored distances are
/// sources (|d| in steps of q, rounded up) and are never lowered; each estimate becomes the least of its seed (over
/// its cell's lattice points p, ceil(l_p / q) plus the length of a path of voxel steps to p) and its value-brick
/// neighbours' values plus their step (1, sqrt 2, sqrt 3 voxels in steps of q, rounded up), keeping its sign, at
/// most Voxelmap::kMaxSteps; voxels past the grid take no part. No array beside the codes but a byte per value brick,
/// and every estimate can be checked from its neighbours without the mesh (`count_unsettled`).
class EstimateTransform {
 public:
  /// Over `codes`: value-brick codes in the layout of vm.brick_values (vm's brick table, lattice and quanta).
  EstimateTransform(const Voxelmap& vm, std::vector<int16_t>& codes);
  /// To check `codes` only (count_unsettled): seed and settle must not be called.
  EstimateTransform(const Voxelmap& vm, const std::vector<int16_t>& codes);

  /// Seeds every estimate from its cell's lattice points; bricks shared out over `threads`.
  void seed(unsigned threads);
  /// Rounds until settled.
  std::vector<BrickRound> settle(unsigned threads);
  /// The estimates that are not the least of their seed and their neighbours' values plus their step (what a
  /// validator counts); bricks shared out over `threads`.
  size_t count_unsettled(unsigned threads) const;
  /// The same for value brick (bi, bj, bk).
  size_t count_unsettled(int bi, int bj, int bk) const;

 private:
  static constexpr int kEdge = int(Voxelmap::kBrickEdge);
  static constexpr int16_t kFar = 32767;
  struct Block {
    int16_t v[kEdge + 2][kEdge + 2][kEdge + 2];  ///< [z][y][x], local + 1: magnitudes in steps of q
    bool fixed[kEdge][kEdge][kEdge];             ///< the brick's stored voxels and those past the grid
  };

  bool in_grid(int i, int j, int k) const { return i < dims_[0] && j < dims_[1] && k < dims_[2]; }
  int path_steps(int a, int b, int c) const;
  int16_t magnitude(int16_t code) const;
  void seed_values(int bi, int bj, int bk, int16_t (&seeds)[kEdge][kEdge][kEdge]) const;
  void seed_brick(size_t b);
  const int16_t* brick_at(int bi, int bj, int bk) const;
  void fill(int bi, int bj, int bk, Block& block) const;
  void fill_from(const int16_t* src, const int (&d)[3], int bi, int bj, int bk, Block& block) const;
  size_t visit(size_t e, int bi, int bj, int bk);
  void wake_lowerable(const Block& block, int x, int y, int z, int32_t (&neighbour)[3][3][3]);
  bool sweep(Block& block, int dir) const;

  const Voxelmap& vm_;
  const std::vector<int16_t>& codes_;
  std::vector<int16_t>* writable_;  ///< codes_, where seed and settle may write them (null: checking only)
  int bricks_[3], dims_[3];
  int axis_step_[4];               ///< steps of q along 0 .. 3 axes at once, rounded up
  int16_t step_[3][3][3];          ///< the same by dk + 1, dj + 1, dx + 1
  std::vector<int16_t> stored_;    ///< |c >> 1| of a stored code in steps of q, rounded up
  std::vector<int16_t> reversed_;  ///< path lengths to offsets -8 .. 8, rows of 17 reversed
  BrickRounds rounds_;
};

// ---- BrickRounds' templates

template <class Visit>
std::vector<BrickRound> BrickRounds::run(unsigned threads, const Visit& visit) {
  const std::vector<std::pair<int, int>> slabs = balanced_slabs(threads);
  const unsigned workers = unsigned(slabs.size());
  std::vector<BrickRound> rounds;
  for (int number = 0;; ++number) {
    const int dir = number % 2 == 0 ? 1 : -1;
    const auto clock = std::chrono::steady_clock::now();
    std::vector<BrickRound> by_worker(workers);
    const int phases = workers == 1 ? 1 : 3;  // one slab: all its layers at once
    for (int phase = 0; phase < phases; ++phase)
      run_workers(workers, [&](unsigned t) {
        const auto [lo, hi] = slabs[t];
        int first = lo, last = hi - 1;  // layers of this phase, inclusive
        if (phases == 3) {
          if (phase == 0) first = lo + 1, last = hi - 2;
          if (phase == 1) last = lo;
          if (phase == 2) first = hi - 1;
        }
        for (int n = 0; n <= last - first; ++n) sweep_layer(dir > 0 ? first + n : last - n, dir, by_worker[t], visit);
      });
    BrickRound round;
    for (const BrickRound& r : by_worker) round.visits += r.visits, round.lowered += r.lowered;
    if (round.visits == 0) break;
    round.s = std::chrono::duration<double>(std::chrono::steady_clock::now() - clock).count();
    rounds.push_back(round);
  }
  return rounds;
}

template <class Visit>
void BrickRounds::sweep_layer(int bk, int dir, BrickRound& round, const Visit& visit) {
  const int per_layer = bricks_[0] * bricks_[1];
  for (int n = 0; n < per_layer; ++n) {
    const int m = dir > 0 ? n : per_layer - 1 - n;
    const int bi = m % bricks_[0], bj = m / bricks_[0];
    const int32_t e = vm_.bricks[vm_.brick_index(uint32_t(bi), uint32_t(bj), uint32_t(bk))];
    if (e < 0 || !pending_[size_t(e)].load(std::memory_order_relaxed)) continue;
    pending_[size_t(e)].store(0, std::memory_order_relaxed);
    round.lowered += visit(size_t(e), bi, bj, bk);
    ++round.visits;
  }
}

}  // namespace voxfmt::detail
