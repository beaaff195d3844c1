// A Bullet world with one VPS body: an asset dropped onto the ground, simulated for two seconds at 1 kHz.
//
//   bullet_hello ASSET.vox.h5
#include <btBulletDynamicsCommon.h>

#include <cstdio>

#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"
#include "voxfmt/runtime/collision_object.h"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s ASSET.vox.h5\n", argv[0]);
    return 2;
  }
  auto object = voxfmt::runtime::CollisionObject::load(argv[1]);
  if (!object) {
    std::fprintf(stderr, "load failed: %s\n", object.error().describe().c_str());
    return 1;
  }
  // A world with the VPS collision algorithm registered for VPS-VPS, plane, box and sphere pairs.
  voxfmt::bullet::World world;
  world.dynamics().setGravity(btVector3(0, -9.81, 0));
  world.add_body(std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0), 0, btTransform::getIdentity());
  // The shape's frame is the asset's principal frame: mass properties come from the asset.
  auto shape = std::make_shared<voxfmt::bullet::VpsMixedShape>(object.value());
  const double drop = 2 * object.value()->bounding_radius();
  btRigidBody* body =
      world.add_body(shape, 1.0, btTransform(btQuaternion::getIdentity(), btVector3(0, btScalar(drop), 0)));
  for (int step = 1; step <= 2000; ++step) {
    world.step(btScalar(1.0 / 1000));
    if (step % 500 == 0)
      std::printf("t = %.1f s: height %.4f m, speed %.4f m/s, narrow phase %.1f us\n", step / 1000.0,
                  double(body->getCenterOfMassPosition().y()), double(body->getLinearVelocity().length()),
                  world.dispatcher().last_narrow_phase_us());
  }
  return 0;
}
