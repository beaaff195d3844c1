#include "test_support.h"

#include <cmath>
#include <filesystem>

namespace voxfmt::test {

Asset make_full_asset() {
  Asset a;
  a.up_axis = "+Z";
  a.bounds_min = {-0.5, -0.25, -0.125};
  a.bounds_max = {0.5, 0.25, 0.125};
  Voxelmap& vm = a.voxelmap;
  vm.origin = {-0.75, -0.5, -0.375};
  vm.voxel_size = 0.125;
  vm.dims = {13, 9, 5};
  vm.distance_band = 2.5;
  vm.margin = 2;
  // Structurally valid bricks with arbitrary contents: 2 x 2 x 1 bricks, two of them value bricks.
  vm.choose_quanta();
  vm.lattice_error = {0.25, 0.05};
  vm.bricks = {0, Voxelmap::kCoarseOutside, Voxelmap::kCoarseInside, 1};
  for (size_t v = 0; v < 2 * Voxelmap::kBrickVoxels; ++v) vm.brick_values.push_back(int16_t(int(v * 37 % 2001) - 1000));
  for (size_t n = 0; n < vm.lattice_count(); ++n) vm.lattice.push_back(float(0.01 * double(n)));
  PointShell& ps = a.point_shell;
  // Root 0 with children 1..3; node 1 has children 4..5, node 3 has child 6.
  for (int i = 0; i < 7; ++i) {
    ps.points.push_back({0.1 * i, -0.05 * i, 0.004 * i * i});  // within the grid (spec §3)
    const double len = std::sqrt(1.0 + i * i);
    ps.normals.push_back({float(1 / len), 0.0f, float(i / len)});
    ps.sphere_centers.push_back({0.1 * i + 0.001, 0.0, 0.0});
    ps.sphere_radii.push_back(0.5 + i);
  }
  ps.child_begin = {1, 4, 6, 6, 7, 7, 7};
  ps.child_count = {3, 2, 0, 1, 0, 0, 0};
  ps.level_offsets = {0, 1, 4, 7};
  ps.point_spacing = 0.0123;
  ps.branching = 3;
  a.mass.volume = 0.125;
  a.mass.center_of_mass = {0.01, 0.02, -0.03};
  a.mass.inertia = {1e-3, 2e-5, 3e-5, 2e-5, 2e-3, -1e-5, 3e-5, -1e-5, 3e-3};
  Provenance& p = a.provenance;
  p.generator = "test_libvoxfmt";
  p.generator_version = "9.8.7";
  p.source_file = "bunny \xC3\xA9.off";  // UTF-8 survives
  p.source_sha256 = std::string(64, 'a');
  p.build_parameters_json = R"({"resolution":64,"points":7})";
  p.dependency_versions = {{"hdf5", "1.10.8"}, {"openvdb", "10.0.1"}};
  p.build_warnings = {{"OPEN_BORDER", "3 border edges"}, {"SELF_INTERSECTION", "2 faces"}};
  p.created_utc = "2026-11-22T03:14:00Z";
  return a;
}

std::string scratch_dir(const std::string& test_name) {
  const auto dir = std::filesystem::temp_directory_path() / ("voxfmt-test-" + test_name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir.string();
}

}  // namespace voxfmt::test
