// The field the MuJoCo plugin gives MuJoCo (loaders/mujoco/src/asset_field.h), on an exact sphere made in code:
// the runtime's values in the grid, the closed form in the band, no jump anywhere (band edge, blocks against
// lattice cells, the grid's boundary), unit gradients that are the field's own, and refusals.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "analytic_sphere.h"
#include "asset_field.h"
#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::mujoco {
namespace {

// Large enough for coarse bricks inside and outside, away from the blocks.
const test::SphereSpec kSphere{{0.01, -0.02, 0.03}, 0.2, 0.01, 500, 4};

const AssetField& field() {
  static const auto made = [] {
    auto f = AssetField::from_asset(test::make_sphere_asset(kSphere));
    if (!f) throw std::runtime_error(f.error().describe());
    return f.value();
  }();
  return *made;
}

const runtime::SparseVoxelmap& runtime_map() {
  static const auto object = [] {
    auto o = runtime::CollisionObject::from_asset(test::make_sphere_asset(kSphere));
    if (!o) throw std::runtime_error(o.error().describe());
    return o.value();
  }();
  return object->voxelmap();
}

double exact(const Eigen::Vector3d& p) {
  return (p - Eigen::Vector3d(kSphere.center[0], kSphere.center[1], kSphere.center[2])).norm() - kSphere.radius;
}

// A point of the grid's box of voxel centres, or around it by `beyond` voxels.
Eigen::Vector3d random_point(std::mt19937& rng, double beyond) {
  const auto& map = runtime_map();
  Eigen::Vector3d p;
  for (int a = 0; a < 3; ++a) {
    std::uniform_real_distribution<double> u(-beyond, map.dims()[a] - 1 + beyond);
    p[a] = map.origin()[a] + u(rng) * map.voxel_size();
  }
  return p;
}

TEST(AssetField, InTheGridItIsTheRuntimesField) {
  std::mt19937 rng(1);
  const auto& map = runtime_map();
  int in_band = 0;
  for (int n = 0; n < 20000; ++n) {
    const Eigen::Vector3d p = random_point(rng, 0.0);
    const double ours = field().evaluate(p.data(), nullptr);
    const runtime::FieldSample s = map.sample(map.to_grid(p));
    // The same float arithmetic: equal to a few ulps of the distance.
    EXPECT_NEAR(ours, double(s.distance) * map.voxel_size(), 1e-6 * (map.voxel_size() + std::abs(ours)))
        << p.transpose();
    in_band += s.exact;
  }
  EXPECT_GT(in_band, 1000);  // the band was sampled, not only the lattice
}

TEST(AssetField, ExactInTheBand) {
  // Where the 8 voxels around a point all store their distance (the runtime's `exact`), the field is the
  // closed form up to the trilinear interpolation's error on a 20-voxel sphere (h^2 / (4 r) = 1/80 voxel).
  std::mt19937 rng(2);
  std::normal_distribution<double> offset(0.0, 1.5 * kSphere.voxel_size);
  std::uniform_real_distribution<double> angle(0, 2 * M_PI), height(-1, 1);
  const Eigen::Vector3d c(kSphere.center[0], kSphere.center[1], kSphere.center[2]);
  const auto& map = runtime_map();
  int checked = 0;
  for (int n = 0; n < 5000; ++n) {
    const double z = height(rng), phi = angle(rng), rho = std::sqrt(1 - z * z);
    const Eigen::Vector3d p =
        c + (kSphere.radius + offset(rng)) * Eigen::Vector3d(rho * std::cos(phi), rho * std::sin(phi), z);
    if (!map.sample(map.to_grid(p)).exact) continue;
    double gradient[3];
    EXPECT_NEAR(field().evaluate(p.data(), gradient), exact(p), kSphere.voxel_size / 60);
    const Eigen::Vector3d radial = (p - c).normalized();
    EXPECT_GT(radial.dot(Eigen::Vector3d(gradient[0], gradient[1], gradient[2])), 0.995);
    ++checked;
  }
  EXPECT_GT(checked, 3000);
}

// Walks straight lines through the whole grid and out of it in steps of 1/1000 voxel: a step never changes the
// field by more than a few times the step (the trilinear field's slope, steeper than 1 only where the coarse
// estimates beyond the band overestimate), so nothing jumps at the band's edge, where blocks meet lattice cells,
// or at the grid's boundary. A jump of 1/100 voxel would show as a slope of 10.
TEST(AssetField, ContinuousEverywhere) {
  std::mt19937 rng(3);
  const double h = kSphere.voxel_size, step = h / 1000;
  double largest = 0;
  for (int line = 0; line < 20; ++line) {
    const Eigen::Vector3d from = random_point(rng, 8.0), to = random_point(rng, 8.0);
    const int steps = int((to - from).norm() / step);
    const Eigen::Vector3d delta = (to - from) / steps;
    double last = field().evaluate(from.data(), nullptr);
    for (int k = 1; k <= steps; ++k) {
      const Eigen::Vector3d p = from + k * delta;
      const double d = field().evaluate(p.data(), nullptr);
      largest = std::max(largest, std::abs(d - last) / delta.norm());
      last = d;
    }
  }
  EXPECT_LT(largest, 5.0);
}

TEST(AssetField, GradientIsTheFieldsUnitSlope) {
  std::mt19937 rng(4);
  const double h = kSphere.voxel_size, e = 2e-3 * h;  // the distances are floats: larger steps, less noise
  int checked = 0;
  for (int n = 0; n < 20000; ++n) {
    const Eigen::Vector3d p = random_point(rng, 6.0);
    double g[3];
    field().evaluate(p.data(), g);
    const Eigen::Vector3d gradient(g[0], g[1], g[2]);
    ASSERT_NEAR(gradient.norm(), 1.0, 1e-5);
    Eigen::Vector3d fd;
    for (int a = 0; a < 3; ++a) {
      Eigen::Vector3d hi = p, lo = p;
      hi[a] += e;
      lo[a] -= e;
      fd[a] = (field().evaluate(hi.data(), nullptr) - field().evaluate(lo.data(), nullptr)) / (2 * e);
    }
    // Across a cell's face the trilinear slope changes: compare where both sides agree (a smooth spot), and
    // where the field is not flat (the gradient then points away from the centre instead).
    if (fd.norm() < 0.1) continue;
    Eigen::Vector3d fd_hi, fd_lo;
    for (int a = 0; a < 3; ++a) {
      Eigen::Vector3d hi = p, lo = p;
      hi[a] += 2 * e;
      lo[a] -= 2 * e;
      fd_hi[a] = (field().evaluate(hi.data(), nullptr) - field().evaluate(p.data(), nullptr)) / (2 * e);
      fd_lo[a] = (field().evaluate(p.data(), nullptr) - field().evaluate(lo.data(), nullptr)) / (2 * e);
    }
    if ((fd_hi - fd_lo).norm() > 1e-2 * fd.norm()) continue;
    EXPECT_GT(gradient.dot(fd.normalized()), 0.999) << p.transpose();
    ++checked;
  }
  EXPECT_GT(checked, 5000);
}

TEST(AssetField, BeyondTheGridItGrowsWithTheDistance) {
  const auto& map = runtime_map();
  const double h = kSphere.voxel_size;
  const Eigen::Vector3d centre(kSphere.center[0], kSphere.center[1], kSphere.center[2]);
  for (int a = 0; a < 3; ++a)
    for (double sign : {-1.0, 1.0}) {
      Eigen::Vector3d edge = centre;
      edge[a] = sign < 0 ? map.origin()[a] : map.origin()[a] + (map.dims()[a] - 1) * h;
      const double at_edge = field().evaluate(edge.data(), nullptr);
      for (double out : {0.5, 3.0, 40.0}) {
        Eigen::Vector3d p = edge;
        p[a] += sign * out * h;
        double g[3];
        EXPECT_NEAR(field().evaluate(p.data(), g), at_edge + out * h, 1e-9);
        EXPECT_GT(g[a] * sign, 0.9);  // mostly away from the face (the field's own slope along it adds)
        EXPECT_GE(field().evaluate(p.data(), nullptr), exact(p) - 0.05 * h);  // never nearer than the sphere
      }
    }
}

TEST(AssetField, FarAwayPointsStillPointAway) {
  // Past 1.8e19 voxels the squared offset overflows float, past 1e154 m a double's: the gradient kept pointing
  // away only while neither did (it lost its axis, then became zero).
  const Eigen::Vector3d centre(kSphere.center[0], kSphere.center[1], kSphere.center[2]);
  const Eigen::Vector3d away = Eigen::Vector3d(2, 1, 0).normalized();
  for (double far : {1e3, 1e18, 1e21, 1e160, 1e300}) {
    const Eigen::Vector3d p = centre + far * away;
    double g[3];
    const double d = field().evaluate(p.data(), g);
    EXPECT_GT(d, 0.5 * far) << far;  // +inf where the distance itself leaves float's range
    EXPECT_GT(Eigen::Vector3d(g[0], g[1], g[2]).dot(away), 0.99) << far;  // (the field at the clamped point adds)
  }
}

TEST(AssetField, FlatFieldStillHasADirection) {
  // Deep inside, where the coarse estimate is clamped to the band's edge, the gradient points away from the
  // centre rather than being zero.
  const Eigen::Vector3d deep(kSphere.center[0] + 0.001, kSphere.center[1] + 0.002, kSphere.center[2] - 0.001);
  double g[3];
  const double d = field().evaluate(deep.data(), g);
  EXPECT_LT(d, 0.0);
  EXPECT_NEAR(std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]), 1.0, 1e-6);
}

