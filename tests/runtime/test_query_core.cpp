// The query core's host/device code (loaders/runtime/src/core: the field lookups, the depth-first walk, the
// batched environment) compiled for the CPU, against the runtime's own queries: the CUDA kernels run these very
// functions, so what is checked here is what the GPU computes (up to the device's float arithmetic, which nvcc is
// told not to contract: loaders/gpu).
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <random>
#include <tuple>
#include <vector>

#include "baked_bunny.h"
#include "core/batch.h"
#include "core/block_walk.h"
#include "traversal/eigen.h"
#include "traversal/field_simd.h"
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

TEST(QueryCore, EveryLowerBoundKernelGivesTheScalarBoundsBitForBit) {
  // Points everywhere a traversal looks: outside the grid, in coarse bricks (inside and outside the object), in
  // value bricks, on brick faces and at the grid's last bricks, in batches of every length.
  const BakedBunny& bunny = BakedBunny::get();
  const core::Field field = field_of(bunny.object->voxelmap());
  ASSERT_TRUE(field.gather_safe);
  std::mt19937 rng(17);
  std::vector<core::Vec3> points;
  for (int t = 0; t < 200000; ++t) {
    float c[3];
    for (int a = 0; a < 3; ++a)
      c[a] = std::uniform_real_distribution<float>(-0.1f * float(field.dims[a]), 1.1f * float(field.dims[a]))(rng);
    core::Vec3 u = core::make_vec3(c[0], c[1], c[2]);
    if (t % 4 == 0) u = core::make_vec3(std::round(u.x), std::round(u.y), std::round(u.z));  // voxel centres
    points.push_back(u);
  }
  // Near the surface: the shell's own points in its grid.
  const PointTree& tree = bunny.object->point_tree();
  const SparseVoxelmap& map = bunny.object->voxelmap();
  for (size_t n = 0; n < tree.size(); ++n) points.push_back(core::to_core(map.to_grid(tree.points[n].cast<double>())));
  std::vector<float> scalar(points.size()), vector(points.size());
  for (const size_t batch : {size_t(1), size_t(7), size_t(8), size_t(31), size_t(64), points.size()}) {
    for (size_t begin = 0; begin < points.size(); begin += batch) {
      const size_t n = std::min(batch, points.size() - begin);
      ASSERT_TRUE(core::lower_bounds_with(core::SimdKernel::Scalar, field, &points[begin], n, &scalar[begin]));
      if (!core::lower_bounds_with(core::SimdKernel::Avx2, field, &points[begin], n, &vector[begin]))
        GTEST_SKIP() << "this CPU has no AVX2: only the scalar kernel runs here";
    }
    for (size_t p = 0; p < points.size(); ++p) {
      ASSERT_EQ(std::memcmp(&scalar[p], &vector[p], sizeof(float)), 0)
          << "point " << p << " (" << points[p].x << ", " << points[p].y << ", " << points[p].z << "): scalar "
          << scalar[p] << ", avx2 " << vector[p];
    }
  }
  // The scalar batch is core::lower_bound point by point.
  for (size_t p = 0; p < points.size(); p += 97) ASSERT_EQ(scalar[p], core::lower_bound(field, points[p])) << p;
  // A field built by hand (no padding) never takes the vector kernel.
  core::Field unpadded = field;
  unpadded.gather_safe = false;
  EXPECT_FALSE(core::lower_bounds_with(core::SimdKernel::Avx2, unpadded, points.data(), 8, vector.data()));
}

