#include "asset_field.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/field.h"
#include "voxfmt/io.h"
#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::mujoco {
namespace {

using runtime::core::kEdge;
constexpr int kRow = AssetField::kBlockEdge, kSlice = kRow * kRow;

voxfmt::Error no_distance_field() {
  return voxfmt::Error(voxfmt::IssueCode::InvalidAsset,
                       "the asset has no voxelmap of at least 2 voxels a side: MuJoCo needs its distance field");
}

}  // namespace

voxfmt::Result<std::shared_ptr<const AssetField>> AssetField::load(const std::string& path) {
  // One read and one validation (every rule of `voxfmt validate`), by the runtime's loader.
  runtime::LoadOptions options;
  options.load_point_shell = false;
  auto object = runtime::CollisionObject::load(path, options);
  auto field =
      object ? from_object(*object.value()) : voxfmt::Result<std::shared_ptr<const AssetField>>(object.error());
  if (!field) {
    voxfmt::Error error = field.error();
    if (error.file.empty()) error.file = path;
    if (error.message.find(path) == std::string::npos) error.message = path + ": " + error.message;
    return error;
  }
  return field;
}

voxfmt::Result<std::shared_ptr<const AssetField>> AssetField::from_asset(voxfmt::Asset asset) {
  runtime::LoadOptions options;
  options.load_point_shell = false;
  if (asset.voxelmap.bricks.empty()) return no_distance_field();
  auto object = runtime::CollisionObject::from_asset(std::move(asset), options);
  if (!object) return object.error();
  return from_object(*object.value());
}

voxfmt::Result<std::shared_ptr<const AssetField>> AssetField::from_object(const runtime::CollisionObject& object) {
  const std::array<int, 3> dims = object.has_voxelmap() ? object.voxelmap().dims() : std::array<int, 3>{};
  if (dims[0] < 2 || dims[1] < 2 || dims[2] < 2) return no_distance_field();
  std::shared_ptr<AssetField> field(new AssetField);
  field->set_geometry(object);
  field->fill_blocks(object.voxelmap());
  return std::shared_ptr<const AssetField>(std::move(field));
}

// The runtime's own numbers: its layout and lattice, so that every lattice cell and block is the runtime's field.
void AssetField::set_geometry(const runtime::CollisionObject& object) {
  const runtime::SparseVoxelmap& map = object.voxelmap();
  field_ = field_of(map);
  voxel_size_ = map.voxel_size();
  inverse_voxel_size_ = 1.0 / map.voxel_size();
  origin_ = map.origin();
  size_t lattice_points = 1;
  for (int a = 0; a < 3; ++a) {
    grid_max_[a] = float(field_.dims[a] - 1);
    lattice_points *= size_t(field_.lattice_dims[a]);
  }
  table_.assign(field_.bricks, field_.bricks + map.brick_count());
  lattice_.assign(field_.lattice, field_.lattice + lattice_points);
  field_.lattice = lattice_.data();
  field_.bricks = nullptr;
  field_.codes = nullptr;
  bounds_min_ = object.bounds_min();
  bounds_max_ = object.bounds_max();
  centre_ = 0.5 * (bounds_min_ + bounds_max_);
  volume_ = object.volume();
  center_of_mass_ = object.center_of_mass();
}

// A block for every value brick, and for every coarse brick with a value brick among its + neighbours (its cells
// along that face reach into the value brick's voxels).
void AssetField::fill_blocks(const voxfmt::runtime::SparseVoxelmap& map) {
  const int bx = field_.brick_dims[0], by = field_.brick_dims[1], bz = field_.brick_dims[2];
  const int* dims = field_.dims;
  auto brick = [&](int i, int j, int k) { return (size_t(k) * size_t(by) + size_t(j)) * size_t(bx) + size_t(i); };
  std::vector<char> blocked(table_.size(), 0);
  for (int k = 0; k < bz; ++k)
    for (int j = 0; j < by; ++j)
      for (int i = 0; i < bx; ++i) {
        if (table_[brick(i, j, k)] < 0) continue;
        for (int d = 0; d < 8; ++d) {
          const int ni = i - (d & 1), nj = j - ((d >> 1) & 1), nk = k - (d >> 2);
          if (ni >= 0 && nj >= 0 && nk >= 0) blocked[brick(ni, nj, nk)] = 1;
        }
      }
  size_t count = 0;
  for (char b : blocked) count += size_t(b);
  blocks_.resize(count * size_t(kBlockValues));
  size_t next = 0;
  for (int k = 0; k < bz; ++k)
    for (int j = 0; j < by; ++j)
      for (int i = 0; i < bx; ++i) {
        const size_t b = brick(i, j, k);
        if (!blocked[b]) continue;  // keeps the coarse brick's kCoarseOutside / kCoarseInside
        float* out = &blocks_[next];
        for (int z = 0; z < kBlockEdge; ++z)
          for (int y = 0; y < kBlockEdge; ++y)
            for (int x = 0; x < kBlockEdge; ++x)
              *out++ = map.value_at(std::min(i * kEdge + x, dims[0] - 1), std::min(j * kEdge + y, dims[1] - 1),
                                    std::min(k * kEdge + z, dims[2] - 1));
        table_[b] = int32_t(next);
        next += size_t(kBlockValues);
      }
  blocks_.shrink_to_fit();
}

