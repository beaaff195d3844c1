// A VPS body against a static triangle mesh indexed once (CollisionSettings::static_mesh_index): the coherent pair
// (a traversal front and the mesh's vertices kept near the body) finds bit for bit the contacts of the pair from
// scratch, along a body sliding across a tilted wavy floor and one jumping far beyond where what it kept was made;
// both find the contacts of the unindexed path (the triangles in the body's box gathered and gridded each test),
// which terrains take: a body pressed deep into one keeps its deepest contacts.
#include <BulletCollision/BroadphaseCollision/btCollisionAlgorithm.h>
#include <BulletCollision/CollisionDispatch/btCollisionObjectWrapper.h>
#include <BulletCollision/CollisionDispatch/btManifoldResult.h>
#include <BulletCollision/CollisionShapes/btBoxShape.h>
#include <BulletCollision/CollisionShapes/btBvhTriangleMeshShape.h>
#include <BulletCollision/CollisionShapes/btHeightfieldTerrainShape.h>
#include <BulletCollision/CollisionShapes/btTriangleMesh.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>
#include <iterator>
#include <memory>
#include <string>
#include <vector>

#include "baked_bunny.h"
#include "voxfmt/bullet/collision.h"
#include "voxfmt/bullet/shape.h"

namespace voxfmt::bullet {
namespace {

using Bunny = voxfmt::test::BakedBunny;
constexpr double kPi = 3.14159265358979323846;

// The floor's heights: 2 cm waves over 0.7 and 0.9 m.
double wave(double x, double z) { return 0.02 * std::sin(2 * kPi * x / 0.7) * std::cos(2 * kPi * z / 0.9); }

// A grid of triangles over [-2, 2]^2 m in x-z at height wave(x, z), 2 cm cells (80,000 triangles), counter-
// clockwise seen from above.
std::unique_ptr<btTriangleMesh> wavy_floor() {
  constexpr int kCells = 200;
  auto mesh = std::make_unique<btTriangleMesh>();
  auto p = [&](int i, int k) {
    const double x = -2 + 4.0 * i / kCells, z = -2 + 4.0 * k / kCells;
    return btVector3(btScalar(x), btScalar(wave(x, z)), btScalar(z));
  };
  for (int i = 0; i < kCells; ++i)
    for (int k = 0; k < kCells; ++k) {
      mesh->addTriangle(p(i, k), p(i, k + 1), p(i + 1, k + 1));
      mesh->addTriangle(p(i, k), p(i + 1, k + 1), p(i + 1, k));
    }
  return mesh;
}

// One VPS body against one static mesh through the registered algorithm, as a world's narrow phase calls it, one
// pose after another (the algorithm and what it keeps persist); each test's contacts before reduction are kept.
class Pair {
 public:
  Pair(std::shared_ptr<btCollisionShape> floor, const btTransform& floor_at, const CollisionSettings& settings)
      : floor_(std::move(floor)) {
    btDefaultCollisionConstructionInfo info;
    prepare_construction_info(info);
    config_ = std::make_unique<btDefaultCollisionConfiguration>(info);
    dispatcher_ = std::make_unique<btCollisionDispatcher>(config_.get());
    CollisionSettings with_hook = settings;
    with_hook.on_contacts = [this](const btCollisionObject*, const btCollisionObject*,
                                   const runtime::ContactSet& contacts) { contacts_ = contacts.contacts; };
    vps_ = register_vps_collision(*dispatcher_, with_hook);
    body_shape_ = std::make_shared<VpsMixedShape>(Bunny::get().object);
    body_.setCollisionShape(body_shape_.get());
    floor_object_.setCollisionShape(floor_.get());
    floor_object_.setWorldTransform(floor_at);
    btCollisionObjectWrapper wa(nullptr, body_shape_.get(), &body_, body_.getWorldTransform(), -1, -1);
    btCollisionObjectWrapper wb(nullptr, floor_.get(), &floor_object_, floor_object_.getWorldTransform(), -1, -1);
    algorithm_ = dispatcher_->findAlgorithm(&wa, &wb, nullptr, BT_CONTACT_POINT_ALGORITHMS);
  }
  ~Pair() {
    algorithm_->~btCollisionAlgorithm();
    dispatcher_->freeCollisionAlgorithm(algorithm_);
  }

