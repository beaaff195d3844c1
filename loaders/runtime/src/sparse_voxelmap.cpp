#include "voxfmt/runtime/sparse_voxelmap.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace voxfmt::runtime {
namespace {

constexpr int kEdge = SparseVoxelmap::kBrickEdge;
constexpr unsigned kEdgeBits = 3;
static_assert(kEdge == 1 << kEdgeBits);
// Format 1.0 layers beyond the band come from a 26-neighbour chamfer transform, which overestimates Euclidean
// distance by at most ~11% (direction (3,2,1)); lower bounds scale layer distances by this factor.
constexpr float kChamferSafety = 0.9f;
// Format 1.1 layers are at most 1/2 + sqrt(3) voxels deeper than the exact depth (spec §3).
constexpr float kLayerExcess = 0.5f + 1.7320508f;

int div_up(int a, int b) { return (a + b - 1) / b; }

}  // namespace

SparseVoxelmap SparseVoxelmap::from_dense(const voxfmt::Voxelmap& dense, const voxfmt::Vec3& bounds_min,
                                          const voxfmt::Vec3& bounds_max, const Options& options,
                                          LayerAccuracy accuracy) {
  SparseVoxelmap map;
  map.layer_accuracy_ = accuracy;
  map.origin_ = Eigen::Vector3d(dense.origin[0], dense.origin[1], dense.origin[2]);
  map.voxel_size_ = dense.voxel_size;
  for (int a = 0; a < 3; ++a) {
    map.dims_[a] = int(dense.dims[a]);
    map.brick_dims_[a] = div_up(map.dims_[a], kEdge);
  }
  // An empty grid covers nothing.
  for (int a = 0; a < 3; ++a) map.cover_max_[a] = map.dims_[a] > 0 ? float(map.dims_[a]) - 0.5f : -1.0f;
  map.object_min_ = map.to_grid(Eigen::Vector3d(bounds_min[0], bounds_min[1], bounds_min[2]));
  map.object_max_ = map.to_grid(Eigen::Vector3d(bounds_max[0], bounds_max[1], bounds_max[2]));

  const int far_layer = -std::max(0, options.outer_layers_kept) - 1;
  const bool have_distances = dense.distances.size() == dense.voxel_count();
  const double h = dense.voxel_size;
  map.bricks_.resize(size_t(map.brick_dims_[0]) * map.brick_dims_[1] * map.brick_dims_[2]);
  // Calls f(local, i, j, k) for the voxels of brick (bi, bj, bk) that lie in the grid.
  auto for_voxels = [&](int bi, int bj, int bk, auto&& f) {
    for (int lk = 0; lk < kEdge; ++lk)
      for (int lj = 0; lj < kEdge; ++lj)
        for (int li = 0; li < kEdge; ++li) {
          const int i = bi * kEdge + li, j = bj * kEdge + lj, k = bk * kEdge + lk;
          if (i < map.dims_[0] && j < map.dims_[1] && k < map.dims_[2])
            f((lk * kEdge + lj) * kEdge + li, dense.linear_index(uint32_t(i), uint32_t(j), uint32_t(k)));
        }
  };
  auto stored = [&](size_t index) { return have_distances && voxfmt::Voxelmap::is_stored(dense.distances[index]); };

  // First pass: each brick's kind and layer range, and the largest stored distance (which sets the fixed-point
  // scale).
  double largest_value = 4.0;
  size_t b = 0;
  for (int bk = 0; bk < map.brick_dims_[2]; ++bk)
    for (int bj = 0; bj < map.brick_dims_[1]; ++bj)
      for (int bi = 0; bi < map.brick_dims_[0]; ++bi, ++b) {
        int lo = std::numeric_limits<int>::max(), hi = std::numeric_limits<int>::min();
        bool any_distance = false;
        for_voxels(bi, bj, bk, [&](int, size_t index) {
          lo = std::min<int>(lo, dense.layers[index]);
          hi = std::max<int>(hi, dense.layers[index]);
          any_distance |= stored(index);
        });
        Brick& brick = map.bricks_[b];
        brick.layer_base = int16_t(lo);
        if (any_distance) {
          brick.kind = BrickKind::Values;
          for_voxels(bi, bj, bk, [&](int, size_t index) {
            if (stored(index)) largest_value = std::max(largest_value, std::abs(double(dense.distances[index]) / h));
          });
        } else if (hi <= far_layer) {
          brick.kind = BrickKind::FarOutside;
          brick.layer_base = int16_t(hi);
        } else {
          brick.kind = hi - lo <= 15 ? BrickKind::Nibbles : BrickKind::Bytes;
        }
      }
  // 15 bits for a distance: a whole number of steps per voxel when it fits.
  const double steps = 16000.0 / (largest_value + 1.0);
  map.value_scale_ = float(steps >= 1.0 ? std::floor(steps) : steps);
  map.value_step_ = 1.0f / map.value_scale_;
  map.decode_step_[0] = 1.0f;  // layers are whole
  map.decode_step_[1] = map.value_step_;
  map.value_slack_ = 0.5f / map.value_scale_ + 1e-6f * float(largest_value);

  // Second pass: the payloads.
  b = 0;
  for (int bk = 0; bk < map.brick_dims_[2]; ++bk)
    for (int bj = 0; bj < map.brick_dims_[1]; ++bj)
      for (int bi = 0; bi < map.brick_dims_[0]; ++bi, ++b) {
        Brick& brick = map.bricks_[b];
        switch (brick.kind) {
          case BrickKind::FarOutside:
            break;
          case BrickKind::Nibbles: {
            brick.data = uint32_t(map.layer_pool_.size());
            map.layer_pool_.resize(map.layer_pool_.size() + kBrickVoxels / 2, 0);
            uint8_t* out = map.layer_pool_.data() + brick.data;
            for_voxels(bi, bj, bk, [&](int local, size_t index) {
              out[local / 2] =
                  uint8_t(out[local / 2] | ((dense.layers[index] - brick.layer_base) << ((local & 1) * 4)));
            });
            break;
          }
          case BrickKind::Bytes: {
            // The spec's 6-neighbour rule bounds the range by 21; a file breaking it is clamped, not rejected.
            brick.data = uint32_t(map.layer_pool_.size());
            map.layer_pool_.resize(map.layer_pool_.size() + kBrickVoxels, 0);
            uint8_t* out = map.layer_pool_.data() + brick.data;
            for_voxels(bi, bj, bk, [&](int local, size_t index) {
              out[local] = uint8_t(std::min(dense.layers[index] - brick.layer_base, 255));
            });
            break;
          }
          case BrickKind::Values: {
            brick.data = uint32_t(map.value_pool_.size() / kBrickVoxels);
            map.value_pool_.resize(map.value_pool_.size() + kBrickVoxels, 0);
            int16_t* out = map.value_pool_.data() + size_t(brick.data) * kBrickVoxels;
            const double scale = map.value_scale_;
            for_voxels(bi, bj, bk, [&](int local, size_t index) {
              const int layer = dense.layers[index];
              if (!stored(index)) {  // minus the layer, whole (deeper than 16383 voxels is clamped)
                out[local] = int16_t(std::clamp(-layer, -16383, 16383) * 2);
                return;
              }
              long q = std::lround(double(dense.distances[index]) / h * scale);
              // Rounding may carry a distance across a layer boundary (spec §3: layer = floor(-d/h + 1/2)); a step
              // back keeps the layer the file gives, which layer_at() reports.
              auto implied = [&](long v) { return long(std::floor(-double(v) / scale + 0.5)); };
              if (implied(q) != layer && implied(q + 1) == layer) ++q;
              if (implied(q) != layer && implied(q - 1) == layer) --q;
              out[local] = int16_t(q * 2 + 1);
            });
            break;
          }
        }
      }
  map.layer_pool_.shrink_to_fit();
  map.value_pool_.shrink_to_fit();
  return map;
}

