// Every kind of Bullet partner against a VPS body: a bunny dropped on a static partner (or a VPS bunny inside
// a compound) comes to rest within a voxel of penetration and stops; pairs without an algorithm are reported.
#include <BulletCollision/CollisionShapes/btHeightfieldTerrainShape.h>
#include <BulletCollision/CollisionShapes/btScaledBvhTriangleMeshShape.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <iostream>
#include <random>
#include <string>
#include <utility>

#include "baked_bunny.h"
#include "triangle_set.h"  // private: the terrain's nearest-triangle search
#include "voxfmt/bullet/collision.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"

namespace voxfmt::bullet {
namespace {

constexpr btScalar kDt = btScalar(1e-3);
using Bunny = voxfmt::test::BakedBunny;

btTransform at(const btVector3& origin, const btQuaternion& rotation = btQuaternion::getIdentity()) {
  return btTransform(rotation, origin);
}

// The deepest penetration of the bunny's shell points into the partner, by the partner's own signed distance.
using PartnerDistance = std::function<float(const Eigen::Vector3f&)>;

struct Rest {
  double speed = 0;         ///< residual speed: the centre of mass's drift over the last 0.1 s, m/s
  double solver_speed = 0;  ///< Bullet's velocity after the last step (the solver's resting residue)
  double angular = 0;       ///< angular speed, rad/s
  double penetration = 0;   ///< deepest shell point inside the partner at the end, metres
  double height = 0;        ///< centre of mass y at the end
  uint64_t raw_contacts = 0;
};

// Drops the bunny (lowest point `drop` above y = top) onto a static partner and lets it settle for `seconds`.
// `also_at`: the same partner placed a second time (two rails).
Rest settle_on(std::shared_ptr<btCollisionShape> partner, const btTransform& partner_at, double top,
               const PartnerDistance& distance, const btTransform* also_at = nullptr,
               const CollisionSettings& settings = {}) {
  const double seconds = 1.5, drop = 0.01;
  const Bunny& bunny = Bunny::get();
  World world(settings);
  world.dynamics().setGravity(btVector3(0, -9.81f, 0));
  if (also_at) world.add_body(partner, 0, *also_at);
  world.add_body(std::move(partner), 0, partner_at);
  auto shape = std::make_shared<VpsMixedShape>(bunny.object);
  btTransform t = shape->asset_to_shape().inverse();
  t.setOrigin(t.getOrigin() + btVector3(0, btScalar(top - bunny.object->bounds_min().y() + drop), 0));
  btRigidBody* body = world.add_body(shape, 1.0, t);
  body->setFriction(0.8f);
  body->setActivationState(DISABLE_DEACTIVATION);  // the residual speed is measured, not put to sleep
  const int steps = int(std::lround(seconds / double(kDt)));
  btVector3 before(0, 0, 0);
  for (int step = 0; step < steps; ++step) {
    if (step == steps - 100) before = body->getCenterOfMassPosition();
    world.step(kDt);
    if (std::getenv("VOXFMT_TRACE") && step % 100 == 0)
      std::cout << step << " com " << body->getCenterOfMassPosition().x() << " " << body->getCenterOfMassPosition().y()
                << " " << body->getCenterOfMassPosition().z() << " v " << body->getLinearVelocity().length() << "\n";
  }
  Rest rest;
  rest.solver_speed = double(body->getLinearVelocity().length());
  rest.speed = double((body->getCenterOfMassPosition() - before).length()) / (100 * double(kDt));
  rest.angular = double(body->getAngularVelocity().length());
  rest.height = double(body->getCenterOfMassPosition().y());
  const runtime::Pose pose = shape->asset_pose(body->getWorldTransform());
  for (const Eigen::Vector3f& p : bunny.object->point_tree().points)
    rest.penetration = std::max(rest.penetration, -double(distance(pose.apply(p.cast<double>()).cast<float>())));
  rest.raw_contacts = world.vps()->counters().raw_contacts;
  return rest;
}

/// A convex partner's signed distance at `placement`, as settle_on measures penetration.
PartnerDistance convex_partner(const btConvexShape& shape, const btTransform& placement) {
  return [&shape, placement](const Eigen::Vector3f& x) {
    Eigen::Vector3f n;
    return convex_distance(shape, placement, x, n);
  };
}

void expect_resting(const Rest& rest, const std::string& partner) {
  const double h = Bunny::get().h;
  std::cout << "[ figures  ] " << partner << ": drift " << rest.speed << " m/s (solver velocity " << rest.solver_speed
            << "), angular " << rest.angular << " rad/s, penetration " << rest.penetration / h << " voxel, "
            << rest.raw_contacts << " raw contacts\n";
  EXPECT_GT(rest.raw_contacts, 0u) << partner;
  // At rest: the aim is a drift below 1e-4 m/s; measured 0.6-2.5e-4 across partners, changing 2-3x with tiny
  // changes of the asset (the solver's resting noise). A body that slides, rocks or falls moves orders of
  // magnitude faster.
  EXPECT_LT(rest.speed, 5e-4) << partner;
  EXPECT_LE(rest.penetration, h) << partner;
}

TEST(Partners, Plane) {
  auto plane = std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0);
  expect_resting(settle_on(plane, btTransform::getIdentity(), 0.0, [](const Eigen::Vector3f& x) { return x.y(); }),
                 "plane");
}

TEST(Partners, BoxFloor) {
  auto box = std::make_shared<btBoxShape>(btVector3(1, 0.1f, 1));
  const btTransform t = at(btVector3(0, -0.1f, 0));
  expect_resting(settle_on(box, t, 0.0,
                           [&](const Eigen::Vector3f& x) {
                             Eigen::Vector3f n;
                             return box_distance(Eigen::Matrix3f::Identity(), Eigen::Vector3f(0, -0.1f, 0),
                                                 Eigen::Vector3f(1, 0.1f, 1), x, n);
                           }),
                 "box");
}

TEST(Partners, CapsuleRails) {
  // Two capsules (radius 5 cm, 2 m long) along x under the bunny's feet, like rails.
  auto capsule = std::make_shared<btCapsuleShapeX>(0.05f, 2.0f);
  const btTransform left = at(btVector3(0, -0.05f, -0.2f)), right = at(btVector3(0, -0.05f, 0.25f));
  expect_resting(
      settle_on(
          capsule, left, 0.0,
          [&](const Eigen::Vector3f& x) {
            Eigen::Vector3f n;
            return std::min(
                capsule_distance(Eigen::Vector3f(-1, -0.05f, -0.2f), Eigen::Vector3f(1, -0.05f, -0.2f), 0.05f, x, n),
                capsule_distance(Eigen::Vector3f(-1, -0.05f, 0.25f), Eigen::Vector3f(1, -0.05f, 0.25f), 0.05f, x, n));
          },
          &right),
      "capsule");
}

TEST(Partners, CylinderStandingUp) {
  auto cylinder = std::make_shared<btCylinderShape>(btVector3(1, 0.1f, 1));
  const btTransform t = at(btVector3(0, -0.1f, 0));
  expect_resting(settle_on(cylinder, t, 0.0, convex_partner(*cylinder, t)), "cylinder");
}

TEST(Partners, MultiSphereTable) {
  // Four spheres of 1 m at the corners of a square: their hull (btMultiSphereShape) is a table with a flat 1 m top at
  // y = 0 and rounded edges. Both directions of the multi-sphere partner: GJK for the bunny's points, the spheres in
  // its voxelmap.
  const btVector3 centres[4] = {btVector3(-0.5f, -1, -0.5f), btVector3(0.5f, -1, -0.5f), btVector3(-0.5f, -1, 0.5f),
                                btVector3(0.5f, -1, 0.5f)};
  const btScalar radii[4] = {1, 1, 1, 1};
  auto spheres = std::make_shared<btMultiSphereShape>(centres, radii, 4);
  const btTransform t = at(btVector3(0, 0, 0));
  expect_resting(settle_on(spheres, t, 0.0, convex_partner(*spheres, t)), "multi-sphere");
}

TEST(Partners, ConeUpsideDown) {
  // Apex down, the flat base (radius 1 m) on top at y = 0.
  auto cone = std::make_shared<btConeShape>(1.0f, 0.2f);
  cone->setMargin(0.001f);  // Bullet's 4 cm default rounds the cone outward; match the others' margin
  const btTransform t = at(btVector3(0, -0.1f, 0), btQuaternion(btVector3(1, 0, 0), SIMD_PI));
  expect_resting(settle_on(cone, t, 0.0, convex_partner(*cone, t)), "cone");
}

TEST(Partners, ConvexHull) {
  // A slab-like hull (12 points) with a collision margin matched to the others' (1 mm), not Bullet's 4 cm.
  auto hull = std::make_shared<btConvexHullShape>();
  for (float x : {-1.0f, 1.0f})
    for (float z : {-1.0f, 1.0f}) {
      hull->addPoint(btVector3(x, 0, z), false);
      hull->addPoint(btVector3(x, -0.2f, z), false);
    }
  for (float x : {-0.5f, 0.5f}) hull->addPoint(btVector3(x, -0.3f, 0.2f * x), false);
  hull->addPoint(btVector3(0, -0.25f, 0.7f), false);
  hull->addPoint(btVector3(0.3f, -0.25f, -0.7f), false);
  hull->recalcLocalAabb();
  hull->setMargin(0.001f);
  hull->initializePolyhedralFeatures();  // exact distances inside the hull
  const btTransform t = at(btVector3(0, -0.001f, 0));
  expect_resting(settle_on(hull, t, 0.0, convex_partner(*hull, t)), "convex hull");
}

TEST(Partners, CompoundOfBoxes) {
  // Two boxes side by side under the bunny: Bullet's compound algorithm meets the VPS shape child by child.
  auto compound = std::make_shared<btCompoundShape>();
  auto half = std::make_shared<btBoxShape>(btVector3(0.5f, 0.1f, 1));
  compound->addChildShape(at(btVector3(-0.5f, -0.1f, 0)), half.get());
  compound->addChildShape(at(btVector3(0.5f, -0.1f, 0)), half.get());
  Rest rest = settle_on(compound, btTransform::getIdentity(), 0.0, [&](const Eigen::Vector3f& x) {
    Eigen::Vector3f n;
    return box_distance(Eigen::Matrix3f::Identity(), Eigen::Vector3f(0, -0.1f, 0), Eigen::Vector3f(1, 0.1f, 1), x, n);
  });
  expect_resting(rest, "compound");
}

// A grid of triangles over [-1, 1]^2 in x-z at height y(x, z), counter-clockwise seen from above.
std::unique_ptr<btTriangleMesh> floor_mesh(int cells, const std::function<float(float, float)>& y) {
  auto mesh = std::make_unique<btTriangleMesh>();
  auto p = [&](int i, int k) {
    const float x = -1 + 2.0f * float(i) / float(cells), z = -1 + 2.0f * float(k) / float(cells);
    return btVector3(x, y(x, z), z);
  };
  for (int i = 0; i < cells; ++i)
    for (int k = 0; k < cells; ++k) {
      mesh->addTriangle(p(i, k), p(i, k + 1), p(i + 1, k + 1));
      mesh->addTriangle(p(i, k), p(i + 1, k + 1), p(i + 1, k));
    }
  return mesh;
}

TEST(Partners, StaticTriangleMesh) {
  // A floor of 20,000 triangles (a VPS bunny used to fall through a triangle-mesh floor without a word).
  static std::unique_ptr<btTriangleMesh> mesh = floor_mesh(100, [](float, float) { return 0.0f; });
  auto floor = std::make_shared<btBvhTriangleMeshShape>(mesh.get(), true);
  expect_resting(settle_on(floor, btTransform::getIdentity(), 0.0, [](const Eigen::Vector3f& x) { return x.y(); }),
                 "static mesh");
}

TEST(Partners, AMirroredStaticMeshKeepsItsOutside) {
  // Scaled by (-1, 1, 1), Bullet hands every triangle over turned over: taken as it came, the floor's inside was
  // above it and the bunny was pulled through (indexed or gathered per test alike).
  static std::unique_ptr<btTriangleMesh> mesh = floor_mesh(20, [](float, float) { return 0.0f; });
  static btBvhTriangleMeshShape unscaled(mesh.get(), true);
  for (const bool indexed : {true, false}) {
    auto floor = std::make_shared<btScaledBvhTriangleMeshShape>(&unscaled, btVector3(-1, 1, 1));
    CollisionSettings settings;
    settings.static_mesh_index = indexed;
    const Rest rest = settle_on(
        floor, btTransform::getIdentity(), 0.0, [](const Eigen::Vector3f& x) { return x.y(); }, nullptr, settings);
    expect_resting(rest, indexed ? "mirrored static mesh, indexed" : "mirrored static mesh, gathered");
  }
}

// Counts the points a contact test reports.
struct ContactCount : btCollisionWorld::ContactResultCallback {
  int points = 0;
  btScalar addSingleResult(btManifoldPoint&, const btCollisionObjectWrapper*, int, int, const btCollisionObjectWrapper*,
                           int, int) override {
    ++points;
    return 0;
  }
};

// The highest point of the asset's shell (asset frame).
Eigen::Vector3d highest_point(const runtime::CollisionObject& object) {
  const auto& points = object.point_tree().points;
  const auto top = std::max_element(points.begin(), points.end(),
                                    [](const Eigen::Vector3f& p, const Eigen::Vector3f& q) { return p.y() < q.y(); });
  return top->cast<double>();
}

TEST(Partners, AScaledMultiSphereIsTestedAtItsScale) {
  // Its spheres are stored unscaled: a ball of 4 cm scaled to a voxel, a voxel clear of the bunny (within the
  // voxelmap's band, where its centre is looked up), touched it.
  const Bunny& bunny = Bunny::get();
  World world;
  auto shape = std::make_shared<VpsMixedShape>(bunny.object);
  world.add_body(shape, 0, shape->asset_to_shape().inverse());  // the asset frame is the world
  const btVector3 centre(0, 0, 0);
  const btScalar radius = 0.04f;
  const double scale = bunny.h / double(radius);
  auto ball = std::make_shared<btMultiSphereShape>(&centre, &radius, 1);
  ball->setLocalScaling(btVector3(1, 1, 1) * btScalar(scale));
  ball->setMargin(btScalar(0.1 * bunny.h));  // Bullet's 4 cm would be most of the ball
  const Eigen::Vector3d top = highest_point(*bunny.object);
  // A voxel above the bunny's highest point: nothing; half a voxel into it: contacts.
  for (const double gap : {1.0, -0.5}) {
    btCollisionObject probe;
    probe.setCollisionShape(ball.get());
    btTransform t = btTransform::getIdentity();
    t.setOrigin(btVector3(btScalar(top.x()), btScalar(top.y() + bunny.h * (1 + gap)), btScalar(top.z())));
    probe.setWorldTransform(t);
    ContactCount count;
    world.dynamics().contactTest(&probe, count);
    if (gap > 0)
      EXPECT_EQ(count.points, 0) << "a voxel clear of the bunny's top";
    else
      EXPECT_GT(count.points, 0) << "in the bunny";
  }
}

TEST(Partners, ContactTestBetweenStaticBodiesSeesTheirOverlap) {
  // The pair's manifold was made only for pairs the dispatcher would collide, and two static bodies are none: a
  // placement check of static geometry (contactTest, contactPairTest) saw no overlap.
  const Bunny& bunny = Bunny::get();
  World world;
  auto shape = std::make_shared<VpsMixedShape>(bunny.object);
  btRigidBody* vps = world.add_body(shape, 0, shape->asset_to_shape().inverse());
  auto box = std::make_shared<btBoxShape>(btVector3(0.02f, 0.02f, 0.02f));
  const Eigen::Vector3d top = highest_point(*bunny.object);  // the box around it: half in the bunny
  btRigidBody* block = world.add_body(box, 0, at(btVector3(btScalar(top.x()), btScalar(top.y()), btScalar(top.z()))));
  ContactCount pair, any;
  world.dynamics().contactPairTest(vps, block, pair);
  world.dynamics().contactTest(vps, any);
  EXPECT_GT(pair.points, 0);
  EXPECT_GT(any.points, 0);
}

TEST(Partners, HeightfieldTerrain) {
  // A flat 64 x 64 terrain, 2 m across, heights 0 (up axis y).
  static std::vector<float> heights(64 * 64, 0.0f);
  auto terrain =
      std::make_shared<btHeightfieldTerrainShape>(64, 64, heights.data(), 1.0f, -1.0f, 1.0f, 1, PHY_FLOAT, false);
  terrain->setLocalScaling(btVector3(2.0f / 63, 1, 2.0f / 63));
  // Bullet centres a terrain on its height range: heights [-1, 1] put height 0 at the origin.
  expect_resting(settle_on(terrain, btTransform::getIdentity(), 0.0, [](const Eigen::Vector3f& x) { return x.y(); }),
                 "heightfield");
}

TEST(Partners, VpsBunnyInsideACompoundRestsOnAPlane) {
  const Bunny& bunny = Bunny::get();
  World world;
  world.dynamics().setGravity(btVector3(0, -9.81f, 0));
  world.add_body(std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), 0), 0, btTransform::getIdentity());
  auto vps = std::make_shared<VpsMixedShape>(bunny.object);
  auto compound = std::make_shared<btCompoundShape>();
  compound->addChildShape(btTransform::getIdentity(), vps.get());
  btTransform t = vps->asset_to_shape().inverse();
  t.setOrigin(t.getOrigin() + btVector3(0, btScalar(-bunny.object->bounds_min().y() + 0.01), 0));
  btVector3 inertia;
  vps->calculateLocalInertia(1.0f, inertia);
  btRigidBody* body = world.add_body(compound, 1.0, t, &inertia);
  body->setFriction(0.8f);
  body->setActivationState(DISABLE_DEACTIVATION);
  btVector3 before(0, 0, 0);
  for (int step = 0; step < 1500; ++step) {
    if (step == 1400) before = body->getCenterOfMassPosition();
    world.step(kDt);
  }
  const runtime::Pose pose = vps->asset_pose(body->getWorldTransform());
  double penetration = 0;
  for (const Eigen::Vector3f& p : bunny.object->point_tree().points)
    penetration = std::max(penetration, -pose.apply(p.cast<double>()).y());
  const double speed = double((body->getCenterOfMassPosition() - before).length()) / (100 * double(kDt));
  std::cout << "[ figures  ] VPS child of a compound on a plane: drift " << speed << " m/s (solver velocity "
            << body->getLinearVelocity().length() << "), penetration " << penetration / bunny.h << " voxel\n";
  EXPECT_GT(world.vps()->counters().raw_contacts, 0u);
  EXPECT_LT(speed, 5e-4);  // as for the other partners (see expect_resting)
  EXPECT_LE(penetration, bunny.h);
}

