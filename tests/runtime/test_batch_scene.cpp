// runtime::BatchScene against the runtime's own query, environment by environment, on exact spheres made in code.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <random>
#include <stdexcept>

#include "analytic_sphere.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {
namespace {

std::shared_ptr<const CollisionObject> sphere(double radius, double voxel, uint32_t points) {
  auto loaded = CollisionObject::from_asset(test::make_sphere_asset({{0, 0, 0}, radius, voxel, points, 4}));
  EXPECT_TRUE(loaded) << loaded.error().describe();
  return loaded.value();
}

// Row-major 4x4 of a rotation about a random axis and a translation.
void random_pose(std::mt19937& rng, double reach, float* m) {
  std::uniform_real_distribution<double> u(-1, 1);
  const Eigen::Vector3d axis = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
  const Eigen::Matrix3d r = Eigen::AngleAxisd(3 * u(rng), axis).toRotationMatrix();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m[4 * i + j] = float(r(i, j));
    m[4 * i + 3] = float(reach * u(rng));
  }
  m[12] = m[13] = m[14] = 0;
  m[15] = 1;
}

Pose pose_of(const float* m) {
  Pose p;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) p.rotation(i, j) = m[4 * i + j];
    p.translation[i] = m[4 * i + 3];
  }
  return p;
}

struct Outputs {
  explicit Outputs(size_t envs, uint32_t k)
      : count(envs),
        overflow(envs),
        error(envs),
        index(envs * k),
        max_depth(envs),
        force(3 * envs),
        torque(3 * envs),
        points(3 * envs * k),
        normals(3 * envs * k),
        depths(envs * k),
        of_b(envs * k) {
    out = {count.data(),  max_depth.data(), force.data(),  torque.data(), overflow.data(), error.data(), k,
           points.data(), normals.data(),   depths.data(), index.data(),  of_b.data()};
  }
  std::vector<int32_t> count, overflow, error, index;
  std::vector<float> max_depth, force, torque, points, normals, depths;
  std::vector<uint8_t> of_b;
  BatchOutputs out;
};

