// The Bullet integration on an exact sphere made in code (no bake): a VPS sphere rests on a plane and on a
// static VPS sphere at the heights the closed form gives.
#include <gtest/gtest.h>

#include "analytic_sphere.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"

namespace voxfmt::bullet {
namespace {

constexpr double kRadius = 0.1, kVoxel = 0.01;

std::shared_ptr<const runtime::CollisionObject> sphere() {
  static const auto object = [] {
    auto loaded = runtime::CollisionObject::from_asset(test::make_sphere_asset({{0, 0, 0}, kRadius, kVoxel, 2000, 4}));
    if (!loaded) throw std::runtime_error(loaded.error().describe());
    return loaded.value();
  }();
  return object;
}

TEST(BulletSphere, RestsOnAPlaneAtItsRadius) {
  World world;
  world.dynamics().setGravity(btVector3(0, -9.81, 0));
  world.add_body(std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0), 0, btTransform::getIdentity());
  btRigidBody* ball = world.add_body(std::make_shared<VpsMixedShape>(sphere()), 1.0,
                                     btTransform(btQuaternion::getIdentity(), btVector3(0, 0.15, 0)));
  for (int step = 0; step < 1500; ++step) world.step(1.0 / 1000);
  EXPECT_NEAR(ball->getCenterOfMassPosition().y(), kRadius, 0.5 * kVoxel);
  EXPECT_LT(std::abs(ball->getLinearVelocity().y()), 1e-2);  // at rest vertically (a ball may still roll)
}

TEST(BulletSphere, RestsOnAStaticVpsSphereWithoutSinking) {
  World world;
  world.dynamics().setGravity(btVector3(0, -9.81, 0));
  world.add_body(std::make_shared<VpsMixedShape>(sphere()), 0, btTransform::getIdentity());
  btRigidBody* ball = world.add_body(std::make_shared<VpsMixedShape>(sphere()), 1.0,
                                     btTransform(btQuaternion::getIdentity(), btVector3(0, 0.22, 0)));
  ball->setAngularFactor(0);  // a sphere balanced on a sphere: keep it on top to measure the contact height
  ball->setLinearFactor(btVector3(0, 1, 0));
  for (int step = 0; step < 1500; ++step) world.step(1.0 / 1000);
  EXPECT_NEAR(ball->getCenterOfMassPosition().y(), 2 * kRadius, 0.5 * kVoxel);
  EXPECT_GT(world.vps()->counters().pair_tests, 0u);
}

}  // namespace
}  // namespace voxfmt::bullet
