// voxfmt::exports::write_voxelmap_vdb: the grids read back with OpenVDB hold the asset's voxelmap.
#include <gtest/gtest.h>
#include <openvdb/openvdb.h>
#include <unistd.h>

#include <filesystem>

#include "voxfmt/bake/bake.h"
#include "voxfmt/exports/exports.h"

namespace voxfmt::exports {
namespace {

Asset bake_bunny(uint32_t resolution, uint32_t points) {
  bake::Settings settings;
  settings.voxelmap.resolution = resolution;
  settings.point_shell.points = points;
  Result<bake::Baked> baked = bake::bake_mesh(std::string(VOXFMT_SAMPLE_MESHES) + "/bunny00.off", settings);
  if (!baked) throw std::runtime_error(baked.error().describe());
  return std::move(baked.value().asset);
}

TEST(VdbExport, GridsHoldTheVoxelmap) {
  const Asset asset = bake_bunny(40, 300);
  const Voxelmap& vm = asset.voxelmap;
  const std::string dir = (std::filesystem::temp_directory_path() / "voxfmt-test-vdb").string();
  std::filesystem::create_directories(dir);
  const std::string path = dir + "/bunny.vdb";
  const Result<VdbInfo> written = write_voxelmap_vdb(asset, path);
  ASSERT_TRUE(written) << written.error().describe();
  const VdbInfo& info = written.value();
  EXPECT_EQ(info.distance_voxels, vm.stored_count());
  EXPECT_EQ(info.layer_voxels, vm.voxel_count());

  openvdb::initialize();
  openvdb::io::File file(path);
  file.open();
  openvdb::FloatGrid::Ptr distance = openvdb::gridPtrCast<openvdb::FloatGrid>(file.readGrid("distance"));
  openvdb::Int32Grid::Ptr layers = openvdb::gridPtrCast<openvdb::Int32Grid>(file.readGrid("layers"));
  file.close();
  ASSERT_TRUE(distance && layers);
  EXPECT_EQ(distance->getGridClass(), openvdb::GRID_LEVEL_SET);
  EXPECT_EQ(distance->activeVoxelCount(), vm.stored_count());

  // Voxel centres land where the asset puts them.
  const openvdb::Vec3d centre = distance->transform().indexToWorld(openvdb::Coord(7, 5, 3));
  const Vec3 expected = vm.voxel_center(7, 5, 3);
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(centre[a], expected[a], 1e-12);

  size_t wrong_distance = 0, wrong_side = 0, wrong_layer = 0;
  auto d_access = distance->getConstAccessor();
  auto l_access = layers->getConstAccessor();
  constexpr uint32_t E = Voxelmap::kBrickEdge;
  for (uint32_t k = 0; k < vm.dims[2]; ++k)
    for (uint32_t j = 0; j < vm.dims[1]; ++j)
      for (uint32_t i = 0; i < vm.dims[0]; ++i) {
        const openvdb::Coord c{int(i), int(j), int(k)};
        const VoxelValue value = vm.voxel(i, j, k);
        const int layer = vm.layer(i, j, k);
        // A coarse brick is one tile holding its middle voxel's layer.
        const bool coarse = vm.bricks[vm.brick_index(i / E, j / E, k / E)] < 0;
        const int expected_layer =
            coarse ? vm.layer(std::min(i / E * E + E / 2, vm.dims[0] - 1), std::min(j / E * E + E / 2, vm.dims[1] - 1),
                              std::min(k / E * E + E / 2, vm.dims[2] - 1))
                   : layer;
        wrong_layer += l_access.getValue(c) != expected_layer;
        if (value.stored) {
          wrong_distance += !d_access.isValueOn(c) || d_access.getValue(c) != float(value.distance);
        } else if (layer != 0) {
          wrong_side += (d_access.getValue(c) < 0) != (layer > 0);  // inside: negative background
        }
      }
  EXPECT_EQ(wrong_distance, 0u);
  EXPECT_EQ(wrong_side, 0u);
  EXPECT_EQ(wrong_layer, 0u);
  EXPECT_FALSE(std::filesystem::exists(path + ".partial-" + std::to_string(::getpid())));
}

TEST(VdbExport, UnwritablePathIsAnErrorNamingIt) {
  const Asset asset = bake_bunny(16, 50);
  const Result<VdbInfo> written = write_voxelmap_vdb(asset, "/nonexistent-dir/x.vdb");
  ASSERT_FALSE(written);
  EXPECT_EQ(written.error().code, IssueCode::WriteFailed);
  EXPECT_EQ(written.error().file, "/nonexistent-dir/x.vdb");
  EXPECT_NE(written.error().message.find("/nonexistent-dir/x.vdb"), std::string::npos) << written.error().message;
}

}  // namespace
}  // namespace voxfmt::exports
