// Bullet integration: a bunny settles on a plane at the exact rest height, a bunny rests on a bunny, and
// Bullet's own pairs still work in a world with VPS registered.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <limits>

#include "baked_bunny.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"

namespace voxfmt::bullet {
namespace {

constexpr btScalar kDt = btScalar(1e-3);  // 1 kHz, the haptic rate

using Bunny = voxfmt::test::BakedBunny;
using namespace voxfmt::runtime;  // the queries the tests compare Bullet against

/// Lowest mesh vertex along +Y for a body whose shape is `shape`.
double lowest_vertex_y(const Bunny& bunny, const VpsShape& shape, const btTransform& t) {
  const Pose pose = shape.asset_pose(t);
  double lowest = 1e9;
  for (const voxfmt::Vec3& v : bunny.mesh.vertices)
    lowest = std::min(lowest, pose.apply(Eigen::Vector3d(v[0], v[1], v[2])).y());
  return lowest;
}

/// Transform placing the bunny's asset frame at `asset_offset` (no rotation) for `shape`.
btTransform place_asset(const VpsShape& shape, const btVector3& asset_offset) {
  btTransform t = shape.asset_to_shape().inverse();
  t.setOrigin(t.getOrigin() + asset_offset);
  return t;
}

Eigen::Vector3d to_eigen_vector(const btVector3& v) { return Eigen::Vector3d(v.x(), v.y(), v.z()); }

bool finite(const btTransform& t) {
  for (int i = 0; i < 3; ++i)
    if (!std::isfinite(double(t.getOrigin()[i])) || !std::isfinite(double(t.getBasis()[i][0])) ||
        !std::isfinite(double(t.getBasis()[i][1])) || !std::isfinite(double(t.getBasis()[i][2])))
      return false;
  return true;
}

TEST(Bullet, BunnySettlesOnPlaneAtExactRestHeight) {
  const Bunny& bunny = Bunny::get();
  World world;
  world.dynamics().setGravity(btVector3(0, -9.81f, 0));
  // The plane is added first, so Bullet meets the pair as (plane, bunny): the swapped algorithm.
  auto plane = std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0);
  world.add_body(plane, 0, btTransform::getIdentity());
  auto shape = std::make_shared<VpsMixedShape>(bunny.object);
  const double drop = 0.05;  // lowest vertex 5 cm above the plane
  const btScalar lift = btScalar(-bunny.object->bounds_min().y() + drop);
  btRigidBody* body = world.add_body(shape, 1.0, place_asset(*shape, btVector3(0, lift, 0)));
  body->setFriction(0.8f);
  for (int step = 0; step < 1000; ++step) world.step(kDt);
  const double speed = double(body->getLinearVelocity().length());
  const double gap = lowest_vertex_y(bunny, *shape, body->getWorldTransform());
  std::cout << "[ figures  ] after 1 s: speed " << speed << " m/s, lowest vertex " << gap / bunny.h
            << " voxel from the plane, angular speed " << body->getAngularVelocity().length() << " rad/s\n";
  ASSERT_TRUE(finite(body->getWorldTransform()));
  EXPECT_LT(speed, 1e-3);
  EXPECT_LE(std::fabs(gap), bunny.h);
}

/// Deepest penetration between two VPS bodies, both directions.
double deepest_penetration(const VpsShape& a, const btTransform& ta, const VpsShape& b, const btTransform& tb) {
  ContactSet contacts;
  QueryOptions options;
  options.direction = QueryDirection::Both;
  query_contacts(a.object(), a.asset_pose(ta), b.object(), b.asset_pose(tb), options, contacts);
  double deepest = 0;
  for (const Contact& c : contacts.contacts) deepest = std::max(deepest, c.depth);
  return deepest;
}

TEST(Bullet, BunnyDroppedOnBunnyComesToRestWithoutSinking) {
  const Bunny& bunny = Bunny::get();
  World world;
  world.dynamics().setGravity(btVector3(0, -9.81f, 0));
  world.add_body(std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0), 0, btTransform::getIdentity());
  auto lower_shape = std::make_shared<VpsMixedShape>(bunny.object);
  auto upper_shape = std::make_shared<VpsMixedShape>(bunny.object);
  const btScalar floor_lift = btScalar(-bunny.object->bounds_min().y());
  btRigidBody* lower = world.add_body(lower_shape, 1.0, place_asset(*lower_shape, btVector3(0, floor_lift, 0)));
  const double height = bunny.object->bounds_max().y() - bunny.object->bounds_min().y();
  btRigidBody* upper = world.add_body(
      upper_shape, 1.0, place_asset(*upper_shape, btVector3(0.2f, btScalar(floor_lift + height + 0.02), 0.05f)));
  for (btRigidBody* body : {lower, upper}) body->setFriction(0.8f);
  double deepest = 0;
  bool touched = false;
  for (int step = 0; step < 5000; ++step) {
    world.step(kDt);
    ASSERT_TRUE(finite(upper->getWorldTransform()) && finite(lower->getWorldTransform())) << "step " << step;
    if (step % 10 == 0) {
      const double d =
          deepest_penetration(*upper_shape, upper->getWorldTransform(), *lower_shape, lower->getWorldTransform());
      deepest = std::max(deepest, d);
      touched |= d > 0;
    }
  }
  const double speed =
      std::max(double(upper->getLinearVelocity().length()), double(lower->getLinearVelocity().length()));
  std::cout << "[ figures  ] after 5 s: speed " << speed << " m/s, upper centre of mass y "
            << upper->getCenterOfMassPosition().y() << ", deepest bunny-bunny penetration " << deepest / bunny.h
            << " voxel\n";
  EXPECT_TRUE(touched);
  EXPECT_LT(speed, 1e-2);
  EXPECT_LE(deepest, 2 * bunny.h);
  // Neither bunny went through the floor.
  for (auto [shape, body] : {std::pair{upper_shape.get(), upper}, std::pair{lower_shape.get(), lower}})
    EXPECT_GT(lowest_vertex_y(bunny, *shape, body->getWorldTransform()), -bunny.h);
}

