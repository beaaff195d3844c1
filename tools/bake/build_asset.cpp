// The whole bake: import -> repair -> voxelmap -> point shell -> tree -> mass -> asset with provenance.
#include <CGAL/version.h>
#include <assimp/version.h>
#include <nlohmann/json.hpp>
#include <openssl/evp.h>
#include <oneapi/tbb/global_control.h>
#include <oneapi/tbb/task_group.h>
#include <oneapi/tbb/version.h>

#include <algorithm>
#include <chrono>
#include <exception>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <memory>

#include "bake.h"
#include "vec3_math.h"
#include "voxfmt/io.h"
#include "voxfmt/version.h"

namespace voxfmt::bake {

Bounds bounding_box(const TriangleMesh& mesh) {
  Bounds b{mesh.vertices.front(), mesh.vertices.front()};
  for (const Vec3& v : mesh.vertices)
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = std::min(b.lo[a], v[a]);
      b.hi[a] = std::max(b.hi[a], v[a]);
    }
  return b;
}

std::string sha256_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw BakeError("INPUT_NOT_FOUND", path + ": cannot open for hashing");
  std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(), EVP_MD_CTX_free);
  EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr);
  std::vector<char> buffer(1 << 16);
  while (in) {
    in.read(buffer.data(), std::streamsize(buffer.size()));
    if (in.gcount() > 0) EVP_DigestUpdate(ctx.get(), buffer.data(), size_t(in.gcount()));
  }
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int length = 0;
  EVP_DigestFinal_ex(ctx.get(), digest, &length);
  static const char* hex = "0123456789abcdef";
  std::string out;
  for (unsigned i = 0; i < length; ++i) {
    out += hex[digest[i] >> 4];
    out += hex[digest[i] & 15];
  }
  return out;
}

std::map<std::string, std::string> dependency_versions() {
  return {{"voxfmt", VOXFMT_VERSION_STRING},
          {"assimp", std::to_string(aiGetVersionMajor()) + "." + std::to_string(aiGetVersionMinor()) + "." +
                         std::to_string(aiGetVersionRevision())},
          {"cgal", CGAL_VERSION_STR},
          {"tbb", std::to_string(TBB_VERSION_MAJOR) + "." + std::to_string(TBB_VERSION_MINOR)},
          {"hdf5", hdf5_library_version()}};
}

