// voxfmt::engines: the NanoVDB grids read back with NanoVDB's own reader and sampler, and the texture SDF sampled as
// Newton samples it, against the runtime's field on baked sample meshes (closed, open, shell).
#include <gtest/gtest.h>

#include <limits>

#define NANOVDB_USE_ZIP
#include <nanovdb/NanoVDB.h>
#include <nanovdb/util/GridValidator.h>
#include <nanovdb/util/IO.h>
#include <nanovdb/util/SampleFromVoxels.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstring>
#include <random>
#include <sstream>

#include "core/field.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/engines/layouts.h"

namespace voxfmt::engines {
namespace {

using runtime::CollisionObject;

std::shared_ptr<const CollisionObject> baked(const std::string& mesh, uint32_t resolution) {
  bake::Settings settings;
  settings.voxelmap.resolution = resolution;
  settings.point_shell.points = 500;
  Result<bake::Baked> b = bake::bake_mesh(std::string(VOXFMT_SAMPLE_MESHES) + "/" + mesh, settings);
  if (!b) throw std::runtime_error(b.error().describe());
  auto object = CollisionObject::from_asset(std::move(b.value().asset));
  if (!object) throw std::runtime_error(object.error().describe());
  return object.value();
}

const CollisionObject& bunny() {
  static const auto object = baked("bunny00.off", 72);
  return *object;
}

/// Grid n of an .nvdb file image.
nanovdb::GridHandle<> read_grid(const std::string& file, uint64_t n) {
  std::istringstream in(file);
  return nanovdb::io::readGrid(in, n);
}

/// The runtime's value of voxel (i, j, k), metres, with `exact` whether it is a stored distance.
float runtime_value(const CollisionObject& o, int i, int j, int k, bool& exact) {
  exact = true;
  const auto f = field_of(o.voxelmap());
  return float(double(runtime::core::voxel_value(f, i, j, k, exact)) * o.voxelmap().voxel_size());
}

void expect_level_set_is_the_runtimes(const CollisionObject& o, const NanoVdbGrids& grids) {
  auto handle = read_grid(grids.file, 0);
  const auto* grid = handle.grid<float>();
  ASSERT_NE(grid, nullptr);
  EXPECT_TRUE(nanovdb::isValid(*grid, true, false));
  EXPECT_EQ(std::string(grid->gridName()), "distance");
  EXPECT_EQ(grid->gridClass(), nanovdb::GridClass::LevelSet);
  const auto& map = o.voxelmap();
  const auto& dims = map.dims();
  const float width = float(grids.width), h = float(map.voxel_size());
  // Every voxel of the grid: within the width the runtime's value; beyond it, in the level set's leaves the runtime's
  // value clamped a cell's diagonal (√3 voxels) past the width (so that every cell with a corner within the width
  // is the runtime's), in its tiles the width, with the runtime's sign (they are signed from the brick table, not
  // flood-filled).
  const float leaf_clamp = (width / h + std::sqrt(3.0f)) * h;
  auto access = grid->getAccessor();
  size_t wrong_value = 0, wrong_sign = 0, voxels = 0;
  for (int k = 0; k < dims[2]; ++k)
    for (int j = 0; j < dims[1]; ++j)
      for (int i = 0; i < dims[0]; ++i, ++voxels) {
        bool exact;
        const float v = runtime_value(o, i, j, k, exact);
        const float g = access.getValue(nanovdb::Coord(i, j, k));
        if (std::abs(v) < width && std::abs(g - v) > 1e-6f * std::max(1.0f, std::abs(v))) ++wrong_value;
        if (v != 0 && (g < 0) != (v < 0)) ++wrong_sign;
        const float beyond = access.isActive(nanovdb::Coord(i, j, k)) ? std::min(std::abs(v), leaf_clamp) : width;
        if (std::abs(v) >= width && std::abs(std::abs(g) - beyond) > 1e-6f * beyond) ++wrong_value;
      }
  EXPECT_EQ(wrong_value, 0u) << "of " << voxels;
  EXPECT_EQ(wrong_sign, 0u) << "of " << voxels;
  // Trilinear samples (NanoVDB's sampler, the one Warp runs) where the runtime interpolates stored distances only,
  // all nearer than the width: the same distance within a micrometre.
  auto sampler = nanovdb::createSampler<1>(grid->tree());
  std::mt19937 random(7);
  std::uniform_real_distribution<float> unit(0, 1);
  int compared = 0;
  float worst = 0;
  for (int n = 0; n < 200000 && compared < 3000; ++n) {
    const Eigen::Vector3f u(unit(random) * float(dims[0] - 1), unit(random) * float(dims[1] - 1),
                            unit(random) * float(dims[2] - 1));
    const runtime::FieldSample s = map.sample(u);
    if (!s.exact) continue;
    bool within = true;
    for (int c = 0; c < 8; ++c) {
      bool stored;
      const float v =
          runtime_value(o, int(u.x()) + (c & 1), int(u.y()) + ((c >> 1) & 1), int(u.z()) + (c >> 2), stored);
      within &= std::abs(v) < width;
    }
    if (!within) continue;
    ++compared;
    worst = std::max(worst, std::abs(sampler(nanovdb::Vec3f(u.x(), u.y(), u.z())) - s.distance * h));
  }
  EXPECT_GT(compared, 500);
  // Float rounding of metres: a micrometre, relatively so for objects larger than a metre.
  const float extent = h * float(std::max({dims[0], dims[1], dims[2]}));
  EXPECT_LT(worst, 1e-6f * std::max(1.0f, extent));
}

TEST(NanoVdbGrids, TheLevelSetIsTheRuntimesFieldWithinItsWidthAndSignedEverywhere) {
  const Result<NanoVdbGrids> grids = nanovdb_grids(bunny());
  ASSERT_TRUE(grids) << grids.error().describe();
  // The default width is the band the asset stores completely: the leaves are exactly its value bricks.
  EXPECT_NEAR(grids->width, (bunny().distance_band() - 0.5) * bunny().voxelmap().voxel_size(), 1e-12);
  EXPECT_EQ(grids->distance_leaves, bunny().voxelmap().value_brick_count());
  expect_level_set_is_the_runtimes(bunny(), grids.value());
}

TEST(NanoVdbGrids, AWiderLevelSetTakesTheBricksItReaches) {
  NanoVdbOptions options;
  options.width_voxels = 6;
  options.compress = false;
  const Result<NanoVdbGrids> grids = nanovdb_grids(bunny(), options);
  ASSERT_TRUE(grids) << grids.error().describe();
  EXPECT_GT(grids->distance_leaves, bunny().voxelmap().value_brick_count());
  EXPECT_NEAR(grids->width, 6 * bunny().voxelmap().voxel_size(), 1e-12);
  expect_level_set_is_the_runtimes(bunny(), grids.value());
}

TEST(NanoVdbGrids, AWidthThatIsNoNumberOfVoxelsIsRefused) {
  for (double width : {-1.0, std::nan(""), 40000.0}) {
    NanoVdbOptions options;
    options.width_voxels = width;
    const Result<NanoVdbGrids> grids = nanovdb_grids(bunny(), options);
    ASSERT_FALSE(grids) << width;
    EXPECT_EQ(grids.error().code, IssueCode::BadOption);
  }
}

TEST(NanoVdbGrids, OpenAndShellAssetsKeepTheirSigns) {
  // CGAL's open_cube.off lacks a face (the winding number closes it); a sheet becomes a shell.
  for (const char* mesh : {"open_cube.off", "cube-ouvert.off", "blade.off"}) {
    SCOPED_TRACE(mesh);
    const auto object = baked(mesh, 40);
    const Result<NanoVdbGrids> grids = nanovdb_grids(*object);
    ASSERT_TRUE(grids) << grids.error().describe();
    expect_level_set_is_the_runtimes(*object, grids.value());
  }
}

TEST(NanoVdbGrids, TheCoarseGridIsTheRuntimesEstimateBetweenBricks) {
  const Result<NanoVdbGrids> grids = nanovdb_grids(bunny());
  ASSERT_TRUE(grids);
  auto handle = read_grid(grids->file, 1);
  const auto* grid = handle.grid<float>();
  ASSERT_NE(grid, nullptr);
  EXPECT_EQ(std::string(grid->gridName()), "coarse");
  const auto& map = bunny().voxelmap();
  const double h = map.voxel_size();
  EXPECT_NEAR(grid->voxelSize()[0], 8 * h, 1e-12);
  const auto f = field_of(map);
  auto sampler = nanovdb::createSampler<1>(grid->tree());
  // Voxels of bricks without codes whose corners are past the band's edge: the runtime interpolates the lattice
  // there, and so does the coarse grid (one cell per brick).
  size_t compared = 0;
  float worst = 0;
  for (int k = 0; k + 8 < map.dims()[2]; k += 3)
    for (int j = 0; j + 8 < map.dims()[1]; j += 3)
      for (int i = 0; i + 8 < map.dims()[0]; i += 3) {
        const int lower[3] = {i >> 3, j >> 3, k >> 3};
        if (runtime::core::entry_of(f, i, j, k) >= 0) continue;
        float p[8];
        runtime::core::cell_values(f, lower, p);
        bool beyond = true;
        for (float v : p) beyond &= v * f.lattice_step >= f.band_edge;
        if (!beyond) continue;
        bool exact;
        const float v = runtime_value(bunny(), i, j, k, exact);
        const float c = sampler(nanovdb::Vec3f(float(i) / 8, float(j) / 8, float(k) / 8));
        worst = std::max(worst, std::abs(c - std::abs(v)));  // the lattice: unsigned
        ++compared;
      }
  EXPECT_GT(compared, 1000u);
  EXPECT_LT(worst, 1e-5 * h * 64);
}

TEST(NanoVdbGrids, EachGridCarriesTheAssetsProvenance) {
  const Result<NanoVdbGrids> grids = nanovdb_grids(bunny());
  ASSERT_TRUE(grids);
  for (uint64_t n = 0; n < 2; ++n) {
    auto handle = read_grid(grids->file, n);
    const auto* grid = handle.grid<float>();
    ASSERT_NE(grid, nullptr);
    ASSERT_EQ(grid->blindDataCount(), 1u);
    const nanovdb::GridBlindMetaData& meta = grid->blindMetaData(0);
    EXPECT_STREQ(meta.mName, "voxfmt");
    const std::string text(meta.getBlindData<char>(), meta.mElementCount);
    const nlohmann::json json = nlohmann::json::parse(text);
    EXPECT_EQ(json["format"], "voxfmt");
    EXPECT_EQ(json["units"], "m");
    EXPECT_EQ(json["grid"], n == 0 ? "distance" : "coarse");
    EXPECT_EQ(json["source_file"], "bunny00.off");
    EXPECT_EQ(json["source_sha256"], bunny().provenance().source_sha256);
    EXPECT_EQ(json["build_parameters"]["resolution"], 72);
    // The first grid says a second follows (Warp's load_next_grid); each starts its own buffer (index 0).
    EXPECT_EQ(grid->gridIndex(), 0u);
    EXPECT_EQ(grid->gridCount(), n == 0 ? 2u : 1u);
  }
}

/// A point sampled as Newton's texture sampler does (sdf_texture.py: the fine cell, its brick's slot, eight texels
/// of the stored brick or the coarse grid's cell), in metres.
float newton_sample(const TextureSdf& t, const Eigen::Vector3d& x) {
  double f[3];
  int cell[3], brick[3];
  for (int a = 0; a < 3; ++a) {
    const double fine = double(t.bricks[size_t(a)]) * TextureSdf::kCells;
    f[a] = std::clamp((x[a] - t.lower[size_t(a)]) / t.cell, 0.0, fine);
    cell[a] = std::clamp(int(std::floor(f[a])), 0, int(fine) - 1);
    brick[a] = std::min(cell[a] / TextureSdf::kCells, t.bricks[size_t(a)] - 1);
  }
  const size_t bx = size_t(t.bricks[0]), by = size_t(t.bricks[1]);
  const uint32_t slot = t.slots[(size_t(brick[2]) * by + size_t(brick[1])) * bx + size_t(brick[0])];
  double v[8], w[3];
  if (slot == TextureSdf::kEmpty) {
    const size_t row = bx + 1, plane = row * (by + 1);
    for (int c = 0; c < 8; ++c)
      v[c] = t.coarse[size_t(brick[2] + (c >> 2)) * plane + size_t(brick[1] + ((c >> 1) & 1)) * row +
                      size_t(brick[0] + (c & 1))];
    for (int a = 0; a < 3; ++a) w[a] = f[a] / TextureSdf::kCells - brick[a];
  } else {
    const int block[3] = {int(slot & 0x3FF), int((slot >> 10) & 0x3FF), int((slot >> 20) & 0x3FF)};
    const size_t side = size_t(t.texture_side);
    for (int c = 0; c < 8; ++c) {
      size_t texel = 0;
      for (int a = 2; a >= 0; --a) {
        const int local = cell[a] - brick[a] * TextureSdf::kCells + ((c >> a) & 1);
        texel = texel * side + size_t(block[a] * TextureSdf::kSamples + local);
      }
      uint16_t code;
      std::memcpy(&code, &t.texels[texel * 2], 2);
      v[c] = double(t.value_min) + double(t.value_range) * (code / 65535.0);
    }
    for (int a = 0; a < 3; ++a) w[a] = f[a] - cell[a];
  }
  const double x0 = v[0] + w[0] * (v[1] - v[0]), x1 = v[2] + w[0] * (v[3] - v[2]);
  const double x2 = v[4] + w[0] * (v[5] - v[4]), x3 = v[6] + w[0] * (v[7] - v[6]);
  const double y0 = x0 + w[1] * (x1 - x0), y1 = x2 + w[1] * (x3 - x2);
  return float(y0 + w[2] * (y1 - y0));
}

TEST(TextureSdf, NewtonsSamplerReadsTheRuntimesFieldWithinOneQuantumNearTheSurface) {
  const Result<TextureSdf> texture = texture_sdf(bunny());
  ASSERT_TRUE(texture) << texture.error().describe();
  const TextureSdf& t = texture.value();
  const auto& map = bunny().voxelmap();
  const double h = map.voxel_size(), quantum = double(t.value_range) / 65535;
  EXPECT_EQ(t.value_bricks, map.value_brick_count());
  EXPECT_LE(t.max_quantisation_error, 0.5 * quantum * 1.001);
  std::mt19937 random(11);
  std::uniform_real_distribution<double> unit(0, 1);
  double worst_exact = 0, worst = 0;
  int exact = 0;
  for (int n = 0; n < 40000; ++n) {
    const Eigen::Vector3d u(unit(random) * (map.dims()[0] - 1), unit(random) * (map.dims()[1] - 1),
                            unit(random) * (map.dims()[2] - 1));
    const runtime::FieldSample s = map.sample(u.cast<float>());
    const double error = std::abs(newton_sample(t, map.origin() + u * h) - double(s.distance) * h);
    worst = std::max(worst, error);
    if (s.exact) worst_exact = std::max(worst_exact, error), ++exact;
  }
  EXPECT_GT(exact, 1000);
  EXPECT_LT(worst_exact, quantum) << "quantum " << quantum / h << " voxel";
  // Elsewhere the coarse grid stands in where it is within the asset's estimate quantum (1/16 voxel).
  EXPECT_LT(worst, h / 16 + quantum);
}

TEST(TextureSdf, EveryFormatAndTheSlotsAddressTheirBricks) {
  for (TextureFormat format : {TextureFormat::Float32, TextureFormat::Uint16, TextureFormat::Uint8}) {
    TextureSdfOptions options;
    options.format = format;
    const Result<TextureSdf> t = texture_sdf(bunny(), options);
    ASSERT_TRUE(t);
    const size_t bytes = format == TextureFormat::Float32 ? 4 : format == TextureFormat::Uint16 ? 2 : 1;
    EXPECT_EQ(t->texels.size(), size_t(t->texture_side) * t->texture_side * t->texture_side * bytes);
    // Every stored brick has its own block.
    std::vector<uint32_t> used;
    for (uint32_t slot : t->slots)
      if (slot != TextureSdf::kEmpty) used.push_back(slot);
    EXPECT_EQ(used.size(), t->value_bricks + t->coarse_stored);
    std::sort(used.begin(), used.end());
    EXPECT_EQ(std::unique(used.begin(), used.end()), used.end());
    const double step = format == TextureFormat::Uint8 ? 255 : 65535;
    if (format != TextureFormat::Float32)
      EXPECT_LE(t->max_quantisation_error, 0.5 * t->value_range / step * 1.001);
    else
      EXPECT_LT(t->max_quantisation_error, 1e-7);
  }
}

TEST(TextureSdf, AFormatOrToleranceThatIsNoneIsRefused) {
  // A format value outside the enum wrote four bytes a texel into a buffer of one (a crash); a NaN tolerance stored
  // no coarse brick at all.
  TextureSdfOptions options;
  options.format = TextureFormat(3);
  Result<TextureSdf> t = texture_sdf(bunny(), options);
  ASSERT_FALSE(t);
  EXPECT_EQ(t.error().code, IssueCode::BadOption);
  options = {};
  options.coarse_tolerance_voxels = std::numeric_limits<double>::quiet_NaN();
  t = texture_sdf(bunny(), options);
  ASSERT_FALSE(t);
  EXPECT_EQ(t.error().code, IssueCode::BadOption);
}

TEST(EngineLayouts, AnObjectWithoutAVoxelmapIsRefused) {
  runtime::LoadOptions options;
  options.load_voxelmap = false;
  bake::Settings settings;
  settings.voxelmap.resolution = 16;
  settings.point_shell.points = 100;
  Result<bake::Baked> b = bake::bake_mesh(std::string(VOXFMT_SAMPLE_MESHES) + "/cube.off", settings);
  ASSERT_TRUE(b);
  const auto shell_only = CollisionObject::from_asset(std::move(b.value().asset), options);
  ASSERT_TRUE(shell_only);
  const Result<NanoVdbGrids> grids = nanovdb_grids(*shell_only.value());
  ASSERT_FALSE(grids);
  EXPECT_EQ(grids.error().code, IssueCode::InvalidAsset);
  const Result<TextureSdf> texture = texture_sdf(*shell_only.value());
  ASSERT_FALSE(texture);
  EXPECT_EQ(texture.error().code, IssueCode::InvalidAsset);
}

}  // namespace
}  // namespace voxfmt::engines