  /// The contacts with the body's shape frame at `body_at` (world).
  const std::vector<runtime::Contact>& test(const btTransform& body_at) {
    body_.setWorldTransform(body_at);
    btCollisionObjectWrapper wa(nullptr, body_shape_.get(), &body_, body_.getWorldTransform(), -1, -1);
    btCollisionObjectWrapper wb(nullptr, floor_.get(), &floor_object_, floor_object_.getWorldTransform(), -1, -1);
    btManifoldResult result(&wa, &wb);
    contacts_.clear();
    algorithm_->processCollision(&wa, &wb, btDispatcherInfo(), &result);
    return contacts_;
  }
  VpsCollisionRegistration& vps() { return *vps_; }
  const VpsShape& body_shape() const { return *body_shape_; }

 private:
  std::shared_ptr<btCollisionShape> floor_;
  std::unique_ptr<btDefaultCollisionConfiguration> config_;
  std::unique_ptr<btCollisionDispatcher> dispatcher_;
  std::unique_ptr<VpsCollisionRegistration> vps_;
  std::shared_ptr<VpsMixedShape> body_shape_;
  btCollisionObject body_, floor_object_;
  btCollisionAlgorithm* algorithm_ = nullptr;
  std::vector<runtime::Contact> contacts_;
};

CollisionSettings indexed(bool coherent) {
  CollisionSettings settings;
  settings.coherent = coherent;
  return settings;
}

CollisionSettings unindexed() {
  CollisionSettings settings;
  settings.static_mesh_index = false;
  return settings;
}

// Bit for bit: every field of every contact, in order (a mesh vertex's contact is numbered by the vertex).
void expect_same(const std::vector<runtime::Contact>& a, const std::vector<runtime::Contact>& b, size_t step) {
  ASSERT_EQ(a.size(), b.size()) << "step " << step;
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].point_index, b[i].point_index) << "step " << step << " contact " << i;
    EXPECT_EQ(a[i].point_of_b, b[i].point_of_b) << "step " << step << " contact " << i;
    EXPECT_EQ(a[i].depth, b[i].depth) << "step " << step << " contact " << i;
    EXPECT_EQ(a[i].point, b[i].point) << "step " << step << " contact " << i;
    EXPECT_EQ(a[i].normal, b[i].normal) << "step " << step << " contact " << i;
  }
}

// The unindexed path's contacts: the same shell points at the same depths (to float rounding of the frames), and
// the same mesh vertices in the body (it lists a vertex once per triangle that has it, the index once).
void expect_as_unindexed(const std::vector<runtime::Contact>& indexed, const std::vector<runtime::Contact>& gathered,
                         size_t step) {
  auto points = [](const std::vector<runtime::Contact>& set) {
    std::vector<std::pair<uint32_t, double>> out;
    for (const auto& c : set)
      if (!c.point_of_b) out.emplace_back(c.point_index, c.depth);
    std::sort(out.begin(), out.end());
    return out;
  };
  const auto a = points(indexed), b = points(gathered);
  ASSERT_EQ(a.size(), b.size()) << "step " << step;
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].first, b[i].first) << "step " << step;
    EXPECT_NEAR(a[i].second, b[i].second, 1e-6) << "step " << step << " point " << a[i].first;
  }
  auto vertices = [](const std::vector<runtime::Contact>& set) {
    std::vector<Eigen::Vector3d> out;
    for (const auto& c : set)
      if (c.point_of_b &&
          std::none_of(out.begin(), out.end(), [&](const Eigen::Vector3d& p) { return (p - c.point).norm() < 1e-6; }))
        out.push_back(c.point);
    return out;
  };
  const auto va = vertices(indexed), vb = vertices(gathered);
  ASSERT_EQ(va.size(), vb.size()) << "step " << step;
  for (const Eigen::Vector3d& p : va)
    EXPECT_TRUE(std::any_of(vb.begin(), vb.end(), [&](const Eigen::Vector3d& q) { return (p - q).norm() < 1e-6; }))
        << "step " << step;
}