std::string build_parameters_json(const BuildOptions& o) {
  nlohmann::json j = {{"unit_scale", o.import.unit_scale},
                      {"resolution", o.voxelmap.resolution},
                      {"voxel_size", o.voxelmap.voxel_size},
                      {"margin", o.voxelmap.margin},
                      {"distance_band", o.voxelmap.distance_band},
                      {"points", o.point_shell.points},
                      {"point_spacing", o.point_shell.point_spacing},
                      {"branching", o.point_shell.branching},
                      {"seed", o.point_shell.seed},
                      {"check_self_intersections", o.check_self_intersections},
                      {"up_axis", o.up_axis}};
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::string utc_now() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof buffer, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

Asset build_asset(const std::string& mesh_path, const BuildOptions& options, BuildReport& report,
                  const ProgressCallback& progress) {
  std::unique_ptr<tbb::global_control> thread_limit;
  if (options.threads > 0)
    thread_limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, options.threads);
  constexpr int kStages = 4;
  int stage_index = 0;
  auto clock = std::chrono::steady_clock::now();
  auto stage = [&](const std::string& name) {
    const auto now = std::chrono::steady_clock::now();
    if (!report.timings.empty())
      report.timings.back().seconds = std::chrono::duration<double>(now - clock).count();
    clock = now;
    if (name.empty()) return;
    report.timings.push_back({name, 0});
    if (progress) progress(++stage_index, kStages, name);
  };

  stage("import");
  const TriangleMesh raw = import_mesh(mesh_path, options.import);
  report.input_vertices = raw.vertices.size();
  report.input_triangles = raw.triangles.size();

  stage("repair");
  const TriangleMesh mesh = repair_mesh(raw, report.repair, options.check_self_intersections);
  const auto [lo, hi] = bounding_box(mesh);
  const double diagonal = length(hi - lo);
  // A closed, oriented surface encloses what the divergence theorem integrates; otherwise inside is where the
  // winding number is >= 1/2, and the mass properties are integrated over that inside, on the voxelmap.
  const RepairReport& r = report.repair;
  const bool winding_inside = !r.closed || !r.consistently_oriented || r.self_intersecting_pairs > 0;
  MassProperties mass;
  auto check_volume = [&](const char* what) {
    if (!(mass.volume > 1e-9 * diagonal * diagonal * diagonal))
      throw BakeError("ZERO_VOLUME", mesh_path + ": the surface encloses no volume (" + what + ")");
  };
  if (!winding_inside) {
    mass = compute_mass_properties(mesh);
    check_volume("flat or inside-out mesh");
  }

  // The voxelmap and the point shell are independent: the (mostly serial) sampling and tree building run
  // beside the voxelmap's parallel work. Stage times are each task's own wall time.
  stage("voxelmap + point shell");
  VoxelmapOptions voxelmap_options = options.voxelmap;
  voxelmap_options.winding_number_sign = winding_inside;
  Voxelmap voxelmap;
  PointShell shell;
  double voxelmap_seconds = 0, shell_seconds = 0, tree_seconds = 0;
  auto timed = [](double& seconds, auto&& work) {
    const auto t0 = std::chrono::steady_clock::now();
    work();
    seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  };
  tbb::task_group tasks;
  std::exception_ptr shell_error;
  tasks.run([&] {
    try {
      timed(shell_seconds, [&] { shell = sample_point_shell(mesh, options.point_shell); });
      timed(tree_seconds, [&] { build_sphere_tree(shell, options.point_shell.branching); });
    } catch (...) {
      shell_error = std::current_exception();
    }
  });
  try {
    timed(voxelmap_seconds, [&] { voxelmap = build_voxelmap(mesh, voxelmap_options); });
  } catch (...) {
    tasks.wait();
    throw;
  }
  tasks.wait();
  if (shell_error) std::rethrow_exception(shell_error);

  stage("assemble");
  if (winding_inside) {
    // No voxel more than half a voxel inside (layer >= 1): an open sheet that closes around nothing, or a part
    // thinner than a voxel; the fractional voxels along it are not a volume the voxelmap can represent.
    if (*std::max_element(voxelmap.layers.begin(), voxelmap.layers.end()) < 1)
      throw BakeError("ZERO_VOLUME", mesh_path + ": the surface encloses no volume at this resolution: no voxel is more "
                                                 "than half a voxel inside (winding number >= 1/2); an open sheet, or "
                                                 "thinner than a voxel (a finer --resolution or --voxel-size may help)");
    mass = voxelmap_mass_properties(voxelmap);
    check_volume("an open sheet");
    // The inside closes the surface, so it lies within the surface's bounds; the voxels' partial fractions can
    // put the centre a fraction of a voxel past a flat side.
    for (int a = 0; a < 3; ++a) mass.center_of_mass[a] = std::clamp(mass.center_of_mass[a], lo[a], hi[a]);
  }
  report.timings.insert(report.timings.end() - 2, {{"voxelmap", voxelmap_seconds}, {"point shell", shell_seconds},
                                                   {"sphere tree", tree_seconds}});
  Asset asset;
  asset.up_axis = options.up_axis;
  asset.bounds_min = lo;
  asset.bounds_max = hi;
  asset.voxelmap = std::move(voxelmap);
  asset.point_shell = std::move(shell);
  asset.mass = mass;
  Provenance& p = asset.provenance;
  p.generator = "voxfmt build";
  p.generator_version = VOXFMT_VERSION_STRING;
  p.source_file = std::filesystem::path(mesh_path).filename().string();
  p.source_sha256 = sha256_file(mesh_path);
  p.build_parameters_json = build_parameters_json(options);
  p.dependency_versions = dependency_versions();
  p.build_warnings = report.repair.warnings;
  p.created_utc = utc_now();
  stage("");
  return asset;
}

}  // namespace voxfmt::bake
