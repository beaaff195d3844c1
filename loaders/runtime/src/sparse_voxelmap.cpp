#include "voxfmt/runtime/sparse_voxelmap.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace voxfmt::runtime {
namespace {

constexpr int kEdge = SparseVoxelmap::kBrickEdge;
constexpr unsigned kEdgeBits = 3;
static_assert(kEdge == 1 << kEdgeBits);
// The lattice interpolated at a voxel is within the sum over the cell's corners of weight x distance of the exact
// distance (the distance is 1-Lipschitz); that sum is largest at a brick's centre: 4 sqrt(3) voxels (spec §3.3).
constexpr float kInterpolationBound = 6.9282032f;

}  // namespace

SparseVoxelmap SparseVoxelmap::from_voxelmap(voxfmt::Voxelmap vm, const voxfmt::Vec3& bounds_min,
                                             const voxfmt::Vec3& bounds_max) {
  SparseVoxelmap map;
  map.origin_ = Eigen::Vector3d(vm.origin[0], vm.origin[1], vm.origin[2]);
  map.voxel_size_ = vm.voxel_size;
  const auto bd = vm.brick_dims();
  for (int a = 0; a < 3; ++a) {
    map.dims_[a] = int(vm.dims[size_t(a)]);
    map.brick_dims_[a] = int(bd[size_t(a)]);
    map.lattice_dims_[a] = int(bd[size_t(a)]) + 1;
  }
  // An empty grid covers nothing.
  for (int a = 0; a < 3; ++a) map.cover_max_[a] = map.dims_[a] > 0 ? float(map.dims_[a]) - 0.5f : -1.0f;
  map.object_min_ = map.to_grid(Eigen::Vector3d(bounds_min[0], bounds_min[1], bounds_min[2]));
  map.object_max_ = map.to_grid(Eigen::Vector3d(bounds_max[0], bounds_max[1], bounds_max[2]));
  const double h = vm.voxel_size;
  map.decode_step_[0] = float(vm.estimate_quantum / h);
  map.decode_step_[1] = float(vm.distance_quantum / h);
  // Fixed point rounds a stored distance by half a step; float arithmetic adds a few ulps of the band.
  map.stored_slack_ = float(0.5 * vm.distance_quantum / h + 1e-6 * vm.distance_band);
  map.estimate_slack_ = float(0.5 * vm.estimate_quantum / h + 1e-5 * vm.distance_band) + kInterpolationBound;
  map.estimate_offset_ = float(vm.lattice_error[0]);
  map.estimate_shrink_ = float(1.0 / (1.0 + vm.lattice_error[1]));
  map.band_edge_ = float(vm.distance_band - 0.5);
  map.bricks_ = std::move(vm.bricks);
  map.codes_ = std::move(vm.brick_values);
  // 1/16 voxel steps, coarser only if the largest distance would not fit in 16 bits.
  float largest = 0;
  for (float v : vm.lattice) largest = std::max(largest, v);
  const double largest_voxels = double(largest) / h;
  map.lattice_step_ = float(std::max(1.0 / 16, largest_voxels / 65000.0));
  map.estimate_slack_ += 0.5f * map.lattice_step_;
  map.lattice_.resize(vm.lattice.size());
  const double to_steps = 1.0 / (h * double(map.lattice_step_));
  for (size_t n = 0; n < vm.lattice.size(); ++n)
    map.lattice_[n] = uint16_t(std::min(65535.0, std::floor(double(vm.lattice[n]) * to_steps + 0.5)));
  std::vector<float>().swap(vm.lattice);
  map.bricks_.shrink_to_fit();
  map.codes_.shrink_to_fit();
  return map;
}

size_t SparseVoxelmap::memory_bytes() const {
  return bricks_.capacity() * sizeof(int32_t) + codes_.capacity() * sizeof(int16_t) +
         lattice_.capacity() * sizeof(uint16_t);
}