TEST(Partners, UnsupportedPairsAreReportedOnce) {
  const Bunny& bunny = Bunny::get();
  std::vector<std::string> messages;
  CollisionSettings settings;
  settings.on_unsupported_pair = [&](const std::string& m) { messages.push_back(m); };
  World world(settings);
  world.dynamics().setGravity(btVector3(0, -9.81f, 0));
  // A custom concave shape no algorithm knows (Bullet's multimaterial mesh type stands in for one).
  struct Unknown : btConcaveShape {
    Unknown() { m_shapeType = MULTIMATERIAL_TRIANGLE_MESH_PROXYTYPE; }
    void getAabb(const btTransform& t, btVector3& lo, btVector3& hi) const override {
      lo = t.getOrigin() - btVector3(1, 1, 1);
      hi = t.getOrigin() + btVector3(1, 1, 1);
    }
    void setLocalScaling(const btVector3&) override {}
    const btVector3& getLocalScaling() const override { return scaling; }
    void calculateLocalInertia(btScalar, btVector3& inertia) const override { inertia.setZero(); }
    const char* getName() const override { return "Unknown"; }
    void processAllTriangles(btTriangleCallback*, const btVector3&, const btVector3&) const override {}
    btVector3 scaling{1, 1, 1};
  };
  world.add_body(std::make_shared<Unknown>(), 0, btTransform::getIdentity());
  auto shape = std::make_shared<VpsMixedShape>(bunny.object);
  world.add_body(shape, 1.0, btTransform::getIdentity());
  for (int step = 0; step < 20; ++step) world.step(kDt);
  ASSERT_EQ(messages.size(), 1u);
  EXPECT_NE(messages[0].find("Unknown"), std::string::npos) << messages[0];
  EXPECT_GE(world.vps()->counters().unsupported_pairs, 20u);
}

