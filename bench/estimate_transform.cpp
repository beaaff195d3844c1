// What better value-brick estimates would cost a producer (issue "fidelity", a format 2.2 candidate): the
// 26-neighbour chamfer transform of an asset's band sources over its value bricks, timed.
//
//   estimate-transform ASSET [--values OUT] [--json OUT] [--max-memory MiB] [--threads N] [--every-brick]
//                      [--fixed16] [--reach 1|2] [--by-brick] [--in-codes]
//
// Sources are the stored distances (|d|) and the lattice points (their value): each value-brick voxel is seeded
// with the least l_q + c(q - v) over its cell's eight lattice points q (c: the chamfer length of a path of voxel
// steps 1, sqrt 2, sqrt 3), then raster passes forward and back over the value bricks' voxels lower each to the
// least of its 13 neighbours visited before plus the step, until a pass changes none. Paths stay inside value
// bricks (coarse bricks are reached by the seed only). A path is no shorter than the straight line, so every value
// is an upper bound of the exact distance, and once settled neighbouring values differ by at most their step: what a
// reader could check without the mesh.
//
// Passes after the second skip the bricks no voxel near them was lowered recently (`--every-brick` visits all).
// `--threads N` shares the seed's bricks out and runs each pass on N slabs of brick layers at once (the same values).
// `--fixed16` holds the values as 16-bit sixteenths of a voxel (steps and seeds rounded up: still upper bounds).
// Beside it, what it would replace: format 2.1's estimates (the lattice's interpolation, `fill_brick_estimates`) on
// as many threads. The asset is read first (not timed). `--values` writes the values (voxels, float32, the value
// bricks' order, 512 each) for bench/estimate_oracle.py --producer-values. `--reach 2` takes steps to the 5^3
// neighbours instead (lengths sqrt(a^2 + b^2 + c^2): a metric within ~2 % of the Euclidean, not 8 %), 62
// neighbours visited before where 1 has 13.
//
// `--by-brick` reaches the same values brick by brick (a brick and a one-voxel apron swept in a 10^3 block until
// settled, its neighbours woken where it lowered a voxel next to them; threads on slabs of brick layers), and
// `--in-codes` is what a format 2.2 producer would run: that, in place on a copy of the 16-bit codes in steps of the
// estimate quantum (stored distances fixed, voxels past the grid left out), then a check of every estimate against
// its seed and neighbours (what a validator would run), timed.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <memory>
#include <thread>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "voxfmt/io.h"

namespace {

using voxfmt::Voxelmap;
constexpr float kFar = 1e30f;
constexpr int kEdge = 8;
const float kStep[4] = {0.0f, 1.0f, 1.41421356f, 1.73205081f};  // by the number of axes a step moves along

float chamfer_length(int a, int b, int c) {
  std::array<int, 3> s = {std::abs(a), std::abs(b), std::abs(c)};
  std::sort(s.begin(), s.end());  // s[0] <= s[1] <= s[2]
  return float(s[0]) * kStep[3] + float(s[1] - s[0]) * kStep[2] + float(s[2] - s[1]) * kStep[1];
}

/// The length of a step (dx, dy, dz).
float step_length(int dx, int dy, int dz) { return std::sqrt(float(dx * dx + dy * dy + dz * dz)); }

/// Shortest path lengths of steps to the (2 Reach + 1)^3 neighbours over the offsets -8 .. 8 (17^3, x fastest):
/// the closed form for Reach 1, relaxation until settled for more.
/// body(n) for every value brick n of the brick table on `threads` threads, each taking every threads-th one
/// (bricks are independent here).
template <class Body>
void for_each_value_brick(const Voxelmap& vm, unsigned threads, const Body& body) {
  auto every = [&](unsigned first) {
    for (size_t n = first; n < vm.bricks.size(); n += threads)
      if (vm.bricks[n] >= 0) body(n);
  };
  std::vector<std::thread> workers;
  for (unsigned t = 1; t < threads; ++t) workers.emplace_back(every, t);
  every(0);
  for (std::thread& w : workers) w.join();
}

template <int Reach>
std::vector<float> offset_lengths() {
  std::vector<float> length(17 * 17 * 17);
  for (int z = 0; z < 17; ++z)
    for (int y = 0; y < 17; ++y)
      for (int x = 0; x < 17; ++x) length[size_t((z * 17 + y) * 17 + x)] = chamfer_length(x - 8, y - 8, z - 8);
  if (Reach == 1) return length;
  for (bool changed = true; changed;) {
    changed = false;
    for (int z = 0; z < 17; ++z)
      for (int y = 0; y < 17; ++y)
        for (int x = 0; x < 17; ++x)
          for (int dz = -Reach; dz <= Reach; ++dz)
            for (int dy = -Reach; dy <= Reach; ++dy)
              for (int dx = -Reach; dx <= Reach; ++dx) {
                const int nx = x + dx, ny = y + dy, nz = z + dz;
                if (nx < 0 || ny < 0 || nz < 0 || nx > 16 || ny > 16 || nz > 16) continue;
                float& here = length[size_t((z * 17 + y) * 17 + x)];
                const float via = length[size_t((nz * 17 + ny) * 17 + nx)] + step_length(dx, dy, dz);
                if (via < here - 1e-6f) here = via, changed = true;
              }
  }
  return length;
}

/// How a transform holds its values: float voxels, or 16-bit fixed point in sixteenths of a voxel (the step lengths
/// and seeds rounded up, so values stay upper bounds; half the memory of floats).
template <class V>
struct Units;
template <>
struct Units<float> {
  static constexpr float kFar = 1e30f;
  static constexpr float kNoise = 1e-4f;  // a lowering smaller than this is not counted as one
  static float from_voxels(float v) { return v; }
  static float to_voxels(float v) { return v; }
  static float lower(float m, float a, float step) { return std::min(m, a + step); }
};
template <>
struct Units<int16_t> {
  static constexpr int kPerVoxel = 16;
  static constexpr int16_t kFar = 32767;
  static constexpr int kNoise = 0;
  static int16_t from_voxels(float v) { return int16_t(std::min(32767.0f, std::ceil(v * float(kPerVoxel)))); }
  static float to_voxels(int16_t v) { return float(v) / float(kPerVoxel); }
  static int16_t lower(int16_t m, int16_t a, int16_t step) { return int16_t(std::min(int(m), int(a) + int(step))); }
};

template <int Reach, class V>
class ChamferTransform {
  using U = Units<V>;

 public:
  explicit ChamferTransform(const Voxelmap& vm) : vm_(vm), bricks_(vm.brick_dims()) {
    for (int dk = 0; dk <= Reach; ++dk)
      for (int dj = -Reach; dj <= Reach; ++dj)
        for (int dx = -Reach; dx <= Reach; ++dx)
          step_[dk][dj + Reach][dx + Reach] = U::from_voxels(step_length(dx, dj, dk));
    for (int a = 0; a < 3; ++a) dims_[a] = int(vm.dims[a]);
    values_.assign(vm.brick_values.size(), U::kFar);
    lowered_in_size_ = vm.brick_values.size() / Voxelmap::kBrickVoxels;
    lowered_in_ = std::make_unique<std::atomic<int>[]>(lowered_in_size_);
    own_lowered_in_.assign(lowered_in_size_, 0);
    split(1);
    rows_.assign(size_t(bricks_[1]) * bricks_[2], {});
    for (uint32_t bk = 0; bk < bricks_[2]; ++bk)
      for (uint32_t bj = 0; bj < bricks_[1]; ++bj)
        for (uint32_t bi = 0; bi < bricks_[0]; ++bi)
          if (vm.bricks[vm.brick_index(bi, bj, bk)] >= 0) rows_[size_t(bk) * bricks_[1] + bj].push_back(int(bi));
  }

  /// The values (in U's units), handed over: a brick-wise transform goes on from the seed.
  std::vector<V> take() { return std::move(values_); }

