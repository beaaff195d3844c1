// Format 1.x voxelmaps: dense `layers` (i16) and `distances` (f32, NaN where not stored) per voxel. They are read
// a slab of 8 (+1) z layers at a time and converted to the bricks of format 2.0, so memory follows the slab and
// the surface, not the whole grid. The 1.x per-voxel rules are checked on the way when asked to.
#include <cmath>
#include <limits>

#include "load.h"

namespace voxfmt::detail {

namespace {

constexpr uint32_t kEdge = Voxelmap::kBrickEdge;

float float_not_below(double value) {
  float f = float(value);
  if (double(f) < value) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

std::string voxel_name(uint64_t i, uint64_t j, uint64_t k) {
  return "voxel (" + std::to_string(i) + ", " + std::to_string(j) + ", " + std::to_string(k) + ")";
}

std::string fmt(double v) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", v);
  return text;
}

// The 1.x rules of spec 1.1 §3 (validate --level full), each reported once.
class LegacyRules {
 public:
  LegacyRules(std::vector<Issue>& findings, const std::string& path, const Voxelmap& vm, bool closed)
      : findings_(findings),
        path_(path),
        vm_(vm),
        closed_(closed),
        min_outside_(int(std::floor(vm.distance_band + 0.5))),
        band_m_(vm.distance_band * vm.voxel_size) {}

  void voxel(uint64_t i, uint64_t j, uint64_t k, int layer, float d) {
    if (!std::isnan(d)) {
      // Stored only within the band (spec §3.1): the conversion clamps codes to it, so a distance beyond it would
      // silently read as the band's edge.
      if (!outside_ && std::abs(double(d)) > band_m_ + 0.5 * vm_.distance_quantum) {
        report(
            IssueCode::DistanceOutsideBand, path_ + "/distances",
            voxel_name(i, j, k) + " stores the distance " + fmt(d) + " m, beyond the band of " + fmt(band_m_) + " m");
        outside_ = true;
      }
      const double expected = std::clamp(std::floor(-double(d) / vm_.voxel_size + 0.5), -32767.0, 32767.0);
      if (!mismatch_ && layer != int(expected)) {
        report(IssueCode::LayerDistanceMismatch, path_ + "/layers",
               voxel_name(i, j, k) + " has layer " + std::to_string(layer) + " but its distance " + fmt(d) +
                   " m gives " + std::to_string(int(expected)));
        mismatch_ = true;
      }
    } else if (!too_small_ && std::abs(layer) < min_outside_) {
      report(IssueCode::LayerOutsideBandTooSmall, path_ + "/layers",
             voxel_name(i, j, k) + " has no stored distance but layer " + std::to_string(layer) +
                 " (|layer| must be >= " + std::to_string(min_outside_) + " outside the band)");
      too_small_ = true;
    }
  }
  // 6-neighbours a and b (b one step up along some axis).
  void neighbours(uint64_t i, uint64_t j, uint64_t k, int layer_a, float d_a, int layer_b, float d_b) {
    if (!closed_) return;  // across a closed hole both rules may break (spec 1.1 §3)
    if (!step_ && std::abs(layer_a - layer_b) > 1) {
      report(IssueCode::LayerStepTooLarge, path_ + "/layers",
             voxel_name(i, j, k) + " and a 6-neighbour differ by " + std::to_string(std::abs(layer_a - layer_b)) +
                 " layers");
      step_ = true;
    }
    if (!jump_ && !std::isnan(d_a) && !std::isnan(d_b) &&
        std::abs(double(d_a) - double(d_b)) > vm_.voxel_size * std::sqrt(3.0)) {
      report(IssueCode::DistanceJump, path_ + "/distances",
             voxel_name(i, j, k) +
                 " and a 6-neighbour are one voxel apart but their distances differ by more than the voxel "
                 "diagonal: " +
                 fmt(std::abs(double(d_a) - double(d_b)) / vm_.voxel_size) + " voxels");
      jump_ = true;
    }
  }

