// The texture SDF layout (Newton's, nearly PhysX's) from the runtime's field: the coarse grid at brick corners,
// then which bricks are stored (those with codes, and those the coarse grid would not reproduce), then the packed
// texture of their 9^3 samples, quantised over their range.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <new>

#include "field_samples.h"
#include "voxfmt/engines/layouts.h"

namespace voxfmt::engines {

namespace {

using detail::FieldSamples;
namespace core = runtime::core;
constexpr int kCells = TextureSdf::kCells, kSamples = TextureSdf::kSamples;
constexpr int kBrickSamples = kSamples * kSamples * kSamples;
constexpr int kMaxBlocksPerSide = 1024;  // 10-bit block coordinates in a slot

uint32_t max_code(TextureFormat format) {
  return format == TextureFormat::Uint16 ? 65535u : format == TextureFormat::Uint8 ? 255u : 0u;
}

size_t texel_bytes(TextureFormat format) {
  return format == TextureFormat::Float32 ? 4 : format == TextureFormat::Uint16 ? 2 : 1;
}

/// The 9^3 samples (voxels) of brick (a, b, c): voxels 8a .. 8a + 8 along x, and so on.
void brick_samples(const FieldSamples& field, int a, int b, int c, float* out) {
  int n = 0;
  for (int z = 0; z < kSamples; ++z)
    for (int y = 0; y < kSamples; ++y)
      for (int x = 0; x < kSamples; ++x) out[n++] = field.value(a * kCells + x, b * kCells + y, c * kCells + z);
}

/// Whether the coarse grid reproduces brick (a, b, c) by construction, up to float rounding: its samples (voxels 8a
/// .. 8a + 8 along each axis) all lie in the grid and in bricks without codes of its own sign, and the lattice at its
/// corners is beyond the band's edge, so the runtime's values there are the lattice's interpolation unclamped.
bool coarse_by_construction(const FieldSamples& field, int a, int b, int c) {
  const core::Field& f = field.field();
  const int32_t entry = field.brick(a, b, c);
  if (entry >= 0 || (a + 1) * kCells >= f.dims[0] || (b + 1) * kCells >= f.dims[1] || (c + 1) * kCells >= f.dims[2])
    return false;
  for (int n = 1; n < 8; ++n)
    if (field.brick(a + (n & 1), b + ((n >> 1) & 1), c + (n >> 2)) != entry) return false;
  return field.least_corner(a, b, c) >= f.band_edge;
}

/// The largest difference, over a brick's samples inside the grid, between the runtime's value and the coarse
/// grid's trilinear interpolation (voxels): the error the engine would make reading the brick from the coarse grid.
float coarse_error(const FieldSamples& field, const std::vector<float>& coarse, const std::array<int, 3>& bricks, int a,
                   int b, int c) {
  const size_t row = size_t(bricks[0]) + 1, plane = row * (size_t(bricks[1]) + 1);
  const float* q = &coarse[size_t(c) * plane + size_t(b) * row + size_t(a)];
  const float v[8] = {q[0], q[1], q[row], q[row + 1], q[plane], q[plane + 1], q[plane + row], q[plane + row + 1]};
  float worst = 0;
  for (int z = 0; z < kSamples; ++z)
    for (int y = 0; y < kSamples; ++y)
      for (int x = 0; x < kSamples; ++x) {
        const int i = a * kCells + x, j = b * kCells + y, k = c * kCells + z;
        if (!field.in_grid(i, j, k)) continue;
        const float tx = float(x) / kCells, ty = float(y) / kCells, tz = float(z) / kCells;
        const float x0 = v[0] + tx * (v[1] - v[0]), x1 = v[2] + tx * (v[3] - v[2]);
        const float x2 = v[4] + tx * (v[5] - v[4]), x3 = v[6] + tx * (v[7] - v[6]);
        const float y0 = x0 + ty * (x1 - x0), y1 = x2 + ty * (x3 - x2);
        worst = std::max(worst, std::abs(y0 + tz * (y1 - y0) - field.value(i, j, k)));
      }
  return worst;
}

// The coarse grid at the brick corners, in voxels.
std::vector<float> coarse_grid(const FieldSamples& field, const std::array<int, 3>& nb) {
  std::vector<float> coarse(size_t(nb[0] + 1) * size_t(nb[1] + 1) * size_t(nb[2] + 1));
  size_t n = 0;
  for (int c = 0; c <= nb[2]; ++c)
    for (int b = 0; b <= nb[1]; ++b)
      for (int a = 0; a <= nb[0]; ++a) coarse[n++] = field.coarse_corner(a, b, c);
  return coarse;
}

// Which bricks are stored, and the range of their samples (voxels) that the quantisation spans: those with codes;
// then those without whose coarse interpolation is off by more than the tolerance. Their samples are computed again
// when packed: kept, they would take 4 bytes a sample, twice the uint16 texture.
struct StoredBricks {
  std::vector<uint8_t> stored;
  float lo = std::numeric_limits<float>::max(), hi = -std::numeric_limits<float>::max();
};

StoredBricks choose_bricks(const FieldSamples& field, double tolerance, TextureSdf& out) {
  const auto& nb = out.bricks;
  StoredBricks chosen;
  chosen.stored.assign(size_t(nb[0]) * size_t(nb[1]) * size_t(nb[2]), 0);
  std::vector<float> samples(kBrickSamples);
  auto store = [&](int a, int b, int c, int n) {
    chosen.stored[size_t(n)] = 1;
    brick_samples(field, a, b, c, samples.data());
    for (float s : samples) chosen.lo = std::min(chosen.lo, s), chosen.hi = std::max(chosen.hi, s);
  };
  for (int c = 0, n = 0; c < nb[2]; ++c)
    for (int b = 0; b < nb[1]; ++b)
      for (int a = 0; a < nb[0]; ++a, ++n)
        if (field.brick(a, b, c) >= 0) {
          store(a, b, c, n);
          ++out.value_bricks;
        }
  for (int c = 0, n = 0; c < nb[2]; ++c)
    for (int b = 0; b < nb[1]; ++b)
      for (int a = 0; a < nb[0]; ++a, ++n)
        if (!chosen.stored[size_t(n)] && !coarse_by_construction(field, a, b, c) &&
            coarse_error(field, out.coarse, nb, a, b, c) > tolerance) {
          store(a, b, c, n);
          ++out.coarse_stored;
        }
  return chosen;
}

// A brick's samples (voxels) into its block (bx, by, bz) of the texture, quantised to `codes` levels over the
// texture's range (0: float32); the largest quantisation error kept.
void pack_brick(const float* samples, uint32_t bx, uint32_t by, uint32_t bz, uint32_t codes, double h,
                TextureSdf& out) {
  const size_t side = size_t(out.texture_side);
  int s = 0;
  for (int z = 0; z < kSamples; ++z)
    for (int y = 0; y < kSamples; ++y)
      for (int x = 0; x < kSamples; ++x, ++s) {
        const size_t texel = ((size_t(bz) * kSamples + size_t(z)) * side + size_t(by) * kSamples + size_t(y)) * side +
                             size_t(bx) * kSamples + size_t(x);
        const double metres = double(samples[s]) * h;
        double decoded = float(metres);
        if (codes == 0) {
          const float v = float(metres);
          std::memcpy(&out.texels[texel * 4], &v, 4);
        } else {
          const double code = std::clamp(
              std::nearbyint((metres - double(out.value_min)) / double(out.value_range) * codes), 0.0, double(codes));
          if (codes == 65535u) {
            const uint16_t v = uint16_t(code);
            std::memcpy(&out.texels[texel * 2], &v, 2);
          } else {
            out.texels[texel] = uint8_t(code);
          }
          decoded = double(out.value_min) + double(out.value_range) * (code / codes);
        }
        out.max_quantisation_error = std::max(out.max_quantisation_error, std::abs(decoded - metres));
      }
}

Result<TextureSdf> build_texture_sdf(const runtime::CollisionObject& object, const TextureSdfOptions& options) {
  if (!object.has_voxelmap())
    return Error{IssueCode::InvalidAsset, "texture_sdf: the object has no voxelmap (loaded point shell only)"};
  if (options.format != TextureFormat::Float32 && options.format != TextureFormat::Uint16 &&
      options.format != TextureFormat::Uint8)
    return Error{IssueCode::BadOption,
                 "texture_sdf: format " + std::to_string(int(options.format)) + " is none of Float32, Uint16, Uint8"};
  if (std::isnan(options.coarse_tolerance_voxels))
    return Error{IssueCode::BadOption, "texture_sdf: coarse_tolerance_voxels is NaN (negative: the default)"};
  const runtime::SparseVoxelmap& map = object.voxelmap();
  const FieldSamples field(field_of(map));
  const double h = map.voxel_size();
  TextureSdf out;
  out.format = options.format;
  out.cell = h;
  for (int a = 0; a < 3; ++a) {
    out.lower[size_t(a)] = map.origin()[a];
    out.bricks[size_t(a)] = std::max(1, (map.dims()[size_t(a)] - 1 + kCells - 1) / kCells);
  }
  const auto& nb = out.bricks;
  out.coarse = coarse_grid(field, nb);
  const double tolerance =
      options.coarse_tolerance_voxels < 0 ? field.field().decode_step[0] : options.coarse_tolerance_voxels;
  const StoredBricks chosen = choose_bricks(field, tolerance, out);
  const size_t blocks = out.value_bricks + out.coarse_stored;
  // The packed texture: block m at (m % k, m / k % k, m / k^2), k blocks a side.
  int k = 0;
  while (size_t(k) * size_t(k) * size_t(k) < blocks) ++k;
  if (k > kMaxBlocksPerSide)
    return Error{IssueCode::OutOfMemory, "texture_sdf: " + std::to_string(blocks) +
                                             " bricks need more than 1024 blocks along a side of the texture"};
  out.blocks_per_side = k;
  out.texture_side = std::max(1, k * kSamples);
  const uint32_t codes = max_code(options.format);
  if (codes != 0 && blocks > 0) {
    out.value_min = chosen.lo * float(h);
    out.value_range = std::max((chosen.hi - chosen.lo) * float(h), std::numeric_limits<float>::min());
  }
  const size_t side = size_t(out.texture_side);
  out.texels.assign(side * side * side * texel_bytes(options.format), 0);
  out.slots.assign(chosen.stored.size(), TextureSdf::kEmpty);
  std::vector<float> samples(kBrickSamples);
  size_t m = 0;
  for (int c = 0, n = 0; c < nb[2]; ++c)
    for (int b = 0; b < nb[1]; ++b)
      for (int a = 0; a < nb[0]; ++a, ++n) {
        if (!chosen.stored[size_t(n)]) continue;
        const uint32_t bx = uint32_t(m % size_t(k)), by = uint32_t(m / size_t(k) % size_t(k)),
                       bz = uint32_t(m / (size_t(k) * size_t(k)));
        ++m;
        out.slots[size_t(n)] = (bz << 20) | (by << 10) | bx;
        brick_samples(field, a, b, c, samples.data());
        pack_brick(samples.data(), bx, by, bz, codes, h, out);
      }
  for (float& v : out.coarse) v *= float(h);
  return out;
}

}  // namespace

Result<TextureSdf> texture_sdf(const runtime::CollisionObject& object, const TextureSdfOptions& options) {
  try {
    return build_texture_sdf(object, options);
  } catch (const std::bad_alloc&) {
    return Error{IssueCode::OutOfMemory, "texture_sdf: out of memory building the texture"};
  }
}

}  // namespace voxfmt::engines