TEST(QueryCore, TheVectorKernelBoundsPointsSoFarOutThatTheirSquaresOverflow) {
  // Beyond ~1.8e19 voxels (1e17 m at a 2 mm voxel) |u - box|^2 overflows float: the scalar kernel takes the root in
  // double (hypot_f), and the vector one must too. An inf bound culled every sphere a huge proximity reached, so
  // a fresh query found nothing where the coherent one (scalar bounds) found every point.
  const BakedBunny& bunny = BakedBunny::get();
  const core::Field field = field_of(bunny.object->voxelmap());
  std::vector<core::Vec3> points;
  for (const float far : {1e18f, 2e19f, 1e25f, -3e30f, 1e38f})
    for (int axis = 0; axis < 4; ++axis)  // along each axis and along the diagonal
      points.push_back(axis == 3
                           ? core::make_vec3(far, far, far)
                           : core::make_vec3(axis == 0 ? far : 5.0f, axis == 1 ? far : 5.0f, axis == 2 ? far : 5.0f));
  points.push_back(core::make_vec3(3.0f, 4.0f, 5.0f));  // an ordinary point in the same batch keeps its bits
  std::vector<float> scalar(points.size()), vector(points.size());
  ASSERT_TRUE(core::lower_bounds_with(core::SimdKernel::Scalar, field, points.data(), points.size(), scalar.data()));
  if (!core::lower_bounds_with(core::SimdKernel::Avx2, field, points.data(), points.size(), vector.data()))
    GTEST_SKIP() << "this CPU has no AVX2: only the scalar kernel runs here";
  for (size_t p = 0; p < points.size(); ++p) {
    EXPECT_TRUE(std::isfinite(vector[p])) << p << ": " << vector[p];
    EXPECT_EQ(std::memcmp(&scalar[p], &vector[p], sizeof(float)), 0)
        << "point " << p << " (" << points[p].x << ", " << points[p].y << ", " << points[p].z << "): scalar "
        << scalar[p] << ", avx2 " << vector[p];
  }
}

TEST(QueryCore, BatchEnvironmentFindsTheRuntimesContactsAndWrench) {
  const BakedBunny& bunny = BakedBunny::get();
  const CollisionObject& object = *bunny.object;
  const core::Body body = core::body_of(object);
  std::mt19937 rng(11);
  QueryScratch scratch;
  const uint32_t capacity = 40000;
  std::vector<float> points(3 * capacity), normals(3 * capacity), depths(capacity);
  std::vector<int32_t> index(capacity);
  std::vector<uint8_t> of_b(capacity);
  const core::ContactArrays buffer{points.data(), normals.data(), depths.data(), index.data(), of_b.data(), capacity};
  size_t compared = 0, touching = 0;
  for (int k = 0; k < 100; ++k) {
    // Half of the poses overlap deeply (coarse bricks and estimates), half graze (the band).
    const Pose pa = random_pose(rng, 0.0), pb = random_pose(rng, k % 2 ? 0.05 : 0.14);
    for (const double proximity : {0.0, 0.003}) {
      // Both normal sources, in turn: the core computes the runtime's normals and the wrench they give.
      const bool gradient = (k + int(proximity > 0)) % 2 == 0;
      QueryOptions options;
      options.proximity = proximity;
      options.normal_source = gradient ? NormalSource::DistanceGradient : NormalSource::PointShell;
      ContactSet set;
      query_contacts(object, pa, object, pb, options, set, scratch);
      const Wrench w = penalty_wrench(set, pa.apply(object.center_of_mass()), 2e4);
      core::EnvResult r;
      core::env_contacts(body, core::to_core(pa), body, core::to_core(pb), proximity, 2e4, gradient, buffer, r);
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
      for (uint32_t i = 0; i < r.count; ++i) core_keys.emplace_back(of_b[i] != 0, uint32_t(index[i]), depths[i]);
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
        const auto match = std::find_if(set.contacts.begin(), set.contacts.end(), [&](const Contact& x) {
          return x.point_index == uint32_t(index[i]) && x.point_of_b == (of_b[i] != 0);
        });
        ASSERT_NE(match, set.contacts.end());
        for (int a = 0; a < 3; ++a) {
          EXPECT_NEAR(points[3 * i + a], match->point[a], 1e-6);
          EXPECT_NEAR(normals[3 * i + a], match->normal[a], 1e-6);
        }
      }
      ++compared;
      touching += r.count > 0;
    }
  }
  EXPECT_EQ(compared, 200u);
  EXPECT_GT(touching, 60u);
}