TEST(AssetField, BoxHoldsTheObject) {
  double box[6];
  field().aabb(0.002, box);
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(box[a], kSphere.center[size_t(a)], 1e-12);
    EXPECT_NEAR(box[3 + a], kSphere.radius + 0.002, 1e-12);
  }
  EXPECT_GT(field().block_count(), 0u);
  EXPECT_GT(field().memory_bytes(), field().block_count() * AssetField::kBlockValues * sizeof(float));
}

TEST(AssetField, RefusesAnAssetWithoutAVoxelmap) {
  Asset asset = test::make_sphere_asset({{0, 0, 0}, 0.1, 0.01, 200, 4});
  asset.voxelmap = Voxelmap{};
  const auto f = AssetField::from_asset(std::move(asset));
  ASSERT_FALSE(f.ok());
  EXPECT_EQ(f.error().code, IssueCode::InvalidAsset);
}

TEST(AssetField, LoadNamesTheFileAndTheReason) {
  const auto f = AssetField::load("/no/such/dir/part.vox.h5");
  ASSERT_FALSE(f.ok());
  EXPECT_EQ(f.error().code, IssueCode::FileNotFound);
  EXPECT_NE(f.error().describe().find("/no/such/dir/part.vox.h5"), std::string::npos);
}

}  // namespace
}  // namespace voxfmt::mujoco