size_t SparseVoxelmap::memory_bytes() const {
  return bricks_.capacity() * sizeof(Brick) + layer_pool_.capacity() + value_pool_.capacity() * sizeof(int16_t);
}

size_t SparseVoxelmap::layer_brick_count() const {
  return size_t(std::count_if(bricks_.begin(), bricks_.end(), [](const Brick& brick) {
    return brick.kind == BrickKind::Nibbles || brick.kind == BrickKind::Bytes;
  }));
}

// The per-voxel helpers run for every sphere-tree node a query visits: always inlined (GCC kept them calls).
[[gnu::always_inline]] inline const SparseVoxelmap::Brick& SparseVoxelmap::brick_of(int i, int j, int k,
                                                                                    int& local) const {
  // Voxel indices are never negative: shifts, not signed divisions (GCC kept idiv for those).
  local = ((k & (kEdge - 1)) * kEdge + (j & (kEdge - 1))) * kEdge + (i & (kEdge - 1));
  return bricks_[(size_t(unsigned(k) >> kEdgeBits) * unsigned(brick_dims_[1]) + (unsigned(j) >> kEdgeBits)) *
                     unsigned(brick_dims_[0]) +
                 (unsigned(i) >> kEdgeBits)];
}

[[gnu::always_inline]] inline float SparseVoxelmap::value_in(const Brick& brick, int local, bool& exact) const {
  const int v = value_pool_[size_t(brick.data) * kBrickVoxels + size_t(local)];
  exact = (v & 1) != 0;
  return float(v >> 1) * decode_step_[v & 1];
}