  /// The values in voxels.
  std::vector<float> values() const {
    std::vector<float> voxels(values_.size());
    std::transform(values_.begin(), values_.end(), voxels.begin(), [](V v) { return U::to_voxels(v); });
    return voxels;
  }

  /// Stored voxels their |d|; the others the least over their cell's lattice points of l_q + c(q - v). Bricks are
  /// independent: `threads` take every threads-th one.
  void seed(unsigned threads) {
    const std::vector<float> length = offset_lengths<Reach>();
    // Each row of 17 reversed, so that a row of voxels reads its lengths to a lattice point in increasing order.
    std::vector<float> reversed(length.size());
    for (size_t r = 0; r < 17 * 17; ++r)
      for (size_t t = 0; t < 17; ++t) reversed[r * 17 + t] = length[r * 17 + 16 - t];
    for_each_value_brick(vm_, threads, [&](size_t b) { seed_brick(b, reversed); });
  }

  /// Splits the passes over `threads` slabs of brick layers along z, each run by its own thread. A slab reads its
  /// neighbours' voxels as they were when the pass began (copies of the layers next to it), so the passes are the
  /// same whatever the threads' timing, and settle where a single thread's do (the least path lengths).
  void split(unsigned threads) {
    slabs_.clear();
    const int layers = int(bricks_[2]);
    threads = std::max(1u, std::min<unsigned>(threads, unsigned(std::max(1, layers / 2))));
    for (unsigned t = 0; t < threads; ++t)
      slabs_.push_back({int(t * layers / threads), int((t + 1) * layers / threads)});
    shadow_slot_.assign(lowered_in_size_, -1);
    shadowed_.clear();
    for (size_t t = 1; t < slabs_.size(); ++t)
      for (int bk : {slabs_[t].lo - 1, slabs_[t].lo})
        for (uint32_t bj = 0; bj < bricks_[1]; ++bj)
          for (uint32_t bi = 0; bi < bricks_[0]; ++bi) {
            const int32_t e = vm_.bricks[vm_.brick_index(bi, bj, uint32_t(bk))];
            if (e < 0) continue;
            shadow_slot_[size_t(e)] = int32_t(shadowed_.size());
            shadowed_.push_back(size_t(e));
          }
    shadow_.assign(shadowed_.size() * Voxelmap::kBrickVoxels, U::kFar);
  }

  struct Outcome {
    size_t lowered = 0;  ///< voxels lowered by over 1e-4 voxel
    size_t changed = 0;  ///< voxels lowered at all
    float largest_drop = 0;
  };

  /// Pass `number` (1, 2, ...: odd forward, even back) over the value bricks' voxels. With `skip_settled`, passes
  /// after the second visit only the bricks within one brick of a voxel lowered recently: a voxel takes the least
  /// over neighbours its pass visits before it, which it last compared two passes ago (the same direction), so only
  /// a neighbour lowered since can lower it (three passes ago for a neighbour in another slab, read from a copy).
  Outcome pass(int number, bool skip_settled) {
    for (size_t n = 0; n < shadowed_.size(); ++n)
      std::memcpy(&shadow_[n * Voxelmap::kBrickVoxels], &values_[shadowed_[n] * Voxelmap::kBrickVoxels],
                  Voxelmap::kBrickVoxels * sizeof(V));
    std::vector<Outcome> outcomes(slabs_.size());
    std::vector<std::thread> workers;
    for (size_t t = 1; t < slabs_.size(); ++t)
      workers.emplace_back([&, t] { outcomes[t] = pass_slab(number, skip_settled, slabs_[t]); });
    outcomes[0] = pass_slab(number, skip_settled, slabs_[0]);
    for (std::thread& w : workers) w.join();
    Outcome all;
    for (const Outcome& o : outcomes) {
      all.lowered += o.lowered;
      all.changed += o.changed;
      all.largest_drop = std::max(all.largest_drop, o.largest_drop);
    }
    return all;
  }

 private:
  struct Slab {
    int lo, hi;  ///< brick layers [lo, hi) along z
  };

  Outcome pass_slab(int number, bool skip_settled, const Slab& slab) {
    const bool forward = number % 2 == 1;
    const int dir = forward ? 1 : -1;
    const int recent = slabs_.size() > 1 ? 2 : 1;  // how many passes back a lowering can still be news
    const int first = slab.lo * kEdge, end = std::min(slab.hi * kEdge, dims_[2]);
    Outcome outcome;
    for (int kk = first; kk < end; ++kk) {
      const int k = forward ? kk : end - 1 - (kk - first);
      for (int jj = 0; jj < dims_[1]; ++jj) {
        const int j = forward ? jj : dims_[1] - 1 - jj;
        const std::vector<int>& columns = rows_[size_t(k / kEdge) * bricks_[1] + size_t(j / kEdge)];
        for (size_t c = 0; c < columns.size(); ++c) {
          const int bi = forward ? columns[c] : columns[columns.size() - 1 - c];
          const size_t e = size_t(vm_.bricks[vm_.brick_index(uint32_t(bi), uint32_t(j / kEdge), uint32_t(k / kEdge))]);
          if (skip_settled && number > 2 && lowered_in_[e].load(std::memory_order_relaxed) + recent < number) continue;
          const size_t changed = segment(bi, j, k, dir, slab, outcome);
          if (changed > 0) mark_lowered(bi, j / kEdge, k / kEdge, number);
        }
      }
    }
    return outcome;
  }

  /// Brick (bi, bj, bk) lowered a voxel in pass `number`: it and its value-brick neighbours are stamped with it.
  void mark_lowered(int bi, int bj, int bk, int number) {
    int& own = own_lowered_in_[size_t(vm_.bricks[vm_.brick_index(uint32_t(bi), uint32_t(bj), uint32_t(bk))])];
    if (own == number) return;  // its neighbours are stamped already
    own = number;
    for (int dk = -1; dk <= 1; ++dk)
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int i = bi + di, j = bj + dj, k = bk + dk;
          if (i < 0 || j < 0 || k < 0 || i >= int(bricks_[0]) || j >= int(bricks_[1]) || k >= int(bricks_[2])) continue;
          const int32_t e = vm_.bricks[vm_.brick_index(uint32_t(i), uint32_t(j), uint32_t(k))];
          if (e >= 0) lowered_in_[size_t(e)].store(number, std::memory_order_relaxed);
        }
  }

  void seed_brick(size_t b, const std::vector<float>& reversed) {
    const int bi = int(b % bricks_[0]), bj = int(b / bricks_[0] % bricks_[1]),
              bk = int(b / (size_t(bricks_[0]) * bricks_[1]));
    float corner[8];
    int cx[2], cy[2], cz[2];
    for (int q = 0; q < 2; ++q) {
      cx[q] = int(Voxelmap::lattice_coordinate(uint32_t(bi + q), vm_.dims[0]));
      cy[q] = int(Voxelmap::lattice_coordinate(uint32_t(bj + q), vm_.dims[1]));
      cz[q] = int(Voxelmap::lattice_coordinate(uint32_t(bk + q), vm_.dims[2]));
    }
    for (int q = 0; q < 8; ++q)
      corner[q] =
          float(vm_.lattice[vm_.lattice_index(bi + (q & 1), bj + (q >> 1 & 1), bk + (q >> 2))] / vm_.voxel_size);
    const size_t first = size_t(vm_.bricks[b]) * Voxelmap::kBrickVoxels;
    for (int lk = 0; lk < kEdge; ++lk)
      for (int lj = 0; lj < kEdge; ++lj) {
        const int j = bj * kEdge + lj, k = bk * kEdge + lk;
        float best[kEdge];
        std::fill(best, best + kEdge, kFar);
        for (int q = 0; q < 8; ++q) {
          // The length from voxel i = 8 bi + x to the point's column cx is reversed[...][8 - (cx - 8 bi) + x].
          const float* lengths = &reversed[size_t(((cz[q >> 2] - k + 8) * 17 + cy[q >> 1 & 1] - j + 8) * 17 + 8 -
                                                  (cx[q & 1] - bi * kEdge))];
          for (int x = 0; x < kEdge; ++x) best[x] = std::min(best[x], corner[q] + lengths[x]);
        }
        const size_t row = first + size_t((lk * kEdge + lj) * kEdge);
        for (int x = 0; x < kEdge; ++x) {
          const int16_t code = vm_.brick_values[row + size_t(x)];
          values_[row + size_t(x)] = Voxelmap::code_is_stored(code)
                                         ? U::from_voxels(float(std::abs(vm_.decode(code)) / vm_.voxel_size))
                                         : U::from_voxels(best[x]);
        }
      }
  }

