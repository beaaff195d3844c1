// An exact sphere asset made in code, without the bake: the synthetic fixture of the runtime and Bullet tests,
// so they run (and fail) on their own. Distances and lattice are the closed form |p - c| - r.
#pragma once

#include <cmath>
#include <functional>

#include "voxfmt/asset.h"

namespace voxfmt::test {

struct SphereSpec {
  Vec3 center{0, 0, 0};
  double radius = 0.1;
  double voxel_size = 0.01;
  uint32_t points = 2000;
  uint32_t branching = 4;
};

inline Asset make_sphere_asset(const SphereSpec& s = {}) {
  constexpr double kPi = 3.14159265358979323846;
  const Vec3& c = s.center;
  const double r = s.radius, h = s.voxel_size, band = 3.0;
  const uint32_t margin = 4;
  Asset a;
  a.bounds_min = {c[0] - r, c[1] - r, c[2] - r};
  a.bounds_max = {c[0] + r, c[1] + r, c[2] + r};
  Voxelmap grid;
  grid.voxel_size = h;
  grid.distance_band = band;
  grid.margin = margin;
  const double half_extent = r + margin * h;
  const uint32_t n = uint32_t(std::lround(2 * half_extent / h)) + 1;
  grid.dims = {n, n, n};
  grid.origin = {c[0] - half_extent, c[1] - half_extent, c[2] - half_extent};
  a.voxelmap =
      make_voxelmap(grid, [&](const Vec3& p) { return std::hypot(p[0] - c[0], p[1] - c[1], p[2] - c[2]) - r; });
  // Fibonacci sphere: evenly spread points with inward normals, in a complete k-ary breadth-first tree.
  PointShell& ps = a.point_shell;
  const uint32_t count = s.points, b = s.branching;
  for (uint32_t i = 0; i < count; ++i) {
    const double z = 1 - 2 * (i + 0.5) / count, rho = std::sqrt(1 - z * z), phi = i * kPi * (3 - std::sqrt(5.0));
    const double x = rho * std::cos(phi), y = rho * std::sin(phi);
    ps.points.push_back({c[0] + r * x, c[1] + r * y, c[2] + r * z});
    ps.normals.push_back({float(-x), float(-y), float(-z)});
  }
  for (uint32_t i = 0; i < count; ++i) {
    const uint64_t first = std::min<uint64_t>(uint64_t(b) * i + 1, count);
    ps.child_begin.push_back(uint32_t(first));
    ps.child_count.push_back(uint32_t(std::min<uint64_t>(uint64_t(b) * i + b + 1, count) - first));
  }
  for (uint64_t begin = 0, width = 1; begin < count; begin += width, width *= b)
    ps.level_offsets.push_back(uint32_t(begin));
  ps.level_offsets.push_back(count);
  ps.branching = b;
  ps.point_spacing = std::sqrt(4 * kPi * r * r / count);
  std::function<double(uint32_t, const Vec3&)> farthest = [&](uint32_t node, const Vec3& from) {
    const Vec3& p = ps.points[node];
    double d = std::hypot(p[0] - from[0], p[1] - from[1], p[2] - from[2]);
    for (uint32_t ch = ps.child_begin[node]; ch < ps.child_begin[node] + ps.child_count[node]; ++ch)
      d = std::max(d, farthest(ch, from));
    return d;
  };
  for (uint32_t i = 0; i < count; ++i) {
    ps.sphere_centers.push_back(ps.points[i]);
    ps.sphere_radii.push_back(farthest(i, ps.points[i]));
  }
  const double volume = 4.0 / 3.0 * kPi * r * r * r, moment = 0.4 * volume * r * r;
  a.mass.volume = volume;
  a.mass.center_of_mass = c;
  a.mass.inertia = {moment, 0, 0, 0, moment, 0, 0, 0, moment};
  a.provenance.generator = "voxfmt tests (analytic sphere)";
  a.provenance.generator_version = "0";
  return a;
}

}  // namespace voxfmt::test