[[gnu::always_inline]] inline int SparseVoxelmap::layer_in(const Brick& brick, int local) const {
  switch (brick.kind) {
    case BrickKind::Nibbles:
      return brick.layer_base + ((layer_pool_[brick.data + local / 2] >> ((local & 1) * 4)) & 0xf);
    case BrickKind::Bytes:
      return brick.layer_base + layer_pool_[brick.data + local];
    case BrickKind::Values: {  // only layer_at() asks: a stored distance implies its layer (spec §3)
      const int v = value_pool_[size_t(brick.data) * kBrickVoxels + size_t(local)];
      return (v & 1) ? int(std::floor(-double(v >> 1) / value_scale_ + 0.5)) : -(v >> 1);
    }
    case BrickKind::FarOutside:
      break;
  }
  return brick.layer_base;
}

[[gnu::always_inline]] inline float SparseVoxelmap::layer_lower_bound(float layer) const {
  // Layer l < 0: outside, |l| less the layers' excess over the exact distance; l >= 0: inside, at most l + 1/2
  // deep (less deep than the layer says, for chamfer layers).
  if (layer_accuracy_ == LayerAccuracy::Chamfer)
    return layer < 0 ? (-layer - 0.5f) * kChamferSafety : -(layer + 0.5f) / kChamferSafety;
  return layer < 0 ? std::max(0.0f, -layer - kLayerExcess) : -(layer + 0.5f);
}

[[gnu::always_inline]] inline float SparseVoxelmap::estimate_in(const Brick& brick, int local, bool& exact,
                                                                bool& bound) const {
  if (brick.kind == BrickKind::Values) {
    bool stored = false;
    const float value = value_in(brick, local, stored);
    exact &= stored;
    return value;
  }
  exact = false;
  bound |= brick.kind == BrickKind::FarOutside;
  return -float(layer_in(brick, local));
}

int SparseVoxelmap::layer_at(int i, int j, int k) const {
  int local = 0;
  const Brick& brick = brick_of(i, j, k, local);
  return layer_in(brick, local);
}

float SparseVoxelmap::stored_distance_at(int i, int j, int k) const {
  int local = 0;
  const Brick& brick = brick_of(i, j, k, local);
  if (brick.kind != BrickKind::Values) return std::nanf("");
  bool exact = false;
  const float value = value_in(brick, local, exact);
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
  // Near the surface the 8 corners usually lie in one Values brick: one header and two cache lines.
  bool fetched = false;
  if ((base[0] & (kEdge - 1)) < kEdge - 1 && (base[1] & (kEdge - 1)) < kEdge - 1 &&
      (base[2] & (kEdge - 1)) < kEdge - 1 && dims_[0] > 1 && dims_[1] > 1 && dims_[2] > 1) {
    int local = 0;
    const Brick& brick = brick_of(base[0], base[1], base[2], local);
    if (brick.kind == BrickKind::Values) {
      const int16_t* q = &value_pool_[size_t(brick.data) * kBrickVoxels + size_t(local)];
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
    }
  }
  if (!fetched) {
    // Corners in several bricks: each axis's two voxel coordinates split once into brick and offset.
    unsigned brick_part[3][2], local_part[3][2];
    for (int a = 0; a < 3; ++a)
      for (int side = 0; side < 2; ++side) {
        const unsigned c = unsigned(std::min(base[a] + side, dims_[a] - 1));
        brick_part[a][side] = c >> kEdgeBits;
        local_part[a][side] = c & (kEdge - 1);
      }
    for (int corner = 0; corner < 8; ++corner) {
      const int x = corner & 1, y = (corner >> 1) & 1, z = corner >> 2;
      const Brick& brick =
          bricks_[(size_t(brick_part[2][z]) * unsigned(brick_dims_[1]) + brick_part[1][y]) * unsigned(brick_dims_[0]) +
                  brick_part[0][x]];
      const int local = int((local_part[2][z] * kEdge + local_part[1][y]) * kEdge + local_part[0][x]);
      v[corner] = estimate_in(brick, local, exact, result.bound);
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
  int local = 0;
  const Brick& brick = brick_of(i, j, k, local);
  float at_voxel;
  if (brick.kind == BrickKind::Values) {
    bool exact = false;
    const float value = value_in(brick, local, exact);
    // Fixed point moves a distance by up to half a step either way.
    at_voxel = exact ? value - value_slack_ : layer_lower_bound(-value);
  } else {
    at_voxel = layer_lower_bound(float(layer_in(brick, local)));
  }
  // The distance is 1-Lipschitz: u is no nearer the surface than the voxel's bound less u's offset from it
  // (at most half the voxel diagonal; the actual offset keeps the bound tight).
  return at_voxel - (u - Eigen::Vector3f(float(i), float(j), float(k))).norm();
}

}  // namespace voxfmt::runtime