// The body's shape frame placed in the floor's frame: turned by `turn` about y (after a fixed tilt), its lowest
// shell point `depth` below the wave under it.
btTransform on_floor(double x, double z, double turn, double depth) {
  const Bunny& bunny = Bunny::get();
  const btQuaternion q = btQuaternion(btVector3(0, 1, 0), btScalar(turn)) * btQuaternion(btVector3(1, 0, 1), 0.3f);
  btTransform t(q, btVector3(0, 0, 0));
  VpsMixedShape shape(bunny.object);
  const runtime::Pose pose = shape.asset_pose(t);
  double lowest = 1e30;
  for (const Eigen::Vector3f& p : bunny.object->point_tree().points) {
    const Eigen::Vector3d w = pose.apply(p.cast<double>());
    lowest = std::min(lowest, w.y() - wave(w.x() + x, w.z() + z));
  }
  t.setOrigin(btVector3(btScalar(x), btScalar(-lowest - depth), btScalar(z)));
  return t;
}

TEST(BulletStaticMesh, CoherentPairFindsTheContactsFromScratchSlidingAcrossAFloor) {
  static std::unique_ptr<btTriangleMesh> mesh = wavy_floor();
  auto floor = std::make_shared<btBvhTriangleMeshShape>(mesh.get(), true);
  // A tilted, shifted floor: the index works in the mesh's frame, the unindexed path in the world's.
  const btTransform floor_at(btQuaternion(btVector3(1, 0, 0), 0.2f), btVector3(0.1f, -0.3f, 0.2f));
  Pair coherent(floor, floor_at, indexed(true)), scratch(floor, floor_at, indexed(false)),
      gathered(floor, floor_at, unindexed());
  const double h = Bunny::get().h;
  const int steps = 500;
  size_t touching = 0, contacts = 0, vertices = 0;
  for (int step = 0; step < steps; ++step) {
    // 1.5 m across the floor at 3 mm (a voxel) a step, turning half a radian, pressed 0.5-2 voxels in.
    const double u = double(step) / steps;
    const btTransform at =
        floor_at * on_floor(-0.75 + 1.5 * u, 0.3 * std::sin(4 * u), 0.5 * u, h * (1.25 + 0.75 * std::sin(0.1 * step)));
    const auto a = coherent.test(at);
    const auto b = scratch.test(at);
    const auto c = gathered.test(at);
    expect_same(a, b, size_t(step));
    expect_as_unindexed(a, c, size_t(step));
    if (::testing::Test::HasFailure()) return;
    touching += !a.empty();
    contacts += a.size();
    vertices += size_t(std::count_if(a.begin(), a.end(), [](const runtime::Contact& x) { return x.point_of_b; }));
  }
  std::cout << "[ figures  ] " << steps << " steps, " << touching << " touching, " << double(contacts) / steps
            << " contacts a step (" << double(vertices) / steps << " of the mesh's vertices); index "
            << coherent.vps().prepare_static_mesh(*floor).memory_bytes / 1e6 << " MB\n";
  EXPECT_EQ(touching, size_t(steps));
  std::cout << "[ figures  ] points looked up: coherent " << coherent.vps().counters().points_tested
            << ", from scratch " << scratch.vps().counters().points_tested << "\n";
  EXPECT_LT(coherent.vps().counters().points_tested, scratch.vps().counters().points_tested);
  EXPECT_EQ(coherent.vps().counters().static_mesh_builds, 1u);
}