// A mesh's triangle that names one vertex twice is a segment. Its closest point once came out NaN (0/0 on the
// zero-length edge) beyond that edge, and a NaN distance passed the tie test and handed the point the segment's zero
// normal and an outside sign: under a floor holding such a triangle, points read as outside with no direction.
TEST(TerrainTriangles, ATriangleNamingAVertexTwiceNeitherHidesNorFlipsTheSurface) {
  const Eigen::Vector3f a(0, 0, 0), b(0.1f, 0, 0), c(0.1f, 0, 0.1f), d(0, 0, 0.1f);
  TriangleSet plain, doubled;  // a square facing +y; and the same with its diagonal and edges again as segments
  for (TriangleSet* set : {&plain, &doubled}) {
    set->add(a, d, c);
    set->add(a, c, b);
  }
  doubled.add(a, a, c);
  doubled.add(c, a, a);
  doubled.add(b, a, a);
  doubled.add(d, d, c);
  for (TriangleSet* set : {&plain, &doubled}) {
    set->set_solid_below(true);
    set->build();
  }
  std::mt19937 random(5);
  std::uniform_real_distribution<float> across(-0.05f, 0.15f), up(-0.03f, 0.03f);
  int beside = 0;
  for (int p = 0; p < 4000; ++p) {
    const Eigen::Vector3f x(across(random), up(random), across(random));
    Eigen::Vector3f outward, expected_outward;
    const float distance = doubled.distance(x, outward), expected = plain.distance(x, expected_outward);
    ASSERT_EQ(distance, expected) << p << " at " << x.transpose();
    ASSERT_TRUE(outward.isApprox(expected_outward, 1e-5f))
        << p << " at " << x.transpose() << ": " << outward.transpose();
    beside += std::max(x.x(), x.z()) > 0.1f || std::min(x.x(), x.z()) < 0.0f;
  }
  EXPECT_GT(beside, 1000);  // points nearest an edge or corner, where the faces' alignment is below 1
}