  /// Value brick (bi, bj, bk)'s values as `slab` sees them, or null (coarse, outside the grid).
  V* brick(int bi, int bj, int bk, const Slab& slab) {
    if (bi < 0 || bj < 0 || bk < 0 || bi >= int(bricks_[0]) || bj >= int(bricks_[1]) || bk >= int(bricks_[2]))
      return nullptr;
    const int32_t e = vm_.bricks[vm_.brick_index(uint32_t(bi), uint32_t(bj), uint32_t(bk))];
    if (e < 0) return nullptr;
    if (bk < slab.lo || bk >= slab.hi) return &shadow_[size_t(shadow_slot_[size_t(e)]) * Voxelmap::kBrickVoxels];
    return &values_[size_t(e) * Voxelmap::kBrickVoxels];
  }

  /// Voxel row (j, k) around brick column bi: the bricks bi - 1, bi, bi + 1 holding it and the row's offset in them.
  struct Row {
    const V* brick[3] = {nullptr, nullptr, nullptr};
    int offset = 0;
  };
  Row row_at(int bi, int j, int k, const Slab& slab) {
    Row r;
    if (j < 0 || k < 0 || j >= dims_[1] || k >= dims_[2]) return r;
    for (int n = 0; n < 3; ++n) r.brick[n] = brick(bi - 1 + n, j / kEdge, k / kEdge, slab);
    r.offset = ((k % kEdge) * kEdge + j % kEdge) * kEdge;
    return r;
  }

  static constexpr int kAround = kEdge + 2 * Reach;

  /// A row's values x = -Reach .. 7 + Reach around segment bi (far where no value brick holds them).
  static void around(const Row& r, V out[kAround]) {
    for (int n = 0; n < Reach; ++n) {
      out[n] = r.brick[0] ? r.brick[0][r.offset + kEdge - Reach + n] : U::kFar;
      out[kEdge + Reach + n] = r.brick[2] ? r.brick[2][r.offset + n] : U::kFar;
    }
    if (r.brick[1])
      std::memcpy(out + Reach, r.brick[1] + r.offset, kEdge * sizeof(V));
    else
      std::fill(out + Reach, out + Reach + kEdge, U::kFar);
  }

  /// Lowers one row segment from the neighbours its pass visited before, counted in `outcome`; how many changed.
  size_t segment(int bi, int j, int k, int dir, const Slab& slab, Outcome& outcome) {
    // The rows visited before: planes k - dir .. k - Reach dir at rows j - Reach .. j + Reach; this plane at rows
    // j - dir .. j - Reach dir. Inside a brick they share the segment's brick row (one lookup of the three bricks).
    const Row own = row_at(bi, j, k, slab);
    const int jl = j % kEdge, kl = k % kEdge;
    const bool plane_inside = dir > 0 ? kl >= Reach : kl < kEdge - Reach && k + Reach < dims_[2];
    const bool rows_inside = jl >= Reach && jl < kEdge - Reach && j + Reach < dims_[1];
    auto shifted = [&](int dj, int dk) {
      if (!(rows_inside && (dk == 0 || plane_inside))) return row_at(bi, j + dj, k + dk, slab);
      Row r = own;
      r.offset += (dk * kEdge + dj) * kEdge;
      return r;
    };
    constexpr int kRows = (2 * Reach + 1) * Reach + Reach;
    V before[kRows][kAround];
    const V* steps[kRows];  // per row, its steps by dx + Reach
    int row = 0;
    for (int dk = 1; dk <= Reach; ++dk)
      for (int dj = -Reach; dj <= Reach; ++dj, ++row) {
        around(shifted(dj, -dk * dir), before[row]);
        steps[row] = step_[dk][dj + Reach];
      }
    for (int dj = 1; dj <= Reach; ++dj, ++row) {
      around(shifted(-dj * dir, 0), before[row]);
      steps[row] = step_[0][dj + Reach];
    }
    V* values = const_cast<V*>(own.brick[1]) + own.offset;
    V best[kEdge];
    for (int x = 0; x < kEdge; ++x) {
      V m = values[x];
      for (int r = 0; r < kRows; ++r)
        for (int dx = -Reach; dx <= Reach; ++dx) m = U::lower(m, before[r][x + Reach + dx], steps[r][dx + Reach]);
      best[x] = m;
    }
    // Along the row: the voxel visited just before it (in the previous segment at the segment's start).
    const V* previous = own.brick[dir > 0 ? 0 : 2];
    V run = previous ? previous[own.offset + (dir > 0 ? kEdge - 1 : 0)] : U::kFar;
    size_t changed = 0;
    for (int n = 0; n < kEdge; ++n) {
      const int x = dir > 0 ? n : kEdge - 1 - n;
      run = U::lower(best[x], run, step_[0][Reach][Reach + 1]);
      changed += run < values[x];
      outcome.lowered += values[x] - run > U::kNoise;
      outcome.largest_drop = std::max(outcome.largest_drop, U::to_voxels(values[x]) - U::to_voxels(run));
      values[x] = run;
    }
    outcome.changed += changed;
    return changed;
  }

  const Voxelmap& vm_;
  std::array<uint32_t, 3> bricks_;
  int dims_[3];
  std::vector<V> values_;                           ///< per value-brick voxel (in U's units), the value bricks' order
  std::unique_ptr<std::atomic<int>[]> lowered_in_;  ///< per value brick: the last pass that lowered it or a neighbour
  size_t lowered_in_size_ = 0;
  std::vector<int> own_lowered_in_;  ///< per value brick: the last pass that lowered one of its own voxels
  std::vector<Slab> slabs_;
  std::vector<int32_t> shadow_slot_;                 ///< per value brick: its copy in shadow_, or -1
  std::vector<size_t> shadowed_;                     ///< the value bricks copied, by slot
  std::vector<V> shadow_;                            ///< their values when the pass began
  std::vector<std::vector<int>> rows_;               ///< per (bj, bk): its value bricks' columns bi, ascending
  V step_[Reach + 1][2 * Reach + 1][2 * Reach + 1];  ///< step lengths by dk, dj + Reach, dx + Reach
};

/// best[x] = the least of own[x] and from[r][x] + step[r] over the `rows` rows r, x = 0 .. 7 (as Units::lower,
/// whose minimum of a value and a far one plus a step is the value: the 16-bit sums saturate).
template <class V>
inline void least_of_rows(const V* own, const V* const* from, const V* step, V* best, int rows = 12) {
  for (int x = 0; x < kEdge; ++x) {
    V v = own[x];
    for (int r = 0; r < rows; ++r) v = Units<V>::lower(v, from[r][x], step[r]);
    best[x] = v;
  }
}