TEST(BulletStaticMesh, ABodyJumpingBeyondWhatItKeptStillGetsExactContacts) {
  static std::unique_ptr<btTriangleMesh> mesh = wavy_floor();
  auto floor = std::make_shared<btBvhTriangleMeshShape>(mesh.get(), true);
  const btTransform floor_at = btTransform::getIdentity();
  Pair coherent(floor, floor_at, indexed(true)), scratch(floor, floor_at, indexed(false)),
      gathered(floor, floor_at, unindexed());
  const double h = Bunny::get().h;
  // Rests (moving by a micrometre a step) at one place, then jumps 0.2-0.5 m to another, or lifts off; the kept
  // front and vertices were made far from the new place.
  const double places[][2] = {{0, 0}, {0.4, 0.1}, {-0.3, 0.5}, {-0.35, 0.45}, {0.6, -0.6}, {0.2, 0.3}};
  size_t step = 0, touching_after_jumps = 0;
  for (const auto& place : places)
    for (int rest = 0; rest < 30; ++rest, ++step) {
      const bool lifted = step % 45 == 44;
      const btTransform at =
          on_floor(place[0] + 1e-6 * rest, place[1], 0.1 * place[0], lifted ? -0.05 : h * (1.0 + 1e-3 * rest));
      const auto a = coherent.test(at);
      const auto b = scratch.test(at);
      const auto c = gathered.test(at);
      expect_same(a, b, step);
      expect_as_unindexed(a, c, step);
      if (::testing::Test::HasFailure()) return;
      EXPECT_EQ(a.empty(), lifted) << "step " << step;
      if (rest == 0 && !lifted) ++touching_after_jumps;
    }
  EXPECT_EQ(touching_after_jumps, std::size(places));
}

TEST(BulletStaticMesh, AnIndexIsSharedRebuiltWhenForgottenOrRescaledAndCountsTheMesh) {
  static std::unique_ptr<btTriangleMesh> mesh = wavy_floor();
  auto floor = std::make_shared<btBvhTriangleMeshShape>(mesh.get(), true);
  Pair pair(floor, btTransform::getIdentity(), indexed(true));
  const StaticMeshInfo info = pair.vps().prepare_static_mesh(*floor);
  std::cout << "[ figures  ] index of " << info.triangles << " triangles, " << info.vertices << " vertices, "
            << info.cells << " cells: " << info.memory_bytes / 1e6 << " MB, built in " << info.build_seconds * 1e3
            << " ms\n";
  EXPECT_EQ(info.triangles, size_t(mesh->getNumTriangles()));
  EXPECT_EQ(info.vertices, size_t(201 * 201));
  EXPECT_EQ(pair.vps().prepare_static_mesh(btBoxShape(btVector3(1, 1, 1))).triangles, 0u);  // not a mesh

  const double h = Bunny::get().h;
  const btTransform at = on_floor(0.1, 0.2, 0.4, 2 * h);
  const auto first = pair.test(at);
  ASSERT_FALSE(first.empty());
  EXPECT_EQ(pair.vps().counters().static_mesh_builds, 1u);  // prepared, then used
  // Forgotten: indexed again at the next test, with the same contacts.
  pair.vps().forget_static_mesh(*floor);
  expect_same(pair.test(at), first, 0);
  EXPECT_EQ(pair.vps().counters().static_mesh_builds, 2u);
  // Rescaled (the floor's waves twice as high): a new box, noticed without being told; deeper contacts.
  floor->setLocalScaling(btVector3(1, 2, 1));
  const auto rescaled = pair.test(at);
  EXPECT_EQ(pair.vps().counters().static_mesh_builds, 3u);
  Pair fresh(floor, btTransform::getIdentity(), unindexed());
  expect_as_unindexed(rescaled, fresh.test(at), 0);
}