size_t AssetField::memory_bytes() const {
  return table_.capacity() * sizeof(int32_t) + blocks_.capacity() * sizeof(float) +
         lattice_.capacity() * sizeof(uint16_t);
}

[[gnu::always_inline]] inline float AssetField::lookup(const Eigen::Vector3f& u, Eigen::Vector3f& gradient) const {
  // The cell whose corners surround u, clamped so that all 8 corners exist.
  int base[3];
  float t[3];
  for (int a = 0; a < 3; ++a) {
    base[a] = std::min(int(u[a]), field_.dims[a] - 2);
    t[a] = u[a] - float(base[a]);
  }
  const int32_t entry = table_[(size_t(base[2] >> 3) * size_t(field_.brick_dims[1]) + size_t(base[1] >> 3)) *
                                   size_t(field_.brick_dims[0]) +
                               size_t(base[0] >> 3)];
  runtime::core::Vec3 g;
  float distance;
  if (entry >= 0) {
    const float* v = &blocks_[size_t(entry) + size_t(((base[2] & 7) * kRow + (base[1] & 7)) * kRow + (base[0] & 7))];
    const float c[8] = {v[0],      v[1],          v[kRow],          v[kRow + 1],
                        v[kSlice], v[kSlice + 1], v[kSlice + kRow], v[kSlice + kRow + 1]};
    distance = runtime::core::trilinear(c, t, &g);
  } else {
    distance = runtime::core::coarse_sample(field_, runtime::core::make_vec3(u[0], u[1], u[2]), entry, &g);
  }
  gradient = Eigen::Vector3f(g.x, g.y, g.z);
  return distance;
}

double AssetField::evaluate_raw(const double point[3], Eigen::Vector3f& direction) const {
  Eigen::Vector3f u;
  for (int a = 0; a < 3; ++a) u[a] = float((point[a] - origin_[a]) * inverse_voxel_size_);
  // A NaN point (a NaN pose in the model) is nowhere: as far as an infinite one, and never a lookup (the clamp
  // below keeps NaN, which indexed the brick table far out of bounds).
  if (!u.array().isFinite().all()) {
    direction.setZero();
    return std::numeric_limits<double>::infinity();
  }
  // Beyond the voxel centres the trilinear field would be constant along the clamped axes (a zero gradient that
  // strands a descent): the distance to the box is added there instead.
  const Eigen::Vector3f clamped = u.cwiseMax(Eigen::Vector3f::Zero()).cwiseMin(grid_max_);
  float distance = lookup(clamped, direction);
  const Eigen::Vector3f out = u - clamped;
  const float out2 = out.squaredNorm();
  if (out2 > 0.0f && out2 <= std::numeric_limits<float>::max()) {
    // Along an axis where the point is past the box the distance grows with the offset from it; along the
    // others, with the field at the clamped point.
    const float beyond = std::sqrt(out2), inverse = 1.0f / beyond;
    distance += beyond;
    for (int a = 0; a < 3; ++a)
      if (out[a] != 0.0f) direction[a] = out[a] * inverse;
  } else if (out2 > 0.0f) {  // squares past float's range (1.8e19 voxels away): the same, scaled first
    const float largest = out.cwiseAbs().maxCoeff();
    const Eigen::Vector3f scaled = out / largest;
    const float length = scaled.norm();
    distance += largest * length;
    for (int a = 0; a < 3; ++a)
      if (out[a] != 0.0f) direction[a] = scaled[a] / length;
  }
  return double(distance) * voxel_size_;
}

void AssetField::unit_gradient(const Eigen::Vector3f& direction, const double point[3], double gradient[3]) const {
  const float length2 = direction.squaredNorm();
  if (length2 > 1e-12f) {
    const float scale = 1.0f / std::sqrt(length2);
    for (int a = 0; a < 3; ++a) gradient[a] = double(direction[a] * scale);
    return;
  }
  Eigen::Vector3d away = Eigen::Vector3d(point[0], point[1], point[2]) - centre_;
  // A point at infinity points away along its infinite axes; a NaN one nowhere in particular (UnitZ below).
  if (!away.allFinite())
    for (int a = 0; a < 3; ++a) away[a] = std::isinf(away[a]) ? std::copysign(1.0, away[a]) : 0.0;
  const double n = away.stableNorm();  // beyond 1e154 m the squares overflow
  away = n > 0 ? Eigen::Vector3d(away / n) : Eigen::Vector3d::UnitZ();
  for (int a = 0; a < 3; ++a) gradient[a] = away[a];
}

double AssetField::evaluate(const double point[3], double gradient[3]) const {
  Eigen::Vector3f direction;
  const double distance = evaluate_raw(point, direction);
  if (gradient) unit_gradient(direction, point, gradient);
  return distance;
}

void AssetField::aabb(double margin, double box[6]) const {
  for (int a = 0; a < 3; ++a) {
    box[a] = 0.5 * (bounds_min_[a] + bounds_max_[a]);
    box[3 + a] = 0.5 * (bounds_max_[a] - bounds_min_[a]) + margin;
  }
}

}  // namespace voxfmt::mujoco