TEST(BatchScene, EveryEnvironmentIsTheRuntimesQueryReduced) {
  const auto big = sphere(0.1, 0.01, 2000), small = sphere(0.05, 0.005, 800);
  auto scene = BatchScene::create({big, small}, {{0, 1}, {1, 0}, {0, 0}});
  ASSERT_TRUE(scene) << scene.error().describe();
  constexpr size_t kEnvs = 600;
  constexpr uint32_t kKeep = 8;
  std::mt19937 rng(5);
  std::vector<float> pa(16 * kEnvs), pb(16 * kEnvs);
  std::vector<int32_t> pair(kEnvs);
  for (size_t e = 0; e < kEnvs; ++e) {
    random_pose(rng, 0.02, &pa[16 * e]);
    random_pose(rng, 0.17, &pb[16 * e]);
    pair[e] = int32_t(e % 3);
  }
  BatchEnvironments in;
  in.count = kEnvs;
  in.poses_a = pa.data();
  in.poses_b = pb.data();
  in.pair = pair.data();
  in.proximity = 0.002;
  in.stiffness = 1e4;
  std::vector<float> trilinear_forces;
  // Either reading, as query_contacts reads with it; the tricubic one gives other forces.
  for (const Interpolation reading : {Interpolation::Trilinear, Interpolation::Tricubic}) {
    in.interpolation = reading;
    Outputs got(kEnvs, kKeep);
    ASSERT_TRUE(scene->contacts(in, got.out, 2));
    QueryOptions options;
    options.proximity = in.proximity;
    options.interpolation = reading;
    const std::shared_ptr<const CollisionObject> objects[] = {big, small};
    const int pairs[3][2] = {{0, 1}, {1, 0}, {0, 0}};
    size_t touching = 0, overflowing = 0;
    for (size_t e = 0; e < kEnvs; ++e) {
      const CollisionObject& a = *objects[pairs[pair[e]][0]];
      const CollisionObject& b = *objects[pairs[pair[e]][1]];
      const Pose posea = pose_of(&pa[16 * e]), poseb = pose_of(&pb[16 * e]);
      ContactSet set;
      query_contacts(a, posea, b, poseb, options, set);
      ASSERT_EQ(got.error[e], 0);
      ASSERT_EQ(size_t(got.count[e]), set.contacts.size()) << e;
      EXPECT_EQ(size_t(got.overflow[e]), set.contacts.size() - std::min<size_t>(set.contacts.size(), kKeep));
      touching += !set.contacts.empty();
      overflowing += got.overflow[e] > 0;
      float deepest = 0;
      for (const Contact& c : set.contacts) deepest = std::max(deepest, c.depth > 0 ? float(c.depth) : 0.0f);
      EXPECT_EQ(got.max_depth[e], deepest);
      const Wrench w = penalty_wrench(set, posea.apply(a.center_of_mass()), in.stiffness);
      for (int k = 0; k < 3; ++k) {
        EXPECT_EQ(got.force[3 * e + k], float(w.force[k]));
        EXPECT_EQ(got.torque[3 * e + k], float(w.torque[k]));
      }
      for (size_t i = 0; i < std::min<size_t>(set.contacts.size(), kKeep); ++i) {
        const Contact& c = set.contacts[i];
        const size_t at = e * kKeep + i;
        for (int k = 0; k < 3; ++k) {
          EXPECT_EQ(got.points[3 * at + k], float(c.point[k]));
          EXPECT_EQ(got.normals[3 * at + k], float(c.normal[k]));
        }
        EXPECT_EQ(got.depths[at], float(c.depth));
        EXPECT_EQ(uint32_t(got.index[at]), c.point_index);
        EXPECT_EQ(bool(got.of_b[at]), c.point_of_b);
      }
    }
    EXPECT_GT(touching, kEnvs / 4) << "too few environments touch: the test no longer compares contacts";
    EXPECT_GT(overflowing, 10u) << "no environment overflows its buffer: the test no longer checks overflow";
    if (reading == Interpolation::Trilinear) {
      trilinear_forces = got.force;
    } else {
      size_t penetrating = 0, differ = 0;
      for (size_t e = 0; e < kEnvs; ++e) {
        penetrating += got.max_depth[e] > 0;
        differ += got.force[3 * e] != trilinear_forces[3 * e];
      }
      EXPECT_GT(penetrating, 20u);
      EXPECT_GT(differ, penetrating / 2) << "the tricubic batch reads as the trilinear one";
    }
  }
}