// The per-voxel helpers run for every sphere-tree node a query visits: always inlined (GCC kept them calls).
[[gnu::always_inline]] inline const int32_t& SparseVoxelmap::entry_of(int i, int j, int k) const {
  // Voxel indices are never negative: shifts, not signed divisions (GCC kept idiv for those).
  return bricks_[(size_t(unsigned(k) >> kEdgeBits) * unsigned(brick_dims_[1]) + (unsigned(j) >> kEdgeBits)) *
                     unsigned(brick_dims_[0]) +
                 (unsigned(i) >> kEdgeBits)];
}

float SparseVoxelmap::coarse_value(int i, int j, int k, int32_t entry) const {
  // Every voxel lies in one lattice cell: that of its brick, from the brick's first voxel to the next brick's.
  const int c[3] = {i, j, k};
  int lower[3];
  float t[3];
  for (int a = 0; a < 3; ++a) {
    lower[a] = c[a] >> kEdgeBits;
    const int x0 = lower[a] * kEdge, x1 = lattice_coordinate(lower[a] + 1, a);
    t[a] = x1 > x0 ? float(c[a] - x0) / float(x1 - x0) : 0.0f;
  }
  const size_t row = size_t(lattice_dims_[0]), plane = row * size_t(lattice_dims_[1]);
  const uint16_t* q = &lattice_[size_t(lower[2]) * plane + size_t(lower[1]) * row + size_t(lower[0])];
  const float p[8] = {float(q[0]),     float(q[1]),         float(q[row]),         float(q[row + 1]),
                      float(q[plane]), float(q[plane + 1]), float(q[plane + row]), float(q[plane + row + 1])};
  const float x00 = p[0] + t[0] * (p[1] - p[0]), x10 = p[2] + t[0] * (p[3] - p[2]);
  const float x01 = p[4] + t[0] * (p[5] - p[4]), x11 = p[6] + t[0] * (p[7] - p[6]);
  const float y0 = x00 + t[1] * (x10 - x00), y1 = x01 + t[1] * (x11 - x01);
  const float magnitude = std::max((y0 + t[2] * (y1 - y0)) * lattice_step_, band_edge_);
  return entry == voxfmt::Voxelmap::kCoarseInside ? -magnitude : magnitude;
}

float SparseVoxelmap::lattice_at(const Eigen::Vector3f& u, Eigen::Vector3f* gradient) const {
  int lower[3];
  float t[3], inverse[3];
  for (int a = 0; a < 3; ++a) {
    const float c = std::clamp(u[a], 0.0f, float(dims_[a] - 1));
    lower[a] = std::min(int(c) >> kEdgeBits, std::max(lattice_dims_[a] - 2, 0));
    const int x0 = lattice_coordinate(lower[a], a), x1 = lattice_coordinate(lower[a] + 1, a);
    inverse[a] = x1 > x0 ? 1.0f / float(x1 - x0) : 0.0f;
    t[a] = std::clamp((c - float(x0)) * inverse[a], 0.0f, 1.0f);
  }
  const size_t row = size_t(lattice_dims_[0]), plane = row * size_t(lattice_dims_[1]);
  const uint16_t* p = &lattice_[size_t(lower[2]) * plane + size_t(lower[1]) * row + size_t(lower[0])];
  const float s = lattice_step_;
  const float v[8] = {s * p[0],     s * p[1],         s * p[row],         s * p[row + 1],
                      s * p[plane], s * p[plane + 1], s * p[plane + row], s * p[plane + row + 1]};
  const float x0 = v[0] + t[0] * (v[1] - v[0]), x1 = v[2] + t[0] * (v[3] - v[2]);
  const float x2 = v[4] + t[0] * (v[5] - v[4]), x3 = v[6] + t[0] * (v[7] - v[6]);
  const float y0 = x0 + t[1] * (x1 - x0), y1 = x2 + t[1] * (x3 - x2);
  if (gradient) {
    const float dx0 = v[1] - v[0], dx1 = v[3] - v[2], dx2 = v[5] - v[4], dx3 = v[7] - v[6];
    const float gx = (1 - t[2]) * (dx0 + t[1] * (dx1 - dx0)) + t[2] * (dx2 + t[1] * (dx3 - dx2));
    const float gy = (1 - t[2]) * (x1 - x0) + t[2] * (x3 - x2);
    *gradient = Eigen::Vector3f(gx * inverse[0], gy * inverse[1], (y1 - y0) * inverse[2]);
  }
  return y0 + t[2] * (y1 - y0);
}