// A triangle whose three distinct corners lie on one line (in float, within rounding of it) is that segment. Its face
// coordinates are rounding noise there, and taken as they came they put the closest point anywhere along it: up to
// half the segment too far from p.
TEST(TerrainTriangles, ATriangleWithItsCornersOnOneLineIsItsSegment) {
  std::mt19937 random(9);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f), along(0.05f, 0.95f);
  const auto segment_distance = [](const Eigen::Vector3f& p, const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
    const Eigen::Vector3d a64 = a.cast<double>(), ab = b.cast<double>() - a64, ap = p.cast<double>() - a64;
    return (ap - ab * std::clamp(ap.dot(ab) / ab.squaredNorm(), 0.0, 1.0)).norm();
  };
  int far_off = 0;
  for (int q = 0; q < 20000; ++q) {
    const Eigen::Vector3f a(unit(random), unit(random), unit(random)), c(unit(random), unit(random), unit(random));
    const Eigen::Vector3f b = a + along(random) * (c - a), p(unit(random), unit(random), unit(random));
    for (const auto& [x, y, z] : {std::array{a, b, c}, std::array{b, c, a}, std::array{c, a, b}}) {
      const float got = (detail::closest_on_triangle(p, x, y, z) - p).norm();
      const double expected = segment_distance(p, a, c);
      far_off += got > expected + 1e-3;
      ASSERT_NEAR(got, expected, 1e-4 * (1.0 + expected)) << q;
    }
  }
  EXPECT_EQ(far_off, 0);
}

