// What a baked asset gives its user, for bench/bench_bake.py --scaling: the runtime's load time and memory
// (CollisionObject::load, read isolation as configured), and the accuracy of the voxelmap against the exact mesh
// (CGAL's AABB tree and side-of-mesh test): stored band distances and estimates beyond the band, on random samples.
// Prints one JSON object.
#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Side_of_triangle_mesh.h>
#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>
#include <CLI/CLI.hpp>

#include <chrono>
#include <cmath>
#include <iostream>
#include <random>

#include "voxfmt/bake/bake.h"
#include "voxfmt/io.h"
#include "voxfmt/runtime/collision_object.h"

namespace {
using K = CGAL::Simple_cartesian<double>;
using Point = K::Point_3;
using Mesh = CGAL::Surface_mesh<Point>;
using Primitive = CGAL::AABB_triangle_primitive<K, std::vector<K::Triangle_3>::const_iterator>;
using Tree = CGAL::AABB_tree<CGAL::AABB_traits<K, Primitive>>;
}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"asset-check: load time, runtime memory and accuracy of a baked asset against its mesh"};
  std::string asset_path, mesh_path;
  size_t samples = 20000;
  app.add_option("asset", asset_path, "The baked asset (.vox.h5)")->required();
  app.add_option("mesh", mesh_path, "The mesh it was baked from")->required();
  app.add_option("--samples", samples, "Voxels sampled for each accuracy figure")->capture_default_str();
  uint64_t max_memory_mib = voxfmt::ReadOptions::kDefaultReadMemoryBytes >> 20;
  app.add_option("--max-memory", max_memory_mib, "MiB a read may take (a 4096^3 bake needs ~2.1 GB)")
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 30))
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  voxfmt::runtime::LoadOptions load;
  load.read.max_memory_bytes = max_memory_mib << 20;

  const auto start = std::chrono::steady_clock::now();
  const auto object = voxfmt::runtime::CollisionObject::load(asset_path, load);
  const double load_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!object) {
    std::cerr << "asset-check: " << object.error().message << "\n";
    return 1;
  }
  const size_t runtime_bytes = object.value()->memory_bytes();

  const auto asset = voxfmt::read_asset(asset_path, nullptr, load.read);
  const auto mesh = voxfmt::bake::read_mesh(mesh_path);
  if (!asset || !mesh) {
    std::cerr << "asset-check: cannot read " << (asset ? mesh_path : asset_path) << "\n";
    return 1;
  }
  const voxfmt::Voxelmap& vm = asset.value().voxelmap;
  std::vector<K::Triangle_3> triangles;
  Mesh surface;
  std::vector<Mesh::Vertex_index> index;
  for (const auto& v : mesh.value().vertices) index.push_back(surface.add_vertex(Point(v[0], v[1], v[2])));
  for (const auto& t : mesh.value().triangles) {
    const auto& a = mesh.value().vertices[t[0]];
    const auto& b = mesh.value().vertices[t[1]];
    const auto& c = mesh.value().vertices[t[2]];
    triangles.emplace_back(Point(a[0], a[1], a[2]), Point(b[0], b[1], b[2]), Point(c[0], c[1], c[2]));
    surface.add_face(index[t[0]], index[t[1]], index[t[2]]);
  }
  Tree tree(triangles.begin(), triangles.end());
  tree.accelerate_distance_queries();
  const CGAL::Side_of_triangle_mesh<Mesh, K> side(surface);
  const double h = vm.voxel_size;
  auto exact = [&](uint32_t i, uint32_t j, uint32_t k) {
    const voxfmt::Vec3 p = vm.voxel_center(i, j, k);
    const Point q(p[0], p[1], p[2]);
    const double u = std::sqrt(tree.squared_distance(q));
    return side(q) == CGAL::ON_BOUNDED_SIDE ? -u : u;
  };

  std::mt19937_64 rng(7);
  double band_max = 0, band_sum = 0, estimate_max = 0, estimate_sum = 0;
  size_t band_n = 0, estimate_n = 0, wrong_sign = 0, out_of_bound = 0;
  const double q = 0.5 * vm.estimate_quantum / h;
  for (size_t tries = 0; tries < 200 * samples && (band_n < samples || estimate_n < samples); ++tries) {
    // Value bricks hold the band: pick one, then a voxel in it; a coarse voxel anywhere half of the time.
    uint32_t i, j, k;
    if (rng() % 2 == 0 && vm.value_brick_count() > 0) {
      size_t b;
      do b = rng() % vm.bricks.size();
      while (vm.bricks[b] < 0);
      const auto bd = vm.brick_dims();
      i = uint32_t(b % bd[0]) * 8 + uint32_t(rng() % 8);
      j = uint32_t(b / bd[0] % bd[1]) * 8 + uint32_t(rng() % 8);
      k = uint32_t(b / (size_t(bd[0]) * bd[1])) * 8 + uint32_t(rng() % 8);
      if (i >= vm.dims[0] || j >= vm.dims[1] || k >= vm.dims[2]) continue;
    } else {
      i = uint32_t(rng() % vm.dims[0]), j = uint32_t(rng() % vm.dims[1]), k = uint32_t(rng() % vm.dims[2]);
    }
    const voxfmt::VoxelValue value = vm.voxel(i, j, k);
    if (value.stored ? band_n >= samples : estimate_n >= samples) continue;
    const double d = exact(i, j, k) / h, v = value.distance / h;
    if (value.stored) {
      band_max = std::max(band_max, std::abs(v - d));
      band_sum += std::abs(v - d);
      ++band_n;
      wrong_sign += v != 0 && std::abs(d) > 1e-6 && (v < 0) != (d < 0);
    } else {
      const double m = std::abs(v), u = std::abs(d), B = vm.interpolation_bound(i, j, k);
      estimate_max = std::max(estimate_max, std::abs(m - u));
      estimate_sum += std::abs(m - u);
      ++estimate_n;
      wrong_sign += (v < 0) != (d < 0);
      // Spec §3.1's bounds: the interpolated lattice's (coarse bricks, and value bricks before 2.2), or a settled
      // estimate's (never below u; above it by at most the path through the nearest lattice point).
      const bool settled =
          vm.estimates == voxfmt::Voxelmap::Estimates::Settled && vm.bricks[vm.brick_index(i / 8, j / 8, k / 8)] >= 0;
      const double e0 = vm.lattice_error[0], e1 = vm.lattice_error[1];
      out_of_bound += settled ? u > m + 0.5 * vm.distance_quantum / h + 1e-6 * u ||
                                    u < (m - e0 - 10 * q) / (1 + e1) - 8 * std::sqrt(3.0)  // q: half a step
                              : u > m + B + q || u < (m - e0) / (1 + e1) - B - q;
    }
  }
  std::cout << "{\"load_s\": " << load_s << ", \"runtime_mb\": " << double(runtime_bytes) / 1e6
            << ", \"band_samples\": " << band_n << ", \"band_err_max_vox\": " << band_max
            << ", \"band_err_mean_vox\": " << band_sum / double(std::max<size_t>(band_n, 1))
            << ", \"estimate_samples\": " << estimate_n << ", \"estimate_err_max_vox\": " << estimate_max
            << ", \"estimate_err_mean_vox\": " << estimate_sum / double(std::max<size_t>(estimate_n, 1))
            << ", \"estimates_out_of_bound\": " << out_of_bound << ", \"wrong_signs\": " << wrong_sign << "}\n";
  return 0;
}
