// Bake a mesh into an asset with voxfmt::bake, load it with the runtime, and collide two copies of it.
//
//   bake_and_load MESH OUT.vox.h5
#include <cstdio>

#include "voxfmt/bake/bake.h"
#include "voxfmt/runtime/collision_object.h"
#include "voxfmt/runtime/query.h"

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s MESH OUT.vox.h5\n", argv[0]);
    return 2;
  }
  voxfmt::bake::Settings settings;  // the defaults of `voxfmt build`
  settings.voxelmap.resolution = 64;
  settings.point_shell.points = 5000;
  // Validated against the spec in memory, then written atomically.
  const voxfmt::Result<voxfmt::bake::Summary> baked = voxfmt::bake::bake_to_file(argv[1], argv[2], settings);
  if (!baked) {
    std::fprintf(stderr, "bake failed: %s\n", baked.error().describe().c_str());
    return 1;
  }
  std::printf("baked %s in %.2f s: %u x %u x %u voxels, %llu points\n", argv[1], baked->total_s, baked->dims[0],
              baked->dims[1], baked->dims[2], static_cast<unsigned long long>(baked->points));

  auto object = voxfmt::runtime::CollisionObject::load(argv[2]);
  if (!object) {
    std::fprintf(stderr, "load failed: %s\n", object.error().describe().c_str());
    return 1;
  }
  // Two copies, the second moved by 90 % of the object's bounding radius along x: they overlap.
  voxfmt::runtime::Pose a, b;
  b.translation = {0.9 * object.value()->bounding_radius(), 0, 0};
  voxfmt::runtime::ContactSet contacts;
  voxfmt::runtime::query_contacts(*object.value(), a, *object.value(), b, {}, contacts);
  double deepest = 0;
  for (const voxfmt::runtime::Contact& c : contacts.contacts) deepest = std::max(deepest, c.depth);
  std::printf("%zu contacts (%zu points tested), deepest %.4f m\n", contacts.contacts.size(),
              contacts.stats.points_tested, deepest);
  return 0;
}