TEST(QueryCore, AFullBufferCountsWhatDidNotFit) {
  const BakedBunny& bunny = BakedBunny::get();
  const core::Body body = core::body_of(*bunny.object);
  const core::RigidPose here;
  core::RigidPose near = here;
  near.t[0] = 0.02;  // deep overlap: hundreds of contacts
  auto run = [&](uint32_t capacity, std::vector<float>& depths, core::EnvResult& r) {
    depths.assign(capacity, 0.0f);
    core::ContactArrays out;
    out.depths = depths.data();
    out.capacity = capacity;
    core::env_contacts(body, here, body, near, 0.0, 1.0, true, out, r);
  };
  std::vector<float> all_depths, few_depths;
  core::EnvResult all, capped;
  run(100000, all_depths, all);
  run(8, few_depths, capped);
  ASSERT_GT(all.count, 8u);
  EXPECT_EQ(all.overflow, 0u);
  EXPECT_EQ(capped.count, all.count);
  EXPECT_EQ(capped.overflow, all.count - 8);
  EXPECT_TRUE(std::equal(few_depths.begin(), few_depths.end(), all_depths.begin()));
  for (int a = 0; a < 3; ++a) EXPECT_EQ(capped.force[a], all.force[a]);
}

TEST(QueryCore, AnEnvironmentWithABadPoseOrPairSaysWhy) {
  const BakedBunny& bunny = BakedBunny::get();
  const core::Body body = core::body_of(*bunny.object);
  const uint32_t zero = 0;
  const int32_t pairs[4] = {0, 0, 1, 0};  // the third environment names a pair that does not exist
  double poses[4][16];
  for (auto& m : poses) {
    std::fill(m, m + 16, 0.0);
    m[0] = m[5] = m[10] = m[15] = 1.0;
  }
  double scaled[16];
  std::copy(poses[0], poses[0] + 16, scaled);
  scaled[0] = 2.0;  // a scale: not a rigid transform
  double other[4][16];
  std::copy(&poses[0][0], &poses[0][0] + 64, &other[0][0]);
  std::copy(scaled, scaled + 16, other[1]);
  other[3][15] = 0.5;  // last row not 0 0 0 1
  core::BatchInputs<double> in;
  in.bodies = &body;
  in.pair_a = &zero;
  in.pair_b = &zero;
  in.pair_count = 1;
  in.pair_index = pairs;
  in.poses_a = &poses[0][0];
  in.poses_b = &other[0][0];
  in.environments = 4;
  int32_t count[4], error[4];
  core::BatchOutputs out;
  out.count = count;
  out.error = error;
  for (size_t e = 0; e < 4; ++e) core::run_environment(in, out, e);
  EXPECT_EQ(error[0], core::kEnvOk);
  EXPECT_GT(count[0], 0);
  EXPECT_EQ(error[1], core::kPoseNotOrthonormal);
  EXPECT_EQ(error[2], core::kEnvPairOutOfRange);
  EXPECT_EQ(error[3], core::kPoseLastRow);
  EXPECT_EQ(count[1] + count[2] + count[3], 0);
}

// A batch of environments of the bunny against itself, walked by EmulatedBlock: the block walk as a CUDA block runs it.
struct BlockBatch {
  core::Body body;
  std::vector<double> poses_a, poses_b;
  std::vector<int32_t> count, overflow, error;
  std::vector<float> max_depth, force, torque, points, normals, depths;
  std::vector<int32_t> index;
  std::vector<uint8_t> of_b;
  uint32_t capacity = 0;

  std::vector<int16_t> apron;  ///< the value bricks with an apron, where the batch reads those (as a GPU does)

