// The floor of the bake's cost: OpenVDB's own narrow band (tools::meshToLevelSet) of the same mesh at the same
// voxel size and band, alone in this process, for bench/bench_bake.py --scaling to show beside the whole bake.
// Prints one JSON object: {"resolution", "voxel_size", "band", "seconds", "active_voxels"}.
#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <iostream>

#include "voxfmt/bake/bake.h"

int main(int argc, char** argv) {
  CLI::App app{"bake-floor: OpenVDB's meshToLevelSet alone, the floor of voxfmt build's cost"};
  std::string mesh_path;
  unsigned resolution = 306;
  double band = 3.0;
  app.add_option("mesh", mesh_path, "Mesh file (any format voxfmt build reads)")->required();
  app.add_option("--resolution", resolution, "Voxels along the longest bounding-box axis, as voxfmt build's")
      ->capture_default_str();
  app.add_option("--band", band, "Half-width of the narrow band in voxels (voxfmt build's --band)")
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  const auto mesh = voxfmt::bake::read_mesh(mesh_path);
  if (!mesh) {
    std::cerr << "bake-floor: " << mesh.error().message << "\n";
    return 1;
  }
  const auto& m = mesh.value();
  voxfmt::Vec3 lo = m.vertices.front(), hi = lo;
  for (const auto& v : m.vertices)
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], v[a]), hi[a] = std::max(hi[a], v[a]);
  const double voxel = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]}) / resolution;

  openvdb::initialize();
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  points.reserve(m.vertices.size());
  for (const auto& v : m.vertices) points.emplace_back(float(v[0]), float(v[1]), float(v[2]));
  for (const auto& t : m.triangles) triangles.emplace_back(t[0], t[1], t[2]);
  const auto start = std::chrono::steady_clock::now();
  const openvdb::math::Transform::Ptr transform = openvdb::math::Transform::createLinearTransform(voxel);
  const openvdb::FloatGrid::Ptr grid =
      openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*transform, points, triangles, float(band));
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::cout << "{\"resolution\": " << resolution << ", \"voxel_size\": " << voxel << ", \"band\": " << band
            << ", \"seconds\": " << seconds << ", \"active_voxels\": " << grid->activeVoxelCount() << "}\n";
  return 0;
}