// A 201 x 201 terrain over [-2, 2]^2 m in x-z at the floor's heights (2 cm cells, up axis y).
std::shared_ptr<btHeightfieldTerrainShape> wavy_terrain() {
  static std::vector<float> heights = [] {
    std::vector<float> h(201 * 201);
    for (int k = 0; k <= 200; ++k)
      for (int i = 0; i <= 200; ++i) h[size_t(k * 201 + i)] = float(wave(-2 + 0.02 * i, -2 + 0.02 * k));
    return h;
  }();
  // Bullet centres a terrain on its declared height range: [-0.02, 0.02] keeps height 0 at the origin.
  auto terrain =
      std::make_shared<btHeightfieldTerrainShape>(201, 201, heights.data(), 1.0f, -0.02f, 0.02f, 1, PHY_FLOAT, false);
  terrain->setLocalScaling(btVector3(0.02f, 1, 0.02f));
  return terrain;
}

// A terrain pair keeps its gathered triangles and its front while a test gathers the same triangles: along a slide
// (the triangles change nearly every step) and at rest (a jitter of a micrometre), the coherent pair's contacts are
// bit for bit those of the pair from scratch, with fewer points looked up.
TEST(BulletTerrain, CoherentPairFindsTheContactsFromScratchSlidingAndAtRest) {
  auto terrain = wavy_terrain();
  CollisionSettings scratch_settings;
  scratch_settings.coherent = false;
  Pair coherent(terrain, btTransform::getIdentity(), CollisionSettings{}),
      scratch(terrain, btTransform::getIdentity(), scratch_settings);
  const double h = Bunny::get().h;
  const int steps = 400;
  size_t touching = 0, coherent_slid = 0, scratch_slid = 0;
  for (int step = 0; step < steps; ++step) {
    // The first half slides 0.6 m at 3 mm a step, pressed 0.5-2 voxels in; the second rests where it ended.
    const double u = std::min(step, steps / 2) / double(steps / 2);
    const double jitter = step > steps / 2 ? 1e-6 * std::sin(double(step)) : 0.0;
    const btTransform at = on_floor(-0.3 + 0.6 * u + jitter, 0.2 * std::sin(3 * u), 0.5 * u,
                                    h * (1.25 + 0.75 * std::sin(0.1 * std::min(step, steps / 2))));
    const auto a = coherent.test(at);
    const auto b = scratch.test(at);
    expect_same(a, b, size_t(step));
    if (::testing::Test::HasFailure()) return;
    touching += !a.empty();
    if (step == steps / 2) {  // from here on at rest
      coherent_slid = coherent.vps().counters().points_tested;
      scratch_slid = scratch.vps().counters().points_tested;
    }
  }
  EXPECT_EQ(touching, size_t(steps));
  const size_t coherent_rest = coherent.vps().counters().points_tested - coherent_slid,
               scratch_rest = scratch.vps().counters().points_tested - scratch_slid;
  std::cout << "[ figures  ] terrain, points looked up sliding: coherent " << coherent_slid << ", from scratch "
            << scratch_slid << "; at rest: coherent " << coherent_rest << ", from scratch " << scratch_rest << "\n";
  // Sliding, the triangles under the box change nearly every step; at rest the front is kept (measured: 0.53).
  EXPECT_LT(3 * coherent_rest, 2 * scratch_rest);
}