  BlockBatch(const CollisionObject& object, const std::vector<std::pair<Pose, Pose>>& poses, uint32_t max_contacts,
             bool with_apron = false)
      : body(core::body_of(object)), capacity(max_contacts) {
    if (with_apron) {
      apron = core::apron_codes(body.field, object.voxelmap().value_brick_count());
      body.field = core::with_apron(body.field, apron.data());
    }
    for (const auto& [a, b] : poses) {
      append(a, poses_a);
      append(b, poses_b);
    }
    const size_t e = poses.size(), k = size_t(max_contacts);
    count.assign(e, -1), overflow.assign(e, -1), error.assign(e, -1);
    max_depth.assign(e, -1), force.assign(3 * e, 0), torque.assign(3 * e, 0);
    points.assign(3 * e * k, 0), normals.assign(3 * e * k, 0), depths.assign(e * k, 0);
    index.assign(e * k, -1), of_b.assign(e * k, 9);
  }
  static void append(const Pose& p, std::vector<double>& m) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) m.push_back(p.rotation(r, c));
      m.push_back(p.translation[r]);
    }
    for (const double x : {0.0, 0.0, 0.0, 1.0}) m.push_back(x);
  }
  // Every environment on one emulated block whose frontier holds `frontier` ranges (0: as a scene sizes it); odd
  // environments with the lanes in reverse order.
  void run(double proximity, double stiffness, bool gradient, uint32_t frontier = 0) {
    const uint32_t zero = 0;
    core::BatchInputs<double> in;
    in.bodies = &body;
    in.pair_a = in.pair_b = &zero;
    in.pair_count = 1;
    in.poses_a = poses_a.data();
    in.poses_b = poses_b.data();
    in.environments = count.size();
    in.proximity = proximity;
    in.stiffness = stiffness;
    in.gradient_normals = gradient;
    core::BatchOutputs out;
    out.count = count.data(), out.overflow = overflow.data(), out.error = error.data();
    out.max_depth = max_depth.data(), out.force = force.data(), out.torque = torque.data();
    out.contacts = {points.data(), normals.data(), depths.data(), index.data(), of_b.data(), capacity};
    const core::Shell* shells[] = {&body.shell};
    if (frontier == 0) frontier = core::frontier_capacity(shells, 1);
    std::vector<core::OpenRange> ranges(2 * size_t(frontier));
    auto state = std::make_unique<core::BlockState>();
    for (size_t e = 0; e < count.size(); ++e)
      core::run_environment_block(core::EmulatedBlock{e % 2 == 1}, *state, in, out, e,
                                  core::Frontier{ranges.data(), frontier});
  }
};

