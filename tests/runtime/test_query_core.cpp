// The query core's host/device code (loaders/runtime/src/core: the field lookups, the depth-first walk, the
// batched environment) compiled for the CPU, against the runtime's own queries: the CUDA kernels run these very
// functions, so what is checked here is what the GPU computes (up to the device's float arithmetic, which nvcc is
// told not to contract: loaders/gpu).
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cstring>
#include <random>
#include <tuple>
#include <vector>

#include "baked_bunny.h"
#include "core/batch.h"
#include "core/eigen.h"
#include "voxfmt/runtime/forces.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {
namespace {

using test::BakedBunny;

TEST(QueryCore, AffineMapsAsEigenDoes) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-3, 3);
  for (int t = 0; t < 100000; ++t) {
    Eigen::Matrix3f M;
    Eigen::Vector3f x, m;
    for (int i = 0; i < 9; ++i) M(i / 3, i % 3) = u(rng);
    for (int i = 0; i < 3; ++i) {
      x[i] = u(rng);
      m[i] = u(rng);
    }
    const Eigen::Vector3f eigen = M * x + m;
    const Eigen::Vector3f core = core::to_eigen(core::to_core(M, m).apply(core::to_core(x)));
    ASSERT_EQ(std::memcmp(eigen.data(), core.data(), sizeof(float) * 3), 0) << t;
  }
}

Pose random_pose(std::mt19937& rng, double spread) {
  std::normal_distribution<double> n(0, 1);
  Pose p;
  p.rotation = Eigen::Quaterniond(n(rng), n(rng), n(rng), n(rng)).normalized().toRotationMatrix();
  p.translation = Eigen::Vector3d(n(rng), n(rng), n(rng)) * spread;
  return p;
}

// One contact as (which point, its distance's bits): what the walk and the runtime must agree on.
using Key = std::tuple<bool, uint32_t, float>;

TEST(QueryCore, BatchEnvironmentFindsTheRuntimesContactsAndWrench) {
  const BakedBunny& bunny = BakedBunny::get();
  const CollisionObject& object = *bunny.object;
  const core::Body body = core::body_of(object);
  std::mt19937 rng(11);
  QueryScratch scratch;
  std::vector<core::BatchContact> buffer(40000);
  size_t compared = 0, touching = 0;
  for (int k = 0; k < 300; ++k) {
    // Half of the poses overlap deeply (coarse bricks and estimates), half graze (the band).
    const Pose pa = random_pose(rng, 0.0), pb = random_pose(rng, k % 2 ? 0.05 : 0.14);
    for (const double proximity : {0.0, 0.003}) {
      QueryOptions options;
      options.proximity = proximity;
      ContactSet set;
      query_contacts(object, pa, object, pb, options, set, scratch);
      const Wrench w = penalty_wrench(set, pa.apply(object.center_of_mass()), 2e4);
      core::EnvResult r;
      core::env_contacts(body, core::to_core(pa), body, core::to_core(pb), proximity, 2e4, buffer.data(),
                         uint32_t(buffer.size()), r);
      ASSERT_EQ(r.error, 0);
      ASSERT_EQ(r.count, set.contacts.size()) << "pose " << k;
      ASSERT_EQ(r.overflow, 0u);
      std::vector<Key> runtime_keys, core_keys;
      double deepest = 0;
      for (const Contact& c : set.contacts) {
        // The runtime's depth is -d * metres_per_unit in double; the distance d itself is the walk's float.
        runtime_keys.emplace_back(c.point_of_b, c.point_index, float(c.depth));
        deepest = std::max(deepest, c.depth);
      }
      for (uint32_t i = 0; i < r.count; ++i)
        core_keys.emplace_back(buffer[i].point_of_b != 0, buffer[i].point_index, buffer[i].depth);
      std::sort(runtime_keys.begin(), runtime_keys.end());
      std::sort(core_keys.begin(), core_keys.end());
      ASSERT_EQ(runtime_keys, core_keys) << "pose " << k;
      EXPECT_EQ(r.max_depth, float(deepest));
      for (int a = 0; a < 3; ++a) {
        // Summed in another order (depth first, not level by level): equal to rounding.
        EXPECT_NEAR(r.force[a], w.force[a], 1e-5 * (1 + w.force.norm()));
        EXPECT_NEAR(r.torque[a], w.torque[a], 1e-5 * (1 + w.torque.norm()));
      }
      // Points and normals: the same double arithmetic as the runtime's, stored as float.
      for (uint32_t i = 0; i < r.count; ++i) {
        const core::BatchContact& c = buffer[i];
        const auto match = std::find_if(set.contacts.begin(), set.contacts.end(), [&](const Contact& x) {
          return x.point_index == c.point_index && x.point_of_b == (c.point_of_b != 0);
        });
        ASSERT_NE(match, set.contacts.end());
        for (int a = 0; a < 3; ++a) {
          EXPECT_NEAR(c.point[a], match->point[a], 1e-6);
          EXPECT_NEAR(c.normal[a], match->normal[a], 1e-6);
        }
      }
      ++compared;
      touching += r.count > 0;
    }
  }
  EXPECT_EQ(compared, 600u);
  EXPECT_GT(touching, 200u);
}

TEST(QueryCore, AFullBufferCountsWhatDidNotFit) {
  const BakedBunny& bunny = BakedBunny::get();
  const core::Body body = core::body_of(*bunny.object);
  std::vector<core::BatchContact> buffer(8);
  core::EnvResult all, capped;
  const core::RigidPose here;
  core::RigidPose near = here;
  near.t[0] = 0.02;  // deep overlap: hundreds of contacts
  std::vector<core::BatchContact> big(100000);
  core::env_contacts(body, here, body, near, 0.0, 1.0, big.data(), uint32_t(big.size()), all);
  core::env_contacts(body, here, body, near, 0.0, 1.0, buffer.data(), uint32_t(buffer.size()), capped);
  ASSERT_GT(all.count, 8u);
  EXPECT_EQ(capped.count, all.count);
  EXPECT_EQ(capped.overflow, all.count - 8);
  EXPECT_EQ(std::memcmp(buffer.data(), big.data(), 8 * sizeof(core::BatchContact)), 0);
  for (int a = 0; a < 3; ++a) EXPECT_EQ(capped.force[a], all.force[a]);
}

}  // namespace
}  // namespace voxfmt::runtime