#if defined(__SSE2__)
// The same in SSE2 (8 lanes: two float vectors, one of 16-bit integers): min(a + s, b) picks a + s only when it
// is less, as std::min does.
template <>
inline void least_of_rows<float>(const float* own, const float* const* from, const float* step, float* best, int rows) {
  __m128 lo = _mm_loadu_ps(own), hi = _mm_loadu_ps(own + 4);
  for (int r = 0; r < rows; ++r) {
    const __m128 s = _mm_set1_ps(step[r]);
    lo = _mm_min_ps(_mm_add_ps(_mm_loadu_ps(from[r]), s), lo);
    hi = _mm_min_ps(_mm_add_ps(_mm_loadu_ps(from[r] + 4), s), hi);
  }
  _mm_storeu_ps(best, lo);
  _mm_storeu_ps(best + 4, hi);
}

template <>
inline void least_of_rows<int16_t>(const int16_t* own, const int16_t* const* from, const int16_t* step, int16_t* best,
                                   int rows) {
  __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(own));
  for (int r = 0; r < rows; ++r)
    v = _mm_min_epi16(
        v, _mm_adds_epi16(_mm_loadu_si128(reinterpret_cast<const __m128i*>(from[r])), _mm_set1_epi16(step[r])));
  _mm_storeu_si128(reinterpret_cast<__m128i*>(best), v);
}
#endif

/// A round of a brick-wise transform.
struct BlockRound {
  double s = 0;
  size_t visits = 0;   ///< bricks swept
  size_t lowered = 0;  ///< voxels lowered (by more than Units::kNoise)
};

/// Which brick along an axis a local coordinate -1 .. 8 lies in: -1, 0 (this one) or 1.
inline int side(int local) { return local < 0 ? -1 : local >= kEdge ? 1 : 0; }

/// What the brick-wise transforms share: which value bricks are pending, and rounds that visit them in raster order,
/// forward then back, until none is. With threads, each takes a slab of brick layers holding about as many value
/// bricks, and a round sweeps the slabs' inner layers, then their first, then their last, so that no two threads
/// touch neighbouring bricks at once.
class BrickRounds {
 public:
  explicit BrickRounds(const Voxelmap& vm)
      : vm_(vm), pending_(std::make_unique<std::atomic<uint8_t>[]>(vm.value_brick_count())) {
    const auto b = vm.brick_dims();
    for (int a = 0; a < 3; ++a) bricks_[a] = int(b[a]);
    for (size_t e = 0; e < vm.value_brick_count(); ++e) pending_[e].store(1, std::memory_order_relaxed);
  }

  /// Rounds until no brick is pending: visit(e, bi, bj, bk) sweeps value brick e (its flag already cleared) and
  /// returns the voxels it lowered.
  template <class Visit>
  std::vector<BlockRound> run(unsigned threads, const Visit& visit) {
    const std::vector<std::pair<int, int>> slabs = balanced_slabs(threads);
    threads = unsigned(slabs.size());
    std::vector<BlockRound> rounds;
    for (int number = 0; number < 64; ++number) {
      const int dir = number % 2 == 0 ? 1 : -1;
      const auto clock = std::chrono::steady_clock::now();
      std::vector<BlockRound> by_thread(threads);
      const int phases = threads == 1 ? 1 : 3;  // one slab: all its layers at once
      for (int phase = 0; phase < phases; ++phase) {
        auto work = [&](unsigned t) {
          const auto [lo, hi] = slabs[t];
          int first = lo, last = hi - 1;  // layers of this phase, inclusive
          if (phases == 3) {
            if (phase == 0) first = lo + 1, last = hi - 2;
            if (phase == 1) last = lo;
            if (phase == 2) first = hi - 1;
          }
          for (int n = 0; n <= last - first; ++n) sweep_layer(dir > 0 ? first + n : last - n, dir, by_thread[t], visit);
        };
        std::vector<std::thread> workers;
        for (unsigned t = 1; t < threads; ++t) workers.emplace_back(work, t);
        work(0);
        for (std::thread& w : workers) w.join();
      }
      BlockRound round;
      for (const BlockRound& r : by_thread) round.visits += r.visits, round.lowered += r.lowered;
      if (round.visits == 0) break;
      round.s = std::chrono::duration<double>(std::chrono::steady_clock::now() - clock).count();
      rounds.push_back(round);
    }
    return rounds;
  }