// The grid search a terrain's triangles get (cells and triangles skipped by their boxes, each triangle once, a reach
// from the block's faces) finds the nearest of every triangle: the same distance as looking at each, above the
// terrain, below it, beside it, beyond its box and on its edges.
TEST(TerrainTriangles, TheGridSearchGivesTheNearestOfEveryTriangle) {
  TriangleSet searched, every;
  const int n = 24;
  const auto height = [](int i, int k) {
    return 0.02f * std::sin(0.7f * float(i)) + 0.015f * std::cos(0.5f * float(k));
  };
  const auto vertex = [&](int i, int k) { return Eigen::Vector3f(0.01f * float(i), height(i, k), 0.01f * float(k)); };
  // A patch of cells x cells squares into both sets, counter-clockwise seen from above.
  const auto add_patch = [&](int cells, TriangleSet& a, TriangleSet& b) {
    for (int i = 0; i < cells; ++i)
      for (int k = 0; k < cells; ++k)
        for (TriangleSet* set : {&a, &b}) {
          set->add(vertex(i, k), vertex(i, k + 1), vertex(i + 1, k + 1));
          set->add(vertex(i, k), vertex(i + 1, k + 1), vertex(i + 1, k));
        }
  };
  add_patch(n - 1, searched, every);
  searched.build();  // `every` is not built: it looks at every triangle
  // The distance the grid search gives at x, and the one looking at every triangle gives.
  const auto both = [](const TriangleSet& grid, const TriangleSet& all, const Eigen::Vector3f& x) {
    Eigen::Vector3f outward;
    const float d = grid.distance(x, outward);
    return std::make_pair(d, all.distance(x, outward));
  };
  std::mt19937 random(7);
  std::uniform_real_distribution<float> across(-0.03f, 0.26f), up(-0.06f, 0.08f);
  int below = 0, cheap = 0;
  for (int p = 0; p < 4000; ++p) {
    const Eigen::Vector3f x(across(random), up(random), across(random));
    const auto [d, expected] = both(searched, every, x);
    ASSERT_NEAR(std::abs(d), std::abs(expected), 1e-6f * (1.0f + std::abs(expected))) << p;
    if (std::abs(expected) > 1e-4f) {
      ASSERT_EQ(d < 0, expected < 0) << p;
    }
    below += expected < 0;
    // Over the terrain, above or below it, the bound prunes only what the search would find outside. (Beside an
    // open patch the sign is the facing triangle's guess, and a body's points are not there: the patch is gathered
    // under the body's box.)
    const bool over = std::min(x.x(), x.z()) >= 0.0f && std::max(x.x(), x.z()) <= 0.01f * float(n - 1);
    const float bound = searched.lower_bound(x);
    if (over) {
      ASSERT_LE(bound, d + 1e-6f) << p << " at " << x.transpose();
    }
    cheap += x.y() < 0.03f && bound > 0.0f && bound < d - 1e-4f;  // a bound without a search (the box's top: 0.035)
  }
  EXPECT_GT(below, 400);  // the points below the terrain were searched too
  EXPECT_GT(cheap, 100);  // and above it, within the box, bounded without a search
  // Far away (more than kMaxRings cells past the first ring that holds a triangle) a point gets a positive bound of
  // its distance's size: deep behind a floor, it has tunnelled through. A grid fewer cells across than those rings
  // is searched whole, so there the distance stays exact on either side.
  TriangleSet small_searched, small_every;
  add_patch(2, small_searched, small_every);
  small_searched.build();
  std::uniform_real_distribution<float> far_across(-0.5f, 0.75f), far_up(-0.5f, 0.5f);
  // A terrain is solid below: under its footprint a point below its column is searched to its nearest triangle
  // however deep.
  TriangleSet solid = searched;
  solid.set_solid_below(true);
  int bounded = 0, deep_below = 0;
  for (int p = 0; p < 1000; ++p) {
    const Eigen::Vector3f x(far_across(random), far_up(random), far_across(random));
    const auto [d, expected] = both(searched, every, x);
    const float tolerance = 1e-6f * (1.0f + std::abs(expected));
    if (std::abs(d - expected) > tolerance) {
      ++bounded;
      ASSERT_GT(d, 0.0f) << p;
      ASSERT_LE(d, std::abs(expected) + tolerance) << p;
    }
    if (std::min(x.x(), x.z()) >= 0.0f && std::max(x.x(), x.z()) <= 0.01f * float(n - 1)) {
      ASSERT_LE(searched.lower_bound(x), d + tolerance) << p;
      if (x.y() < -0.04f) {  // below every triangle
        // Inside, exactly as deep (searched over the columns), where the ring search stops at its reach; the
        // nearest triangle's normal out, which faces up.
        const auto [s, exact] = both(solid, every, x);
        ASSERT_LT(s, 0.0f) << p << " at " << x.transpose();
        ASSERT_NEAR(s, exact, tolerance) << p;
        ASSERT_LE(solid.lower_bound(x), s) << p;
        Eigen::Vector3f outward;
        solid.distance(x, outward);
        ASSERT_GT(outward.y(), 0.0f) << p;
        if (d > 0.0f) {  // beyond the ring search's reach: counted as tunnelled through when not solid, and pruned
          ++deep_below;
          ASSERT_GT(searched.lower_bound(x), 0.0f) << p;
        }
      }
    }
    const auto [small, small_expected] = both(small_searched, small_every, x);
    ASSERT_NEAR(small, small_expected, 1e-6f * (1.0f + std::abs(small_expected))) << p;
  }
  EXPECT_GT(bounded, 100);
  EXPECT_GT(deep_below, 0);  // measured: 10 of the 1,000 points
  // Under the footprint at every depth to 0.6 m (60 cells; the ring search reaches 8), the nearest triangle.
  std::uniform_real_distribution<float> footprint(0.0f, 0.01f * float(n - 1)), depth(-0.6f, -0.04f);
  for (int p = 0; p < 2000; ++p) {
    const Eigen::Vector3f x(footprint(random), depth(random), footprint(random));
    const auto [s, exact] = both(solid, every, x);
    ASSERT_NEAR(s, exact, 1e-6f * (1.0f + std::abs(exact))) << p << " at " << x.transpose();
  }
}

