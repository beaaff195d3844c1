// Writes a tiny asset with the installed library, reads it back, loads it into the runtime (and a Bullet shape).
#include <voxfmt/io.h>
#include <voxfmt/version.h>
#include <vps/collision_object.h>
#ifdef CONSUMER_WITH_BULLET
#include <vps/bullet/vps_shape.h>
#endif

#include <cmath>
#include <cstdio>

int main(int argc, char** argv) {
  if (argc != 2) return 2;
  voxfmt::Asset a;
  a.bounds_max = {1, 1, 1};
  a.voxelmap.voxel_size = 0.5;
  a.voxelmap.dims = {2, 2, 2};
  a.voxelmap.layers.assign(8, 0);
  a.voxelmap.distances.assign(8, 0.25f);
  a.point_shell.points = {{0, 0, 0}};
  a.point_shell.normals = {{0, 0, 1}};
  a.point_shell.sphere_centers = {{0, 0, 0}};
  a.point_shell.sphere_radii = {0};
  a.point_shell.child_begin = {1};
  a.point_shell.child_count = {0};
  a.point_shell.level_offsets = {0, 1};
  a.mass.volume = 1;
  a.provenance.generator = "consumer";
  a.provenance.generator_version = VOXFMT_VERSION_STRING;
  if (!voxfmt::write_asset(argv[1], a)) return 1;
  auto back = voxfmt::read_asset(argv[1]);
  if (!back) {
    std::fprintf(stderr, "%s\n", back.error().message.c_str());
    return 1;
  }
  std::printf("consumer: read %zu voxels, voxfmt %s\n", back.value().voxelmap.voxel_count(), VOXFMT_VERSION_STRING);
  if (back.value().voxelmap.distances[7] != 0.25f) return 1;
  auto object = vps::CollisionObject::from_asset(back.value());
  if (!object) {
    std::fprintf(stderr, "runtime: %s\n", object.error().message.c_str());
    return 1;
  }
  std::printf("consumer: runtime object with %s voxelmap and %s point shell\n",
              object.value()->has_voxelmap() ? "a" : "no", object.value()->has_point_shell() ? "a" : "no");
#ifdef CONSUMER_WITH_BULLET
  vps::bullet::VpsVoxelmapShape shape(object.value());
  btVector3 lo, hi;
  shape.getAabb(btTransform::getIdentity(), lo, hi);
  std::printf("consumer: Bullet shape, AABB x %.3f..%.3f\n", double(lo.x()), double(hi.x()));
  if (!(lo.x() <= hi.x())) return 1;
#endif
  return 0;
}