  /// The 26 neighbours of brick (bi, bj, bk) that are value bricks not pending, by offset + 1 (-1 for the others and
  /// the brick itself): those a lowered voxel next to them may have to wake. Whether there is any.
  bool awake_neighbours(int bi, int bj, int bk, int32_t (&neighbour)[3][3][3]) const {
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

  /// Value brick e is to be swept again.
  void wake(int32_t e) { pending_[size_t(e)].store(1, std::memory_order_relaxed); }

 private:
  /// Up to `threads` slabs [lo, hi) of brick layers, each of at least three layers, holding about as many value
  /// bricks each.
  std::vector<std::pair<int, int>> balanced_slabs(unsigned threads) const {
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

  /// Visits the pending value bricks of brick layer bk in raster order (reversed for dir < 0).
  template <class Visit>
  void sweep_layer(int bk, int dir, BlockRound& round, const Visit& visit) {
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

  const Voxelmap& vm_;
  int bricks_[3];
  std::unique_ptr<std::atomic<uint8_t>[]> pending_;  ///< per value brick: to be swept again
};

/// The same transform (steps to the 26 neighbours, the same least path lengths) run brick by brick: a value brick
/// and a one-voxel apron of its neighbours' values are copied into a 10^3 block, swept forward and back there until
/// a sweep lowers nothing, and written back; a neighbour whose voxel next to a lowered one would be lowered by it
/// is visited again (BrickRounds). The least path lengths do not depend on the order the relaxations run in, so the
/// values are the raster passes' to the byte, whatever the threads.
template <class V>
class BlockTransform {
  using U = Units<V>;
  static constexpr int kPad = kEdge + 2;

 public:
  BlockTransform(const Voxelmap& vm, std::vector<V> seeded) : vm_(vm), values_(std::move(seeded)), rounds_(vm) {
    const auto b = vm.brick_dims();
    for (int a = 0; a < 3; ++a) bricks_[a] = int(b[a]), dims_[a] = int(vm.dims[a]);
    for (int dk = -1; dk <= 1; ++dk)
      for (int dj = -1; dj <= 1; ++dj)
        for (int dx = -1; dx <= 1; ++dx) step_[dk + 1][dj + 1][dx + 1] = U::from_voxels(step_length(dx, dj, dk));
  }

  /// Rounds until no brick is pending; each round's time, visits and lowerings.
  std::vector<BlockRound> run(unsigned threads) {
    return rounds_.run(threads, [this](size_t e, int bi, int bj, int bk) { return visit(e, bi, bj, bk); });
  }

  /// The values in voxels.
  std::vector<float> values() const {
    std::vector<float> voxels(values_.size());
    std::transform(values_.begin(), values_.end(), voxels.begin(), [](V v) { return U::to_voxels(v); });
    return voxels;
  }

 private:
  const V* brick_at(int bi, int bj, int bk) const {
    if (bi < 0 || bj < 0 || bk < 0 || bi >= bricks_[0] || bj >= bricks_[1] || bk >= bricks_[2]) return nullptr;
    const int32_t e = vm_.bricks[vm_.brick_index(uint32_t(bi), uint32_t(bj), uint32_t(bk))];
    return e < 0 ? nullptr : &values_[size_t(e) * Voxelmap::kBrickVoxels];
  }

  /// Whether voxel row (j, k) is one the raster passes visit (rows past the grid are neither read nor lowered).
  bool row_in_grid(int j, int k) const { return j >= 0 && k >= 0 && j < dims_[1] && k < dims_[2]; }

  /// Sweeps brick e in its block until settled, writes it back and marks the neighbours it lowered a voxel next
  /// to; the voxels lowered by more than U::kNoise.
  size_t visit(size_t e, int bi, int bj, int bk) {
    V block[kPad][kPad][kPad];  // [z][y][x], local coordinates + 1
    fill(bi, bj, bk, block);
    V before[kEdge][kEdge][kEdge];
    for (int z = 0; z < kEdge; ++z)
      for (int y = 0; y < kEdge; ++y) std::memcpy(before[z][y], &block[z + 1][y + 1][1], kEdge * sizeof(V));
    // Settled at the first sweep after the first that lowers nothing: the sweep before it (the other direction)
    // left each voxel at most its neighbours on that side plus their step, and nothing has moved since.
    for (int n = 0; n < 64; ++n)
      if (!this->sweep(bj, bk, block, n % 2 == 0 ? 1 : -1) && n >= 1) break;
    V* own = &values_[e * Voxelmap::kBrickVoxels];
    int32_t neighbour[3][3][3];
    const bool any_awake = rounds_.awake_neighbours(bi, bj, bk, neighbour);
    size_t lowered = 0;
    for (int z = 0; z < kEdge; ++z)
      for (int y = 0; y < kEdge; ++y) {
        if (!row_in_grid(bj * kEdge + y, bk * kEdge + z)) continue;
        std::memcpy(own + (z * kEdge + y) * kEdge, &block[z + 1][y + 1][1], kEdge * sizeof(V));
        for (int x = 0; x < kEdge; ++x) {
          if (!(block[z + 1][y + 1][x + 1] < before[z][y][x])) continue;
          lowered += before[z][y][x] - block[z + 1][y + 1][x + 1] > U::kNoise;
          if (any_awake && (x == 0 || y == 0 || z == 0 || x == kEdge - 1 || y == kEdge - 1 || z == kEdge - 1))
            wake_lowerable(block, x, y, z, neighbour);
        }
      }
    return lowered;
  }

  /// Face voxel (x, y, z) of the block's brick was lowered: wakes the awake neighbour bricks holding a voxel next to
  /// it that its new value lowers (the block's apron holds their values, which no thread writes during this phase).
  void wake_lowerable(const V (&block)[kPad][kPad][kPad], int x, int y, int z, int32_t (&neighbour)[3][3][3]) {
    const V v = block[z + 1][y + 1][x + 1];
    for (int ez = -1; ez <= 1; ++ez)
      for (int ey = -1; ey <= 1; ++ey)
        for (int ex = -1; ex <= 1; ++ex) {
          int32_t& n = neighbour[side(z + ez) + 1][side(y + ey) + 1][side(x + ex) + 1];
          if (n < 0) continue;  // the brick itself, no value brick, or pending already
          const V w = block[z + 1 + ez][y + 1 + ey][x + 1 + ex];
          if (U::lower(w, v, step_[ez + 1][ey + 1][ex + 1]) < w) rounds_.wake(n), n = -1;
        }
  }

  /// The block of brick (bi, bj, bk): its values and a one-voxel apron of its value-brick neighbours' (far
  /// elsewhere, and in rows past the grid).
  void fill(int bi, int bj, int bk, V (&block)[kPad][kPad][kPad]) const {
    std::fill(&block[0][0][0], &block[0][0][0] + kPad * kPad * kPad, U::kFar);
    // Along one axis, offset d: the block's range [lo, lo + n) reads the neighbour's local coordinates from `from`.
    auto span = [](int d, int& lo, int& n, int& from) {
      lo = d < 0 ? 0 : d == 0 ? 1 : kEdge + 1;
      n = d == 0 ? kEdge : 1;
      from = d < 0 ? kEdge - 1 : 0;
    };
    for (int dk = -1; dk <= 1; ++dk)
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const V* src = brick_at(bi + di, bj + dj, bk + dk);
          if (!src) continue;
          int xl, xn, xf, yl, yn, yf, zl, zn, zf;
          span(di, xl, xn, xf);
          span(dj, yl, yn, yf);
          span(dk, zl, zn, zf);
          for (int z = 0; z < zn; ++z)
            for (int y = 0; y < yn; ++y) {
              if (!row_in_grid((bj + dj) * kEdge + yf + y, (bk + dk) * kEdge + zf + z)) continue;
              std::memcpy(&block[zl + z][yl + y][xl], src + ((zf + z) * kEdge + yf + y) * kEdge + xf, xn * sizeof(V));
            }
        }
  }

  /// One sweep over the brick's voxels in the block, forward (dir 1) or back; whether it lowered any.
  bool sweep(int bj, int bk, V (&block)[kPad][kPad][kPad], int dir) const {
    bool changed = false;
    for (int n = 0; n < kEdge; ++n) {
      const int z = dir > 0 ? n + 1 : kEdge - n;
      for (int m = 0; m < kEdge; ++m) {
        const int y = dir > 0 ? m + 1 : kEdge - m;
        if (!row_in_grid(bj * kEdge + y - 1, bk * kEdge + z - 1)) continue;
        // The 12 neighbours visited before a voxel outside its row: 9 in the plane before, 3 in the row before.
        const V* from[12];
        V steps[12];
        int r = 0;
        for (int dj = -1; dj <= 1; ++dj)
          for (int dx = -1; dx <= 1; ++dx, ++r)
            from[r] = &block[z - dir][y + dj][1 + dx], steps[r] = step_[2][dj + 1][dx + 1];
        for (int dx = -1; dx <= 1; ++dx, ++r) from[r] = &block[z][y - dir][1 + dx], steps[r] = step_[1][2][dx + 1];
        V best[kEdge];
        least_of_rows(&block[z][y][1], from, steps, best);
        V* row = block[z][y];
        V run = row[dir > 0 ? 0 : kEdge + 1];
        for (int s = 0; s < kEdge; ++s) {
          const int x = dir > 0 ? s : kEdge - 1 - s;
          run = U::lower(best[x], run, step_[1][1][2]);
          changed |= run < row[x + 1];
          row[x + 1] = run;
        }
      }
    }
    return changed;
  }

  const Voxelmap& vm_;
  std::vector<V> values_;
  int bricks_[3], dims_[3];
  BrickRounds rounds_;
  V step_[3][3][3];  ///< step lengths by dk + 1, dj + 1, dx + 1
};

/// What a producer of a format 2.2 would run: the brick-wise transform on the value bricks' 16-bit codes in place,
/// in steps of the estimate quantum q, all in integers. Stored distances are sources (|d| in steps of q, rounded up)
/// and are never lowered; each estimate becomes the least of its seed (over its cell's lattice points p,
/// ceil(l_p / q) plus the length of a path of voxel steps to p) and its value-brick neighbours' values plus their
/// step (1, sqrt 2, sqrt 3 voxels in steps of q, rounded up), keeping its sign; voxels past the grid take no part.
/// No array beside the codes, and a reader can check every estimate from its neighbours (`check`).
class CodeTransform {
 public:
  static constexpr int16_t kFar = 32767;
  static constexpr int kMaxSteps = 16383;  // the largest magnitude an estimate code holds

  CodeTransform(const Voxelmap& vm, std::vector<int16_t>& codes) : vm_(vm), codes_(codes), rounds_(vm) {
    const auto b = vm.brick_dims();
    for (int a = 0; a < 3; ++a) bricks_[a] = int(b[a]), dims_[a] = int(vm.dims[a]);
    const double per_voxel = vm.voxel_size / vm.estimate_quantum;
    for (int k = 0; k < 4; ++k) axis_step_[k] = int(std::ceil(std::sqrt(double(k)) * per_voxel - 1e-9));
    for (int dk = -1; dk <= 1; ++dk)
      for (int dj = -1; dj <= 1; ++dj)
        for (int dx = -1; dx <= 1; ++dx)
          step_[dk + 1][dj + 1][dx + 1] = int16_t(axis_step_[(dx != 0) + (dj != 0) + (dk != 0)]);
    stored_.resize(16385);
    for (int x = 0; x <= 16384; ++x)
      stored_[size_t(x)] =
          int16_t(std::min<double>(kMaxSteps, std::ceil(x * vm.distance_quantum / vm.estimate_quantum - 1e-9)));
    // Path lengths to offsets -8 .. 8, each row of 17 reversed (a row of voxels reads them in increasing order).
    reversed_.resize(17 * 17 * 17);
    for (int z = 0; z < 17; ++z)
      for (int y = 0; y < 17; ++y)
        for (int x = 0; x < 17; ++x)
          reversed_[size_t((z * 17 + y) * 17 + 16 - x)] = int16_t(path_steps(x - 8, y - 8, z - 8));
  }

  /// Seeds every estimate from its cell's lattice points; bricks shared out over `threads`.
  void seed(unsigned threads) {
    for_each_value_brick(vm_, threads, [&](size_t b) { seed_brick(b); });
  }

  /// Rounds until settled (BrickRounds), each brick swept as BlockTransform sweeps it, fixed voxels kept.
  std::vector<BlockRound> run(unsigned threads) {
    return rounds_.run(threads, [this](size_t e, int bi, int bj, int bk) { return visit(e, bi, bj, bk); });
  }

  /// The estimates that are not the least of their seed and their neighbours' values plus their step (what a
  /// validator would count); bricks shared out over `threads`.
  size_t check(unsigned threads) const {
    std::atomic<size_t> wrong{0};
    for_each_value_brick(vm_, threads, [&](size_t b) {
      const int bi = int(b % size_t(bricks_[0])), bj = int(b / size_t(bricks_[0]) % size_t(bricks_[1])),
                bk = int(b / (size_t(bricks_[0]) * size_t(bricks_[1])));
      Block block;
      fill(bi, bj, bk, block);
      int16_t seeds[kEdge][kEdge][kEdge];
      seed_values(bi, bj, bk, seeds);
      size_t here = 0;
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
          for (int x = 0; x < kEdge; ++x) here += !block.fixed[z - 1][y - 1][x] && best[x] != block.v[z][y][x + 1];
        }
      wrong += here;
    });
    return wrong;
  }

  /// Per value-brick voxel (the value bricks' order): |d| / h where stored, the estimate's magnitude in voxels,
  /// 1e30 past the grid.
  std::vector<float> values() const {
    std::vector<float> out(codes_.size(), 1e30f);
    for (size_t b = 0; b < vm_.bricks.size(); ++b) {
      if (vm_.bricks[b] < 0) continue;
      const int bi = int(b % size_t(bricks_[0])), bj = int(b / size_t(bricks_[0]) % size_t(bricks_[1])),
                bk = int(b / (size_t(bricks_[0]) * size_t(bricks_[1])));
      const size_t first = size_t(vm_.bricks[b]) * Voxelmap::kBrickVoxels;
      for (int l = 0; l < int(Voxelmap::kBrickVoxels); ++l)
        if (in_grid(bi * kEdge + (l & 7), bj * kEdge + (l >> 3 & 7), bk * kEdge + (l >> 6)))
          out[first + size_t(l)] = float(std::abs(vm_.decode(codes_[first + size_t(l)])) / vm_.voxel_size);
    }
    return out;
  }

 private:
  struct Block {
    int16_t v[kEdge + 2][kEdge + 2][kEdge + 2];  ///< [z][y][x], local + 1: magnitudes in steps of q
    bool fixed[kEdge][kEdge][kEdge];             ///< the brick's stored voxels and those past the grid
  };

  bool in_grid(int i, int j, int k) const { return i < dims_[0] && j < dims_[1] && k < dims_[2]; }

  /// The length, in steps of q, of the shortest path of voxel steps along (a, b, c).
  int path_steps(int a, int b, int c) const {
    std::array<int, 3> s = {std::abs(a), std::abs(b), std::abs(c)};
    std::sort(s.begin(), s.end());
    return s[0] * axis_step_[3] + (s[1] - s[0]) * axis_step_[2] + (s[2] - s[1]) * axis_step_[1];
  }

  int16_t magnitude(int16_t code) const {
    const int m = std::abs(code >> 1);
    const int16_t as_stored = stored_[size_t(m)];
    return Voxelmap::code_is_stored(code) ? as_stored : int16_t(m);
  }

  /// The seeds of brick (bi, bj, bk)'s voxels: the least over the cell's lattice points p of ceil(l_p / q) plus
  /// the path to p, at most kMaxSteps.
  void seed_values(int bi, int bj, int bk, int16_t (&seeds)[kEdge][kEdge][kEdge]) const {
    int corner[8], cx[2], cy[2], cz[2];
    for (int q = 0; q < 2; ++q) {
      cx[q] = int(Voxelmap::lattice_coordinate(uint32_t(bi + q), vm_.dims[0]));
      cy[q] = int(Voxelmap::lattice_coordinate(uint32_t(bj + q), vm_.dims[1]));
      cz[q] = int(Voxelmap::lattice_coordinate(uint32_t(bk + q), vm_.dims[2]));
    }
    for (int q = 0; q < 8; ++q)
      corner[q] = int(std::min<double>(
          kMaxSteps, std::ceil(vm_.lattice[vm_.lattice_index(uint32_t(bi + (q & 1)), uint32_t(bj + (q >> 1 & 1)),
                                                             uint32_t(bk + (q >> 2)))] /
                                   vm_.estimate_quantum -
                               1e-9)));
    for (int lk = 0; lk < kEdge; ++lk)
      for (int lj = 0; lj < kEdge; ++lj) {
        const int j = bj * kEdge + lj, k = bk * kEdge + lk;
        // 16-bit sums (at most 16383 + 8 * 28): SSE2's minimum of 16-bit lanes.
        const int16_t* lengths[8];
        int16_t values[8];
        for (int q = 0; q < 8; ++q) {
          lengths[q] = &reversed_[size_t(((cz[q >> 2] - k + 8) * 17 + cy[q >> 1 & 1] - j + 8) * 17 + 8 -
                                         (cx[q & 1] - bi * kEdge))];
          values[q] = int16_t(corner[q]);
        }
        const int16_t far[kEdge] = {kMaxSteps, kMaxSteps, kMaxSteps, kMaxSteps,
                                    kMaxSteps, kMaxSteps, kMaxSteps, kMaxSteps};
        least_of_rows(far, lengths, values, seeds[lk][lj], 8);
      }
  }

  void seed_brick(size_t b) {
    const int bi = int(b % size_t(bricks_[0])), bj = int(b / size_t(bricks_[0]) % size_t(bricks_[1])),
              bk = int(b / (size_t(bricks_[0]) * size_t(bricks_[1])));
    int16_t seeds[kEdge][kEdge][kEdge];
    seed_values(bi, bj, bk, seeds);
    int16_t* codes = &codes_[size_t(vm_.bricks[b]) * Voxelmap::kBrickVoxels];
    for (int l = 0; l < int(Voxelmap::kBrickVoxels); ++l) {
      const int x = l & 7, y = l >> 3 & 7, z = l >> 6;
      if (Voxelmap::code_is_stored(codes[l]) || !in_grid(bi * kEdge + x, bj * kEdge + y, bk * kEdge + z)) continue;
      codes[l] = int16_t((codes[l] < 0 ? -2 : 2) * seeds[z][y][x]);
    }
  }

  const int16_t* brick_at(int bi, int bj, int bk) const {
    if (bi < 0 || bj < 0 || bk < 0 || bi >= bricks_[0] || bj >= bricks_[1] || bk >= bricks_[2]) return nullptr;
    const int32_t e = vm_.bricks[vm_.brick_index(uint32_t(bi), uint32_t(bj), uint32_t(bk))];
    return e < 0 ? nullptr : &codes_[size_t(e) * Voxelmap::kBrickVoxels];
  }

  /// Brick (bi, bj, bk)'s magnitudes and a one-voxel apron of its value-brick neighbours' (far elsewhere and past
  /// the grid), and which of its voxels are fixed.
  void fill(int bi, int bj, int bk, Block& block) const {
    std::fill(&block.v[0][0][0], &block.v[0][0][0] + (kEdge + 2) * (kEdge + 2) * (kEdge + 2), kFar);
    for (int dk = -1; dk <= 1; ++dk)
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int16_t* src = brick_at(bi + di, bj + dj, bk + dk);
          if (!src) continue;
          // Along each axis the block's range [lo, lo + n) reads the neighbour's local coordinates from `from`.
          int lo[3], n[3], from[3];
          const int d[3] = {di, dj, dk};
          for (int a = 0; a < 3; ++a) {
            lo[a] = d[a] < 0 ? 0 : d[a] == 0 ? 1 : kEdge + 1;
            n[a] = d[a] == 0 ? kEdge : 1;
            from[a] = d[a] < 0 ? kEdge - 1 : 0;
          }
          const int i0 = (bi + di) * kEdge + from[0], j0 = (bj + dj) * kEdge + from[1],
                    k0 = (bk + dk) * kEdge + from[2];
          if (in_grid(i0 + n[0] - 1, j0 + n[1] - 1, k0 + n[2] - 1)) {  // all of it (most bricks)
            for (int z = 0; z < n[2]; ++z)
              for (int y = 0; y < n[1]; ++y) {
                const int16_t* row = src + ((from[2] + z) * kEdge + from[1] + y) * kEdge + from[0];
                int16_t* to = &block.v[lo[2] + z][lo[1] + y][lo[0]];
                for (int x = 0; x < n[0]; ++x) to[x] = magnitude(row[x]);
              }
            continue;
          }
          for (int z = 0; z < n[2]; ++z)
            for (int y = 0; y < n[1]; ++y)
              for (int x = 0; x < n[0]; ++x)
                if (in_grid(i0 + x, j0 + y, k0 + z))
                  block.v[lo[2] + z][lo[1] + y][lo[0] + x] =
                      magnitude(src[((from[2] + z) * kEdge + from[1] + y) * kEdge + from[0] + x]);
        }
    const int16_t* own = brick_at(bi, bj, bk);
    for (int l = 0; l < int(Voxelmap::kBrickVoxels); ++l) {
      const int x = l & 7, y = l >> 3 & 7, z = l >> 6;
      block.fixed[z][y][x] =
          Voxelmap::code_is_stored(own[l]) || !in_grid(bi * kEdge + x, bj * kEdge + y, bk * kEdge + z);
    }
  }