[[gnu::always_inline]] inline float SparseVoxelmap::voxel_value(int i, int j, int k, bool& exact) const {
  const int32_t entry = entry_of(i, j, k);
  if (entry >= 0) {
    const int local = ((k & (kEdge - 1)) * kEdge + (j & (kEdge - 1))) * kEdge + (i & (kEdge - 1));
    const int code = codes_[size_t(entry) * kBrickVoxels + size_t(local)];
    exact &= (code & 1) != 0;
    return float(code >> 1) * decode_step_[code & 1];
  }
  exact = false;
  return coarse_value(i, j, k, entry);
}

[[gnu::always_inline]] inline float SparseVoxelmap::value_lower_bound(float value, bool stored) const {
  if (stored) return value - stored_slack_;
  // A voxel without a stored distance is at least the band's edge from the surface, and its estimate bounds the
  // exact distance both ways (spec §3.3).
  return value > 0 ? std::max(band_edge_, (value - estimate_offset_) * estimate_shrink_ - estimate_slack_)
                   : value - estimate_slack_;
}

float SparseVoxelmap::value_at(int i, int j, int k) const {
  bool exact = true;
  return voxel_value(i, j, k, exact);
}

int SparseVoxelmap::layer_at(int i, int j, int k) const {
  return int(std::clamp(std::floor(-double(value_at(i, j, k)) + 0.5), -32767.0, 32767.0));
}

float SparseVoxelmap::stored_distance_at(int i, int j, int k) const {
  bool exact = true;
  const float value = voxel_value(i, j, k, exact);
  return exact ? value : std::nanf("");
}

[[gnu::always_inline]] inline bool SparseVoxelmap::covers(const Eigen::Vector3f& u) const {
  // Bitwise, not short-circuit: one branch for the caller instead of six hard-to-predict ones.
  return (u.x() > -0.5f) & (u.y() > -0.5f) & (u.z() > -0.5f) & (u.x() < cover_max_.x()) & (u.y() < cover_max_.y()) &
         (u.z() < cover_max_.z());
}

[[gnu::always_inline]] inline float SparseVoxelmap::bounds_distance(const Eigen::Vector3f& u) const {
  const Eigen::Vector3f outside = (object_min_ - u).cwiseMax(u - object_max_).cwiseMax(Eigen::Vector3f::Zero());
  return outside.norm();
}