/// What a bunny dropped on a bunny did (coarse_bunny_drop).
struct DropOutcome {
  double gain = 0;         ///< largest rise of its energy above the start, over the fall's potential energy
  double final_speed = 0;  ///< m/s
  double deepest = 0;      ///< deepest penetration between the bunnies (full shells, every 10 steps), voxels
  uint64_t budget_cuts = 0;
  double narrow_phase_us_p50 = 0;  ///< over the last second (in contact)
};

/// Drops a bunny from 2 cm onto a static bunny standing on a plane for 3 s, both cut at tree level `max_level`
/// of their shells, or both whole under a step time budget of `step_budget_us`.
DropOutcome coarse_bunny_drop(runtime::CutLevel cut_level, uint32_t max_level, double step_budget_us = 0.0,
                              bool coherent = true, bool refine = true) {
  const Bunny& bunny = Bunny::get();
  CollisionSettings settings;
  settings.query.cut_level = cut_level;
  settings.query.refine_cut_contacts = refine;
  settings.step_time_budget_us = step_budget_us;
  settings.coherent = coherent;
  World world(settings);
  const double g = 9.81;
  world.dynamics().setGravity(btVector3(0, btScalar(-g), 0));
  world.add_body(std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0), 0, btTransform::getIdentity());
  auto lower_shape = std::make_shared<VpsMixedShape>(bunny.object);
  auto upper_shape = std::make_shared<VpsMixedShape>(bunny.object);
  for (auto* shape : {lower_shape.get(), upper_shape.get()}) shape->set_max_level(max_level);
  const btScalar floor_lift = btScalar(-bunny.object->bounds_min().y());
  btRigidBody* lower = world.add_body(lower_shape, 0, place_asset(*lower_shape, btVector3(0, floor_lift, 0)));
  const double height = bunny.object->bounds_max().y() - bunny.object->bounds_min().y();
  const double drop = 0.02;
  btRigidBody* upper = world.add_body(
      upper_shape, 1.0, place_asset(*upper_shape, btVector3(0.2f, btScalar(floor_lift + height + drop), 0.05f)));
  upper->setFriction(0.8f);
  auto energy = [&] {
    const btVector3 w = upper->getWorldTransform().getBasis().transpose() * upper->getAngularVelocity();
    const btVector3 inertia = upper->getLocalInertia();
    const double rotational =
        0.5 * double(inertia.x() * w.x() * w.x() + inertia.y() * w.y() * w.y() + inertia.z() * w.z() * w.z());
    return 0.5 * double(upper->getLinearVelocity().length2()) + rotational +
           g * double(upper->getCenterOfMassPosition().y());
  };
  const double start = energy();
  DropOutcome outcome;
  std::vector<double> narrow_us;
  for (int step = 0; step < 3000; ++step) {
    world.step(kDt);
    if (step >= 2000) narrow_us.push_back(world.dispatcher().last_narrow_phase_us());
    if (step % 10 == 0)
      outcome.deepest = std::max(outcome.deepest, deepest_penetration(*upper_shape, upper->getWorldTransform(),
                                                                      *lower_shape, lower->getWorldTransform()) /
                                                      bunny.h);
    const double e = energy();
    if (!std::isfinite(e)) {
      outcome.gain = INFINITY;
      return outcome;
    }
    outcome.gain = std::max(outcome.gain, e - start);
  }
  outcome.gain /= g * drop;
  outcome.final_speed = double(upper->getLinearVelocity().length());
  outcome.budget_cuts = world.vps()->counters().budget_cuts;
  std::nth_element(narrow_us.begin(), narrow_us.begin() + narrow_us.size() / 2, narrow_us.end());
  outcome.narrow_phase_us_p50 = narrow_us[narrow_us.size() / 2];
  return outcome;
}

