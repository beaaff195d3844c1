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
// `--in-codes` is what a format 2.2 producer would run (libvoxfmt's voxfmt/detail/estimate_transform.h): that, in place
// on a copy of the 16-bit codes in steps of the estimate quantum (stored distances fixed, voxels past the grid left
// out), then a check of every estimate against its seed and neighbours (what a validator would run), timed.
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

#include "voxfmt/detail/estimate_transform.h"
#include "voxfmt/io.h"

namespace {

using voxfmt::Voxelmap;
using voxfmt::detail::brick_coordinates;
using voxfmt::detail::brick_side;
using voxfmt::detail::BrickRound;
using voxfmt::detail::BrickRounds;
using voxfmt::detail::least_of_rows;
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
    voxfmt::detail::for_each_value_brick_shared(vm_, threads, [&](size_t b) { seed_brick(b, reversed); });
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
    const auto [bi, bj, bk] = brick_coordinates(vm_, b);
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
  std::vector<BrickRound> run(unsigned threads) {
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
          int32_t& n = neighbour[brick_side(z + ez) + 1][brick_side(y + ey) + 1][brick_side(x + ex) + 1];
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
  voxfmt::detail::for_each_value_brick_shared(vm, threads, [&](size_t n) {
    const auto [bi, bj, bk] = brick_coordinates(vm, n);
    voxfmt::fill_brick_estimates(vm, uint32_t(bi), uint32_t(bj), uint32_t(bk),
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

/// Per value-brick voxel of `codes` (the value bricks' order): |d| / h where stored, the estimate's magnitude in
/// voxels, 1e30 past the grid.
std::vector<float> code_values(const Voxelmap& vm, const std::vector<int16_t>& codes) {
  std::vector<float> out(codes.size(), 1e30f);
  for (size_t b = 0; b < vm.bricks.size(); ++b) {
    if (vm.bricks[b] < 0) continue;
    const auto [bi, bj, bk] = brick_coordinates(vm, b);
    const size_t first = size_t(vm.bricks[b]) * Voxelmap::kBrickVoxels;
    for (int l = 0; l < int(Voxelmap::kBrickVoxels); ++l) {
      const uint32_t i = uint32_t(bi * kEdge + (l & 7)), j = uint32_t(bj * kEdge + (l >> 3 & 7)),
                     k = uint32_t(bk * kEdge + (l >> 6));
      if (i < vm.dims[0] && j < vm.dims[1] && k < vm.dims[2])
        out[first + size_t(l)] = float(std::abs(vm.decode(codes[first + size_t(l)])) / vm.voxel_size);
    }
  }
  return out;
}

/// The in-place transform of a copy of `vm`'s codes (the copy not timed), timed: its rounds as passes; its values
/// in `values`, and in `check_s` / `wrong` the time of a check of every estimate and what it found.
Timing code_transform(const Voxelmap& vm, unsigned threads, std::vector<float>& values, double& check_s,
                      size_t& wrong) {
  std::vector<int16_t> codes = vm.brick_values;
  Timing timing;
  auto clock = std::chrono::steady_clock::now();
  voxfmt::detail::EstimateTransform transform(vm, codes);
  transform.seed(threads);
  timing.seed_s = seconds_since(clock);
  for (const auto& round : transform.settle(threads))
    timing.passes.push_back({round.s, round.lowered, 0.0f, round.visits});
  seconds_since(clock);
  wrong = transform.count_unsettled(threads);
  check_s = seconds_since(clock);
  values = code_values(vm, codes);
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