FieldSample SparseVoxelmap::sample(const Eigen::Vector3f& u, Eigen::Vector3f* gradient) const {
  FieldSample result;
  if (!covers(u)) {
    // Outside the grid the object is at least as far as its bounding box (margin voxels are all outside).
    result.distance = bounds_distance(u);
    result.bound = true;
    if (gradient) {
      const Eigen::Vector3f centre = 0.5f * (object_min_ + object_max_);
      *gradient = u - centre;
    }
    return result;
  }
  // The cell whose corners surround u, clamped so that all 8 corners exist.
  int base[3];
  float t[3];
  for (int a = 0; a < 3; ++a) {
    const float c = std::clamp(u[a], 0.0f, float(dims_[a] - 1));
    base[a] = std::min(int(c), std::max(dims_[a] - 2, 0));
    t[a] = c - float(base[a]);
  }
  bool exact = true;
  float v[8];
  bool fetched = false;
  const bool in_one_brick = (base[0] & (kEdge - 1)) < kEdge - 1 && (base[1] & (kEdge - 1)) < kEdge - 1 &&
                            (base[2] & (kEdge - 1)) < kEdge - 1 && dims_[0] > 1 && dims_[1] > 1 && dims_[2] > 1;
  if (in_one_brick) {
    const int32_t entry = entry_of(base[0], base[1], base[2]);
    if (entry >= 0) {
      // Near the surface the 8 corners usually lie in one value brick: one table entry and two cache lines.
      const int local = ((base[2] & (kEdge - 1)) * kEdge + (base[1] & (kEdge - 1))) * kEdge + (base[0] & (kEdge - 1));
      const int16_t* q = &codes_[size_t(entry) * kBrickVoxels + size_t(local)];
      constexpr int kOffset[8] = {
          0, 1, kEdge, kEdge + 1, kEdge * kEdge, kEdge * kEdge + 1, kEdge * kEdge + kEdge, kEdge * kEdge + kEdge + 1};
      int flags = 1;
      for (int corner = 0; corner < 8; ++corner) {
        const int value = q[kOffset[corner]];
        flags &= value;
        v[corner] = float(value >> 1) * decode_step_[value & 1];
      }
      exact = flags != 0;
      fetched = true;
    } else {
      // Inside a coarse brick the voxels' values are the lattice's interpolation, which is trilinear across the
      // whole brick: interpolating the lattice at u directly gives the same field.
      const float magnitude = lattice_at(u, gradient);
      const bool clamped = magnitude < band_edge_;
      const float sign = entry == voxfmt::Voxelmap::kCoarseInside ? -1.0f : 1.0f;
      result.distance = sign * std::max(magnitude, band_edge_);
      if (gradient) *gradient = clamped ? Eigen::Vector3f::Zero() : Eigen::Vector3f(sign * *gradient);
      return result;
    }
  }
  if (!fetched) {
    for (int corner = 0; corner < 8; ++corner) {
      const int x = std::min(base[0] + (corner & 1), dims_[0] - 1),
                y = std::min(base[1] + ((corner >> 1) & 1), dims_[1] - 1),
                z = std::min(base[2] + (corner >> 2), dims_[2] - 1);
      v[corner] = voxel_value(x, y, z, exact);
    }
  }
  const float x0 = v[0] + t[0] * (v[1] - v[0]), x1 = v[2] + t[0] * (v[3] - v[2]);
  const float x2 = v[4] + t[0] * (v[5] - v[4]), x3 = v[6] + t[0] * (v[7] - v[6]);
  const float y0 = x0 + t[1] * (x1 - x0), y1 = x2 + t[1] * (x3 - x2);
  result.distance = y0 + t[2] * (y1 - y0);
  result.exact = exact;
  if (gradient) {
    const float dx0 = v[1] - v[0], dx1 = v[3] - v[2], dx2 = v[5] - v[4], dx3 = v[7] - v[6];
    const float gx = (1 - t[2]) * (dx0 + t[1] * (dx1 - dx0)) + t[2] * (dx2 + t[1] * (dx3 - dx2));
    const float gy = (1 - t[2]) * (x1 - x0) + t[2] * (x3 - x2);
    const float gz = y1 - y0;
    *gradient = Eigen::Vector3f(gx, gy, gz);
  }
  return result;
}

float SparseVoxelmap::distance_lower_bound(const Eigen::Vector3f& u) const {
  // Outside the grid the object is at least as far as its bounding box; inside, the nearest voxel says more.
  if (!covers(u)) return bounds_distance(u);
  // Nearest voxel; covers() keeps every coordinate above -1/2, so truncation rounds (std::lround is a call).
  const int i = int(u.x() + 0.5f), j = int(u.y() + 0.5f), k = int(u.z() + 0.5f);
  bool stored = true;
  const float value = voxel_value(i, j, k, stored);
  // The distance is 1-Lipschitz: u is no nearer the surface than the voxel's bound less u's offset from it
  // (at most half the voxel diagonal; the actual offset keeps the bound tight).
  return value_lower_bound(value, stored) - (u - Eigen::Vector3f(float(i), float(j), float(k))).norm();
}

}  // namespace voxfmt::runtime
