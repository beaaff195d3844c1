// The Bullet integration on an exact sphere made in code (no bake): a VPS sphere rests on a plane and on a
// static VPS sphere at the heights the closed form gives.
#include <gtest/gtest.h>

#include <algorithm>
#include <limits>

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

TEST(BulletSphere, TheSettingsQueryLimitsEveryShellAndItsDefaultsAreForPhysics) {
  // The physics defaults differ from the runtime's in the one way physics_query_defaults says, and nowhere else.
  const runtime::QueryOptions runtime_defaults, physics = CollisionSettings{}.query;
  EXPECT_EQ(runtime_defaults.normal_source, runtime::NormalSource::DistanceGradient);
  EXPECT_EQ(physics.normal_source, runtime_defaults.normal_source);
  EXPECT_EQ(physics.cut_level, runtime::CutLevel::Points);
  EXPECT_EQ(physics.direction, runtime_defaults.direction);
  EXPECT_EQ(physics.max_level, runtime_defaults.max_level);
  EXPECT_EQ(physics.point_budget, runtime_defaults.point_budget);

  // A level limit in the settings' query reaches every pair: against the plane and against the other sphere.
  for (const uint32_t limit : {1u, std::numeric_limits<uint32_t>::max()}) {
    CollisionSettings settings;
    settings.query.max_level = limit;
    uint32_t deepest = 0;
    size_t contact_sets = 0;
    settings.on_contacts = [&](const btCollisionObject*, const btCollisionObject*, const runtime::ContactSet& set) {
      if (set.contacts.empty()) return;
      deepest = std::max(deepest, set.stats.deepest_level);
      ++contact_sets;
    };
    World world(settings);
    world.dynamics().setGravity(btVector3(0, -9.81, 0));
    world.add_body(std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0), 0, btTransform::getIdentity());
    world.add_body(std::make_shared<VpsMixedShape>(sphere()), 0,
                   btTransform(btQuaternion::getIdentity(), btVector3(0.5, kRadius, 0)));
    world.add_body(std::make_shared<VpsMixedShape>(sphere()), 1.0,
                   btTransform(btQuaternion::getIdentity(), btVector3(0, 0.12, 0)));
    btRigidBody* upper = world.add_body(std::make_shared<VpsMixedShape>(sphere()), 1.0,
                                        btTransform(btQuaternion::getIdentity(), btVector3(0.5, 0.32, 0)));
    upper->setAngularFactor(0);
    upper->setLinearFactor(btVector3(0, 1, 0));
    for (int step = 0; step < 300; ++step) world.step(1.0 / 1000);
    EXPECT_GT(contact_sets, 0u) << limit;
    const uint32_t leaves = uint32_t(sphere()->point_tree().level_count()) - 1;
    EXPECT_EQ(deepest, std::min(limit, leaves)) << limit;
  }
}

}  // namespace
}  // namespace voxfmt::bullet