TEST(QueryCore, BricksWithAnApronGiveEveryLookupBitForBit) {
  const BakedBunny& bunny = BakedBunny::get();
  const SparseVoxelmap& map = bunny.object->voxelmap();
  const core::Field field = field_of(map);
  const std::vector<int16_t> apron = core::apron_codes(field, map.value_brick_count());
  const core::Field aproned = core::with_apron(field, apron.data());
  // Points everywhere, many near the surface (value bricks, their faces, edges and corners: where a cell reaches
  // into a neighbour, stored or coarse).
  std::mt19937 rng(29);
  std::vector<core::Vec3> points;
  for (int t = 0; t < 100000; ++t) {
    float c[3];
    for (int a = 0; a < 3; ++a)
      c[a] = std::uniform_real_distribution<float>(-0.1f * float(field.dims[a]), 1.1f * float(field.dims[a]))(rng);
    points.push_back(core::make_vec3(c[0], c[1], c[2]));
  }
  const PointTree& tree = bunny.object->point_tree();
  std::uniform_real_distribution<float> jitter(-2.0f, 2.0f);
  for (size_t n = 0; n < tree.size(); ++n) {
    const core::Vec3 u = core::to_core(map.to_grid(tree.points[n].cast<double>()));
    points.push_back(u);
    points.push_back(core::make_vec3(std::floor(u.x) + 0.5f, std::floor(u.y), u.z));
    points.push_back(u + core::make_vec3(jitter(rng), jitter(rng), jitter(rng)));
  }
  size_t in_one_brick = 0, straddling = 0;
  for (const core::Vec3& u : points) {
    core::Vec3 g0, g1;
    const core::Sample a = core::sample(field, u, &g0), b = core::sample(aproned, u, &g1);
    ASSERT_EQ(std::memcmp(&a.distance, &b.distance, sizeof(float)), 0) << u.x << " " << u.y << " " << u.z;
    ASSERT_EQ(a.exact, b.exact);
    ASSERT_EQ(a.bound, b.bound);
    ASSERT_EQ(std::memcmp(&g0, &g1, sizeof g0), 0)
        << u.x << " " << u.y << " " << u.z << ": " << g0.x << " " << g0.y << " " << g0.z << " vs " << g1.x << " "
        << g1.y << " " << g1.z << " d " << a.distance << " exact " << a.exact;
    const float l0 = core::lower_bound(field, u), l1 = core::lower_bound(aproned, u);
    ASSERT_EQ(std::memcmp(&l0, &l1, sizeof(float)), 0);
    // How often a GPU's sample stays in one brick with and without the apron.
    int base[3];
    for (int k = 0; k < 3; ++k)
      base[k] = std::min(int(std::clamp(u[k], 0.0f, float(field.dims[k] - 1))), std::max(field.dims[k] - 2, 0));
    float v[8];
    bool exact = true;
    int32_t entry = 0;
    if (core::apron_corners(aproned, base, v, exact, entry)) {
      ++in_one_brick;
      straddling += !core::brick_corners(field, base, v, exact, entry);
    }
  }
  // The apron is what serves the samples that straddle a brick's face (a third of those in value bricks).
  EXPECT_GT(straddling, in_one_brick / 5);
}

TEST(QueryCore, TheBlockWalkFindsTheRuntimesContactsInItsOrderAndItsWrenchBitForBit) {
  const BakedBunny& bunny = BakedBunny::get();
  const CollisionObject& object = *bunny.object;
  std::mt19937 rng(23);
  std::vector<std::pair<Pose, Pose>> poses;
  for (int k = 0; k < 60; ++k) poses.emplace_back(random_pose(rng, 0.0), random_pose(rng, k % 2 ? 0.05 : 0.14));
  const uint32_t capacity = 20000;
  // The runtime's bricks, and bricks with an apron (a GPU's): the same contacts either way.
  BlockBatch plain(object, poses, capacity), with_apron(object, poses, capacity, true);
  QueryScratch scratch;
  size_t touching = 0, compared = 0;
  for (const double proximity : {0.0, 0.003})
    for (const bool gradient : {true, false}) {
      BlockBatch& batch = gradient == (proximity > 0) ? with_apron : plain;
      batch.run(proximity, 2e4, gradient);
      QueryOptions options;
      options.proximity = proximity;
      options.normal_source = gradient ? NormalSource::DistanceGradient : NormalSource::PointShell;
      for (size_t e = 0; e < poses.size(); ++e) {
        const auto& [pa, pb] = poses[e];
        ContactSet set;
        query_contacts(object, pa, object, pb, options, set, scratch);
        const Wrench w = penalty_wrench(set, pa.apply(object.center_of_mass()), 2e4);
        ASSERT_EQ(batch.error[e], core::kEnvOk);
        ASSERT_EQ(size_t(batch.count[e]), set.contacts.size()) << "environment " << e;
        ASSERT_EQ(batch.overflow[e], 0);
        double deepest = 0;
        for (size_t i = 0; i < set.contacts.size(); ++i) {
          // Contact i is the runtime's contact i: the same point, depth, position and normal.
          const Contact& c = set.contacts[i];
          const size_t at = e * capacity + i;
          ASSERT_EQ(uint32_t(batch.index[at]), c.point_index) << e << ", contact " << i;
          ASSERT_EQ(batch.of_b[at] != 0, c.point_of_b);
          ASSERT_EQ(batch.depths[at], float(c.depth));
          for (int a = 0; a < 3; ++a) {
            ASSERT_EQ(batch.points[3 * at + a], float(c.point[a])) << e << ", contact " << i;
            ASSERT_EQ(batch.normals[3 * at + a], float(c.normal[a])) << e << ", contact " << i;
          }
          deepest = std::max(deepest, c.depth);
        }
        EXPECT_EQ(batch.max_depth[e], float(deepest));
        for (int a = 0; a < 3; ++a) {
          EXPECT_EQ(batch.force[3 * e + a], float(w.force[a])) << "environment " << e;
          EXPECT_EQ(batch.torque[3 * e + a], float(w.torque[a])) << "environment " << e;
        }
        touching += !set.contacts.empty();
        ++compared;
      }
    }
  EXPECT_EQ(compared, 240u);
  EXPECT_GT(touching, 80u);
}

