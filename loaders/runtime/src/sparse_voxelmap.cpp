#include "voxfmt/runtime/collision_object.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/field.h"
#include "traversal/eigen.h"
#include "traversal/field_simd.h"

namespace voxfmt::runtime {

SparseVoxelmap SparseVoxelmap::from_voxelmap(voxfmt::Voxelmap vm, const voxfmt::Vec3& bounds_min,
                                             const voxfmt::Vec3& bounds_max) {
  SparseVoxelmap map;
  map.origin_ = Eigen::Vector3d(vm.origin[0], vm.origin[1], vm.origin[2]);
  map.voxel_size_ = vm.voxel_size;
  core::FieldLayout& f = map.layout_;
  const auto bd = vm.brick_dims();
  for (int a = 0; a < 3; ++a) {
    f.dims[a] = int(vm.dims[size_t(a)]);
    f.brick_dims[a] = int(bd[size_t(a)]);
    f.lattice_dims[a] = int(bd[size_t(a)]) + 1;
  }
  // An empty grid covers nothing.
  auto cover_end = [&](int a) { return f.dims[a] > 0 ? float(f.dims[a]) - 0.5f : -1.0f; };
  f.cover_max = core::make_vec3(cover_end(0), cover_end(1), cover_end(2));
  f.object_min = core::to_core(map.to_grid(Eigen::Vector3d(bounds_min[0], bounds_min[1], bounds_min[2])));
  f.object_max = core::to_core(map.to_grid(Eigen::Vector3d(bounds_max[0], bounds_max[1], bounds_max[2])));
  const double h = vm.voxel_size;
  f.decode_step[0] = float(vm.estimate_quantum / h);
  f.decode_step[1] = float(vm.distance_quantum / h);
  // Fixed point rounds a stored distance by half a step; float arithmetic adds a few ulps of the band.
  f.stored_slack = float(0.5 * vm.distance_quantum / h + 1e-6 * vm.distance_band);
  f.estimate_slack = float(0.5 * vm.estimate_quantum / h + 1e-5 * vm.distance_band) + core::kInterpolationBound;
  f.estimate_offset = float(vm.lattice_error[0]);
  f.estimate_shrink = float(1.0 / (1.0 + vm.lattice_error[1]));
  f.band_edge = float(vm.distance_band - 0.5);
  map.bricks_ = std::move(vm.bricks);
  map.codes_ = std::move(vm.brick_values);
  // 1/16 voxel steps, coarser only if the largest distance would not fit in 16 bits.
  float largest = 0;
  for (float v : vm.lattice) largest = std::max(largest, v);
  const double largest_voxels = double(largest) / h;
  f.lattice_step = float(std::max(1.0 / 16, largest_voxels / 65000.0));
  f.estimate_slack += 0.5f * f.lattice_step;
  // A settled estimate m is at most the path through the voxel's nearest lattice point p (at most 4 voxels along
  // each axis: 4 steps, each rounded up by less than a step of q, and l_p rounded up by one): with
  // l_p <= (1 + e1)(u + |v - p|) + e0, u >= (m - e0) / (1 + e1) - 8 sqrt(3) - 5 q.
  f.value_estimate_slack =
      vm.estimates == voxfmt::Voxelmap::Estimates::Settled
          ? float(2 * core::kInterpolationBound + 5 * vm.estimate_quantum / h + 1e-5 * vm.distance_band)
          : f.estimate_slack;
  map.lattice_.resize(vm.lattice.size());
  const double to_steps = 1.0 / (h * double(f.lattice_step));
  for (size_t n = 0; n < vm.lattice.size(); ++n)
    map.lattice_[n] = uint16_t(std::min(65535.0, std::floor(double(vm.lattice[n]) * to_steps + 0.5)));
  std::vector<float>().swap(vm.lattice);
  // Vector gathers read 16-bit arrays as 32-bit words (field_simd.h): one element more, outside the counts.
  map.codes_.resize(map.codes_.size() + core::kGatherPadding, 0);
  map.lattice_.resize(map.lattice_.size() + core::kGatherPadding, 0);
  f.gather_safe = map.lattice_.size() > core::kGatherPadding && map.codes_.size() < (size_t(1) << 31) &&
                  map.lattice_.size() < (size_t(1) << 31) && map.bricks_.size() < (size_t(1) << 31);
  map.bricks_.shrink_to_fit();
  map.codes_.shrink_to_fit();
  map.lattice_.shrink_to_fit();
  return map;
}

size_t SparseVoxelmap::memory_bytes() const {
  return bricks_.capacity() * sizeof(int32_t) + codes_.capacity() * sizeof(int16_t) +
         lattice_.capacity() * sizeof(uint16_t);
}

core::Field field_of(const SparseVoxelmap& map) {
  core::Field f;
  static_cast<core::FieldLayout&>(f) = map.layout_;
  f.bricks = map.bricks_.data();
  f.codes = map.codes_.data();
  f.lattice = map.lattice_.data();
  return f;
}

namespace core {

std::vector<int16_t> apron_codes(const Field& f, size_t value_bricks) {
  std::vector<int16_t> out(value_bricks * kApronBrickCodes, 0);
  for (int bz = 0; bz < f.brick_dims[2]; ++bz)
    for (int by = 0; by < f.brick_dims[1]; ++by)
      for (int bx = 0; bx < f.brick_dims[0]; ++bx) {
        const int32_t entry = entry_of(f, bx * kEdge, by * kEdge, bz * kEdge);
        if (entry < 0) continue;
        int16_t* brick = &out[size_t(entry) * kApronBrickCodes];
        // Neighbour (dx, dy, dz) is in the apron where it is a value brick of the grid.
        int32_t neighbour[8];
        int mask = 0;
        for (int o = 1; o < 8; ++o) {
          const int n[3] = {bx + (o & 1), by + ((o >> 1) & 1), bz + (o >> 2)};
          const bool in_grid = n[0] < f.brick_dims[0] && n[1] < f.brick_dims[1] && n[2] < f.brick_dims[2];
          neighbour[o] = in_grid ? entry_of(f, n[0] * kEdge, n[1] * kEdge, n[2] * kEdge) : -1;
          if (neighbour[o] >= 0) mask |= 1 << o;
        }
        neighbour[0] = entry;
        brick[kApronMask] = int16_t(mask);
        for (int k = 0; k < kApronEdge; ++k)
          for (int j = 0; j < kApronEdge; ++j)
            for (int i = 0; i < kApronEdge; ++i) {
              const int o = int(i == kEdge) | int(j == kEdge) << 1 | int(k == kEdge) << 2;
              if (neighbour[o] < 0) continue;  // not in the mask: never read
              const int local = ((k & (kEdge - 1)) * kEdge + (j & (kEdge - 1))) * kEdge + (i & (kEdge - 1));
              brick[(k * kApronEdge + j) * kApronEdge + i] = f.codes[size_t(neighbour[o]) * kBrickVoxels + local];
            }
      }
  return out;
}

}  // namespace core

bool SparseVoxelmap::in_grid(int i, int j, int k) const {
  return !empty() && i >= 0 && j >= 0 && k >= 0 && i < layout_.dims[0] && j < layout_.dims[1] && k < layout_.dims[2];
}

float SparseVoxelmap::value_at(int i, int j, int k) const {
  if (!in_grid(i, j, k)) return std::nanf("");
  bool exact = true;
  return core::voxel_value(field_of(*this), i, j, k, exact);
}

int SparseVoxelmap::layer_at(int i, int j, int k) const {
  const float value = value_at(i, j, k);  // NaN outside the grid only: a voxel's value is always finite
  if (std::isnan(value)) return std::numeric_limits<int>::min();
  return int(std::clamp(std::floor(-double(value) + 0.5), -32767.0, 32767.0));
}

float SparseVoxelmap::stored_distance_at(int i, int j, int k) const {
  if (!in_grid(i, j, k)) return std::nanf("");
  bool exact = true;
  const float value = core::voxel_value(field_of(*this), i, j, k, exact);
  return exact ? value : std::nanf("");
}

FieldSample SparseVoxelmap::sample(const Eigen::Vector3f& u, Eigen::Vector3f* gradient) const {
  if (empty()) {  // no grid to continue: the lower bound alone (the object's box), as distance_lower_bound
    if (gradient) gradient->setZero();
    FieldSample bound;
    bound.distance = distance_lower_bound(u);
    bound.bound = true;
    return bound;
  }
  core::Vec3 g;
  const FieldSample s = core::sample(field_of(*this), core::to_core(u), gradient ? &g : nullptr);
  if (gradient) *gradient = core::to_eigen(g);
  return s;
}

float SparseVoxelmap::distance_lower_bound(const Eigen::Vector3f& u) const {
  return core::lower_bound(field_of(*this), core::to_core(u));
}

}  // namespace voxfmt::runtime
