// CGAL's bunny baked at the seed's settings (resolution 306, 35k points) and loaded for the runtime, once per
// test process: the shared input of the runtime and Bullet tests.
//
// With VOXFMT_TEST_CACHE set (ctest sets it), the asset and the repaired mesh are kept in that folder: the
// ctest fixture test_cache.bunny bakes them once per ctest run (VOXFMT_TEST_CACHE_REFRESH=1) and every other
// test process reads them instead of baking again, which in sanitizer builds is most of a test's time. Run
// directly, without the variable, a test bakes its own.
#pragma once

#include <unistd.h>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <string>

#include "stages.h"
#include "voxfmt/io.h"
#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::test {

struct BakedBunny {
  Asset asset;
  std::shared_ptr<const voxfmt::runtime::CollisionObject> object;
  bake::TriangleMesh mesh;  ///< the repaired mesh the asset was baked from
  double h = 0;             ///< voxel size, metres

  static const BakedBunny& get() {
    static const BakedBunny bunny = [] {
      BakedBunny b;
      const char* cache = std::getenv("VOXFMT_TEST_CACHE");
      const bool refresh = std::getenv("VOXFMT_TEST_CACHE_REFRESH") != nullptr;
      const std::string asset_path = cache ? std::string(cache) + "/bunny-r306-p35000.vox.h5" : "";
      const std::string mesh_path = cache ? std::string(cache) + "/bunny-repaired.mesh" : "";
      if (!cache || refresh || !read_cache(asset_path, mesh_path, b)) {
        const std::string path = std::string(VOXFMT_SAMPLE_MESHES) + "/bunny00.off";
        bake::Settings options;
        options.voxelmap.resolution = 306;
        options.point_shell.points = 35000;
        bake::BuildReport report;
        b.asset = bake::build_asset(path, options, report);
        bake::RepairReport repair;
        b.mesh = bake::repair_mesh(bake::import_mesh(path), repair, false);
        if (cache) write_cache(asset_path, mesh_path, b);
      }
      auto loaded = voxfmt::runtime::CollisionObject::from_asset(b.asset);
      if (!loaded) throw std::runtime_error(loaded.error().message);
      b.object = loaded.value();
      b.h = b.asset.voxelmap.voxel_size;
      return b;
    }();
    return bunny;
  }

 private:
  // The mesh as raw counts, doubles and indices (a test's own cache, never read by anything else).
  static bool read_cache(const std::string& asset_path, const std::string& mesh_path, BakedBunny& b) {
    std::ifstream in(mesh_path, std::ios::binary);
    uint64_t vertices = 0, triangles = 0;
    if (!in.read(reinterpret_cast<char*>(&vertices), 8) || !in.read(reinterpret_cast<char*>(&triangles), 8))
      return false;
    b.mesh.vertices.resize(vertices);
    b.mesh.triangles.resize(triangles);
    if (!in.read(reinterpret_cast<char*>(b.mesh.vertices.data()), std::streamsize(vertices * sizeof(Vec3))) ||
        !in.read(reinterpret_cast<char*>(b.mesh.triangles.data()), std::streamsize(triangles * 3 * sizeof(uint32_t))))
      return false;
    Result<Asset> asset = read_asset(asset_path);
    if (!asset) return false;
    b.asset = std::move(asset.value());
    return true;
  }

  static void write_cache(const std::string& asset_path, const std::string& mesh_path, const BakedBunny& b) {
    // Both files appear whole (a temporary renamed into place), so a test started meanwhile bakes its own.
    std::error_code ignored;
    std::filesystem::create_directories(std::filesystem::path(asset_path).parent_path(), ignored);
    if (!write_asset(asset_path, b.asset)) return;
    const std::string partial = mesh_path + ".partial-" + std::to_string(::getpid());
    {
      std::ofstream out(partial, std::ios::binary);
      const uint64_t vertices = b.mesh.vertices.size(), triangles = b.mesh.triangles.size();
      out.write(reinterpret_cast<const char*>(&vertices), 8);
      out.write(reinterpret_cast<const char*>(&triangles), 8);
      out.write(reinterpret_cast<const char*>(b.mesh.vertices.data()), std::streamsize(vertices * sizeof(Vec3)));
      out.write(reinterpret_cast<const char*>(b.mesh.triangles.data()),
                std::streamsize(triangles * 3 * sizeof(uint32_t)));
      if (!out) return;
    }
    std::rename(partial.c_str(), mesh_path.c_str());
  }
};

}  // namespace voxfmt::test
