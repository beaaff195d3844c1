// CGAL's bunny baked at the seed's settings (resolution 306, 35k points) and loaded for the runtime, once per
// test process: the shared input of the runtime and Bullet tests.
#pragma once

#include <memory>
#include <stdexcept>
#include <string>

#include "stages.h"
#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::test {

struct BakedBunny {
  Asset asset;
  std::shared_ptr<const voxfmt::runtime::CollisionObject> object;
  bake::TriangleMesh mesh;  ///< the repaired mesh the asset was baked from
  double h = 0;             ///< voxel size, metres

  static const BakedBunny& get() {
    static const BakedBunny bunny = [] {
      const std::string path = std::string(VOXFMT_SAMPLE_MESHES) + "/bunny00.off";
      BakedBunny b;
      bake::Settings options;
      options.voxelmap.resolution = 306;
      options.point_shell.points = 35000;
      bake::BuildReport report;
      b.asset = bake::build_asset(path, options, report);
      bake::RepairReport repair;
      b.mesh = bake::repair_mesh(bake::import_mesh(path), repair, false);
      auto loaded = voxfmt::runtime::CollisionObject::from_asset(b.asset);
      if (!loaded) throw std::runtime_error(loaded.error().message);
      b.object = loaded.value();
      b.h = b.asset.voxelmap.voxel_size;
      return b;
    }();
    return bunny;
  }
};

}  // namespace voxfmt::test