// A terrain whose heights change under a body at rest (the caller owns them: Bullet reads them in place) is seen at
// the next test, though the pair keeps its front while it gathers the same triangles.
TEST(BulletTerrain, HeightsChangedUnderARestingBodyAreSeenAtTheNextTest) {
  std::vector<float> heights(101 * 101, 0.0f);  // before the pairs, which read it in place
  auto terrain =
      std::make_shared<btHeightfieldTerrainShape>(101, 101, heights.data(), 1.0f, -0.05f, 0.05f, 1, PHY_FLOAT, false);
  terrain->setLocalScaling(btVector3(0.02f, 1, 0.02f));
  CollisionSettings scratch_settings;
  scratch_settings.coherent = false;
  Pair coherent(terrain, btTransform::getIdentity(), CollisionSettings{}),
      scratch(terrain, btTransform::getIdentity(), scratch_settings);
  const Bunny& bunny = Bunny::get();
  const double h = bunny.h;
  // Turned, its lowest shell point a voxel below the flat ground.
  btTransform at(btQuaternion(btVector3(1, 0, 1), 0.3f), btVector3(0, 0, 0));
  const runtime::Pose pose = VpsMixedShape(bunny.object).asset_pose(at);
  double lowest = 1e30;
  for (const Eigen::Vector3f& p : bunny.object->point_tree().points)
    lowest = std::min(lowest, pose.apply(p.cast<double>()).y());
  at.setOrigin(btVector3(0.05f, btScalar(-lowest - h), -0.05f));
  const auto deepest = [](const std::vector<runtime::Contact>& contacts) {
    double d = -1e30;
    for (const runtime::Contact& c : contacts) d = std::max(d, c.depth);
    return d;
  };
  double before = 0;
  for (int step = 0; step < 3; ++step) {
    const std::vector<runtime::Contact> contacts = coherent.test(at);
    expect_same(contacts, scratch.test(at), size_t(step));
    before = deepest(contacts);
  }
  EXPECT_NEAR(before, h, 0.1 * h);
  std::fill(heights.begin(), heights.end(), float(2 * h));  // the ground rises two voxels everywhere
  const std::vector<runtime::Contact> raised = coherent.test(at);
  expect_same(raised, scratch.test(at), 3);
  EXPECT_NEAR(deepest(raised), before + 2 * h, 0.25 * h);
}

// The terrain's cheap bound (its ring map) holds only above the surface: a bunny pressed 20 cm (about five of the
// gathered triangles' cells) into a slope gets contacts as deep as its deepest shell point sits. A bound with the
// outside's sign below the surface pruned the tree's clusters more than a cell deep (its deepest contact: 0.195 m).
// And a terrain is solid: pressed 60 cm (19 cells, past the ring search's reach), every shell point below the slope
// is a contact, as deep as it sits (searched over the columns; they used to count as tunnelled through: no contact
// at all).
TEST(BulletTerrain, ABodyPressedDeepIntoASlopeKeepsItsDeepestContacts) {
  // 64 x 64 heights over [-1, 1]^2 m in x-z, rising 0.5 m a metre along x (from -0.5 to 0.5; up axis y).
  static std::vector<float> heights(64 * 64);
  for (int k = 0; k < 64; ++k)
    for (int i = 0; i < 64; ++i) heights[size_t(k * 64 + i)] = 0.5f * (-1.0f + 2.0f * float(i) / 63.0f);
  auto terrain =
      std::make_shared<btHeightfieldTerrainShape>(64, 64, heights.data(), 1.0f, -0.5f, 0.5f, 1, PHY_FLOAT, false);
  terrain->setLocalScaling(btVector3(2.0f / 63, 1, 2.0f / 63));
  const Eigen::Vector3d up = Eigen::Vector3d(-0.5, 1, 0).normalized();  // the slope y = x / 2 through the origin
  const Bunny& bunny = Bunny::get();
  btTransform at(btQuaternion(btVector3(1, 0, 1), 0.3f), btVector3(0, 0, 0));
  const auto heights_over_slope = [&](const btTransform& t) {  // each shell point's, metres
    const runtime::Pose pose = VpsMixedShape(bunny.object).asset_pose(t);
    std::vector<double> over;
    for (const Eigen::Vector3f& p : bunny.object->point_tree().points)
      over.push_back(pose.apply(p.cast<double>()).dot(up));
    return over;
  };
  for (const double sunk : {0.2, 0.6}) {
    at.setOrigin(btVector3(0, 0, 0));
    const std::vector<double> level = heights_over_slope(at);
    at.setOrigin(btVector3(0, btScalar((-*std::min_element(level.begin(), level.end()) - sunk) / up.y()), 0));
    const std::vector<double> over = heights_over_slope(at);
    ASSERT_NEAR(*std::min_element(over.begin(), over.end()), -sunk, 1e-6);
    Pair pair(terrain, btTransform::getIdentity(), CollisionSettings{});
    double deepest = 0;
    std::vector<bool> touching(over.size(), false);
    const auto start = std::chrono::steady_clock::now();
    const std::vector<runtime::Contact> contacts = pair.test(at);
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    for (const runtime::Contact& c : contacts) {
      if (c.point_of_b) continue;
      deepest = std::max(deepest, c.depth);
      touching[c.point_index] = c.depth > 0;
      ASSERT_LE(c.depth, -over[c.point_index] + 1e-4) << "point " << c.point_index;
    }
    size_t below = 0, missed = 0;
    for (size_t i = 0; i < over.size(); ++i)
      if (over[i] < -1e-3) {
        ++below;
        missed += !touching[i];
      }
    std::cout << "[ figures  ] bunny " << sunk << " m into a slope: deepest shell contact " << deepest << " m; "
              << below - missed << " of the " << below << " shell points below it are contacts (one test: " << ms
              << " ms)\n";
    EXPECT_EQ(missed, 0u);
    EXPECT_NEAR(deepest, sunk, 1e-4);  // exact at any depth
  }
}