TEST(Bullet, ACoarseShapeDoesNotGainEnergyFromItsCut) {
  // Shapes cut at tree level 2 report the level's own points (CutLevel::Points, the default): dropped on a
  // bunny, the body never has more energy than it started with, and it comes to rest. Reporting each point as
  // its sphere (Spheres, up to two radii deeper than the surface), the solver turns the extra depth into energy.
  // Refining the cut where it touches (the default) adds none either.
  const DropOutcome points = coarse_bunny_drop(runtime::CutLevel::Points, 2, 0.0, true, false);
  const DropOutcome spheres = coarse_bunny_drop(runtime::CutLevel::Spheres, 2, 0.0, true, false);
  const DropOutcome refined = coarse_bunny_drop(runtime::CutLevel::Points, 2);
  std::cout << "[ figures  ] largest energy gain over the drop's potential energy: points " << points.gain
            << " (final speed " << points.final_speed << " m/s), spheres " << spheres.gain << " (final "
            << spheres.final_speed << " m/s), points refined where they touch " << refined.gain << " (deepest "
            << refined.deepest << " voxel, the cut alone " << points.deepest << ")\n";
  EXPECT_LT(points.gain, 0.05);
  EXPECT_LT(points.final_speed, 1e-2);
  EXPECT_GT(spheres.gain, points.gain);
  EXPECT_LT(refined.gain, 0.05);
  EXPECT_LT(refined.deepest, points.deepest);
}

/// The speed after 2 s of a bunny dropped from 10 cm onto a box table, its shell cut at the ~800-point level (the
/// seed's coarse shell, as bunny_drop's vps-coarse), with or without refining the cut's nearest points.
double coarse_bunny_on_a_table(bool refine) {
  const Bunny& bunny = Bunny::get();
  CollisionSettings settings;
  settings.query.refine_cut_contacts = refine;
  World world(settings);
  world.dynamics().setGravity(btVector3(0, -9.81f, 0));
  world.add_body(std::make_shared<btBoxShape>(btVector3(3, 0.05f, 3)), 0,
                 btTransform(btQuaternion::getIdentity(), btVector3(0, -0.05f, 0)));
  auto shape = std::make_shared<VpsMixedShape>(bunny.object);
  const PointTree& tree = bunny.object->point_tree();
  size_t budget = tree.points_up_to_level(0);
  for (size_t level = 0; level < tree.level_count(); ++level)
    if (tree.points_up_to_level(level) <= 1000) budget = tree.points_up_to_level(level);
  shape->set_point_budget(budget);
  btRigidBody* body = world.add_body(
      shape, 1.0, place_asset(*shape, btVector3(0.1f, btScalar(-bunny.object->bounds_min().y() + 0.1), 0.05f)));
  body->setFriction(0.6f);
  for (int step = 0; step < 2000; ++step) world.step(kDt);
  return double(body->getLinearVelocity().length());
}

TEST(Bullet, ACoarseShapeComesToRestOnATable) {
  // Resting on a coarse level's own points, a bunny stands on a few of them: a narrower base than its surface's,
  // on which it rocked for seconds (bunny_drop's vps-coarse: 9 mm/s after 2 s). The physics defaults refine the
  // cut where it touches (refine_cut_contacts): it rests on its surface's points there.
  const double refined = coarse_bunny_on_a_table(true), cut = coarse_bunny_on_a_table(false);
  std::cout << "[ figures  ] speed after 2 s on a table: refined cut " << refined << " m/s, the cut alone " << cut
            << " m/s\n";
  EXPECT_LT(refined, 1e-4);
}

