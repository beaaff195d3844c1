// Built against the installed package: bakes a small mesh through voxfmt::bake, loads it with the runtime and
// steps a Bullet world with it.
#include <voxfmt/bake/bake.h>
#include <voxfmt/bullet/shape.h>
#include <voxfmt/bullet/world.h>
#include <voxfmt/io.h>
#include <voxfmt/runtime/collision_object.h>
#include <voxfmt/version.h>

#include <cstdio>
#include <fstream>
#include <string>

int main(int argc, char** argv) {
  if (argc != 2) return 2;
  const std::string dir = argv[1];
  {  // a 0.1 x 0.06 x 0.04 m box (distinct principal moments: its principal frame is the asset's axes)
    std::ofstream off(dir + "/cube.off");
    off << "OFF\n8 12 0\n";
    for (int v = 0; v < 8; ++v)
      off << 0.1 * (v & 1) << " " << 0.06 * ((v >> 1) & 1) << " " << 0.04 * ((v >> 2) & 1) << "\n";
    off << "3 0 2 1\n3 1 2 3\n3 4 5 6\n3 5 7 6\n3 0 1 4\n3 1 5 4\n3 2 6 3\n3 3 6 7\n3 0 4 2\n3 2 4 6\n3 1 3 5\n3 3 7 "
           "5\n";
  }
  voxfmt::bake::Settings settings;
  settings.voxelmap.resolution = 24;
  settings.point_shell.points = 500;
  const auto summary = voxfmt::bake::bake_to_file(dir + "/cube.off", dir + "/cube.vox.h5", settings);
  if (!summary) {
    std::fprintf(stderr, "bake: %s\n", summary.error().describe().c_str());
    return 1;
  }
  std::printf("consumer: voxfmt %s baked a box, volume %.6f m^3\n", VOXFMT_VERSION_STRING, summary->volume);
  const auto object = voxfmt::runtime::CollisionObject::load(dir + "/cube.vox.h5");
  if (!object) {
    std::fprintf(stderr, "runtime: %s\n", object.error().describe().c_str());
    return 1;
  }
  voxfmt::bullet::World world;
  world.dynamics().setGravity(btVector3(0, -9.81, 0));
  world.add_body(std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0), 0, btTransform::getIdentity());
  btRigidBody* cube = world.add_body(std::make_shared<voxfmt::bullet::VpsMixedShape>(object.value()), 1.0,
                                     btTransform(btQuaternion::getIdentity(), btVector3(0, 0.2, 0)));
  for (int step = 0; step < 1000; ++step) world.step(btScalar(0.001));
  const double y = double(cube->getCenterOfMassPosition().y());
  std::printf("consumer: the box rests at %.4f m (expected 0.03)\n", y);
  return y > 0.027 && y < 0.033 ? 0 : 1;
}
