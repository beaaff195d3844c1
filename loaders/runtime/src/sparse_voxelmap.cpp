#include "voxfmt/runtime/sparse_voxelmap.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace voxfmt::runtime {
namespace {

constexpr int kEdge = SparseVoxelmap::kBrickEdge;
// Half the voxel diagonal: how far a point can be from its nearest voxel centre (the distance is 1-Lipschitz).
constexpr float kHalfDiagonal = 0.8661f;
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
  map.object_min_ = map.to_grid(Eigen::Vector3d(bounds_min[0], bounds_min[1], bounds_min[2]));
  map.object_max_ = map.to_grid(Eigen::Vector3d(bounds_max[0], bounds_max[1], bounds_max[2]));
  // 16-bit fixed point with room for the whole band plus rounding slack.
  const float max_stored = float(std::max(4.0, dense.distance_band + 2.0));
  map.distance_scale_ = 32000.0f / max_stored;

  const int far_layer = -std::max(0, options.outer_layers_kept) - 1;
  const bool have_distances = dense.distances.size() == dense.voxel_count();
  map.bricks_.resize(size_t(map.brick_dims_[0]) * map.brick_dims_[1] * map.brick_dims_[2]);
  std::vector<int> brick_layers(kBrickVoxels);
  std::vector<float> brick_distances(kBrickVoxels);

  size_t b = 0;
  for (int bk = 0; bk < map.brick_dims_[2]; ++bk)
    for (int bj = 0; bj < map.brick_dims_[1]; ++bj)
      for (int bi = 0; bi < map.brick_dims_[0]; ++bi, ++b) {
        int lo = std::numeric_limits<int>::max(), hi = std::numeric_limits<int>::min();
        bool any_distance = false;
        for (int lk = 0; lk < kEdge; ++lk)
          for (int lj = 0; lj < kEdge; ++lj)
            for (int li = 0; li < kEdge; ++li) {
              const int local = (lk * kEdge + lj) * kEdge + li;
              const int i = bi * kEdge + li, j = bj * kEdge + lj, k = bk * kEdge + lk;
              if (i >= map.dims_[0] || j >= map.dims_[1] || k >= map.dims_[2]) {
                brick_layers[local] = std::numeric_limits<int>::min();  // padding, never read
                brick_distances[local] = std::nanf("");
                continue;
              }
              const size_t index = dense.linear_index(uint32_t(i), uint32_t(j), uint32_t(k));
              const int layer = dense.layers[index];
              brick_layers[local] = layer;
              lo = std::min(lo, layer);
              hi = std::max(hi, layer);
              const float d = have_distances ? dense.distances[index] : std::nanf("");
              brick_distances[local] = d;
              any_distance |= voxfmt::Voxelmap::is_stored(d);
            }
        Brick& brick = map.bricks_[b];
        if (hi <= far_layer && !any_distance) {
          brick.kind = BrickKind::FarOutside;
          brick.layer_base = int16_t(hi);
          continue;
        }
        brick.layer_base = int16_t(lo);
        const int range = hi - lo;
        brick.layer_data = uint32_t(map.layer_pool_.size());
        if (range <= 15) {
          brick.kind = BrickKind::Nibbles;
          map.layer_pool_.resize(map.layer_pool_.size() + kBrickVoxels / 2, 0);
          uint8_t* out = map.layer_pool_.data() + brick.layer_data;
          for (int local = 0; local < kBrickVoxels; ++local) {
            const int offset = brick_layers[local] == std::numeric_limits<int>::min() ? 0 : brick_layers[local] - lo;
            out[local / 2] = uint8_t(out[local / 2] | (offset << ((local & 1) * 4)));
          }
        } else {
          // The spec's 6-neighbour rule bounds the range by 21; a file breaking it is clamped, not rejected.
          brick.kind = BrickKind::Bytes;
          map.layer_pool_.resize(map.layer_pool_.size() + kBrickVoxels, 0);
          uint8_t* out = map.layer_pool_.data() + brick.layer_data;
          for (int local = 0; local < kBrickVoxels; ++local) {
            const int offset = brick_layers[local] == std::numeric_limits<int>::min() ? 0 : brick_layers[local] - lo;
            out[local] = uint8_t(std::min(offset, 255));
          }
        }
        if (any_distance) {
          brick.distance_data = uint32_t(map.distance_pool_.size() / kBrickVoxels);
          for (int local = 0; local < kBrickVoxels; ++local) {
            const float d = brick_distances[local];
            const float q = d / float(map.voxel_size_) * map.distance_scale_;
            const bool representable = voxfmt::Voxelmap::is_stored(d) && std::fabs(q) <= 32767.0f;
            map.distance_pool_.push_back(representable ? int16_t(std::lround(q)) : kNotStored);
          }
        }
      }
  map.layer_pool_.shrink_to_fit();
  map.distance_pool_.shrink_to_fit();
  return map;
}

size_t SparseVoxelmap::memory_bytes() const {
  return bricks_.capacity() * sizeof(Brick) + layer_pool_.capacity() + distance_pool_.capacity() * sizeof(int16_t);
}

size_t SparseVoxelmap::layer_brick_count() const {
  return size_t(std::count_if(bricks_.begin(), bricks_.end(),
                              [](const Brick& brick) { return brick.kind != BrickKind::FarOutside; }));
}