TEST(Bullet, AStepTimeBudgetCutsWithoutAddingEnergy) {
  // Whole shells under a step budget of half what the pair costs at rest from the root (measured first, so the
  // test means the same on a slow, instrumented build): the cap drops tree levels until the steps fit, never
  // below the levels within step_budget_min_points (the bunny's first 4 levels, 330 points), and the bunny
  // lands on the bunny without gaining energy or sinking into it by more than that level's spacing allows.
  const DropOutcome full = coarse_bunny_drop(runtime::CutLevel::Points, UINT32_MAX, 0.0, false);
  const double budget_us = 0.5 * full.narrow_phase_us_p50;
  const DropOutcome budget = coarse_bunny_drop(runtime::CutLevel::Points, UINT32_MAX, budget_us);
  std::cout << "[ figures  ] full tree " << full.narrow_phase_us_p50 << " us a step at rest; a budget of " << budget_us
            << " us cut " << budget.budget_cuts << " pair tests of 6000: energy gain " << budget.gain
            << ", deepest penetration " << budget.deepest << " voxel (full tree " << full.deepest << ")\n";
  EXPECT_GT(budget.budget_cuts, 100u);
  EXPECT_LT(budget.gain, 0.05);
  EXPECT_LT(budget.deepest, 5.0);  // level 3 alone (no floor) sinks 9.4 voxels, level 2 33
}

TEST(Bullet, BulletsOwnPairsStillWork) {
  const Bunny& bunny = Bunny::get();
  World world;
  world.dynamics().setGravity(btVector3(0, -9.81f, 0));
  world.add_body(std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0), 0, btTransform::getIdentity());
  auto box_shape = std::make_shared<btBoxShape>(btVector3(0.1f, 0.1f, 0.1f));
  btTransform t = btTransform::getIdentity();
  t.setOrigin(btVector3(5, 0.1f, 0));
  world.add_body(box_shape, 0, t);  // a static box on the plane
  t.setOrigin(btVector3(5, 0.5f, 0));
  btRigidBody* box = world.add_body(box_shape, 1.0, t);  // box on box
  t.setOrigin(btVector3(-5, 0.5f, 0));
  btRigidBody* ball = world.add_body(std::make_shared<btSphereShape>(0.1f), 1.0, t);  // sphere on plane
  auto bunny_shape = std::make_shared<VpsMixedShape>(bunny.object);                   // a VPS body in the same world
  world.add_body(bunny_shape, 1.0,
                 place_asset(*bunny_shape, btVector3(0, btScalar(-bunny.object->bounds_min().y()), 0)));
  for (int step = 0; step < 1500; ++step) world.step(kDt);
  EXPECT_NEAR(box->getCenterOfMassPosition().y(), 0.3f, 0.01f);
  EXPECT_NEAR(ball->getCenterOfMassPosition().y(), 0.1f, 0.01f);
  ASSERT_NE(world.vps(), nullptr);
  EXPECT_GT(world.vps()->counters().pair_tests, 0u);  // the bunny against the plane
}