 private:
  void report(IssueCode code, const std::string& path, const std::string& message) {
    findings_.push_back(Issue{code, severity_of(code), path, message});
  }
  std::vector<Issue>& findings_;
  const std::string& path_;
  const Voxelmap& vm_;
  bool closed_;
  int min_outside_;
  double band_m_;
  bool mismatch_ = false, too_small_ = false, step_ = false, jump_ = false, outside_ = false;
};

/// One slab of a 1.x grid: the voxel layers of one layer of bricks (z0 .. z_end - 1) and the next layer (the
/// neighbours the rules compare), as read from the file.
struct DenseSlab {
  int64_t W, H, D, z0, z_end;
  std::vector<int16_t> layers;
  std::vector<float> distances;
  size_t at(int64_t i, int64_t j, int64_t k) const { return size_t(((k - z0) * H + j) * W + i); }
};

/// The slab's voxels against the 1.x rules (`check`), and the first infinite distance of the grid reported.
void check_slab(const DenseSlab& s, bool check, LegacyRules& rules, h5::Reader& r, const std::string& p,
                bool& infinite_reported) {
  for (int64_t k = s.z0; k < s.z_end; ++k)
    for (int64_t j = 0; j < s.H; ++j)
      for (int64_t i = 0; i < s.W; ++i) {
        const size_t v = s.at(i, j, k);
        const float d = s.distances[v];
        if (std::isinf(d) && !infinite_reported) {
          r.report(IssueCode::NonFiniteValue, p + "/distances",
                   voxel_name(uint64_t(i), uint64_t(j), uint64_t(k)) +
                       " holds an infinite distance (use NaN for 'not stored')");
          infinite_reported = true;
        }
        if (!check) continue;
        rules.voxel(uint64_t(i), uint64_t(j), uint64_t(k), s.layers[v], d);
        const size_t row = size_t(s.W), plane = size_t(s.W * s.H);
        if (i + 1 < s.W) rules.neighbours(i, j, k, s.layers[v], d, s.layers[v + 1], s.distances[v + 1]);
        if (j + 1 < s.H) rules.neighbours(i, j, k, s.layers[v], d, s.layers[v + row], s.distances[v + row]);
        if (k + 1 < s.D) rules.neighbours(i, j, k, s.layers[v], d, s.layers[v + plane], s.distances[v + plane]);
      }
}

/// Lattice plane `c` (which the slab holds): the stored |d|, or (|layer| + 1/2) h where none is stored.
void fill_lattice_plane(const DenseSlab& s, uint32_t c, Voxelmap& vm) {
  const auto bd = vm.brick_dims();
  const int64_t k = Voxelmap::lattice_coordinate(c, uint32_t(s.D));
  for (uint32_t b = 0; b < bd[1] + 1; ++b)
    for (uint32_t a = 0; a < bd[0] + 1; ++a) {
      const size_t v =
          s.at(Voxelmap::lattice_coordinate(a, uint32_t(s.W)), Voxelmap::lattice_coordinate(b, uint32_t(s.H)), k);
      const float d = s.distances[v];
      const double value =
          std::isfinite(d) ? std::abs(double(d)) : (std::abs(double(s.layers[v])) + 0.5) * vm.voxel_size;
      vm.lattice[vm.lattice_index(a, b, c)] = float_not_below(value);
    }
}

/// Brick (bi, bj) of the slab's layer bk into `codes` (stored distances, or the sign alone, +-2); which kinds of
/// voxel it holds.
struct BrickKinds {
  bool stored = false, inside = false, outside = false;
};
BrickKinds slab_brick_codes(const DenseSlab& s, uint32_t bi, uint32_t bj, const Voxelmap& vm, int16_t* codes) {
  std::fill(codes, codes + Voxelmap::kBrickVoxels, int16_t(0));
  BrickKinds kinds;
  for (int64_t k = s.z0; k < s.z_end; ++k)
    for (int64_t j = int64_t(bj) * kEdge; j < std::min<int64_t>(s.H, int64_t(bj + 1) * kEdge); ++j)
      for (int64_t i = int64_t(bi) * kEdge; i < std::min<int64_t>(s.W, int64_t(bi + 1) * kEdge); ++i) {
        const size_t v = s.at(i, j, k);
        const float d = s.distances[v];
        int16_t& code = codes[Voxelmap::local_index(uint32_t(i % kEdge), uint32_t(j % kEdge), uint32_t(k % kEdge))];
        const bool inside = std::isfinite(d) ? d < 0 : s.layers[v] > 0;
        if (std::isfinite(d)) {
          code = vm.encode_stored(double(d));
          kinds.stored = true;
        } else {
          code = int16_t(inside ? -2 : 2);
        }
        (inside ? kinds.inside : kinds.outside) = true;
      }
  return kinds;
}

/// The slab's layer bk of bricks into vm: a value brick where a distance is stored or the surface passes, else
/// coarse. False (reported) where the value bricks would outgrow the read budget.
bool convert_slab_bricks(const DenseSlab& s, uint32_t bk, const DenseReadBudget& budget, h5::Reader& r,
                         const std::string& p, Voxelmap& vm) {
  const auto bd = vm.brick_dims();
  std::vector<int16_t> codes(Voxelmap::kBrickVoxels);
  for (uint32_t bj = 0; bj < bd[1]; ++bj)
    for (uint32_t bi = 0; bi < bd[0]; ++bi) {
      const BrickKinds kinds = slab_brick_codes(s, bi, bj, vm, codes.data());
      const size_t n = vm.brick_index(bi, bj, bk);
      if (!kinds.stored && !(kinds.inside && kinds.outside)) {
        vm.bricks[n] = kinds.inside ? Voxelmap::kCoarseInside : Voxelmap::kCoarseOutside;
        continue;
      }
      // A vector's capacity reaches twice its size as it grows.
      if (2 * (vm.value_brick_count() + 1) * Voxelmap::kBrickVoxels * sizeof(int16_t) > budget.value_brick_bytes) {
        r.report(
            IssueCode::OutOfMemory, p + "/layers",
            "converting this 1.x grid to bricks needs more than the read budget leaves for its value bricks (" +
                std::to_string(budget.value_brick_bytes >> 20) +
                " MiB; a larger budget reads it: --max-memory MiB, max_memory_mib=, ReadOptions::max_memory_bytes)");
        return false;
      }
      vm.bricks[n] = int32_t(vm.value_brick_count());
      vm.brick_values.insert(vm.brick_values.end(), codes.begin(), codes.end());
    }
  return true;
}

}  // namespace

bool grid_size_allowed(const std::array<uint32_t, 3>& dims, const FormatVersion& version) {
  if (dims[0] == 0 || dims[1] == 0 || dims[2] == 0) return false;
  if (version.major == 1) return uint64_t(dims[0]) * dims[1] * dims[2] <= 0x7fffffffull;
  uint64_t lattice = 1;
  for (uint32_t d : dims) lattice *= (d + kEdge - 1) / kEdge + 1;
  return lattice <= 0x7fffffffull;
}

std::string grid_size_limit(const FormatVersion& version) {
  return version.major == 1 ? "at most 2^31-1 voxels in all" : "at most 2^31-1 bricks and lattice points in all";
}

void read_dense_voxelmap(h5::Reader& r, hid_t g, const std::string& p, const FormatVersion& version,
                         ValidationLevel level, bool closed_surface, const DenseReadBudget& budget, Voxelmap& vm,
                         std::vector<Issue>& findings) {
  DenseSlab slab{vm.dims[0], vm.dims[1], vm.dims[2], 0, 0, {}, {}};
  const h5::Shape grid = {slab.D, slab.H, slab.W};
  std::optional<h5::OpenDataset> layers = r.open_dataset<int16_t>(g, p, "layers", grid, budget.chunk_cache_bytes);
  std::optional<h5::OpenDataset> distances = r.open_dataset<float>(g, p, "distances", grid, budget.chunk_cache_bytes);
  if (!layers || !distances) return;
  // Out-of-range geometry is validate_asset's finding; nothing is converted from it.
  if (!(vm.distance_band >= 1 && vm.distance_band <= 32767) ||
      !(vm.voxel_size >= kMinVoxelSize && vm.voxel_size <= kMaxVoxelSize))
    return;

  vm.choose_quanta();
  const auto bd = vm.brick_dims();
  vm.bricks.assign(vm.brick_count(), Voxelmap::kCoarseOutside);
  vm.lattice.assign(vm.lattice_count(), 0.0f);
  LegacyRules rules(findings, p, vm, closed_surface);
  const bool check = level == ValidationLevel::Full;
  bool infinite_reported = false;
  for (uint32_t bk = 0; bk < bd[2]; ++bk) {
    slab.z0 = int64_t(bk) * kEdge;
    slab.z_end = std::min<int64_t>(slab.z0 + kEdge, slab.D);
    const int64_t rows = std::min<int64_t>(kEdge + 1, slab.D - slab.z0);  // and the next layer, for the rules
    slab.layers.resize(size_t(rows * slab.H * slab.W));
    slab.distances.resize(size_t(rows * slab.H * slab.W));
    if (!r.read_rows<int16_t>(*layers, uint64_t(slab.z0), uint64_t(rows), slab.layers.data()) ||
        !r.read_rows<float>(*distances, uint64_t(slab.z0), uint64_t(rows), slab.distances.data()))
      return;
    if (check || !infinite_reported) check_slab(slab, check, rules, r, p, infinite_reported);
    // The lattice planes this slab holds: its first z layer, and the grid's last one for the last slab.
    fill_lattice_plane(slab, bk, vm);
    if (bk + 1 == bd[2]) fill_lattice_plane(slab, bk + 1, vm);
    if (!convert_slab_bricks(slab, bk, budget, r, p, vm)) return;
  }
  // 1.1 layers lie within [|d| - 1/2 - sqrt(3), |d| + 1/2] (in voxels) of the exact depth; 1.0's came from a chamfer
  // transform, never shallower and at most ~11 % deeper (spec 1.1 §3). So a lattice value (|layer| + 1/2) h is never
  // below the exact distance u; it exceeds it by at most 1 + sqrt(3) voxels (1.1), or by 1 voxel + 1/9 of u (1.0:
  // |d| >= 0.9 (|layer| - 1/2) h).
  const bool chamfer = version.minor == 0;
  vm.lattice_error = chamfer ? std::array<double, 2>{1.0, 1.0 / 9.0} : std::array<double, 2>{1.0 + std::sqrt(3.0), 0.0};
  fill_interpolated_estimates(vm);
}

}  // namespace voxfmt::detail