TEST(BatchScene, EachEnvironmentIsVisitedOnceWithTheQueryItsOptionsAndTrajectoryGive) {
  const auto big = sphere(0.1, 0.01, 2000), small = sphere(0.05, 0.005, 800);
  auto scene = BatchScene::create({big, small}, {{0, 1}});
  ASSERT_TRUE(scene) << scene.error().describe();
  constexpr size_t kEnvs = 300;
  std::mt19937 rng(9);
  std::vector<float> pa(16 * kEnvs), pb(16 * kEnvs);
  for (size_t e = 0; e < kEnvs; ++e) {
    random_pose(rng, 0.0, &pa[16 * e]);
    random_pose(rng, 0.15, &pb[16 * e]);
  }
  BatchEnvironments in;
  in.count = kEnvs;
  in.poses_a = pa.data();
  in.poses_b = pb.data();
  in.proximity = 0.002;
  QueryOptions cut;  // a cut level: options reach every query
  cut.max_level = 2;
  cut.cut_level = CutLevel::Points;
  QueryScratch scratch;
  auto expect_runtime = [&](const BatchScene::Visit& v, const QueryOptions& options) {
    ContactSet set;
    QueryOptions o = options;
    o.proximity = in.proximity;
    query_contacts(*big, pose_of(&pa[16 * v.environment]), *small, pose_of(&pb[16 * v.environment]), o, set, scratch);
    ASSERT_EQ(v.contacts.contacts.size(), set.contacts.size()) << v.environment;
    for (size_t i = 0; i < set.contacts.size(); ++i) {
      EXPECT_EQ(v.contacts.contacts[i].point_index, set.contacts[i].point_index);
      EXPECT_EQ(v.contacts.contacts[i].depth, set.contacts[i].depth);
    }
  };
  std::vector<int> visits(kEnvs, 0);  // one slot per environment: each written by the one worker that visits it
  std::atomic<size_t> touching{0};
  ASSERT_TRUE(scene.value().each_environment(in, cut, 2, [&](const BatchScene::Visit& v) {
    ++visits[v.environment];
    EXPECT_EQ(v.error, 0);
    EXPECT_LT(v.worker, BatchScene::workers(kEnvs, 2));
    touching += !v.contacts.contacts.empty();
  }));
  EXPECT_EQ(std::count(visits.begin(), visits.end(), 1), int(kEnvs));
  EXPECT_GT(touching.load(), 30u);
  // One thread, so the check may query here; with the cut, and then as a trajectory (in order, coherent).
  ASSERT_TRUE(scene.value().each_environment(in, cut, 1, [&](const BatchScene::Visit& v) { expect_runtime(v, cut); }));
  QueryScratch trajectory_scratch;
  QueryState state;
  const BatchScene::Trajectory trajectory{trajectory_scratch, state};
  size_t next = 0;
  ASSERT_TRUE(scene.value().each_environment(
      in, QueryOptions{}, 4,
      [&](const BatchScene::Visit& v) {
        EXPECT_EQ(v.environment, next++);  // in order, whatever `threads` says
        expect_runtime(v, QueryOptions{});
      },
      &trajectory));
  EXPECT_EQ(next, kEnvs);
  // A visitor's exception stops the workers and reaches the caller (not std::terminate on a worker thread).
  EXPECT_THROW(scene.value().each_environment(in, QueryOptions{}, 2,
                                              [&](const BatchScene::Visit& v) {
                                                if (v.environment == 77) throw std::runtime_error("visitor failed");
                                              }),
               std::runtime_error);
}

TEST(BatchScene, OneThreadOrSeveralDoublesOrFloatsTheSameAnswers) {
  const auto ball = sphere(0.1, 0.01, 2000);
  auto scene = BatchScene::create({ball}, {{0, 0}});
  ASSERT_TRUE(scene);
  constexpr size_t kEnvs = 200;
  std::mt19937 rng(9);
  std::vector<float> pa(16 * kEnvs), pb(16 * kEnvs);
  for (size_t e = 0; e < kEnvs; ++e) {
    random_pose(rng, 0.05, &pa[16 * e]);
    random_pose(rng, 0.2, &pb[16 * e]);
  }
  const std::vector<double> da(pa.begin(), pa.end()), db(pb.begin(), pb.end());
  BatchEnvironments in;
  in.count = kEnvs;
  in.poses_a = pa.data();
  in.poses_b = pb.data();
  Outputs one(kEnvs, 4), three(kEnvs, 4), doubles(kEnvs, 4);
  ASSERT_TRUE(scene->contacts(in, one.out, 1));
  ASSERT_TRUE(scene->contacts(in, three.out, 3));
  BatchEnvironments in64 = in;
  in64.poses_a = in64.poses_b = nullptr;
  in64.poses_a_f64 = da.data();
  in64.poses_b_f64 = db.data();
  ASSERT_TRUE(scene->contacts(in64, doubles.out, 2));
  for (const Outputs* other : {&three, &doubles}) {
    EXPECT_EQ(other->count, one.count);
    EXPECT_EQ(other->force, one.force);
    EXPECT_EQ(other->torque, one.torque);
    EXPECT_EQ(other->points, one.points);
    EXPECT_EQ(other->index, one.index);
  }
}