TEST(Bullet, BoxesAndSpheresBounceOffAStaticBunny) {
  const Bunny& bunny = Bunny::get();
  World world;
  world.dynamics().setGravity(btVector3(0, -9.81f, 0));
  auto bunny_shape = std::make_shared<VpsMixedShape>(bunny.object);
  const btTransform bunny_transform = place_asset(*bunny_shape, btVector3(0, 0, 0));
  world.add_body(bunny_shape, 0, bunny_transform);
  // Drop a ball and a box onto the bunny's highest points.
  const Pose pose = bunny_shape->asset_pose(bunny_transform);
  std::vector<Eigen::Vector3d> tops;
  for (const Eigen::Vector3f& p : bunny.object->point_tree().points) tops.push_back(pose.apply(p.cast<double>()));
  std::sort(tops.begin(), tops.end(), [](const auto& a, const auto& b) { return a.y() > b.y(); });
  const double r = 0.05;
  btTransform t = btTransform::getIdentity();
  t.setOrigin(btVector3(btScalar(tops[0].x()), btScalar(tops[0].y() + 0.2), btScalar(tops[0].z())));
  btRigidBody* ball = world.add_body(std::make_shared<btSphereShape>(btScalar(r)), 0.2f, t);
  t.setOrigin(btVector3(btScalar(tops[0].x()), btScalar(tops[0].y() + 0.5), btScalar(tops[0].z())));
  auto box_shape = std::make_shared<btBoxShape>(btVector3(0.04f, 0.04f, 0.04f));
  btRigidBody* box = world.add_body(box_shape, 0.2f, t);
  double ball_depth = 0, box_depth = 0;
  for (int step = 0; step < 800; ++step) {
    world.step(kDt);
    // Penetration of the ball (centre against the bunny's distance field) and of the box's corners.
    ContactSet contacts;
    const Eigen::Vector3d centre = to_eigen_vector(ball->getCenterOfMassPosition());
    query_points_in_voxelmap(*bunny.object, pose, &centre, 1, r, QueryOptions{}, contacts);
    for (const Contact& c : contacts.contacts) ball_depth = std::max(ball_depth, c.depth);
    contacts.clear();
    std::array<Eigen::Vector3d, 8> corners;
    const btTransform& tb = box->getWorldTransform();
    for (int k = 0; k < 8; ++k)
      corners[size_t(k)] =
          to_eigen_vector(tb(btVector3((k & 1) ? 0.04f : -0.04f, (k & 2) ? 0.04f : -0.04f, (k & 4) ? 0.04f : -0.04f)));
    query_points_in_voxelmap(*bunny.object, pose, corners.data(), corners.size(), 0.0, QueryOptions{}, contacts);
    for (const Contact& c : contacts.contacts) box_depth = std::max(box_depth, c.depth);
  }
  std::cout << "[ figures  ] deepest penetration into the bunny: ball " << ball_depth / bunny.h
            << " voxel, box corners " << box_depth / bunny.h << " voxel; " << world.vps()->counters().raw_contacts
            << " raw contacts\n";
  EXPECT_GT(world.vps()->counters().raw_contacts, 0u);
  EXPECT_LE(ball_depth, 2 * bunny.h);
  EXPECT_LE(box_depth, 2 * bunny.h);
  // Both were stopped or deflected by the bunny rather than falling through it.
  EXPECT_GT(ball->getCenterOfMassPosition().y(), btScalar(tops[0].y() - 0.5));
}

TEST(Bullet, ShapeInertiaComesFromTheAsset) {
  const Bunny& bunny = Bunny::get();
  VpsMixedShape shape(bunny.object);
  btVector3 inertia;
  shape.calculateLocalInertia(2.0f, inertia);
  const Eigen::Vector3d expected = bunny.object->principal_moments() * 2.0 / bunny.object->volume();
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(double(inertia[i]), expected[i], 1e-6 * expected.maxCoeff());
  shape.setLocalScaling(btVector3(0.5f, 0.5f, 0.5f));
  shape.calculateLocalInertia(2.0f, inertia);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(double(inertia[i]), 0.25 * expected[i], 1e-6 * expected.maxCoeff());
  // The AABB holds every point at any pose.
  btTransform t(btQuaternion(btVector3(1, 1, 0).normalized(), 0.7f), btVector3(1, 2, 3));
  btVector3 lo, hi;
  shape.getAabb(t, lo, hi);
  const Pose pose = shape.asset_pose(t);
  for (const Eigen::Vector3f& p : bunny.object->point_tree().points) {
    const Eigen::Vector3d w = pose.apply(p.cast<double>());
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(w[a], double(lo[a]) - 1e-5);
      EXPECT_LE(w[a], double(hi[a]) + 1e-5);
    }
  }
  // A scale that is not a finite number > 0 is refused and leaves the shape as it was: 0 made every point a
  // contact, -1 turned the box inside out (never paired), NaN made the box and the inertia NaN.
  for (const float bad : {0.0f, -1.0f, std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()})
    EXPECT_THROW(shape.setLocalScaling(btVector3(bad, bad, bad)), std::invalid_argument) << bad;
  // Non-uniform, given or passed on by a compound stretched along y: refused, not taken as x (the shape would
  // collide as an unstretched body).
  EXPECT_THROW(shape.setLocalScaling(btVector3(0.5f, 1.0f, 0.5f)), std::invalid_argument);
  EXPECT_THROW(shape.setLocalScaling(btVector3(2.0f, 2.0f, 0.0f)), std::invalid_argument);
  btCompoundShape compound;
  compound.addChildShape(btTransform::getIdentity(), &shape);
  EXPECT_THROW(compound.setLocalScaling(btVector3(1, 2, 1)), std::invalid_argument);
  EXPECT_EQ(shape.getLocalScaling(), btVector3(0.5f, 0.5f, 0.5f));
  EXPECT_EQ(shape.asset_pose(t).scale, 0.5);
}

}  // namespace
}  // namespace voxfmt::bullet