// A body buried under a terrain, 5 cm below the surface at its highest shell point, for a terrain up each axis: the
// triangles over it are gathered (its box swept up the terrain's axis; a pair used to gather only those that met
// its box, beside it, and measured its depth from them), and every shell point is a contact as deep as it lies,
// pushed straight up. (Bullet pairs the two while the body is within the terrain's box: its declared height range
// reaches down to -0.5 m here.)
TEST(BulletTerrain, ABodyBuriedUnderTheSurfaceIsPushedUp) {
  static std::vector<float> heights(101 * 101, 0.0f);
  const Bunny& bunny = Bunny::get();
  for (const int up : {0, 1, 2}) {
    auto terrain =
        std::make_shared<btHeightfieldTerrainShape>(101, 101, heights.data(), 1.0f, -0.5f, 0.5f, up, PHY_FLOAT, false);
    btVector3 scaling(0.02f, 0.02f, 0.02f);
    scaling[up] = 1;
    terrain->setLocalScaling(scaling);
    btTransform at(btQuaternion(btVector3(1, 0, 1), 0.3f), btVector3(0, 0, 0));
    const auto heights_of = [&](const btTransform& t) {  // each shell point's coordinate along the up axis
      const runtime::Pose pose = VpsMixedShape(bunny.object).asset_pose(t);
      std::vector<double> h;
      for (const Eigen::Vector3f& p : bunny.object->point_tree().points) h.push_back(pose.apply(p.cast<double>())[up]);
      return h;
    };
    const std::vector<double> level = heights_of(at);
    // Terrain heights are relative to the middle of their range: the surface is at 0 along the up axis.
    btVector3 origin(0.1f, 0.1f, -0.1f);
    origin[up] = btScalar(-0.05 - *std::max_element(level.begin(), level.end()));
    at.setOrigin(origin);
    const std::vector<double> h = heights_of(at);
    Pair pair(terrain, btTransform::getIdentity(), CollisionSettings{});
    std::vector<bool> touching(h.size(), false);
    for (const runtime::Contact& c : pair.test(at)) {
      if (c.point_of_b) continue;
      touching[c.point_index] = true;
      ASSERT_NEAR(c.depth, -h[c.point_index], 1e-5) << "up " << up << " point " << c.point_index;
      ASSERT_GT(c.normal[up], 0.999) << "up " << up << " point " << c.point_index;
    }
    EXPECT_EQ(size_t(std::count(touching.begin(), touching.end(), true)), h.size()) << "up " << up;
  }
}

}  // namespace
}  // namespace voxfmt::bullet
