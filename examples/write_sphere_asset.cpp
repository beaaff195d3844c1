// Writes an analytic sphere as a voxfmt asset, without any mesh or bake step: the smallest example of the
// libvoxfmt API, and the fixture the spec tests (tests/spec/spec_fixture.py) recompute independently.
//
//   write_sphere_asset OUT.vox.h5
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>

#include "voxfmt/io.h"
#include "voxfmt/version.h"

namespace {

constexpr double kPi = 3.14159265358979323846;

voxfmt::Asset make_sphere_asset() {
  const voxfmt::Vec3 c = {0.1, -0.2, 0.3};
  const double r = 0.25, h = 0.05, band = 2.0;
  const uint32_t margin = 2, n_points = 200, branching = 4;

  voxfmt::Asset a;
  a.bounds_min = {c[0] - r, c[1] - r, c[2] - r};
  a.bounds_max = {c[0] + r, c[1] + r, c[2] + r};

  // The grid's geometry; make_voxelmap fills its bricks and lattice from the exact signed distance.
  voxfmt::Voxelmap grid;
  grid.voxel_size = h;
  grid.distance_band = band;
  grid.margin = margin;
  const double half_extent = r + margin * h;
  const uint32_t n = uint32_t(std::lround(2 * half_extent / h)) + 1;
  grid.dims = {n, n, n};
  grid.origin = {c[0] - half_extent, c[1] - half_extent, c[2] - half_extent};
  a.voxelmap = voxfmt::make_voxelmap(grid, [&](const voxfmt::Vec3& p) {
    return std::sqrt((p[0] - c[0]) * (p[0] - c[0]) + (p[1] - c[1]) * (p[1] - c[1]) + (p[2] - c[2]) * (p[2] - c[2])) - r;
  });

  // Fibonacci sphere: evenly spread points with inward normals.
  voxfmt::PointShell& ps = a.point_shell;
  for (uint32_t i = 0; i < n_points; ++i) {
    const double z = 1 - 2 * (i + 0.5) / n_points, rho = std::sqrt(1 - z * z), phi = i * kPi * (3 - std::sqrt(5.0));
    const double x = rho * std::cos(phi), y = rho * std::sin(phi);
    ps.points.push_back({c[0] + r * x, c[1] + r * y, c[2] + r * z});
    ps.normals.push_back({float(-x), float(-y), float(-z)});
  }
  // A complete 4-ary tree in breadth-first order: node i's children are 4i+1 .. 4i+4.
  for (uint32_t i = 0; i < n_points; ++i) {
    const uint32_t first = std::min(branching * i + 1, n_points);
    ps.child_begin.push_back(first);
    ps.child_count.push_back(std::min(branching * i + branching + 1, n_points) - first);
  }
  for (uint32_t begin = 0, width = 1; begin < n_points; begin += width, width *= branching)
    ps.level_offsets.push_back(begin);
  ps.level_offsets.push_back(n_points);
  ps.branching = branching;
  // Each sphere is centred on its node's point and reaches its farthest descendant.
  std::function<double(uint32_t, const voxfmt::Vec3&)> farthest = [&](uint32_t node, const voxfmt::Vec3& from) {
    const voxfmt::Vec3& p = ps.points[node];
    double d = std::sqrt((p[0] - from[0]) * (p[0] - from[0]) + (p[1] - from[1]) * (p[1] - from[1]) +
                         (p[2] - from[2]) * (p[2] - from[2]));
    for (uint32_t ch = ps.child_begin[node]; ch < ps.child_begin[node] + ps.child_count[node]; ++ch)
      d = std::max(d, farthest(ch, from));
    return d;
  };
  for (uint32_t i = 0; i < n_points; ++i) {
    ps.sphere_centers.push_back(ps.points[i]);
    ps.sphere_radii.push_back(farthest(i, ps.points[i]));
  }

  const double volume = 4.0 / 3.0 * kPi * r * r * r, moment = 0.4 * volume * r * r;
  a.mass.volume = volume;
  a.mass.center_of_mass = c;
  a.mass.inertia = {moment, 0, 0, 0, moment, 0, 0, 0, moment};

  a.provenance.generator = "write_sphere_asset";
  a.provenance.generator_version = VOXFMT_VERSION_STRING;
  a.provenance.build_parameters_json = R"({"shape": "sphere", "radius": 0.25, "voxel_size": 0.05, "points": 200})";
  a.provenance.dependency_versions = {{"voxfmt", VOXFMT_VERSION_STRING}};
  return a;
}

}  // namespace

int main(int argc, char** argv) {
  const bool help = argc == 2 && (std::strcmp(argv[1], "--help") == 0 || std::strcmp(argv[1], "-h") == 0);
  if (argc != 2 || help || argv[1][0] == '-') {
    std::fprintf(help ? stdout : stderr,
                 "usage: %s OUT.vox.h5\nWrites an analytic sphere (r = 0.25 m) as a voxfmt asset.\n", argv[0]);
    return help ? 0 : 2;
  }
  const voxfmt::Status status = voxfmt::write_asset(argv[1], make_sphere_asset());
  if (!status) {
    std::fprintf(stderr, "write_sphere_asset: error: %s\n", status.error().message.c_str());
    return 1;
  }
  return 0;
}