// The per-voxel helpers run for every sphere-tree node a query visits: always inlined (GCC kept them calls).
[[gnu::always_inline]] inline const SparseVoxelmap::Brick& SparseVoxelmap::brick_of(int i, int j, int k,
                                                                                    int& local) const {
  local = ((k & (kEdge - 1)) * kEdge + (j & (kEdge - 1))) * kEdge + (i & (kEdge - 1));
  return bricks_[(size_t(k / kEdge) * brick_dims_[1] + j / kEdge) * brick_dims_[0] + i / kEdge];
}

[[gnu::always_inline]] inline int SparseVoxelmap::layer_in(const Brick& brick, int local) const {
  switch (brick.kind) {
    case BrickKind::Nibbles:
      return brick.layer_base + ((layer_pool_[brick.layer_data + local / 2] >> ((local & 1) * 4)) & 0xf);
    case BrickKind::Bytes:
      return brick.layer_base + layer_pool_[brick.layer_data + local];
    case BrickKind::FarOutside:
      break;
  }
  return brick.layer_base;
}

[[gnu::always_inline]] inline bool SparseVoxelmap::distance_in(const Brick& brick, int local, float& distance) const {
  if (brick.distance_data == kNoDistance) return false;
  const int16_t q = distance_pool_[size_t(brick.distance_data) * kBrickVoxels + local];
  if (q == kNotStored) return false;
  distance = float(q) / distance_scale_;
  return true;
}

[[gnu::always_inline]] inline float SparseVoxelmap::estimate_at(int i, int j, int k, bool& exact, bool& bound) const {
  int local = 0;
  const Brick& brick = brick_of(i, j, k, local);
  float distance = 0.0f;
  if (distance_in(brick, local, distance)) return distance;
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
  float distance = 0.0f;
  return distance_in(brick, local, distance) ? distance : std::nanf("");
}

[[gnu::always_inline]] inline bool SparseVoxelmap::covers(const Eigen::Vector3f& u) const {
  return !bricks_.empty() && u.x() > -0.5f && u.y() > -0.5f && u.z() > -0.5f && u.x() < float(dims_[0]) - 0.5f &&
         u.y() < float(dims_[1]) - 0.5f && u.z() < float(dims_[2]) - 0.5f;
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
  // Near the surface the 8 corners usually lie in one brick that stores all their distances: one brick fetch
  // and 8 reads from one 1 KB block.
  bool fetched = false;
  if ((base[0] & (kEdge - 1)) < kEdge - 1 && (base[1] & (kEdge - 1)) < kEdge - 1 &&
      (base[2] & (kEdge - 1)) < kEdge - 1 && dims_[0] > 1 && dims_[1] > 1 && dims_[2] > 1) {
    int local = 0;
    const Brick& brick = brick_of(base[0], base[1], base[2], local);
    if (brick.distance_data != kNoDistance) {
      const int16_t* q = &distance_pool_[size_t(brick.distance_data) * kBrickVoxels + size_t(local)];
      constexpr int kOffset[8] = {
          0, 1, kEdge, kEdge + 1, kEdge * kEdge, kEdge * kEdge + 1, kEdge * kEdge + kEdge, kEdge * kEdge + kEdge + 1};
      fetched = true;
      for (int corner = 0; corner < 8; ++corner) {
        const int16_t stored = q[kOffset[corner]];
        if (stored == kNotStored) {
          fetched = false;
          break;
        }
        v[corner] = float(stored) / distance_scale_;
      }
    }
  }
  if (!fetched)
    for (int corner = 0; corner < 8; ++corner) {
      const int i = std::min(base[0] + (corner & 1), dims_[0] - 1);
      const int j = std::min(base[1] + ((corner >> 1) & 1), dims_[1] - 1);
      const int k = std::min(base[2] + ((corner >> 2) & 1), dims_[2] - 1);
      v[corner] = estimate_at(i, j, k, exact, result.bound);
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
  const float box = bounds_distance(u);
  if (!covers(u)) return box;
  // Nearest voxel; covers() keeps every coordinate above -1/2, so truncation rounds (std::lround is a call).
  const int i = int(u.x() + 0.5f), j = int(u.y() + 0.5f), k = int(u.z() + 0.5f);
  int local = 0;
  const Brick& brick = brick_of(i, j, k, local);
  float distance = 0.0f;
  float at_voxel;
  if (distance_in(brick, local, distance)) {
    at_voxel = distance;
  } else {
    const int layer = layer_in(brick, local);
    // Layer l < 0: outside, |l| less the layers' excess over the exact distance; l >= 0: inside, at most l + 1/2
    // deep (less deep than the layer says, for chamfer layers).
    if (layer_accuracy_ == LayerAccuracy::Chamfer)
      at_voxel = layer < 0 ? (float(-layer) - 0.5f) * kChamferSafety : -(float(layer) + 0.5f) / kChamferSafety;
    else
      at_voxel = layer < 0 ? std::max(0.0f, float(-layer) - kLayerExcess) : -(float(layer) + 0.5f);
  }
  // Outside the object's box the point is outside the object, at least `box` away; inside it the box says nothing.
  return box > 0.0f ? std::max(box, at_voxel - kHalfDiagonal) : at_voxel - kHalfDiagonal;
}

}  // namespace voxfmt::runtime
