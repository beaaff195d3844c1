// No tunnelling and ray tests: a VPS bunny thrown at 10 m/s (10 mm per 1 kHz step) at walls two voxels thick
// stays in front of them thanks to speculative contacts, and passes through without them (so the test can
// fail); Bullet's ray tests hit a VPS body's surface (the splats of VpsShape::processAllTriangles).
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "baked_bunny.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"

namespace voxfmt::bullet {
namespace {

constexpr btScalar kDt = btScalar(1e-3);
using Bunny = voxfmt::test::BakedBunny;

struct Throw {
  double furthest = -1e9;  ///< largest x any shell point reached (the wall's front face is at x = 0)
  double final_vx = 0;
};

// Throws the bunny along +x at `speed` from 0.05 m in front of a wall whose front face is at x = 0.
Throw throw_at(std::shared_ptr<btCollisionShape> wall, const btTransform& wall_at, double speed, bool speculative,
               btScalar dt = kDt) {
  const Bunny& bunny = Bunny::get();
  CollisionSettings settings;
  settings.speculative_contacts = speculative;
  World world(settings);
  world.dynamics().setGravity(btVector3(0, 0, 0));
  world.add_body(std::move(wall), 0, wall_at);
  auto shape = std::make_shared<VpsMixedShape>(bunny.object);
  btTransform t = shape->asset_to_shape().inverse();
  t.setOrigin(t.getOrigin() + btVector3(btScalar(-bunny.object->bounds_max().x() - 0.05), 0, 0));
  btRigidBody* body = world.add_body(shape, 1.0, t);
  body->setLinearVelocity(btVector3(btScalar(speed), 0, 0));
  body->setActivationState(DISABLE_DEACTIVATION);
  Throw result;
  for (int step = 0; step < int(std::lround(0.15 / double(dt))); ++step) {
    world.step(dt);
    const runtime::Pose pose = shape->asset_pose(body->getWorldTransform());
    for (size_t i = 0; i < bunny.object->point_tree().size(); i += 7)
      result.furthest = std::max(result.furthest, pose.apply(bunny.object->point_tree().points[i].cast<double>()).x());
  }
  result.final_vx = double(body->getLinearVelocity().x());
  return result;
}

TEST(Tunnelling, FastBunnyStaysInFrontOfAThinBoxWall) {
  const double h = Bunny::get().h;
  auto wall = std::make_shared<btBoxShape>(btVector3(btScalar(h), 2, 2));  // 2 voxels thick
  const btTransform at(btQuaternion::getIdentity(), btVector3(btScalar(h), 0, 0));
  const Throw guarded = throw_at(wall, at, 10.0, true);
  const Throw unguarded = throw_at(wall, at, 10.0, false);
  std::cout << "[ figures  ] box wall 2 voxels thick, 10 m/s: speculative contacts: furthest point "
            << guarded.furthest / h << " voxel into the wall, final vx " << guarded.final_vx
            << " m/s; without: furthest " << unguarded.furthest / h << " voxel\n";
  EXPECT_LE(guarded.furthest, h);        // never more than a voxel into the front face
  EXPECT_LE(guarded.final_vx, 1.0);      // stopped (it may still turn about its contact), not slowed a little
  EXPECT_GT(unguarded.furthest, 2 * h);  // the same throw passes through without them
}

TEST(Tunnelling, AtSixtyHertzTooTheSpeculativeContactStops) {
  // 17 cm a step, far beyond Bullet's breaking threshold (a few mm from the shapes' size): it dropped every
  // speculative contact, and the bunny passed the wall as if there were none.
  const double h = Bunny::get().h;
  auto wall = std::make_shared<btBoxShape>(btVector3(btScalar(h), 2, 2));
  const btTransform at(btQuaternion::getIdentity(), btVector3(btScalar(h), 0, 0));
  const Throw guarded = throw_at(wall, at, 10.0, true, btScalar(1.0 / 60));
  std::cout << "[ figures  ] box wall 2 voxels thick, 10 m/s at 60 Hz: furthest point " << guarded.furthest / h
            << " voxel into the wall, final vx " << guarded.final_vx << " m/s\n";
  EXPECT_LE(guarded.furthest, h);
  EXPECT_LE(guarded.final_vx, 1.0);
}

TEST(Tunnelling, FastBunnyStaysInFrontOfAThinVpsSheet) {
  // A 1 m square sheet baked as a shell two voxels (of the bunny) thick: VPS against VPS.
  const double h = Bunny::get().h;
  const std::string mesh = (std::filesystem::temp_directory_path() / "voxfmt_ccd_sheet.obj").string();
  {
    std::ofstream obj(mesh);
    obj << "v 0 -1 -1\nv 0 1 -1\nv 0 1 1\nv 0 -1 1\nf 1 2 3\nf 1 3 4\n";
  }
  bake::Settings settings;
  settings.voxelmap.voxel_size = h;
  settings.voxelmap.shell_thickness = 2 * h;
  settings.point_shell.points = 2000;
  auto baked = bake::bake_mesh(mesh, settings);
  std::filesystem::remove(mesh);
  ASSERT_TRUE(baked) << baked.error().describe();
  auto sheet_object = runtime::CollisionObject::from_asset(baked.value().asset);
  ASSERT_TRUE(sheet_object) << sheet_object.error().message;
  auto sheet = std::make_shared<VpsVoxelmapShape>(sheet_object.value());
  // The sheet lies in its asset frame's x = 0 plane, solid from x = -h to h; its asset frame goes to x = h, so
  // its front face is at x = 0.
  btTransform at = sheet->asset_to_shape().inverse();
  at.setOrigin(at.getOrigin() + btVector3(btScalar(h), 0, 0));
  const Throw guarded = throw_at(sheet, at, 10.0, true);
  const Throw unguarded = throw_at(sheet, at, 10.0, false);
  std::cout << "[ figures  ] VPS sheet 2 voxels thick, 10 m/s: speculative contacts: furthest point "
            << guarded.furthest / h << " voxel into the sheet, final vx " << guarded.final_vx
            << " m/s; without: furthest " << unguarded.furthest / h << " voxel\n";
  EXPECT_LE(guarded.furthest, h);
  EXPECT_LE(guarded.final_vx, 1.0);
  EXPECT_GT(unguarded.furthest, 2 * h);
}

TEST(Rays, BulletRayTestsHitTheVpsSurface) {
  const Bunny& bunny = Bunny::get();
  World world;
  auto shape = std::make_shared<VpsMixedShape>(bunny.object);
  btRigidBody* body = world.add_body(shape, 0, shape->asset_to_shape().inverse());
  (void)body;
  world.dynamics().updateAabbs();
  const runtime::SparseVoxelmap& map = bunny.object->voxelmap();
  size_t hits = 0, rays = 0;
  double worst = 0;
  for (int i = -4; i <= 4; ++i)
    for (int k = -4; k <= 4; ++k) {
      // Straight down through the bunny's box; asset frame = world frame here.
      const btVector3 from(btScalar(0.08 * i), 2, btScalar(0.08 * k)), to(btScalar(0.08 * i), -2, btScalar(0.08 * k));
      btCollisionWorld::ClosestRayResultCallback callback(from, to);
      world.dynamics().rayTest(from, to, callback);
      // Does the ray meet the body at all? The field along the ray says (sampled every half voxel).
      bool crosses = false;
      for (double y = 2; y > -2 && !crosses; y -= 0.5 * bunny.h)
        crosses = map.sample(map.to_grid(Eigen::Vector3d(0.08 * i, y, 0.08 * k))).distance < -1.0f;
      if (!crosses) continue;
      ++rays;
      if (!callback.hasHit()) continue;
      ++hits;
      const btVector3& p = callback.m_hitPointWorld;
      const double d = std::abs(double(map.sample(map.to_grid(Eigen::Vector3d(p.x(), p.y(), p.z()))).distance));
      worst = std::max(worst, d);
    }
  std::cout << "[ figures  ] " << hits << " of " << rays << " rays through the bunny hit it; hit points within "
            << worst << " voxel of the surface\n";
  ASSERT_GT(rays, 10u);
  EXPECT_EQ(hits, rays);
  EXPECT_LE(worst, 1.0);
}

}  // namespace
}  // namespace voxfmt::bullet
