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

TEST(BulletSphere, PrimitivesLargerThanTheBandRestOnAStaticVoxelmapRoleSphere) {
  // A partner without points was seen only by its corners (box) or centre (sphere) in the voxelmap, which beyond
  // the band (3 voxels) says nothing: a 0.6 m box fell through a static VpsVoxelmapShape, a 0.3 m ball sank into it.
  struct Case {
    std::shared_ptr<btCollisionShape> shape;
    double rest;  ///< centre height at rest on the sphere's top
  };
  for (const Case& c : {Case{std::make_shared<btBoxShape>(btVector3(0.3f, 0.05f, 0.3f)), kRadius + 0.05},
                        Case{std::make_shared<btSphereShape>(0.3f), kRadius + 0.3}}) {
    c.shape->setMargin(0.001f);
    World world;
    world.dynamics().setGravity(btVector3(0, -9.81, 0));
    world.add_body(std::make_shared<VpsVoxelmapShape>(sphere()), 0, btTransform::getIdentity());
    btRigidBody* body = world.add_body(
        c.shape, 1.0, btTransform(btQuaternion::getIdentity(), btVector3(0, btScalar(c.rest + 0.01), 0)));
    body->setAngularFactor(0);  // balanced on the top: measure the contact height
    body->setLinearFactor(btVector3(0, 1, 0));
    for (int step = 0; step < 1000; ++step) world.step(1.0 / 1000);
    EXPECT_NEAR(body->getCenterOfMassPosition().y(), c.rest, 0.5 * kVoxel) << c.shape->getName();
  }
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