TEST(QueryCore, TheBlockWalkCountsWhatDidNotFitAndRefusesNoNodeWithinItsFrontier) {
  const BakedBunny& bunny = BakedBunny::get();
  Pose here, near;
  near.translation = Eigen::Vector3d(0.02, 0, 0);  // deep overlap: hundreds of contacts
  BlockBatch all(*bunny.object, {{here, near}}, 100000), capped(*bunny.object, {{here, near}}, 8);
  all.run(0.0, 1.0, true);
  capped.run(0.0, 1.0, true);
  ASSERT_GT(all.count[0], 8);
  EXPECT_EQ(all.overflow[0], 0);
  EXPECT_EQ(capped.count[0], all.count[0]);
  EXPECT_EQ(capped.overflow[0], all.count[0] - 8);
  EXPECT_TRUE(std::equal(capped.depths.begin(), capped.depths.end(), all.depths.begin()));
  for (int a = 0; a < 3; ++a) EXPECT_EQ(capped.force[a], all.force[a]);
  // The depth-first walk finds the same contacts (in its own order).
  const core::Body body = core::body_of(*bunny.object);
  std::vector<float> dfs(100000);
  core::ContactArrays out;
  out.depths = dfs.data();
  out.capacity = 100000;
  core::EnvResult r;
  core::env_contacts(body, core::to_core(here), body, core::to_core(near), 0.0, 1.0, true, out, r);
  ASSERT_EQ(int32_t(r.count), all.count[0]);
  std::vector<float> block_depths(all.depths.begin(), all.depths.begin() + all.count[0]);
  dfs.resize(r.count);
  std::sort(dfs.begin(), dfs.end());
  std::sort(block_depths.begin(), block_depths.end());
  EXPECT_EQ(dfs, block_depths);
  // A frontier smaller than a level's opened nodes ends the environment with its code, nothing counted.
  BlockBatch small(*bunny.object, {{here, near}}, 8);
  small.run(0.0, 1.0, true, 4);
  EXPECT_EQ(small.error[0], core::kEnvFrontierFull);
  EXPECT_EQ(small.count[0], 0);
  EXPECT_EQ(small.force[0], 0.0f);
}

TEST(QueryCore, TheBlockWalkSaysWhyAnEnvironmentHasNoResult) {
  const BakedBunny& bunny = BakedBunny::get();
  Pose here, near;
  near.translation = Eigen::Vector3d(0.02, 0, 0);
  BlockBatch batch(*bunny.object, {{here, near}, {here, near}, {here, near}}, 4);
  batch.poses_b[16 + 0] = 2.0;           // environment 1: a scale, not a rigid transform
  batch.poses_a[32 + 3] = std::nan("");  // environment 2: not finite
  batch.run(0.0, 1.0, true);
  EXPECT_EQ(batch.error[0], core::kEnvOk);
  EXPECT_GT(batch.count[0], 0);
  EXPECT_EQ(batch.error[1], core::kPoseNotOrthonormal);
  EXPECT_EQ(batch.error[2], core::kPoseNotFinite);
  EXPECT_EQ(batch.count[1] + batch.count[2], 0);
}

}  // namespace
}  // namespace voxfmt::runtime