// The columns' bound over a set with gaps (two strips of a floor with nothing between them) and one that faces down
// the z axis: never above the distance, for points over the gap and below it too; and under a solid set the search
// over the columns finds the nearest triangle at any depth, along any axis.
TEST(TerrainTriangles, TheColumnsBoundHoldsOverGapsAndAlongAnyAxis) {
  for (const int up : {1, 2}) {
    for (const float sign : {1.0f, -1.0f}) {
      TriangleSet strips;
      // A point of the floor at (u, v) across the up axis, at height h along it (times sign), on a ramp along v
      // (so the columns' tops differ along one axis across the up axis and not the other).
      const auto at = [&](float u, float v, float h) {
        Eigen::Vector3f p;
        p[up] = sign * (h + 0.2f * v);
        p[(up + 1) % 3] = u;
        p[(up + 2) % 3] = v;
        return p;
      };
      for (const float u0 : {0.0f, 5.0f})  // strips [0, 1] and [5, 6] across, [0, 6] along
        for (int i = 0; i < 4; ++i)
          for (int k = 0; k < 24; ++k) {
            const float u = u0 + 0.25f * float(i), v = 0.25f * float(k);
            Eigen::Vector3f a = at(u, v, 0), b = at(u, v + 0.25f, 0), c = at(u + 0.25f, v + 0.25f, 0),
                            d = at(u + 0.25f, v, 0);
            // Facing up the axis (times sign): counter-clockwise seen from there.
            if ((b - a).cross(c - a)[up] * sign < 0) std::swap(b, d);
            strips.add(a, b, c);
            strips.add(a, c, d);
          }
      const TriangleSet every = strips;  // not built: looks at every triangle
      strips.build();
      TriangleSet solid = strips;
      solid.set_solid_below(true);
      std::mt19937 random(3);
      std::uniform_real_distribution<float> across(0.0f, 6.0f), height(-1.5f, 1.5f);
      int positive = 0;
      for (int p = 0; p < 3000; ++p) {
        const Eigen::Vector3f x = at(across(random), across(random), height(random));
        Eigen::Vector3f outward;
        const float d = strips.distance(x, outward), bound = strips.lower_bound(x);
        ASSERT_LE(bound, d + 1e-5f) << "up " << up << " sign " << sign << " at " << x.transpose();
        positive += bound > 0.0f && bound < d - 1e-5f;
      }
      EXPECT_GT(positive, 300) << "up " << up << " sign " << sign;  // bounded without a search above the strips
      // Below a strip, up to 18 cells deep (the ring search reaches 8), a solid set's distance is the nearest
      // triangle's.
      std::uniform_real_distribution<float> strip(0.0f, 1.0f), deep(-5.0f, -0.5f);
      int beyond_rings = 0;
      for (int p = 0; p < 600; ++p) {
        const Eigen::Vector3f x = at(strip(random) + (p % 2 ? 5.0f : 0.0f), across(random), deep(random));
        Eigen::Vector3f outward;
        const float s = solid.distance(x, outward), expected = every.distance(x, outward);
        ASSERT_NEAR(s, expected, 1e-6f * (1.0f - expected))
            << "up " << up << " sign " << sign << " at " << x.transpose();
        ASSERT_LE(solid.lower_bound(x), s) << "up " << up << " sign " << sign << " at " << x.transpose();
        beyond_rings += strips.distance(x, outward) > 0.0f;
      }
      EXPECT_GT(beyond_rings, 100) << "up " << up << " sign " << sign;
    }
  }
}