TEST(BatchScene, BadEnvironmentsAreTheirCodesAndTheOthersAreAnswered) {
  const auto ball = sphere(0.1, 0.01, 500);
  auto scene = BatchScene::create({ball}, {{0, 0}});
  ASSERT_TRUE(scene);
  float identity[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  std::vector<float> pa, pb;
  auto add = [&](const float* a, const float* b) {
    pa.insert(pa.end(), a, a + 16);
    pb.insert(pb.end(), b, b + 16);
  };
  float shifted[16], nan_pose[16], last_row[16], sheared[16], mirrored[16];
  std::copy(identity, identity + 16, shifted);
  shifted[3] = 0.05f;
  std::copy(identity, identity + 16, nan_pose);
  nan_pose[3] = std::nanf("");
  std::copy(identity, identity + 16, last_row);
  last_row[14] = 1;
  std::copy(identity, identity + 16, sheared);
  sheared[1] = 0.5f;
  std::copy(identity, identity + 16, mirrored);
  mirrored[0] = -1;
  add(identity, shifted);
  add(nan_pose, identity);
  add(identity, last_row);
  add(sheared, identity);
  add(identity, mirrored);
  add(identity, identity);
  const std::vector<int32_t> pair = {0, 0, 0, 0, 0, 1};
  BatchEnvironments in;
  in.count = pair.size();
  in.poses_a = pa.data();
  in.poses_b = pb.data();
  in.pair = pair.data();
  Outputs got(pair.size(), 0);
  ASSERT_TRUE(scene->contacts(in, got.out));
  EXPECT_EQ(got.error, (std::vector<int32_t>{0, 2, 3, 4, 5, 6}));
  EXPECT_GT(got.count[0], 0);  // two spheres overlapping by half a radius
  for (size_t e = 1; e < pair.size(); ++e) EXPECT_EQ(got.count[e], 0);
}

TEST(BatchScene, AMalformedCallIsRefusedAndWritesNothing) {
  const auto ball = sphere(0.1, 0.01, 500);
  EXPECT_EQ(BatchScene::create({}, {{0, 0}}).error().code, IssueCode::BadOption);
  EXPECT_EQ(BatchScene::create({ball}, {}).error().code, IssueCode::BadOption);
  EXPECT_EQ(BatchScene::create({ball}, {{0, 1}}).error().code, IssueCode::BadOption);
  EXPECT_EQ(BatchScene::create({nullptr}, {{0, 0}}).error().code, IssueCode::BadOption);
  auto scene = BatchScene::create({ball}, {{0, 0}});
  ASSERT_TRUE(scene);
  float identity[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  double identity64[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  BatchEnvironments in;
  in.count = 1;
  in.poses_a = in.poses_b = identity;
  Outputs got(1, 0);
  got.count[0] = -7;
  BatchOutputs no_count = got.out;
  no_count.count = nullptr;
  EXPECT_EQ(scene->contacts(in, no_count).error().code, IssueCode::BadOption);
  BatchEnvironments mixed = in;
  mixed.poses_b = nullptr;
  mixed.poses_b_f64 = identity64;
  EXPECT_EQ(scene->contacts(mixed, got.out).error().code, IssueCode::BadOption);
  BatchEnvironments float_beside_doubles;  // once read as float, with a null poses_b: a crash
  float_beside_doubles.count = 1;
  float_beside_doubles.poses_a = identity;
  float_beside_doubles.poses_a_f64 = float_beside_doubles.poses_b_f64 = identity64;
  EXPECT_EQ(scene->contacts(float_beside_doubles, got.out).error().code, IssueCode::BadOption);
  BatchEnvironments negative = in;
  negative.proximity = -1;
  EXPECT_EQ(scene->contacts(negative, got.out).error().code, IssueCode::BadOption);
  BatchEnvironments infinite = in;
  infinite.stiffness = INFINITY;
  EXPECT_EQ(scene->contacts(infinite, got.out).error().code, IssueCode::BadOption);
  BatchEnvironments unknown_reading = in;
  unknown_reading.interpolation = Interpolation(7);
  EXPECT_EQ(scene->contacts(unknown_reading, got.out).error().code, IssueCode::BadOption);
  EXPECT_EQ(got.count[0], -7);  // nothing written
  BatchEnvironments empty;
  EXPECT_TRUE(scene->contacts(empty, got.out));  // no environments, no poses needed
}

}  // namespace
}  // namespace voxfmt::runtime
