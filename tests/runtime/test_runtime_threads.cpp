// The runtime across threads (run under ThreadSanitizer by scripts/run-tsan.sh): one loaded CollisionObject
// queried from several threads at once — it is immutable after loading, so every thread must get exactly the
// contacts a single thread gets — and LatestValue's hand-off between a producer and a consumer running at once.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <thread>
#include <vector>

#include "analytic_sphere.h"
#include "voxfmt/runtime/collision_object.h"
#include "voxfmt/runtime/haptics.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {
namespace {

constexpr double kRadius = 0.1, kVoxel = 0.01;
constexpr int kPoses = 120, kThreads = 4;

// What one pose gives: the contacts' count and depths, bit for bit, and the wrench.
struct Answer {
  std::vector<double> depths;
  Eigen::Vector3d force = Eigen::Vector3d::Zero(), torque = Eigen::Vector3d::Zero();
  size_t nodes_visited = 0;
  bool operator==(const Answer& other) const {
    return depths == other.depths && force == other.force && torque == other.torque &&
           nodes_visited == other.nodes_visited;
  }
};

// Sphere B around sphere A at the origin, from apart to deep overlap, turned (the tree sees every rotation),
// every query kind of the runtime in turn.
Answer ask(const CollisionObject& object, int k, ContactSet& contacts, QueryScratch& scratch) {
  Pose a, b;
  const double phi = 2.399963 * k, z = 1.0 - 2.0 * (k + 0.5) / kPoses;
  const Eigen::Vector3d direction(std::sqrt(1 - z * z) * std::cos(phi), std::sqrt(1 - z * z) * std::sin(phi), z);
  b.translation = direction * (2 * kRadius - 0.02 * (k % 5) + 0.004);
  b.rotation = Eigen::AngleAxisd(0.7 * k, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  QueryOptions options;
  options.direction = k % 3 == 0 ? QueryDirection::Both : QueryDirection::Auto;
  options.proximity = k % 2 ? 0.005 : 0.0;
  options.normal_source = k % 4 < 2 ? NormalSource::DistanceGradient : NormalSource::PointShell;
  if (k % 7 == 0) options.max_level = 3;
  contacts.clear();
  query_contacts(object, a, object, b, options, contacts, scratch);
  const Eigen::Vector3d corners[2] = {b.translation, b.translation + direction * 0.01};
  query_points_in_voxelmap(object, a, corners, 2, 0.5 * kRadius, options, contacts);
  Answer answer;
  for (const Contact& c : contacts.contacts) answer.depths.push_back(c.depth);
  const Wrench w = penalty_wrench(contacts, a.apply(object.center_of_mass()), 2000.0);
  answer.force = w.force;
  answer.torque = w.torque;
  answer.nodes_visited = contacts.stats.nodes_visited;
  return answer;
}

TEST(RuntimeThreads, OneObjectQueriedFromFourThreadsGivesTheSingleThreadedContacts) {
  const auto loaded = CollisionObject::from_asset(test::make_sphere_asset({{0, 0, 0}, kRadius, kVoxel, 1000, 4}));
  ASSERT_TRUE(loaded) << loaded.error().describe();
  const CollisionObject& object = *loaded.value();

  std::vector<Answer> expected(kPoses);
  {
    ContactSet contacts;
    QueryScratch scratch;
    for (int k = 0; k < kPoses; ++k) expected[k] = ask(object, k, contacts, scratch);
  }
  size_t touching = 0;
  for (const Answer& answer : expected) touching += !answer.depths.empty();
  ASSERT_GT(touching, size_t(kPoses / 2));  // most poses overlap: the threads have contacts to disagree on

  // Every thread asks every pose, each starting at a different one, with its own buffers.
  std::vector<std::vector<Answer>> answers(kThreads, std::vector<Answer>(kPoses));
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t)
    threads.emplace_back([&, t] {
      ContactSet contacts;
      QueryScratch scratch;
      for (int i = 0; i < kPoses; ++i) {
        const int k = (i + t * kPoses / kThreads) % kPoses;
        answers[t][k] = ask(object, k, contacts, scratch);
      }
    });
  for (std::thread& thread : threads) thread.join();
  for (int t = 0; t < kThreads; ++t)
    for (int k = 0; k < kPoses; ++k) EXPECT_TRUE(answers[t][k] == expected[k]) << "thread " << t << ", pose " << k;
}

TEST(RuntimeThreads, LatestValueHandsWholeNewerValuesToAConsumerRunningAtOnce) {
  struct Pair {
    int64_t value = 0, negated = 0;  // a torn read would break negated == -value
  };
  constexpr int64_t kLast = 20000;
  LatestValue<Pair> latest;
  std::thread producer([&] {
    for (int64_t v = 1; v <= kLast; ++v) latest.publish({v, -v});
  });
  int64_t seen = 0, fresh_reads = 0;
  bool whole = true, newer = true;
  while (seen < kLast) {
    bool fresh = false;
    const Pair p = latest.latest(&fresh);
    whole = whole && p.negated == -p.value;
    newer = newer && (fresh ? p.value > seen : p.value == seen);
    fresh_reads += fresh;
    seen = p.value;
  }
  producer.join();
  EXPECT_TRUE(whole);
  EXPECT_TRUE(newer);
  EXPECT_GT(fresh_reads, 0);
}

}  // namespace
}  // namespace voxfmt::runtime