// Less than a cell above a gentle terrain, where no cell is empty for rings around, the tops of the columns around
// a point bound its distance without a search, and never above it.
TEST(TerrainTriangles, PointsJustAboveAGentleTerrainAreBoundedByTheColumnsAround) {
  TriangleSet terrain;
  const int n = 40;
  const auto vertex = [](int i, int k) {
    return Eigen::Vector3f(0.01f * float(i), 0.003f * std::sin(0.2f * float(i)) * std::cos(0.15f * float(k)),
                           0.01f * float(k));
  };
  for (int i = 0; i + 1 < n; ++i)
    for (int k = 0; k + 1 < n; ++k) {
      terrain.add(vertex(i, k), vertex(i, k + 1), vertex(i + 1, k + 1));
      terrain.add(vertex(i, k), vertex(i + 1, k + 1), vertex(i + 1, k));
    }
  terrain.build();
  std::mt19937 random(11);
  std::uniform_real_distribution<float> across(0.0f, 0.01f * float(n - 1)), above(0.0005f, 0.01f);
  int bounded = 0;
  const int points = 2000;
  for (int p = 0; p < points; ++p) {
    const float x = across(random), z = across(random);
    // Above the surface: over the highest of the patch's heights within a cell (its slope is below 0.1).
    const Eigen::Vector3f at(x, 0.003f * std::sin(20.0f * x) * std::cos(15.0f * z) + 0.001f + above(random), z);
    Eigen::Vector3f outward;
    const float d = terrain.distance(at, outward), bound = terrain.lower_bound(at);
    ASSERT_GT(d, 0.0f) << p;
    ASSERT_LE(bound, d + 1e-7f) << p << " at " << at.transpose();
    bounded += bound > 0.25f * d && bound < d - 1e-7f;
  }
  std::cout << "[ figures  ] " << bounded << " of " << points << " points within a cell above bounded by the columns\n";
  EXPECT_GT(2 * bounded, points);
}

}  // namespace
}  // namespace voxfmt::bullet