  size_t visit(size_t e, int bi, int bj, int bk) {
    Block block;
    fill(bi, bj, bk, block);
    int16_t before[kEdge][kEdge][kEdge];
    for (int z = 0; z < kEdge; ++z)
      for (int y = 0; y < kEdge; ++y) std::memcpy(before[z][y], &block.v[z + 1][y + 1][1], kEdge * sizeof(int16_t));
    for (int n = 0; n < 64; ++n)
      if (!sweep(block, n % 2 == 0 ? 1 : -1) && n >= 1) break;
    int32_t neighbour[3][3][3];
    const bool any_awake = rounds_.awake_neighbours(bi, bj, bk, neighbour);
    int16_t* codes = &codes_[e * Voxelmap::kBrickVoxels];
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

  void wake_lowerable(const Block& block, int x, int y, int z, int32_t (&neighbour)[3][3][3]) {
    const int v = block.v[z + 1][y + 1][x + 1];
    for (int ez = -1; ez <= 1; ++ez)
      for (int ey = -1; ey <= 1; ++ey)
        for (int ex = -1; ex <= 1; ++ex) {
          int32_t& n = neighbour[side(z + ez) + 1][side(y + ey) + 1][side(x + ex) + 1];
          if (n < 0) continue;
          if (v + step_[ez + 1][ey + 1][ex + 1] < block.v[z + 1 + ez][y + 1 + ey][x + 1 + ex]) rounds_.wake(n), n = -1;
        }
  }

  /// One sweep over the brick's voxels, forward (dir 1) or back; whether it lowered any. Fixed voxels keep their
  /// values (and pass them on).
  bool sweep(Block& block, int dir) const {
    bool changed = false;
    for (int n = 0; n < kEdge; ++n) {
      const int z = dir > 0 ? n + 1 : kEdge - n;
      for (int m = 0; m < kEdge; ++m) {
        const int y = dir > 0 ? m + 1 : kEdge - m;
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

  const Voxelmap& vm_;
  std::vector<int16_t>& codes_;
  int bricks_[3], dims_[3];
  int axis_step_[4];               ///< steps of q along 0 .. 3 axes at once, rounded up
  int16_t step_[3][3][3];          ///< the same by dk + 1, dj + 1, dx + 1
  std::vector<int16_t> stored_;    ///< |c >> 1| of a stored code in steps of q, rounded up
  std::vector<int16_t> reversed_;  ///< path lengths to offsets -8 .. 8, rows reversed
  BrickRounds rounds_;
};

double seconds_since(std::chrono::steady_clock::time_point& start) {
  const auto now = std::chrono::steady_clock::now();
  const double s = std::chrono::duration<double>(now - start).count();
  start = now;
  return s;
}

struct Timing {
  double seed_s = 0;
  struct Pass {
    double s;
    size_t lowered;
    float largest_drop;  // voxels
    size_t visits = 0;   // bricks swept (brick-wise rounds)
  };
  std::vector<Pass> passes;
};

/// Format 2.1's estimates of every value brick (what the seed would replace), on `threads` threads; seconds.
double time_format21_estimates(const Voxelmap& vm, unsigned threads) {
  std::vector<int16_t> codes = vm.brick_values;
  const auto start = std::chrono::steady_clock::now();
  const auto b = vm.brick_dims();
  for_each_value_brick(vm, threads, [&](size_t n) {
    voxfmt::fill_brick_estimates(vm, uint32_t(n % b[0]), uint32_t(n / b[0] % b[1]), uint32_t(n / (size_t(b[0]) * b[1])),
                                 &codes[size_t(vm.bricks[n]) * Voxelmap::kBrickVoxels]);
  });
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

/// The transform of `vm`'s value bricks, timed; its values in `values`.
template <int Reach, class V>
Timing transform(const Voxelmap& vm, unsigned threads, bool skip_settled, std::vector<float>& values) {
  Timing timing;
  auto clock = std::chrono::steady_clock::now();
  ChamferTransform<Reach, V> transform(vm);
  transform.seed(threads);
  transform.split(threads);
  timing.seed_s = seconds_since(clock);
  // Settled once a pass changes nothing (two in a row with slabs: a slab sees its neighbours' last changes a pass
  // late).
  const int quiet_needed = threads > 1 ? 2 : 1;
  for (int p = 1, quiet = 0; p <= 32 && quiet < quiet_needed; ++p) {
    const auto outcome = transform.pass(p, skip_settled);
    timing.passes.push_back({seconds_since(clock), outcome.lowered, outcome.largest_drop});
    quiet = outcome.changed == 0 && p >= 2 ? quiet + 1 : 0;
  }
  values = transform.values();
  return timing;
}

/// The brick-wise transform of `vm`'s value bricks (the same seed), timed: its rounds as passes.
template <class V>
Timing block_transform(const Voxelmap& vm, unsigned threads, std::vector<float>& values) {
  Timing timing;
  auto clock = std::chrono::steady_clock::now();
  ChamferTransform<1, V> seeded(vm);
  seeded.seed(threads);
  BlockTransform<V> transform(vm, seeded.take());
  timing.seed_s = seconds_since(clock);
  for (const auto& round : transform.run(threads))
    timing.passes.push_back({round.s, round.lowered, 0.0f, round.visits});
  values = transform.values();
  return timing;
}

/// The in-place transform of a copy of `vm`'s codes (the copy not timed), timed: its rounds as passes; its values
/// in `values`, and in `check_s` / `wrong` the time of a check of every estimate and what it found.
Timing code_transform(const Voxelmap& vm, unsigned threads, std::vector<float>& values, double& check_s,
                      size_t& wrong) {
  std::vector<int16_t> codes = vm.brick_values;
  Timing timing;
  auto clock = std::chrono::steady_clock::now();
  CodeTransform transform(vm, codes);
  transform.seed(threads);
  timing.seed_s = seconds_since(clock);
  for (const auto& round : transform.run(threads))
    timing.passes.push_back({round.s, round.lowered, 0.0f, round.visits});
  seconds_since(clock);
  wrong = transform.check(threads);
  check_s = seconds_since(clock);
  values = transform.values();
  return timing;
}

struct Settings {
  std::string asset_path, values_path, json_path;
  uint64_t max_memory_mib = voxfmt::ReadOptions::kDefaultReadMemoryBytes >> 20;
  int reach = 1;
  unsigned threads = 1;
  bool every_brick = false, fixed16 = false, by_brick = false, in_codes = false;
};

void add_options(CLI::App& app, Settings& s) {
  app.add_option("asset", s.asset_path, "a baked asset")->required();
  app.add_option("--values", s.values_path, "write the values here (float32, voxels, value bricks' order)");
  app.add_option("--json", s.json_path, "write the figures here");
  app.add_option("--max-memory", s.max_memory_mib, "MiB the read may take (a 4096^3 bake needs ~2.1 GB)")
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 30));
  app.add_option("--reach", s.reach, "steps to the 26 neighbours (1) or the 5^3 (2)")->check(CLI::IsMember({1, 2}));
  app.add_option(
         "--threads", s.threads,
         "threads: the seed's bricks shared out, the passes over as many slabs of brick layers (the same values)")
      ->check(CLI::Range(1u, 64u));
  app.add_flag("--every-brick", s.every_brick,
               "passes after the second visit every value brick (default: only those near a voxel lowered since the "
               "pass before)");
  app.add_flag("--fixed16", s.fixed16,
               "hold the values as 16-bit sixteenths of a voxel (steps and seeds rounded up) instead of floats");
  app.add_flag("--by-brick", s.by_brick,
               "run the transform brick by brick (a brick and a one-voxel apron swept until settled, neighbours woken "
               "where it lowered a voxel next to them; threads on slabs of brick layers) instead of raster passes: "
               "the same values (reach 1)");
  app.add_flag("--in-codes", s.in_codes,
               "what a producer would run: the brick-wise transform in place on (a copy of) the 16-bit codes, in "
               "steps of the estimate quantum, stored distances fixed, voxels past the grid left out; then a check of "
               "every estimate against its seed and neighbours, timed");
}

/// The transform `s` asks for, timed; its values, and for --in-codes the check's time and findings.
Timing run_transform(const Voxelmap& vm, const Settings& s, std::vector<float>& values, double& check_s,
                     size_t& wrong) {
  if (s.in_codes) return code_transform(vm, s.threads, values, check_s, wrong);
  if (s.by_brick)
    return s.fixed16 ? block_transform<int16_t>(vm, s.threads, values) : block_transform<float>(vm, s.threads, values);
  const bool skip = !s.every_brick;
  if (s.fixed16)
    return s.reach == 2 ? transform<2, int16_t>(vm, s.threads, skip, values)
                        : transform<1, int16_t>(vm, s.threads, skip, values);
  return s.reach == 2 ? transform<2, float>(vm, s.threads, skip, values)
                      : transform<1, float>(vm, s.threads, skip, values);
}

/// Prints the table of `timing` and returns its figures (JSON).
nlohmann::json report(const Voxelmap& vm, const Settings& s, const Timing& timing) {
  size_t estimates = 0;
  for (int16_t code : vm.brick_values) estimates += code != 0 && !Voxelmap::code_is_stored(code);
  std::printf("estimate-transform: %s: %zu value bricks, %zu of their voxels estimates\n", s.asset_path.c_str(),
              vm.brick_values.size() / Voxelmap::kBrickVoxels, estimates);
  std::printf("| stage | s | voxels lowered | largest drop (voxels) |\n|---|---|---|---|\n| seed | %.3f | | |\n",
              timing.seed_s);
  nlohmann::json figures = {{"asset", s.asset_path},
                            {"value_brick_voxels", vm.brick_values.size()},
                            {"estimates", estimates},
                            {"seed_s", timing.seed_s},
                            {"passes", nlohmann::json::array()}};
  figures["reach"] = s.reach;
  figures["threads"] = s.threads;
  figures["skip_settled"] = !s.every_brick;
  figures["values"] = s.fixed16 || s.in_codes ? "int16, 1/16 voxel" : "float32";
  figures["by_brick"] = s.by_brick;
  figures["in_codes"] = s.in_codes;
  double total = timing.seed_s;
  for (size_t p = 0; p < timing.passes.size(); ++p) {
    const Timing::Pass& pass = timing.passes[p];
    total += pass.s;
    if (s.by_brick)
      std::printf("| round %zu (%zu bricks) | %.3f | %zu | |\n", p + 1, pass.visits, pass.s, pass.lowered);
    else
      std::printf("| pass %zu (%s) | %.3f | %zu | %.4f |\n", p + 1, p % 2 == 0 ? "forward" : "back", pass.s,
                  pass.lowered, double(pass.largest_drop));
    figures["passes"].push_back(
        {{"s", pass.s}, {"lowered", pass.lowered}, {"largest_drop", pass.largest_drop}, {"visits", pass.visits}});
  }
  const double per_voxel_ns = 1e9 * total / double(vm.brick_values.size());
  std::printf("| all | %.3f | (%.1f ns a value-brick voxel) | |\n", total, per_voxel_ns);
  figures["total_s"] = total;
  figures["ns_per_value_brick_voxel"] = per_voxel_ns;
  return figures;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"The cost of a chamfer transform of band sources over an asset's value bricks (bench)"};
  Settings s;
  add_options(app, s);
  CLI11_PARSE(app, argc, argv);
  if (s.in_codes) s.by_brick = true;
  if (s.by_brick && s.reach != 1) {
    std::cerr << "estimate-transform: --by-brick and --in-codes take steps to the 26 neighbours only (--reach 1)\n";
    return 2;
  }
  voxfmt::ReadOptions read;
  read.max_memory_bytes = s.max_memory_mib << 20;
  auto asset = voxfmt::read_asset(s.asset_path, nullptr, read);
  if (!asset) {
    std::cerr << "estimate-transform: " << asset.error().describe() << "\n";
    return 2;
  }
  const Voxelmap& vm = asset->voxelmap;
  std::vector<float> values;
  double check_s = 0;
  size_t wrong = 0;
  nlohmann::json figures = report(vm, s, run_transform(vm, s, values, check_s, wrong));
  const double format21_s = time_format21_estimates(vm, s.threads);
  std::printf("| format 2.1's estimates, %u thread(s) (what the seed replaces) | %.3f | | |\n", s.threads, format21_s);
  figures["format21_estimates_s"] = format21_s;
  if (s.in_codes) {
    std::printf("| check of every estimate (what a validator would run) | %.3f | %zu wrong | |\n", check_s, wrong);
    figures["check_s"] = check_s;
    figures["check_wrong"] = wrong;
  }
  if (!s.values_path.empty()) {
    std::ofstream out(s.values_path, std::ios::binary);
    out.write(reinterpret_cast<const char*>(values.data()), std::streamsize(values.size() * sizeof(float)));
    if (!out.flush()) {
      std::cerr << "estimate-transform: cannot write " << s.values_path << "\n";
      return 1;
    }
  }
  if (!s.json_path.empty() && !(std::ofstream(s.json_path) << figures.dump(1) << "\n").flush()) {
    std::cerr << "estimate-transform: cannot write " << s.json_path << "\n";
    return 1;
  }
  return 0;
}
