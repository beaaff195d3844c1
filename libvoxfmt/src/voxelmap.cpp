#include "voxfmt/voxelmap.h"

#include "voxfmt/detail/cores.h"
#include "voxfmt/detail/estimate_transform.h"

#include <limits>

namespace voxfmt {

namespace {

constexpr uint32_t kEdge = Voxelmap::kBrickEdge;

// std::lround (half away from zero) without the library call: codes are rounded for every voxel of a bake and a
// full validation. Exact for the magnitudes clamp_steps keeps.
long round_half_away(double x) {
  const double r = std::floor(std::abs(x) + 0.5);
  const long magnitude = r < 1e9 ? long(r) : 1000000000L;
  return x < 0 ? -magnitude : magnitude;
}

int16_t clamp_steps(long steps, long minimum_magnitude) {
  steps = std::clamp<long>(steps, -Voxelmap::kMaxSteps, Voxelmap::kMaxSteps);
  if (std::abs(steps) < minimum_magnitude) steps = steps < 0 ? -minimum_magnitude : minimum_magnitude;
  return int16_t(steps);
}

// The lattice corners around voxel coordinate `v` along an axis of `n` voxels, and v's weight toward the upper.
struct AxisCell {
  uint32_t lower = 0;                         // lattice index of the lower corner (the upper is lower + 1)
  double t = 0;                               // 0 at the lower corner, 1 at the upper
  double lower_offset = 0, upper_offset = 0;  // voxels from the corners
};
AxisCell axis_cell(uint32_t v, uint32_t n) {
  AxisCell c;
  c.lower = v / kEdge;
  const uint32_t x0 = Voxelmap::lattice_coordinate(c.lower, n), x1 = Voxelmap::lattice_coordinate(c.lower + 1, n);
  c.t = x1 > x0 ? double(v - x0) / double(x1 - x0) : 0.0;
  c.lower_offset = double(v - x0);
  c.upper_offset = double(x1 - v);
  return c;
}

// A float not below `value` (lattice values promise never to be below the exact distance).
float float_not_below(double value) {
  float f = float(value);
  if (double(f) < value) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

}  // namespace

int16_t Voxelmap::encode_stored(double distance) const {
  return int16_t(clamp_steps(round_half_away(distance / distance_quantum), 0) * 2 + 1);
}

int16_t Voxelmap::encode_estimate(double distance) const {
  const int16_t steps = clamp_steps(round_half_away(distance / estimate_quantum), 1);
  return int16_t(steps * 2 * ((distance < 0) == (steps < 0) ? 1 : -1));
}

double Voxelmap::coarse_magnitude(uint32_t i, uint32_t j, uint32_t k) const {
  const AxisCell x = axis_cell(i, dims[0]), y = axis_cell(j, dims[1]), z = axis_cell(k, dims[2]);
  auto at = [&](uint32_t da, uint32_t db, uint32_t dc) {
    return double(lattice[lattice_index(x.lower + da, y.lower + db, z.lower + dc)]);
  };
  const double x00 = at(0, 0, 0) + x.t * (at(1, 0, 0) - at(0, 0, 0));
  const double x10 = at(0, 1, 0) + x.t * (at(1, 1, 0) - at(0, 1, 0));
  const double x01 = at(0, 0, 1) + x.t * (at(1, 0, 1) - at(0, 0, 1));
  const double x11 = at(0, 1, 1) + x.t * (at(1, 1, 1) - at(0, 1, 1));
  const double y0 = x00 + y.t * (x10 - x00), y1 = x01 + y.t * (x11 - x01);
  return std::max(y0 + z.t * (y1 - y0), (distance_band - 0.5) * voxel_size);
}

double Voxelmap::interpolation_bound(uint32_t i, uint32_t j, uint32_t k) const {
  const AxisCell c[3] = {axis_cell(i, dims[0]), axis_cell(j, dims[1]), axis_cell(k, dims[2])};
  double bound = 0;
  for (int corner = 0; corner < 8; ++corner) {
    double weight = 1, d2 = 0;
    for (int a = 0; a < 3; ++a) {
      const bool upper = (corner >> a) & 1;
      weight *= upper ? c[a].t : 1 - c[a].t;
      const double offset = upper ? c[a].upper_offset : c[a].lower_offset;
      d2 += offset * offset;
    }
    bound += weight * std::sqrt(d2);
  }
  return bound;
}

VoxelValue Voxelmap::voxel(uint32_t i, uint32_t j, uint32_t k) const {
  const int32_t entry = bricks[brick_index(i / kEdge, j / kEdge, k / kEdge)];
  if (entry >= 0) {
    const int16_t code = brick_values[size_t(entry) * kBrickVoxels + local_index(i % kEdge, j % kEdge, k % kEdge)];
    return {decode(code), code_is_stored(code)};
  }
  const double magnitude = coarse_magnitude(i, j, k);
  return {entry == kCoarseInside ? -magnitude : magnitude, false};
}

int Voxelmap::layer(uint32_t i, uint32_t j, uint32_t k) const {
  // In voxels straight from the code: steps times (quantum / h), which is exact for the bake's h/16 estimates, so
  // an estimate on a layer tie rounds the same way whatever h is (m q / h in metres could land an ulp either side).
  const int32_t entry = bricks[brick_index(i / kEdge, j / kEdge, k / kEdge)];
  double d;
  if (entry >= 0) {
    const int16_t code = brick_values[size_t(entry) * kBrickVoxels + local_index(i % kEdge, j % kEdge, k % kEdge)];
    d = double(code >> 1) * ((code_is_stored(code) ? distance_quantum : estimate_quantum) / voxel_size);
  } else {
    d = voxel(i, j, k).distance / voxel_size;
  }
  return int(std::clamp(std::floor(-d + 0.5), -32767.0, 32767.0));
}

void Voxelmap::read_block(const std::array<uint32_t, 3>& first, const std::array<uint32_t, 3>& size, float* distances,
                          int16_t* layers) const {
  size_t n = 0;
  for (uint32_t k = first[2]; k < first[2] + size[2]; ++k)
    for (uint32_t j = first[1]; j < first[1] + size[1]; ++j)
      for (uint32_t i = first[0]; i < first[0] + size[0]; ++i, ++n) {
        const VoxelValue v = voxel(i, j, k);
        if (distances) distances[n] = v.stored ? float(v.distance) : std::numeric_limits<float>::quiet_NaN();
        if (layers) layers[n] = int16_t(layer(i, j, k));
      }
}

size_t Voxelmap::stored_count() const {
  size_t count = 0;
  const auto b = brick_dims();
  for_each_value_brick([&](uint32_t bi, uint32_t bj, uint32_t bk, const int16_t* codes) {
    for (uint32_t lk = 0; lk < kEdge && bk * kEdge + lk < dims[2]; ++lk)
      for (uint32_t lj = 0; lj < kEdge && bj * kEdge + lj < dims[1]; ++lj)
        for (uint32_t li = 0; li < kEdge && bi * kEdge + li < dims[0]; ++li)
          count += code_is_stored(codes[local_index(li, lj, lk)]);
  });
  (void)b;
  return count;
}

std::pair<int, int> Voxelmap::layer_range() const {
  int lo = std::numeric_limits<int>::max(), hi = std::numeric_limits<int>::min();
  auto add = [&](double d) {
    const int l = int(std::clamp(std::floor(-d / voxel_size + 0.5), -32767.0, 32767.0));
    lo = std::min(lo, l);
    hi = std::max(hi, l);
  };
  for_each_value_brick([&](uint32_t bi, uint32_t bj, uint32_t bk, const int16_t* codes) {
    for (uint32_t lk = 0; lk < kEdge && bk * kEdge + lk < dims[2]; ++lk)
      for (uint32_t lj = 0; lj < kEdge && bj * kEdge + lj < dims[1]; ++lj)
        for (uint32_t li = 0; li < kEdge && bi * kEdge + li < dims[0]; ++li)
          add(decode(codes[local_index(li, lj, lk)]));
  });
  // Coarse bricks: their estimates lie between their corners' values (and the band's edge).
  const auto b = brick_dims();
  size_t n = 0;
  for (uint32_t bk = 0; bk < b[2]; ++bk)
    for (uint32_t bj = 0; bj < b[1]; ++bj)
      for (uint32_t bi = 0; bi < b[0]; ++bi, ++n) {
        if (bricks[n] >= 0) continue;
        const double sign = bricks[n] == kCoarseInside ? -1 : 1;
        for (int corner = 0; corner < 8; ++corner) {
          const uint32_t i = std::min(bi * kEdge + (corner & 1 ? kEdge - 1 : 0), dims[0] - 1);
          const uint32_t j = std::min(bj * kEdge + (corner & 2 ? kEdge - 1 : 0), dims[1] - 1);
          const uint32_t k = std::min(bk * kEdge + (corner & 4 ? kEdge - 1 : 0), dims[2] - 1);
          add(sign * coarse_magnitude(i, j, k));
        }
      }
  if (lo > hi) lo = hi = 0;
  return {lo, hi};
}

void brick_estimate_magnitudes(const Voxelmap& vm, uint32_t bi, uint32_t bj, uint32_t bk, double* magnitudes) {
  // The brick's voxels all lie in the lattice cell of its 8 corners: those are read once, and the weights along each
  // axis are the same for every row. The result is coarse_magnitude()'s, term for term.
  const uint32_t first[3] = {bi * kEdge, bj * kEdge, bk * kEdge};
  double corner[8];
  for (int c = 0; c < 8; ++c)
    corner[c] = vm.lattice[vm.lattice_index(bi + (c & 1), bj + ((c >> 1) & 1), bk + (c >> 2))];
  double t[3][kEdge];
  uint32_t count[3];
  for (int a = 0; a < 3; ++a) {
    count[a] = std::min(kEdge, vm.dims[size_t(a)] - first[a]);
    for (uint32_t l = 0; l < count[a]; ++l) t[a][l] = axis_cell(first[a] + l, vm.dims[size_t(a)]).t;
  }
  const double edge_of_band = (vm.distance_band - 0.5) * vm.voxel_size;
  std::fill(magnitudes, magnitudes + Voxelmap::kBrickVoxels, 0.0);
  for (uint32_t lk = 0; lk < count[2]; ++lk)
    for (uint32_t lj = 0; lj < count[1]; ++lj)
      for (uint32_t li = 0; li < count[0]; ++li) {
        const double tx = t[0][li], ty = t[1][lj], tz = t[2][lk];
        const double x00 = corner[0] + tx * (corner[1] - corner[0]), x10 = corner[2] + tx * (corner[3] - corner[2]);
        const double x01 = corner[4] + tx * (corner[5] - corner[4]), x11 = corner[6] + tx * (corner[7] - corner[6]);
        const double y0 = x00 + ty * (x10 - x00), y1 = x01 + ty * (x11 - x01);
        magnitudes[Voxelmap::local_index(li, lj, lk)] = std::max(y0 + tz * (y1 - y0), edge_of_band);
      }
}

void fill_brick_estimates(const Voxelmap& vm, uint32_t bi, uint32_t bj, uint32_t bk, int16_t* codes) {
  double magnitudes[Voxelmap::kBrickVoxels];
  brick_estimate_magnitudes(vm, bi, bj, bk, magnitudes);
  const uint32_t count[3] = {std::min(kEdge, vm.dims[0] - bi * kEdge), std::min(kEdge, vm.dims[1] - bj * kEdge),
                             std::min(kEdge, vm.dims[2] - bk * kEdge)};
  for (uint32_t lk = 0; lk < count[2]; ++lk)
    for (uint32_t lj = 0; lj < count[1]; ++lj)
      for (uint32_t li = 0; li < count[0]; ++li) {
        int16_t& code = codes[Voxelmap::local_index(li, lj, lk)];
        if (Voxelmap::code_is_stored(code)) continue;
        const double magnitude = magnitudes[Voxelmap::local_index(li, lj, lk)];
        code = vm.encode_estimate(code < 0 ? -magnitude : magnitude);
      }
}

void fill_interpolated_estimates(Voxelmap& vm) {
  for (size_t b = 0; b < vm.bricks.size(); ++b)
    if (vm.bricks[b] >= 0) {
      const auto [bi, bj, bk] = detail::brick_coordinates(vm, b);
      fill_brick_estimates(vm, uint32_t(bi), uint32_t(bj), uint32_t(bk),
                           vm.brick_values.data() + size_t(vm.bricks[b]) * Voxelmap::kBrickVoxels);
    }
  vm.estimates = Voxelmap::Estimates::Interpolated;
}

void fill_estimates(Voxelmap& vm, unsigned threads) {
  if (threads == 0) threads = usable_cores();
  detail::EstimateTransform transform(vm, vm.brick_values);
  transform.seed(threads);
  transform.settle(threads);
  vm.estimates = Voxelmap::Estimates::Settled;
}

Voxelmap make_voxelmap(const Voxelmap& geometry, const SignedDistanceFunction& signed_distance) {
  Voxelmap vm = geometry;
  vm.bricks.clear();
  vm.brick_values.clear();
  vm.lattice.clear();
  if (!(vm.distance_quantum > 0) || !(vm.estimate_quantum > 0)) vm.choose_quanta();
  vm.lattice_error = {1e-6 * double(std::max({vm.dims[0], vm.dims[1], vm.dims[2]})), 0.0};  // float rounding
  const double h = vm.voxel_size, band = vm.distance_band * h;
  const auto l = vm.lattice_dims();
  vm.lattice.resize(vm.lattice_count());
  for (uint32_t c = 0; c < l[2]; ++c)
    for (uint32_t b = 0; b < l[1]; ++b)
      for (uint32_t a = 0; a < l[0]; ++a)
        vm.lattice[vm.lattice_index(a, b, c)] =
            float_not_below(std::abs(signed_distance(vm.lattice_point_center(a, b, c))));
  const auto bd = vm.brick_dims();
  vm.bricks.resize(vm.brick_count());
  std::vector<int16_t> codes(Voxelmap::kBrickVoxels);
  size_t n = 0;
  for (uint32_t bk = 0; bk < bd[2]; ++bk)
    for (uint32_t bj = 0; bj < bd[1]; ++bj)
      for (uint32_t bi = 0; bi < bd[0]; ++bi, ++n) {
        std::fill(codes.begin(), codes.end(), int16_t(0));
        bool any_stored = false, any_inside = false, any_outside = false;
        for (uint32_t lk = 0; lk < kEdge && bk * kEdge + lk < vm.dims[2]; ++lk)
          for (uint32_t lj = 0; lj < kEdge && bj * kEdge + lj < vm.dims[1]; ++lj)
            for (uint32_t li = 0; li < kEdge && bi * kEdge + li < vm.dims[0]; ++li) {
              const double d = signed_distance(vm.voxel_center(bi * kEdge + li, bj * kEdge + lj, bk * kEdge + lk));
              int16_t& code = codes[Voxelmap::local_index(li, lj, lk)];
              if (std::abs(d) <= band) {
                code = vm.encode_stored(d);
                any_stored = true;
              } else {
                code = int16_t(d < 0 ? -2 : 2);  // the sign; fill_estimates sets the value
              }
              (d < 0 ? any_inside : any_outside) = true;
            }
        if (any_stored || (any_inside && any_outside)) {
          vm.bricks[n] = int32_t(vm.value_brick_count());
          vm.brick_values.insert(vm.brick_values.end(), codes.begin(), codes.end());
        } else {
          vm.bricks[n] = any_inside ? Voxelmap::kCoarseInside : Voxelmap::kCoarseOutside;
        }
      }
  fill_estimates(vm);
  return vm;
}

}  // namespace voxfmt
