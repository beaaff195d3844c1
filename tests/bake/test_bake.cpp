// voxfmt build stages against exact references: CGAL's AABB tree for the bunny, analytic distance for a torus.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <random>
#include <stdexcept>

#include <sys/stat.h>

#include "boundary_winding.h"
#include "closest_triangle.h"
#include "exact_surface.h"
#include "stages.h"
#include "triangle_closest_point.h"
#include "vec3_math.h"
#include "voxfmt/io.h"
#include "winding_number.h"

namespace voxfmt::bake {
namespace {

const std::string kMeshes = VOXFMT_SAMPLE_MESHES;

using test::ExactSurface;

struct ErrorStats {
  size_t samples = 0, sign_mismatches = 0;
  double max_error = 0, mean_error = 0;  // in voxels
};

/// A voxel with a stored distance (metres).
struct StoredVoxel {
  uint32_t i, j, k;
  double d;
};

/// Every voxel with a stored distance, read brick by brick.
std::vector<StoredVoxel> stored_voxels(const Voxelmap& vm) {
  std::vector<StoredVoxel> out;
  constexpr uint32_t E = Voxelmap::kBrickEdge;
  vm.for_each_value_brick([&](uint32_t bi, uint32_t bj, uint32_t bk, const int16_t* codes) {
    for (uint32_t lk = 0; lk < E && bk * E + lk < vm.dims[2]; ++lk)
      for (uint32_t lj = 0; lj < E && bj * E + lj < vm.dims[1]; ++lj)
        for (uint32_t li = 0; li < E && bi * E + li < vm.dims[0]; ++li) {
          const int16_t code = codes[Voxelmap::local_index(li, lj, lk)];
          if (Voxelmap::code_is_stored(code)) out.push_back({bi * E + li, bj * E + lj, bk * E + lk, vm.decode(code)});
        }
  });
  return out;
}

/// A voxel of the grid chosen at random.
std::array<uint32_t, 3> random_voxel(const Voxelmap& vm, std::mt19937_64& rng) {
  return {uint32_t(rng() % vm.dims[0]), uint32_t(rng() % vm.dims[1]), uint32_t(rng() % vm.dims[2])};
}

/// Compares stored distances at (up to) `wanted` stored voxels against `exact` (signed, negative inside).
/// Signs are compared where the exact distance exceeds `sign_tolerance` (metres): a tessellated reference
/// surface may lie on the other side of a voxel centre that close to it. A stored 0 (within half a quantum of the
/// surface) is on it, of either sign (spec §3.1).
ErrorStats compare_distances(const Voxelmap& vm, const std::function<double(const Vec3&)>& exact, size_t wanted,
                             double sign_tolerance) {
  std::vector<StoredVoxel> stored = stored_voxels(vm);
  std::mt19937_64 rng(7);
  std::shuffle(stored.begin(), stored.end(), rng);
  if (stored.size() > wanted) stored.resize(wanted);
  ErrorStats s;
  for (const StoredVoxel& v : stored) {
    const double truth = exact(vm.voxel_center(v.i, v.j, v.k));
    const double error = std::abs(v.d - truth) / vm.voxel_size;
    s.max_error = std::max(s.max_error, error);
    s.mean_error += error;
    // A sign is only meaningful away from the surface itself.
    if (std::abs(truth) > sign_tolerance && v.d != 0 && (truth < 0) != (v.d < 0)) ++s.sign_mismatches;
    ++s.samples;
  }
  s.mean_error /= double(std::max<size_t>(1, s.samples));
  return s;
}

/// The spec's band accuracy (§3.1): >= 10,000 samples, each within `max_error` voxel of the reference (half a
/// distance quantum, 9.2e-5 voxel at band 3, against an exact mesh distance), no sign mismatch.
void expect_accurate(const ErrorStats& s, const char* label, double max_error = 1e-4) {
  std::printf("%s: %zu samples, max error %.3g voxel, mean %.3g voxel, %zu sign mismatches\n", label, s.samples,
              s.max_error, s.mean_error, s.sign_mismatches);
  EXPECT_GE(s.samples, 10000u);
  EXPECT_LE(s.max_error, max_error);
  EXPECT_EQ(s.sign_mismatches, 0u);
}

/// Errors of `validate --level full` (signs, band, estimates, tree, mass), with their messages.
std::vector<std::string> full_errors(const Asset& a) {
  std::vector<std::string> out;
  for (const Issue& issue : validate_asset(a, ValidationLevel::Full))
    if (issue.severity == Severity::Error) out.push_back(std::string(code_name(issue.code)) + " " + issue.message);
  return out;
}

void expect_tree_encloses_descendants(const PointShell& ps, double tolerance) {
  // Every node's sphere contains the points of its whole subtree (walk each subtree explicitly).
  size_t violations = 0;
  std::vector<uint32_t> stack;
  for (uint32_t node = 0; node < ps.size(); ++node) {
    stack.assign(1, node);
    while (!stack.empty()) {
      const uint32_t d = stack.back();
      stack.pop_back();
      const Vec3 &c = ps.sphere_centers[node], &p = ps.points[d];
      const double dist =
          std::sqrt((p[0] - c[0]) * (p[0] - c[0]) + (p[1] - c[1]) * (p[1] - c[1]) + (p[2] - c[2]) * (p[2] - c[2]));
      violations += dist > ps.sphere_radii[node] + tolerance;
      for (uint32_t ch = ps.child_begin[d]; ch < ps.child_begin[d] + ps.child_count[d]; ++ch) stack.push_back(ch);
    }
  }
  EXPECT_EQ(violations, 0u);
  // Every point exactly once: reachable from the root once.
  std::vector<int> seen(ps.size(), 0);
  stack.assign(1, 0);
  while (!stack.empty()) {
    const uint32_t d = stack.back();
    stack.pop_back();
    ++seen[d];
    for (uint32_t ch = ps.child_begin[d]; ch < ps.child_begin[d] + ps.child_count[d]; ++ch) stack.push_back(ch);
  }
  EXPECT_EQ(std::count(seen.begin(), seen.end(), 1), std::ptrdiff_t(ps.size()));
}

void expect_points_on_surface_with_inward_normals(const PointShell& ps, const ExactSurface& surface, double diagonal) {
  size_t off_surface = 0, not_unit = 0, not_inward = 0;
  double worst = 0;
  for (size_t n = 0; n < ps.size(); ++n) {
    const double d = surface.distance(ps.points[n]);
    worst = std::max(worst, d);
    off_surface += d > 1e-5 * diagonal;
    const Vec3f& nn = ps.normals[n];
    const double len = std::sqrt(double(nn[0]) * nn[0] + double(nn[1]) * nn[1] + double(nn[2]) * nn[2]);
    not_unit += std::abs(len - 1) > 1e-5;
    const double eps = 1e-4 * diagonal;
    const Vec3& p = ps.points[n];
    const Vec3 in = {p[0] + eps * nn[0], p[1] + eps * nn[1], p[2] + eps * nn[2]};
    const Vec3 out = {p[0] - eps * nn[0], p[1] - eps * nn[1], p[2] - eps * nn[2]};
    not_inward += !surface.inside(in) || surface.inside(out);
  }
  EXPECT_EQ(off_surface, 0u) << "farthest point is " << worst / diagonal << " diagonals from the surface";
  EXPECT_EQ(not_unit, 0u);
  EXPECT_EQ(not_inward, 0u);
}

double diagonal_of(const Asset& a) {
  double s = 0;
  for (int i = 0; i < 3; ++i) s += (a.bounds_max[i] - a.bounds_min[i]) * (a.bounds_max[i] - a.bounds_min[i]);
  return std::sqrt(s);
}

// Brute force over every triangle: the squared distance to the nearest, via ClosestTriangle's own search over a
// one-triangle tree (the per-triangle distance is not what this test checks, the tree is).
double nearest_by_brute_force(const std::vector<std::array<Vec3, 3>>& tris, const Vec3& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const auto& t : tris)
    best = std::min(best, ClosestTriangle({t}).nearest(p, std::numeric_limits<double>::infinity(), 0).first);
  return best;
}

TEST(ClosestTriangle, FindsTheNearestInTreesOfEveryShape) {
  // Random triangles; a run of triangles at doubling distances (each surface-area split cuts off the farthest few:
  // 84 levels unbounded, where the search's stack of 64 lost subtrees and answered 1.5e33 for 0.77 — build() must
  // fall back to the median before that); and all triangles on one spot (no plane separates their centroids).
  std::mt19937 random(7);
  std::uniform_real_distribution<double> unit(-1, 1);
  std::vector<std::array<Vec3, 3>> scattered, run, stacked;
  for (int t = 0; t < 3000; ++t) {
    const Vec3 c{unit(random), unit(random), unit(random)};
    scattered.push_back({c, c + Vec3{0.02 * unit(random), 0.02, 0}, c + Vec3{0, 0.01, 0.02 * unit(random)}});
  }
  for (int t = 0; t < 400; ++t) {
    const double x = std::pow(2.0, t) * 1e-9;
    run.push_back({Vec3{x, 0, 0}, Vec3{x, 1e-7, 0}, Vec3{x, 0, 1e-7}});
  }
  for (int t = 0; t < 100; ++t) stacked.push_back({Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, double(t) * 1e-3}});
  for (const auto* tris : {&scattered, &run, &stacked}) {
    const ClosestTriangle tree(*tris, std::numeric_limits<uint32_t>::max());  // on this thread alone
    EXPECT_LE(tree.depth(), 62) << "triangles " << tris->size();
    // Split at the top first and built below on all threads (down to a few triangles a subtree): the same tree.
    for (uint32_t parallel_from : {5u, 64u, 1000u}) EXPECT_TRUE(ClosestTriangle(*tris, parallel_from) == tree);
    for (int q = 0; q < 300; ++q) {
      const double scale = q % 3 == 0 ? 1.0 : q % 3 == 1 ? 1e3 : 1e-4;
      const Vec3 p{scale * unit(random), scale * unit(random), scale * unit(random)};
      const auto [d2, triangle] = tree.nearest(p, std::numeric_limits<double>::infinity(), 0);
      ASSERT_LT(triangle, tris->size());
      EXPECT_EQ(d2, nearest_by_brute_force(*tris, p)) << "triangles " << tris->size() << ", query " << q;
      // The triangle it names is at that distance.
      EXPECT_EQ(ClosestTriangle({(*tris)[triangle]}).nearest(p, std::numeric_limits<double>::infinity(), 0).first, d2);
    }
  }
}

// The squared distance from p to segment ab, written without the triangle's region tests.
double segment_distance2(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double t = dot(ab, ab) > 0 ? std::clamp(dot(p - a, ab) / dot(ab, ab), 0.0, 1.0) : 0.0;
  return distance2(p, a + ab * t);
}

TEST(TriangleClosestPoint, ATriangleWhoseCornersMeetOrLineUpIsItsSegmentOrPoint) {
  // A soup's triangles after repair: two corners copies of one vertex (a segment, in each of the three orders), all
  // three on one spot, three distinct corners on one line, and a sliver 1e-9 wide. Each is its longest segment
  // (or its point); before the region tests skipped zero-length edges, a segment gave NaN (0/0) wherever p lay
  // beyond its zero-length edge, and the bake's lattice missed it (tests/fuzz/regressions/mesh-stl-soup-*).
  std::mt19937 random(11);
  std::uniform_real_distribution<double> unit(-1, 1);
  const Vec3 a{0.1, -0.2, 0.3}, c{0.9, 0.4, -0.5}, mid = a + (c - a) * 0.3;
  const Vec3 off{1e-9, -2e-9, 0};
  const std::vector<std::array<Vec3, 3>> triangles = {{a, a, c},   {a, c, a},   {c, a, a},        {a, a, a},
                                                      {a, mid, c}, {mid, c, a}, {a, mid + off, c}};
  for (const auto& t : triangles)
    for (int q = 0; q < 2000; ++q) {
      const Vec3 p{2 * unit(random), 2 * unit(random), 2 * unit(random)};
      Feature feature;
      const Vec3 x = closest_on_triangle(p, t[0], t[1], t[2], feature);
      const double expected = std::min(
          {segment_distance2(p, t[0], t[1]), segment_distance2(p, t[1], t[2]), segment_distance2(p, t[2], t[0])});
      ASSERT_TRUE(std::isfinite(x[0]) && std::isfinite(x[1]) && std::isfinite(x[2])) << "query " << q;
      EXPECT_NEAR(distance2(p, x), expected, 1e-12)
          << "triangle " << (&t - triangles.data()) << " query " << q << " feature " << int(feature);
    }
  // A proper triangle keeps Ericson's answer: on the face, the point's offset is along the normal.
  const Vec3 b{0.5, 0.9, 0.1}, n = normalized(cross(b - a, c - a));
  Feature feature;
  const Vec3 centre = (a + b + c) * (1.0 / 3);
  const Vec3 x = closest_on_triangle(centre + n * 0.25, a, b, c, feature);
  EXPECT_EQ(feature, Feature::kFace);
  EXPECT_NEAR(distance2(x, centre), 0.0, 1e-24);
}

TEST(Bake, BunnyDistancesMatchExactSurface) {
  Settings options;
  options.voxelmap.resolution = 128;
  options.point_shell.points = 35000;
  BuildReport report;
  const Asset asset = build_asset(kMeshes + "/bunny00.off", options, report);
  EXPECT_TRUE(report.repair.closed);
  EXPECT_TRUE(validate_asset(asset).empty());

  RepairReport again;
  const TriangleMesh mesh = repair_mesh(import_mesh(kMeshes + "/bunny00.off"), again, false);
  const ExactSurface surface(mesh);
  const ErrorStats s = compare_distances(
      asset.voxelmap, [&](const Vec3& p) { return surface.inside(p) ? -surface.distance(p) : surface.distance(p); },
      12000, 1e-9);
  expect_accurate(s, "bunny res 128");
  EXPECT_EQ(full_errors(asset), std::vector<std::string>());
  // Spec §3.1: every voxel within (band - 1/2) voxels of the surface has its distance stored.
  {
    const Voxelmap& vm = asset.voxelmap;
    std::mt19937_64 rng(11);
    size_t missing = 0, checked = 0;
    for (int n = 0; n < 200000; ++n) {
      const auto [i, j, k] = random_voxel(vm, rng);
      if (vm.voxel(i, j, k).stored) continue;
      ++checked;
      const double exact = surface.distance(vm.voxel_center(i, j, k));
      if (exact <= (vm.distance_band - 0.5) * vm.voxel_size) {
        ++missing;
        std::printf("not stored: voxel (%u, %u, %u) at %.4f voxels from the surface\n", i, j, k, exact / vm.voxel_size);
      }
    }
    EXPECT_GT(checked, 100000u);
    EXPECT_EQ(missing, 0u);
  }
  // Spec §3.3: every lattice value is the exact unsigned distance at its voxel, or above it by at most its stated
  // error; and the sweeps carry nearest triangles until they settle, so that far from the surface it is nearer
  // the exact distance than the stated tenth of it (at this coarse resolution, lattice points 8 voxels apart on
  // a 128-voxel bunny, propagation is at its roughest; at 1024 it is within 0.9 voxel, one round 41).
  {
    const Voxelmap& vm = asset.voxelmap;
    const auto l = vm.lattice_dims();
    const double h = vm.voxel_size;
    double worst_over = 0, farthest = 0, far_over = 0;
    size_t below = 0, beyond_bound = 0, far = 0;
    for (uint32_t c = 0; c < l[2]; ++c)
      for (uint32_t b = 0; b < l[1]; ++b)
        for (uint32_t a = 0; a < l[0]; ++a) {
          const double u = surface.distance(vm.lattice_point_center(a, b, c));
          const double value = vm.lattice[vm.lattice_index(a, b, c)];
          below += value < u * (1 - 1e-6);
          beyond_bound += value > (1 + vm.lattice_error[1]) * u + vm.lattice_error[0] * h;
          worst_over = std::max(worst_over, (value - u) / h);
          farthest = std::max(farthest, u / h);
          if (u > 16 * h) {  // beyond the exact reach
            ++far;
            far_over += (value - u) / h;
          }
        }
    std::printf(
        "lattice: %u points, farthest %.1f voxels from the surface, at most %.3f voxel above it; %zu beyond 16 "
        "voxels, %.4f voxel above on average\n",
        l[0] * l[1] * l[2], farthest, worst_over, far, far_over / double(far));
    EXPECT_GT(farthest, 40.0);
    EXPECT_GT(far, 1000u);
    EXPECT_EQ(below, 0u);
    EXPECT_EQ(beyond_bound, 0u);
    EXPECT_LE(worst_over, 2.5);               // measured 1.86; one round of sweeps: 4.30
    EXPECT_LE(far_over / double(far), 0.35);  // measured 0.25; one round: 0.48
  }
  // Spec §3.1: beyond the band an estimate has the voxel's sign and bounds the exact distance both ways
  // (interpolation of an exact lattice: within the position's interpolation bound); on the smooth bunny it is
  // close to it on average.
  {
    const Voxelmap& vm = asset.voxelmap;
    std::mt19937_64 rng(12);
    double worst_over = 0, worst_under = 0, deepest = 0, sum = 0;
    size_t checked = 0, out_of_bound = 0, wrong_sign = 0;
    const double q = 0.5 * vm.estimate_quantum / vm.voxel_size;
    for (int n = 0; n < 400000 && checked < 20000; ++n) {
      const auto [i, j, k] = random_voxel(vm, rng);
      const VoxelValue value = vm.voxel(i, j, k);
      if (value.stored) continue;
      const Vec3 p = vm.voxel_center(i, j, k);
      const double exact = (surface.inside(p) ? -surface.distance(p) : surface.distance(p)) / vm.voxel_size;
      const double m = std::abs(value.distance) / vm.voxel_size, u = std::abs(exact);
      ++checked;
      wrong_sign += (exact < 0) != (value.distance < 0);
      deepest = std::max(deepest, -exact);
      worst_over = std::max(worst_over, m - u);
      worst_under = std::max(worst_under, u - m);
      sum += std::abs(m - u);
      const double B = vm.interpolation_bound(i, j, k);
      out_of_bound += u > m + B + q || u < (m - vm.lattice_error[0]) / (1 + vm.lattice_error[1]) - B - q;
    }
    std::printf(
        "estimates beyond the band: %zu voxels, deepest %.1f voxels, at most %.3f too far from the surface, "
        "%.3f too near, mean error %.3f voxel\n",
        checked, deepest, worst_over, worst_under, sum / double(checked));
    EXPECT_GT(checked, 10000u);
    EXPECT_GT(deepest, 10.0);
    EXPECT_EQ(wrong_sign, 0u);
    EXPECT_EQ(out_of_bound, 0u);
    EXPECT_LE(sum / double(checked), 0.6);  // measured 0.53 at this coarse resolution
  }

  const PointShell& ps = asset.point_shell;
  EXPECT_EQ(ps.size(), 35000u);
  expect_points_on_surface_with_inward_normals(ps, surface, diagonal_of(asset));
  expect_tree_encloses_descendants(ps, 1e-9 * diagonal_of(asset));
  // The seed's coarse shell: some prefix of levels holds roughly 800 points.
  bool coarse_level = false;
  for (uint32_t offset : ps.level_offsets) coarse_level |= offset >= 600 && offset <= 1000;
  EXPECT_TRUE(coarse_level);
  // Mass properties of a closed mesh: the centre of mass lies inside the bounds; inertia is positive.
  for (int a = 0; a < 3; ++a) {
    EXPECT_GT(asset.mass.center_of_mass[a], asset.bounds_min[a]);
    EXPECT_LT(asset.mass.center_of_mass[a], asset.bounds_max[a]);
    EXPECT_GT(asset.mass.inertia[a * 4], 0);
  }
}

// Writes a triangle mesh as OFF, coordinates at full double precision.
std::string write_off(const std::string& path, const TriangleMesh& mesh) {
  std::ofstream off(path);
  off << "OFF\n" << mesh.vertices.size() << " " << mesh.triangles.size() << " 0\n";
  off.precision(17);
  for (const Vec3& p : mesh.vertices) off << p[0] << " " << p[1] << " " << p[2] << "\n";
  for (const auto& t : mesh.triangles) off << "3 " << t[0] << " " << t[1] << " " << t[2] << "\n";
  return path;
}

// A torus (R = 0.3, r = 0.1, finely tessellated) written to OFF: distances have a closed form.
std::string write_torus(const std::string& path, double R, double r, int segments, int rings) {
  TriangleMesh torus;
  const double pi = 3.14159265358979323846;
  for (int s = 0; s < segments; ++s)
    for (int q = 0; q < rings; ++q) {
      const double u = 2 * pi * s / segments, v = 2 * pi * q / rings;
      torus.vertices.push_back(
          {(R + r * std::cos(v)) * std::cos(u), (R + r * std::cos(v)) * std::sin(u), r * std::sin(v)});
    }
  for (int s = 0; s < segments; ++s)
    for (int q = 0; q < rings; ++q) {
      const uint32_t a = uint32_t(s * rings + q), b = uint32_t(((s + 1) % segments) * rings + q),
                     c = uint32_t(((s + 1) % segments) * rings + (q + 1) % rings),
                     d = uint32_t(s * rings + (q + 1) % rings);
      torus.triangles.push_back({a, b, c});
      torus.triangles.push_back({a, c, d});
    }
  return write_off(path, torus);
}

TEST(Bake, AMeshFarFromItsOriginBakesLikeTheSameMeshAtTheOrigin) {
  // Coordinates read in double precision (CGAL's OFF reader; assimp's are floats): the bunny moved 2 km bakes
  // into the same distances, signs and normals as at the origin (through floats: 0.02 voxel, 850 wrong signs,
  // normals 18.6 degrees off).
  RepairReport unused;
  TriangleMesh far = import_mesh(kMeshes + "/bunny00.off");
  for (Vec3& v : far.vertices) v[0] += 2000.0;
  const std::string far_path = (std::filesystem::temp_directory_path() / "voxfmt_far_bunny.off").string();
  write_off(far_path, far);
  Settings options;
  options.voxelmap.resolution = 96;
  options.point_shell.points = 3000;
  BuildReport report_near, report_far;
  const Asset near_asset = build_asset(kMeshes + "/bunny00.off", options, report_near);
  const Asset far_asset = build_asset(far_path, options, report_far);
  std::filesystem::remove(far_path);
  const Voxelmap &a = near_asset.voxelmap, &b = far_asset.voxelmap;
  ASSERT_EQ(a.dims, b.dims);
  EXPECT_NEAR(b.origin[0] - a.origin[0], 2000.0, 1e-9);
  size_t wrong_sign = 0, layer_differs = 0;
  double worst = 0;
  for (uint32_t k = 0; k < a.dims[2]; ++k)
    for (uint32_t j = 0; j < a.dims[1]; ++j)
      for (uint32_t i = 0; i < a.dims[0]; ++i) {
        layer_differs += a.layer(i, j, k) != b.layer(i, j, k);
        const VoxelValue va = a.voxel(i, j, k), vb = b.voxel(i, j, k);
        if (!va.stored || !vb.stored) continue;
        worst = std::max(worst, std::abs(va.distance - vb.distance) / a.voxel_size);
        wrong_sign += va.distance != 0 && vb.distance != 0 && (va.distance < 0) != (vb.distance < 0);
      }
  double worst_angle = 0;
  ASSERT_EQ(near_asset.point_shell.size(), far_asset.point_shell.size());
  for (size_t i = 0; i < near_asset.point_shell.size(); ++i) {
    const Vec3f &n = near_asset.point_shell.normals[i], &m = far_asset.point_shell.normals[i];
    const double c = std::clamp(double(n[0]) * m[0] + double(n[1]) * m[1] + double(n[2]) * m[2], -1.0, 1.0);
    worst_angle = std::max(worst_angle, std::acos(c) * 180 / 3.14159265358979323846);
  }
  std::printf(
      "2 km away: distances differ by at most %.2e voxel, %zu wrong signs, %zu layers differ, normals "
      "%.2e degrees\n",
      worst, wrong_sign, layer_differs, worst_angle);
  EXPECT_LT(worst, 1e-3);
  EXPECT_EQ(wrong_sign, 0u);
  EXPECT_LE(layer_differs, 10u);  // exact ties can round either way
  EXPECT_LT(worst_angle, 0.1);    // measured 0.024 degrees
}

TEST(Bake, TorusDistancesMatchClosedForm) {
  const double R = 0.3, r = 0.1;
  const std::string file = write_torus(::testing::TempDir() + "/torus.off", R, r, 720, 240);
  Settings options;
  options.voxelmap.resolution = 160;
  options.point_shell.points = 5000;
  BuildReport report;
  const Asset asset = build_asset(file, options, report);
  EXPECT_TRUE(report.repair.closed);
  // The tessellation is within 1e-4 of the ideal torus (sagitta), i.e. < 0.03 voxel here.
  const ErrorStats s = compare_distances(
      asset.voxelmap, [&](const Vec3& p) { return std::hypot(std::hypot(p[0], p[1]) - R, p[2]) - r; }, 20000,
      2e-5 /* > sagitta of the 720 x 240 tessellation, ~9e-6 m */);
  // Against the ideal torus the tessellation's sagitta (~9e-6 m, 0.002 voxel) dominates the error.
  expect_accurate(s, "torus res 160", 0.01);
  EXPECT_EQ(full_errors(asset), std::vector<std::string>());
  // Deep layers approximate the true depth: the tube centre is r deep.
  const Voxelmap& vm = asset.voxelmap;
  const double i = (R - vm.origin[0]) / vm.voxel_size, j = (0 - vm.origin[1]) / vm.voxel_size,
               k = (0 - vm.origin[2]) / vm.voxel_size;
  EXPECT_NEAR(vm.layer(uint32_t(std::lround(i)), uint32_t(std::lround(j)), uint32_t(std::lround(k))) * vm.voxel_size, r,
              1.5 * vm.voxel_size);
  // Analytic volume 2 pi^2 R r^2, within the tessellation's shrinkage.
  EXPECT_NEAR(asset.mass.volume, 2 * M_PI * M_PI * R * r * r, 2e-3 * asset.mass.volume);
  expect_tree_encloses_descendants(asset.point_shell, 1e-9);
}

TEST(Bake, BoxFacesOnVoxelBoundariesKeepLayersConsistent) {
  // Regression (review): faces exactly on voxel boundaries give distances of k + 1/2 voxels; with an inexact
  // voxel size (resolution 100) band layers and chamfer layers used to round apart by 2.
  const std::string file = ::testing::TempDir() + "/box.off";
  std::ofstream(file) << "OFF\n8 12 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n1 0 1\n1 1 1\n0 1 1\n"
                         "3 0 2 1\n3 0 3 2\n3 4 5 6\n3 4 6 7\n3 0 1 5\n3 0 5 4\n3 1 2 6\n3 1 6 5\n3 2 3 7\n3 2 7 6\n"
                         "3 3 0 4\n3 3 4 7\n";
  for (uint32_t resolution : {25u, 50u, 100u}) {
    Settings options;
    options.voxelmap.resolution = resolution;
    options.point_shell.points = 500;
    BuildReport report;
    const Asset asset = build_asset(file, options, report);
    ASSERT_TRUE(report.repair.closed);
    EXPECT_EQ(full_errors(asset), std::vector<std::string>()) << resolution;
    EXPECT_NEAR(asset.mass.volume, 1.0, 1e-12);
  }
}

// Repair on small hand-made soups: what it reports and how it orients.
TriangleMesh tetrahedron(const Vec3& offset, bool flip_one_face) {
  TriangleMesh m;
  for (const Vec3& v : {Vec3{0, 0, 0}, Vec3{1, 0, 0}, Vec3{0, 1, 0}, Vec3{0, 0, 1}})
    m.vertices.push_back({v[0] + offset[0], v[1] + offset[1], v[2] + offset[2]});
  m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};  // outward
  if (flip_one_face) std::swap(m.triangles[3][1], m.triangles[3][2]);
  return m;
}

TriangleMesh append(TriangleMesh a, const TriangleMesh& b) {
  const uint32_t base = uint32_t(a.vertices.size());
  a.vertices.insert(a.vertices.end(), b.vertices.begin(), b.vertices.end());
  for (auto t : b.triangles) a.triangles.push_back({t[0] + base, t[1] + base, t[2] + base});
  return a;
}

bool has_warning(const RepairReport& r, const std::string& code) {
  return std::any_of(r.warnings.begin(), r.warnings.end(), [&](const BuildWarning& w) { return w.code == code; });
}

TEST(Repair, KeepsAnOrientedManifoldAndOrientsAFlippedFace) {
  for (bool flipped : {false, true}) {
    RepairReport report;
    const TriangleMesh out = repair_mesh(tetrahedron({0, 0, 0}, flipped), report);
    EXPECT_TRUE(report.closed);
    EXPECT_TRUE(report.consistently_oriented);
    EXPECT_EQ(report.non_manifold_vertices, 0u);
    EXPECT_TRUE(report.warnings.empty());
    EXPECT_NEAR(compute_mass_properties(out).volume, 1.0 / 6.0, 1e-12) << "outward after repair";
  }
}

TEST(Repair, ReportsAPinchedVertexAndSplitsIt) {
  // Two tetrahedra touching at one vertex (the second is the first mirrored through the origin; the soup's two
  // copies of the origin are merged): every edge is manifold, that vertex is not.
  TriangleMesh mirrored = tetrahedron({0, 0, 0}, false);
  for (Vec3& v : mirrored.vertices) v = {-v[0], -v[1], -v[2]};
  for (auto& t : mirrored.triangles) std::swap(t[1], t[2]);  // a mirror turns faces inside out
  RepairReport report;
  const TriangleMesh out = repair_mesh(append(tetrahedron({0, 0, 0}, false), mirrored), report);
  EXPECT_EQ(report.merged_vertices, 1u);
  EXPECT_FALSE(report.consistently_oriented);
  EXPECT_EQ(report.non_manifold_vertices, 1u);
  EXPECT_TRUE(has_warning(report, "NON_MANIFOLD"));
  EXPECT_EQ(report.components, 2u);
  EXPECT_EQ(out.vertices.size(), 8u);
  EXPECT_TRUE(report.closed);
}

TEST(Repair, ASoupRepairThatDoesNotFinishIsStoppedAsRepairFailed) {
  // CGAL's soup orientation has looped on a fuzzed mesh: the soup steps run in a child stopped at their time limit.
  // A limit no repair can meet stands in for such a mesh (none is known since that one was fixed).
  RepairReport report;
  const TriangleMesh bunny = import_mesh(kMeshes + "/bunny00.off");
  try {
    repair_mesh(bunny, report, false, 1e-6);
    ADD_FAILURE() << "the repair was not stopped";
  } catch (const BakeError& e) {
    EXPECT_EQ(e.code(), IssueCode::RepairFailed) << e.what();
    EXPECT_NE(std::string(e.what()).find("did not finish"), std::string::npos) << e.what();
  }
  // The same mesh with the default limit repairs.
  RepairReport again;
  EXPECT_EQ(repair_mesh(bunny, again, false).triangles.size(), bunny.triangles.size());
}

TEST(Repair, ReportsAnEdgeSharedByThreeFaces) {
  TriangleMesh fin = tetrahedron({0, 0, 0}, false);
  fin.vertices.push_back({1, 1, -1});
  fin.triangles.push_back({0, 1, 4});  // a third face on edge 0-1
  RepairReport report;
  repair_mesh(fin, report);
  EXPECT_FALSE(report.consistently_oriented);
  EXPECT_TRUE(has_warning(report, "NON_MANIFOLD"));
  EXPECT_TRUE(has_warning(report, "OPEN_BORDER"));
}

TEST(Bake, SameInputSameDatasets) {
  Settings options;
  options.voxelmap.resolution = 48;
  options.point_shell.points = 3000;
  BuildReport r1, r2;
  const Asset a = build_asset(kMeshes + "/bunny00.off", options, r1);
  const Asset b = build_asset(kMeshes + "/bunny00.off", options, r2);
  EXPECT_EQ(a.voxelmap.bricks, b.voxelmap.bricks);
  EXPECT_EQ(a.voxelmap.brick_values, b.voxelmap.brick_values);
  ASSERT_EQ(a.voxelmap.lattice.size(), b.voxelmap.lattice.size());
  EXPECT_EQ(0, std::memcmp(a.voxelmap.lattice.data(), b.voxelmap.lattice.data(), a.voxelmap.lattice.size() * 4));
  EXPECT_EQ(a.point_shell.points, b.point_shell.points);
  EXPECT_EQ(a.point_shell.normals, b.point_shell.normals);
  EXPECT_EQ(a.point_shell.sphere_centers, b.point_shell.sphere_centers);
  EXPECT_EQ(a.point_shell.sphere_radii, b.point_shell.sphere_radii);
  EXPECT_EQ(a.point_shell.child_begin, b.point_shell.child_begin);
  EXPECT_EQ(a.point_shell.level_offsets, b.point_shell.level_offsets);
  EXPECT_EQ(a.mass.inertia, b.mass.inertia);
}

// An open surface's mass properties are summed over the voxelmap in parallel: in the same order on any number of
// threads, so that a bake repeats bit for bit.
TEST(Bake, WindingMassIsTheSameOnAnyNumberOfThreads) {
  Settings options;
  options.voxelmap.resolution = 96;
  options.point_shell.points = 500;
  std::vector<MassProperties> masses;
  for (unsigned threads : {1u, 2u, 3u}) {
    options.threads = threads;
    BuildReport report;
    masses.push_back(build_asset(kMeshes + "/horizons.off", options, report).mass);
    ASSERT_FALSE(report.repair.closed);
  }
  for (size_t n = 1; n < masses.size(); ++n) {
    EXPECT_EQ(masses[n].volume, masses[0].volume);
    EXPECT_EQ(masses[n].center_of_mass, masses[0].center_of_mass);
    EXPECT_EQ(masses[n].inertia, masses[0].inertia);
  }
}

// Every timing and every progress report names a stage of kBakeStages, in the list's order; each stage of the whole
// bake is announced once with its share, rising to "done" at 1; sub-stages fit within the stage they are part of.
TEST(Bake, TimingsAndProgressFollowTheStageList) {
  Settings options;
  options.voxelmap.resolution = 48;
  options.point_shell.points = 2000;
  std::vector<std::pair<std::string, double>> reported;
  const std::string out = (std::filesystem::temp_directory_path() / "voxfmt_stage_list.vox.h5").string();
  const Result<Summary> summary = bake_to_file(
      kMeshes + "/bunny00.off", out, options,
      [&](std::string_view stage, double fraction) { reported.emplace_back(std::string(stage), fraction); });
  std::filesystem::remove(out);
  ASSERT_TRUE(summary) << summary.error().describe();
  std::vector<std::pair<std::string, double>> expected;
  for (const BakeStageInfo& info : kBakeStages)
    if (info.progress_start >= 0) expected.emplace_back(info.name, info.progress_start);
  expected.emplace_back("done", 1.0);
  // Each stage's first report is its start; the voxelmap's stage may be told again as it goes (a long one is:
  // ALongVoxelmapTellsItsProgress), rising and below the next stage's start.
  std::vector<std::pair<std::string, double>> starts;
  const double from = stage_info(BakeStage::VoxelmapAndPointShell).progress_start;
  const double to = stage_info(BakeStage::Assemble).progress_start;
  for (size_t n = 0; n < reported.size(); ++n) {
    if (n > 0) {
      EXPECT_GE(reported[n].second, reported[n - 1].second) << n;
    }
    if (starts.empty() || starts.back().first != reported[n].first) {
      starts.push_back(reported[n]);
      continue;
    }
    EXPECT_EQ(reported[n].first, stage_name(BakeStage::VoxelmapAndPointShell));
    EXPECT_GT(reported[n].second, from);
    EXPECT_LT(reported[n].second, to);
  }
  EXPECT_EQ(starts, expected);
  std::vector<std::string> names;
  for (const StageTiming& t : summary->timings) names.push_back(t.stage);
  std::vector<std::string> all;
  for (const BakeStageInfo& info : kBakeStages) all.push_back(info.name);
  EXPECT_EQ(names, all);  // a closed mesh runs every stage once
  auto seconds = [&](BakeStage stage) {
    for (const StageTiming& t : summary->timings)
      if (t.stage == stage_name(stage)) return t.seconds;
    return -1.0;
  };
  for (const BakeStageInfo& info : kBakeStages) {
    EXPECT_GE(seconds(info.stage), 0) << info.name;
    if (info.within != info.stage) {
      EXPECT_LE(seconds(info.stage), seconds(info.within) + 1e-3) << info.name;
    }
  }
}

// A bake of seconds tells the voxelmap's progress as it goes, at most every 0.2 s, from its band on (a bar would sit
// at one figure for minutes at 4096); a callback that throws there, while the band's rows run on every thread,
// stops the bake with a code and no file.
TEST(Bake, ALongVoxelmapTellsItsProgress) {
  Settings options;
  options.voxelmap.resolution = 512;
  options.point_shell.points = 2000;
  const std::string mesh = kMeshes + "/bunny00.off";
  const std::string out = (std::filesystem::temp_directory_path() / "voxfmt_long_voxelmap.vox.h5").string();
  const std::string stage = stage_name(BakeStage::VoxelmapAndPointShell);
  const double from = stage_info(BakeStage::VoxelmapAndPointShell).progress_start;
  const double span = stage_info(BakeStage::Assemble).progress_start - from;
  // The band's part of the stage (voxelize.cpp's shares), past its fixed start.
  const auto in_band = [&](double f) { return f > from + 0.06 * span + 1e-9 && f < from + 0.45 * span; };
  std::vector<std::pair<double, std::chrono::steady_clock::time_point>> told;
  const Result<Summary> summary = bake_to_file(mesh, out, options, [&](std::string_view at, double fraction) {
    if (at == stage && fraction > from) told.emplace_back(fraction, std::chrono::steady_clock::now());
  });
  ASSERT_TRUE(summary) << summary.error().describe();
  ASSERT_GE(told.size(), 2u);
  for (size_t n = 1; n < told.size(); ++n)
    EXPECT_GE(std::chrono::duration<double>(told[n].second - told[n - 1].second).count(), 0.199) << n;
  EXPECT_TRUE(std::any_of(told.begin(), told.end(), [&](const auto& t) { return in_band(t.first); }));

  std::filesystem::remove(out);
  const Result<Summary> stopped = bake_to_file(mesh, out, options, [&](std::string_view at, double fraction) {
    if (at == stage && in_band(fraction)) throw std::runtime_error("cancelled in the band");
  });
  ASSERT_FALSE(stopped);
  EXPECT_EQ(stopped.error().code, IssueCode::Internal);
  EXPECT_NE(stopped.error().message.find("cancelled in the band"), std::string::npos) << stopped.error().message;
  EXPECT_FALSE(std::filesystem::exists(out));
}

// A caller's mistakes through the library (not the CLI, which refuses most before): coded errors, no file left.
TEST(Bake, ACallersMistakesAreCodedErrorsAndLeaveNoFile) {
  const std::string cube = kMeshes + "/cube.off";
  Settings small;
  small.voxelmap.resolution = 16;
  small.point_shell.points = 300;
  small.threads = 1;
  Settings threads = small;  // 2^32 - 1 threads aborted on bad_alloc inside TBB
  threads.threads = std::numeric_limits<unsigned>::max();
  EXPECT_EQ(check_settings(threads).error().code, IssueCode::BadOption);
  EXPECT_EQ(bake_mesh(cube, threads).error().code, IssueCode::BadOption);
  for (const double limit : {std::nan(""), -1.0, double(INFINITY)}) {
    Settings timed = small;
    timed.import.time_limit_s = limit;
    EXPECT_EQ(check_settings(timed).error().code, IssueCode::BadOption) << limit;
  }
  // A point spacing's count is judged before sampling, as a point count is (it took 5x the limit).
  Settings dense = small;
  dense.point_shell.point_spacing = 1e-3;  // ~8 million points on the cube's 6 m^2
  dense.voxelmap.max_memory_bytes = uint64_t(64) << 20;
  EXPECT_EQ(bake_mesh(cube, dense).error().code, IssueCode::OutOfMemory);

  // A progress callback that throws stops the bake at any stage with a code: no file up to "write"; at "done" the
  // file is in place and stays.
  const std::string out = (std::filesystem::temp_directory_path() / "voxfmt_thrown_progress.vox.h5").string();
  for (const char* stage : {"import", "write", "done"}) {
    for (const bool standard : {true, false}) {
      std::filesystem::remove(out);
      const auto thrower = [&](std::string_view at, double) {
        if (at != stage) return;
        if (standard) throw std::runtime_error("cancelled");
        throw 42;
      };
      const Result<Summary> stopped = bake_to_file(cube, out, small, thrower);
      ASSERT_FALSE(stopped) << stage;
      EXPECT_EQ(stopped.error().code, IssueCode::Internal) << stage;
      EXPECT_EQ(std::filesystem::exists(out), std::string_view(stage) == "done") << stage;
    }
  }
  // bake_mesh ends its progress at "done" too.
  std::vector<std::string> stages;
  ASSERT_TRUE(bake_mesh(cube, small, [&](std::string_view at, double) { stages.emplace_back(at); }));
  ASSERT_FALSE(stages.empty());
  EXPECT_EQ(stages.back(), "done");

  // Only a regular file has a hash: a folder read as empty, a pipe never ended.
  const std::filesystem::path folder = std::filesystem::temp_directory_path() / "voxfmt_hash_folder";
  std::filesystem::create_directories(folder);
  EXPECT_EQ(sha256_file(folder.string()).error().code, IssueCode::InputNotFound);
  const std::string fifo = (folder / "pipe").string();
  std::filesystem::remove(fifo);
  ASSERT_EQ(mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_EQ(sha256_file(fifo).error().code, IssueCode::InputNotFound);
  std::filesystem::remove_all(folder);
  EXPECT_EQ(sha256_file(cube).value().size(), 64u);
}

TEST(Bake, PointsAreEvenlySpread) {
  // Poisson-disk: no two points closer than the sampling radius; far more even than uniform random.
  RepairReport report;
  const TriangleMesh mesh = repair_mesh(import_mesh(kMeshes + "/bunny00.off"), report, false);
  PointShellSettings options;
  options.points = 4000;
  const PointShell ps = sample_point_shell(mesh, options);
  ASSERT_EQ(ps.size(), 4000u);
  double nearest_min = 1e300, nearest_mean = 0;
  for (size_t a = 0; a < ps.size(); ++a) {
    double best = 1e300;
    for (size_t b = 0; b < ps.size(); ++b)
      if (a != b) {
        const Vec3 &p = ps.points[a], &q = ps.points[b];
        best = std::min(best,
                        (p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) + (p[2] - q[2]) * (p[2] - q[2]));
      }
    nearest_min = std::min(nearest_min, std::sqrt(best));
    nearest_mean += std::sqrt(best) / double(ps.size());
  }
  // Uniform random sampling gives a minimum nearest-neighbour distance near 0; Poisson-disk keeps it a large
  // fraction of the mean.
  EXPECT_GT(nearest_min, 0.5 * nearest_mean);
}

TEST(Bake, WindingNumberAgreesWithExactInsideTest) {
  RepairReport report;
  const TriangleMesh mesh = repair_mesh(import_mesh(kMeshes + "/bunny00.off"), report, false);
  const ExactSurface surface(mesh);
  const WindingNumber winding(mesh);
  Vec3 lo = mesh.vertices[0], hi = lo;
  for (const Vec3& v : mesh.vertices)
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], v[a]), hi[a] = std::max(hi[a], v[a]);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> unit(0, 1);
  size_t disagreements = 0, tested = 0;
  for (int n = 0; n < 3000; ++n) {
    Vec3 p;
    for (int a = 0; a < 3; ++a) p[a] = lo[a] + (hi[a] - lo[a]) * (1.2 * unit(rng) - 0.1);
    if (surface.distance(p) < 1e-3 * (hi[0] - lo[0])) continue;  // the approximation is for points off the surface
    ++tested;
    disagreements += (winding(p) >= 0.5) != surface.inside(p);
  }
  EXPECT_GT(tested, 2500u);
  EXPECT_EQ(disagreements, 0u);
}

// A UV sphere appended to `soup` (outward oriented, poles as single vertices); `open_rings` > 0 leaves that
// many rings around the north pole out (a hole).
void append_sphere(TriangleMesh& soup, const Vec3& centre, double radius, int segments, int rings, int open_rings = 0) {
  const double pi = 3.14159265358979323846;
  const uint32_t base = uint32_t(soup.vertices.size());
  soup.vertices.push_back({centre[0], centre[1], centre[2] + radius});
  for (int q = 1; q < rings; ++q)
    for (int s = 0; s < segments; ++s) {
      const double v = pi * q / rings, u = 2 * pi * s / segments;
      soup.vertices.push_back({centre[0] + radius * std::sin(v) * std::cos(u),
                               centre[1] + radius * std::sin(v) * std::sin(u), centre[2] + radius * std::cos(v)});
    }
  soup.vertices.push_back({centre[0], centre[1], centre[2] - radius});
  const uint32_t south = uint32_t(soup.vertices.size() - 1);
  auto ring = [&](int q, int s) { return base + 1 + uint32_t((q - 1) * segments + (s % segments)); };
  for (int s = 0; s < segments; ++s) {
    if (open_rings == 0) soup.triangles.push_back({base, ring(1, s), ring(1, s + 1)});
    soup.triangles.push_back({south, ring(rings - 1, s + 1), ring(rings - 1, s)});
    for (int q = std::max(1, open_rings); q + 1 < rings; ++q) {
      soup.triangles.push_back({ring(q, s), ring(q + 1, s), ring(q + 1, s + 1)});
      soup.triangles.push_back({ring(q, s), ring(q + 1, s + 1), ring(q, s + 1)});
    }
  }
}

TEST(Bake, OverlappingPartsGetTheExactWindingSignInTheBand) {
  // Overlapping parts, some open (a robot hand's fingers and palm are modelled like this): the winding number
  // is 2 where parts overlap and fractional near the holes, where band voxels see values close to 1/2. Every
  // band voxel's sign must be the exact winding number's (>= 1/2 inside), however close the fast
  // approximation comes to 1/2.
  TriangleMesh soup;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> unit(-1, 1);
  for (int part = 0; part < 8; ++part)
    append_sphere(soup, {0.3 * unit(rng), 0.3 * unit(rng), 0.3 * unit(rng)}, 0.15 + 0.05 * unit(rng), 24, 12,
                  part % 2 == 0 ? 3 : 0);
  VoxelmapSettings options;
  options.resolution = 40;
  options.winding_number_sign = true;
  const Voxelmap vm = build_voxelmap(soup, options);
  const WindingNumber winding(soup);
  size_t band = 0, near_half = 0, wrong = 0;
  for (const StoredVoxel& v : stored_voxels(vm)) {
    if (v.d == 0) continue;
    ++band;
    const Vec3 p = vm.voxel_center(v.i, v.j, v.k);
    const bool near = std::abs(winding(p) - 0.5) < 0.1;  // where the bake refines
    if (!near && rng() % 8 != 0) continue;               // and a sample of the rest (exact sums are slow)
    near_half += near;
    const double exact = winding.evaluate(p, std::numeric_limits<double>::infinity());
    wrong += (exact >= 0.5) != (v.d < 0);
  }
  std::printf("%zu band voxels, %zu with the fast winding number within 0.1 of 1/2, %zu with the wrong sign\n", band,
              near_half, wrong);
  EXPECT_GT(band, 5000u);
  EXPECT_GT(near_half, 20u);
  EXPECT_EQ(wrong, 0u);
}

TEST(Bake, OpenCubeIsFilledByWindingNumber) {
  // CGAL's open_cube.off lacks a face: flood fills leak, the winding number gives the solid cube.
  Settings options;
  options.voxelmap.resolution = 40;
  options.voxelmap.margin = 4;
  options.point_shell.points = 500;
  BuildReport report;
  const Asset asset = build_asset(kMeshes + "/open_cube.off", options, report);
  ASSERT_FALSE(report.repair.closed);
  bool warned = false;
  for (const BuildWarning& w : asset.provenance.build_warnings) warned |= w.code == "OPEN_BORDER";
  EXPECT_TRUE(warned);
  const Voxelmap& vm = asset.voxelmap;
  std::vector<int16_t> layers(vm.voxel_count());
  vm.read_block({0, 0, 0}, vm.dims, nullptr, layers.data());
  size_t inside = 0;
  for (int16_t layer : layers) inside += layer > 0;
  // The cube spans 40 voxels per axis; voxel centres on its missing face's plane count as either side.
  EXPECT_GE(inside, 40u * 40 * 39);
  EXPECT_LE(inside, 40u * 40 * 41);
  // Signs may change across the missing face without a surface between (spec §3: the sign rule holds for closed
  // surfaces only): every other rule holds.
  EXPECT_EQ(full_errors(asset), std::vector<std::string>());
}

// ---- the winding rule's exact side of 1/2 (BoundaryWinding): open, non-manifold, self-intersecting parts

// An axis-aligned box of 12 triangles, outward, without the faces named in `omit` ("-x", "+y", ...), leaning by
// `lean` radians about z around its bottom.
void append_box(TriangleMesh& soup, const Vec3& centre, const Vec3& half, const std::string& omit = "",
                double lean = 0) {
  const uint32_t base = uint32_t(soup.vertices.size());
  const double c = std::cos(lean), s = std::sin(lean), bottom = centre[1] - half[1];
  for (int n = 0; n < 8; ++n) {
    const double x = (n & 1 ? 1 : -1) * half[0], y = centre[1] + (n & 2 ? 1 : -1) * half[1] - bottom;
    soup.vertices.push_back(
        {centre[0] + c * x - s * y, bottom + s * x + c * y, centre[2] + (n & 4 ? 1 : -1) * half[2]});
  }
  const struct {
    const char* name;
    uint32_t q[4];  // counter-clockwise seen from outside
  } faces[6] = {{"-x", {0, 4, 6, 2}}, {"+x", {1, 3, 7, 5}}, {"-y", {0, 1, 5, 4}},
                {"+y", {2, 6, 7, 3}}, {"-z", {0, 2, 3, 1}}, {"+z", {4, 5, 7, 6}}};
  for (const auto& f : faces) {
    if (omit.find(f.name) != std::string::npos) continue;
    soup.triangles.push_back({base + f.q[0], base + f.q[1], base + f.q[2]});
    soup.triangles.push_back({base + f.q[0], base + f.q[2], base + f.q[3]});
  }
}

// Thin, open, self-intersecting parts like a CAD export of a bookshelf: boards through each other, books without
// a top leaning into their neighbours and sunk into their board, two books face to face on one plane, boards
// sharing an edge (non-manifold), an open sheet, and overlapping open spheres.
TriangleMesh broken_parts() {
  TriangleMesh soup;
  for (int i = 0; i < 3; ++i) append_box(soup, {0.5 * i, 0.5, 0.15}, {0.01, 0.5, 0.15}, "+z");  // open channels
  for (int j = 0; j < 3; ++j) append_box(soup, {0.5, 0.05 + 0.4 * j, 0.15}, {0.52, 0.01, 0.14}, "-x+x");
  double x = 0.03;
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> unit(0, 1);
  for (int book = 0; book < 14; ++book) {
    const double thick = 0.02 + 0.03 * unit(rng), tall = 0.15 + 0.15 * unit(rng);
    const bool twin = book % 5 == 1;  // face to face with the previous book, upright
    append_box(soup, {x + thick / 2, 0.06 - 0.004 + tall / 2, 0.12}, {thick / 2, tall / 2, 0.09}, "+y",
               twin ? 0.0 : 0.15 * (unit(rng) - 0.5));
    x += thick + (twin || book % 5 == 0 ? 0.0 : -0.003);
  }
  append_box(soup, {0.5, 0.5, 0.0}, {0.5, 0.5, 0.0}, "-x+x-y+y-z");  // the back: one open sheet
  append_box(soup, {0.25, 0.85, 0.15}, {0.25, 0.01, 0.14});          // a board on the top edge of another
  append_box(soup, {0.75, 0.85 - 0.02, 0.15}, {0.25, 0.01, 0.14});
  for (int n = 0; n < 3; ++n) append_sphere(soup, {0.7 + 0.08 * n, 0.65, 0.15}, 0.07, 12, 8, n % 2 ? 2 : 0);
  return soup;
}

// Distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
double triangle_distance(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return length(ap);
  const Vec3 bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return length(bp);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return length(p - (a + ab * (d1 / (d1 - d3))));
  const Vec3 cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return length(cp);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return length(p - (a + ac * (d2 / (d2 - d6))));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return length(p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))));
  const double denom = 1 / (va + vb + vc);
  return length(p - (a + ab * (vb * denom) + ac * (vc * denom)));
}

// The winding number as the bake takes it apart: the crossings of the ray from q towards -x with the surface and
// with the fans (by brute force here; the bake sorts them per row), plus every cap.
double boundary_form(const TriangleMesh& mesh, const BoundaryWinding& boundary, const Vec3& q) {
  int32_t count = 0;
  auto cross_if = [&](const Vec3& a, const Vec3& b, const Vec3& c, int32_t multiplicity) {
    LineCrossing x;
    if (!BoundaryWinding::line_crossing(a, b, c, q[1], q[2], x)) return;
    const bool past = x.x + x.slack < q[0]   ? true
                      : x.x - x.slack > q[0] ? false
                                             : BoundaryWinding::past_plane(a, b, c, q);
    if (past) count += x.step * multiplicity;
  };
  for (const auto& t : mesh.triangles) cross_if(mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]], 1);
  std::vector<uint32_t> fans;
  boundary.row_fan_triangles(int64_t(q[1]) / 8, int64_t(q[2]) / 8, fans);
  for (const uint32_t f : fans) {
    Vec3 a, b, c;
    int32_t multiplicity;
    boundary.fan_triangle(f, a, b, c, multiplicity);
    cross_if(a, b, c, multiplicity);
  }
  return count + boundary.caps(q);
}

TEST(BoundaryWinding, CrossingsPlusCapsAreTheSolidAngleSum) {
  // w = I + caps must equal the sum of every triangle's solid angle wherever it is defined (off the surface), with
  // strips, with fans and with the bake's choice, also where voxel lines run through vertices and edges: the
  // broken parts are placed in index space with every vertex on a voxel line's (y, z) (degenerate for the
  // perturbed predicates) and an x that puts no voxel centre on a face.
  TriangleMesh mesh = broken_parts();
  for (Vec3& v : mesh.vertices)
    v = {3.7 + 100 * v[0] + 0.01 * std::sqrt(2.0) * v[1], std::round(4 + 100 * v[1]), std::round(4 + 100 * v[2])};
  const WindingNumber exact(mesh);
  std::vector<int64_t> bricks;
  const std::array<int64_t, 3> dims{14, 14, 14};
  for (int64_t n = 0; n < dims[0] * dims[1] * dims[2]; ++n) bricks.push_back(n);
  std::mt19937_64 rng(17);
  for (const auto caps : {BoundaryWinding::Caps::Strips, BoundaryWinding::Caps::Fans, BoundaryWinding::Caps::Cheaper}) {
    BoundaryWinding boundary(mesh.triangles, mesh.vertices);
    ASSERT_FALSE(boundary.closed());
    boundary.prepare(bricks, dims, caps);
    size_t tested = 0, wrong = 0;
    double worst = 0;
    for (int n = 0; n < 6000; ++n) {
      // Voxel centres, half of them next to the surface.
      Vec3 q{double(rng() % 112), double(rng() % 112), double(rng() % 112)};
      if (n % 2) {
        const auto& t = mesh.triangles[rng() % mesh.triangles.size()];
        for (int a = 0; a < 3; ++a) q[a] = std::round(mesh.vertices[t[a % 3]][a] + double(rng() % 5) - 2);
      }
      double nearest = std::numeric_limits<double>::infinity();
      for (const auto& t : mesh.triangles)
        nearest =
            std::min(nearest, triangle_distance(q, mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]]));
      if (nearest < 1e-6) continue;  // on the surface: no winding number
      ++tested;
      const double error =
          std::abs(boundary_form(mesh, boundary, q) - exact.evaluate(q, std::numeric_limits<double>::infinity()));
      worst = std::max(worst, error);
      wrong += error > 1e-7;
    }
    std::printf("caps %d: %zu points, worst difference %.2g, %zu wrong\n", int(caps), tested, worst, wrong);
    EXPECT_GT(tested, 5000u);
    EXPECT_EQ(wrong, 0u);
  }
}

// Every band voxel's sign against the exact winding number (every triangle's solid angle), where it is not within
// rounding of 1/2; `sample` > 0 checks that many voxels at random. Outside the surface's box the bake keeps every
// voxel outside (a plane separates it from the surface), though stacked open sheets can add up past 1/2 there.
void expect_exact_winding_signs(const TriangleMesh& mesh, const Voxelmap& vm, const char* label, size_t sample = 0) {
  const WindingNumber winding(mesh);
  const auto [lo, hi] = bounding_box(mesh);
  std::vector<StoredVoxel> stored = stored_voxels(vm);
  if (sample > 0 && stored.size() > sample) {
    std::mt19937_64 rng(5);
    std::shuffle(stored.begin(), stored.end(), rng);
    stored.resize(sample);
  }
  size_t checked = 0, near_half = 0, wrong = 0;
  for (const StoredVoxel& v : stored) {
    if (v.d == 0) continue;  // on the surface: either sign
    const Vec3 p = vm.voxel_center(v.i, v.j, v.k);
    bool in_box = true;
    for (int a = 0; a < 3; ++a) in_box = in_box && p[a] >= lo[a] && p[a] <= hi[a];
    const double w = winding.evaluate(p, std::numeric_limits<double>::infinity());
    if (std::abs(w - 0.5) < 1e-9) continue;
    ++checked;
    near_half += std::abs(w - 0.5) < 0.01;
    wrong += (w >= 0.5 && in_box) != (v.d < 0);
  }
  std::printf("%s: %zu band voxels checked, %zu within 0.01 of 1/2, %zu with the wrong sign\n", label, checked,
              near_half, wrong);
  EXPECT_GT(checked, 1000u) << label;
  EXPECT_EQ(wrong, 0u) << label;
}

TEST(Bake, WindingSignsAreTheExactSolidAngleSumsOnBrokenParts) {
  // The bake decides each band voxel's side of 1/2 through the boundary, interpolating far caps within a bound:
  // every sign must be the exact sum's, also for voxels very near 1/2 (behind open sheets, at the books' tops).
  const TriangleMesh parts = broken_parts();
  VoxelmapSettings options;
  options.resolution = 96;
  options.winding_number_sign = true;
  expect_exact_winding_signs(parts, build_voxelmap(parts, options), "broken parts at 96");
  // CGAL's samples with open borders and self-intersections.
  for (const char* name : {"mask_cone.off", "three_peaks.off", "mech-holes-shark.off"}) {
    RepairReport report;
    const TriangleMesh mesh = repair_mesh(import_mesh(kMeshes + "/" + name), report, false);
    options.resolution = 64;
    expect_exact_winding_signs(mesh, build_voxelmap(mesh, options), name, 3000);
  }
}

}  // namespace
}  // namespace voxfmt::bake

namespace voxfmt::bake {
namespace {

// Full validation: a baked asset is clean; breaking one rule at a time yields exactly that rule's code.
class FullValidation : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    Settings options;
    options.voxelmap.resolution = 48;
    options.point_shell.points = 2000;
    BuildReport report;
    asset_ = new Asset(build_asset(kMeshes + "/bunny00.off", options, report));
  }
  static void TearDownTestSuite() { delete asset_; }

  static std::vector<std::string> codes(const Asset& a) {
    std::vector<std::string> out;
    for (const Issue& issue : validate_asset(a, ValidationLevel::Full)) out.push_back(code_name(issue.code));
    return out;
  }
  // The code of voxel (i, j, k) of a value brick (nullptr in a coarse brick).
  static int16_t* code_of(Voxelmap& vm, uint32_t i, uint32_t j, uint32_t k) {
    constexpr uint32_t E = Voxelmap::kBrickEdge;
    const int32_t entry = vm.bricks[vm.brick_index(i / E, j / E, k / E)];
    if (entry < 0) return nullptr;
    return &vm.brick_values[size_t(entry) * Voxelmap::kBrickVoxels + Voxelmap::local_index(i % E, j % E, k % E)];
  }
  // Finds an inner voxel of a value brick whose code and its 6-neighbours' codes (nullptr for coarse ones) satisfy
  // `pick`.
  static int16_t* find_code(Voxelmap& vm, const std::function<bool(int16_t, const std::vector<int16_t*>&)>& pick) {
    for (uint32_t k = 1; k + 1 < vm.dims[2]; ++k)
      for (uint32_t j = 1; j + 1 < vm.dims[1]; ++j)
        for (uint32_t i = 1; i + 1 < vm.dims[0]; ++i) {
          int16_t* c = code_of(vm, i, j, k);
          if (!c) continue;
          const std::vector<int16_t*> n = {code_of(vm, i - 1, j, k), code_of(vm, i + 1, j, k),
                                           code_of(vm, i, j - 1, k), code_of(vm, i, j + 1, k),
                                           code_of(vm, i, j, k - 1), code_of(vm, i, j, k + 1)};
          if (pick(*c, n)) return c;
        }
    ADD_FAILURE() << "no suitable voxel";
    static int16_t none = 0;
    return &none;
  }
  static Asset* asset_;
};
Asset* FullValidation::asset_ = nullptr;

TEST_F(FullValidation, BakedAssetIsClean) { EXPECT_TRUE(codes(*asset_).empty()); }

TEST_F(FullValidation, DistanceOutsideBand) {
  Asset a = *asset_;
  Voxelmap& vm = a.voxelmap;
  const double h = vm.voxel_size;
  // The bake's quantum codes exactly the band; a producer with a coarser one can code beyond it. Twice the
  // quantum (every stored code halved: the same distances within a step), then a stored distance near the band's
  // edge moved half a voxel past it: its neighbours stay within the voxel diagonal and on its side.
  vm.distance_quantum *= 2;
  for (int16_t& code : vm.brick_values)
    if (Voxelmap::code_is_stored(code)) code = int16_t(((code >> 1) / 2) * 2 + 1);
  int16_t* c = find_code(vm, [&](int16_t code, const std::vector<int16_t*>&) {
    return Voxelmap::code_is_stored(code) && vm.decode(code) > (vm.distance_band - 0.2) * h;
  });
  *c = vm.encode_stored((vm.distance_band + 0.5) * h);
  fill_estimates(vm);  // settled from the new codes, as that producer would
  EXPECT_EQ(codes(a), std::vector<std::string>{"DISTANCE_OUTSIDE_BAND"});
}

TEST_F(FullValidation, EstimateMismatch) {
  Asset a = *asset_;
  Voxelmap& vm = a.voxelmap;
  // A value-brick voxel without a stored distance whose estimate is two voxels above the settled one (same side).
  int16_t* c = find_code(vm, [&](int16_t code, const std::vector<int16_t*>&) {
    return !Voxelmap::code_is_stored(code) && vm.decode(code) > 0;
  });
  *c = vm.encode_estimate(vm.decode(*c) + 2 * vm.voxel_size);
  EXPECT_EQ(codes(a), std::vector<std::string>{"ESTIMATE_MISMATCH"});
}

TEST_F(FullValidation, AnEstimateOneStepBelowTheSettledOneIsFound) {
  // Settled estimates are exact integers (spec §3.1, 2.2): a single step too low breaks the rule at that voxel.
  Asset a = *asset_;
  Voxelmap& vm = a.voxelmap;
  ASSERT_EQ(vm.estimates, Voxelmap::Estimates::Settled);
  int16_t* c = find_code(vm, [&](int16_t code, const std::vector<int16_t*>&) {
    return !Voxelmap::code_is_stored(code) && (code >> 1) > 40;
  });
  *c = int16_t(*c - 2);
  EXPECT_EQ(codes(a), std::vector<std::string>{"ESTIMATE_MISMATCH"});
}

TEST_F(FullValidation, SignMismatch) {
  Asset a = *asset_;
  Voxelmap& vm = a.voxelmap;
  // The grid's corner brick (far outside, in the margin) said to be inside, among coarse bricks outside.
  ASSERT_EQ(vm.bricks[0], Voxelmap::kCoarseOutside);
  vm.bricks[0] = Voxelmap::kCoarseInside;
  EXPECT_EQ(codes(a), std::vector<std::string>{"SIGN_MISMATCH"});
}

TEST_F(FullValidation, DistanceJump) {
  Asset a = *asset_;
  Voxelmap& vm = a.voxelmap;
  const double h = vm.voxel_size;
  // A stored voxel just outside, all of whose neighbours are stored and outside, moved 1.8 voxels farther out:
  // still within the band, on its side, but more than the voxel diagonal from the neighbour toward the surface.
  int16_t* c = find_code(vm, [&](int16_t code, const std::vector<int16_t*>& n) {
    if (!Voxelmap::code_is_stored(code)) return false;
    const double d = vm.decode(code);
    if (!(d > 0.3 * h && d < 0.9 * h)) return false;
    bool nearer = false;
    for (int16_t* m : n) {
      if (!m || !Voxelmap::code_is_stored(*m) || !(vm.decode(*m) > 0.1 * h)) return false;
      nearer |= vm.decode(*m) < d + 1.8 * h - std::sqrt(3.0) * h - 0.01 * h;
    }
    return nearer;
  });
  *c = vm.encode_stored(vm.decode(*c) + 1.8 * h);
  EXPECT_EQ(codes(a), std::vector<std::string>{"DISTANCE_JUMP"});
}

TEST_F(FullValidation, NormalNotInward) {
  Asset a = *asset_;
  for (Vec3f& n : a.point_shell.normals) n = {-n[0], -n[1], -n[2]};
  EXPECT_EQ(codes(a), std::vector<std::string>{"NORMAL_NOT_INWARD"});
}

TEST_F(FullValidation, SphereNotEnclosing) {
  Asset a = *asset_;
  a.point_shell.sphere_radii[0] *= 0.5;
  EXPECT_EQ(codes(a), std::vector<std::string>{"SPHERE_NOT_ENCLOSING"});
}

TEST_F(FullValidation, InertiaNotPositiveDefinite) {
  Asset a = *asset_;
  a.mass.inertia[4] = -a.mass.inertia[4];
  EXPECT_EQ(codes(a), std::vector<std::string>{"INERTIA_NOT_POSITIVE_DEFINITE"});
}

TEST_F(FullValidation, CenterOfMassOutsideBounds) {
  Asset a = *asset_;
  a.mass.center_of_mass[1] = a.bounds_max[1] + 1;
  EXPECT_EQ(codes(a), std::vector<std::string>{"CENTER_OF_MASS_OUTSIDE_BOUNDS"});
}

}  // namespace
}  // namespace voxfmt::bake

namespace voxfmt::bake {
namespace {

// Regressions from baking CGAL's whole sample library at default settings (voxfmt batch): each of these gave an
// asset that `validate --level full` rejects.
Asset bake_default(const std::string& name, BuildReport& report, uint32_t points = 1000) {
  Settings options;  // resolution 128, margin 4, band 3: the defaults
  options.point_shell.points = points;
  return build_asset(kMeshes + "/" + name, options, report);
}

TEST(LibraryRegressions, HalfVoxelTiesDoNotStepTwoLayers) {
  // Axis-aligned faces half a voxel from the voxel centres (the grid starts at the bounding box): float
  // rounding used to put 2.5 above and 1.5 below their ties, or computed 0.4999987 beside an exact 1.5.
  for (const char* name : {"beam.off", "cheese-box.off", "small_cube.off", "fandisk_large.off", "torus_quad.off"}) {
    BuildReport report;
    const Asset asset = bake_default(name, report);
    EXPECT_EQ(full_errors(asset), std::vector<std::string>()) << name;
  }
}

TEST(LibraryRegressions, MissedClosestTrianglesAreFoundExactly) {
  // Thin parts: the earlier band search (OpenVDB meshToVolume's local closest-triangle candidates) missed the closest
  // one, giving distances a voxel too large with the wrong sign inside the femur and homer.
  for (const char* name : {"femur.off", "homer.off"}) {
    BuildReport report;
    const Asset asset = bake_default(name, report);
    ASSERT_TRUE(report.repair.closed) << name;
    EXPECT_EQ(full_errors(asset), std::vector<std::string>()) << name;
    const ExactSurface surface(import_mesh(kMeshes + "/" + name));
    expect_accurate(compare_distances(
                        asset.voxelmap, [&](const Vec3& p) { return surface.signed_distance(p); }, 10000,
                        1e-3 * asset.voxelmap.voxel_size),
                    name);
  }
}

// A cylinder (radius 1, height 3) of `segments` long side slivers and fan caps, its axis along (1, 1, 1): thin
// triangles oblique to every axis, as CAD exports have.
std::string write_tilted_cylinder(const std::string& path, int segments) {
  const double pi = 3.14159265358979323846, s3 = 1 / std::sqrt(3.0), s2 = 1 / std::sqrt(2.0), s6 = 1 / std::sqrt(6.0);
  const Vec3 u{s2, -s2, 0}, v{s6, s6, -2 * s6}, w{s3, s3, s3};  // orthonormal, w the axis
  auto place = [&](double x, double y, double z) {
    return Vec3{x * u[0] + y * v[0] + z * w[0], x * u[1] + y * v[1] + z * w[1], x * u[2] + y * v[2] + z * w[2]};
  };
  TriangleMesh cylinder;
  for (int s = 0; s < segments; ++s) {
    const double a = 2 * pi * s / segments;
    cylinder.vertices.push_back(place(std::cos(a), std::sin(a), 0));
    cylinder.vertices.push_back(place(std::cos(a), std::sin(a), 3));
  }
  cylinder.vertices.push_back(place(0, 0, 0));
  cylinder.vertices.push_back(place(0, 0, 3));
  const uint32_t bottom = uint32_t(2 * segments), top = bottom + 1;
  for (int s = 0; s < segments; ++s) {
    const uint32_t b0 = uint32_t(2 * s), t0 = b0 + 1, b1 = uint32_t(2 * ((s + 1) % segments)), t1 = b1 + 1;
    cylinder.triangles.insert(cylinder.triangles.end(), {{b0, b1, t1}, {b0, t1, t0}, {bottom, b1, b0}, {top, t0, t1}});
  }
  return write_off(path, cylinder);
}

TEST(Bake, FarLatticePointsKeepTheLatticesPromise) {
  // Spec §3.3 far from the surface, where the bake keeps a carried distance without searching once the cells the
  // surface touches bound it within the lattice's slack: a 48-voxel bunny in a margin of 250 voxels, so that most
  // lattice points are hundreds of voxels away. Every value must lie in [u, (1 + e1) u + e0 h].
  Settings options;
  options.voxelmap.resolution = 48;
  options.voxelmap.margin = 250;
  options.point_shell.points = 500;
  BuildReport report;
  const Asset asset = build_asset(kMeshes + "/bunny00.off", options, report);
  RepairReport again;
  const ExactSurface surface(repair_mesh(import_mesh(kMeshes + "/bunny00.off"), again, false));
  const Voxelmap& vm = asset.voxelmap;
  const auto l = vm.lattice_dims();
  const double h = vm.voxel_size;
  size_t checked = 0, far = 0, below = 0, beyond_bound = 0;
  double worst_ratio = 0;
  for (size_t n = 0; n < vm.lattice_count(); n += 5) {
    const uint32_t a = uint32_t(n % l[0]), b = uint32_t(n / l[0] % l[1]), c = uint32_t(n / (size_t(l[0]) * l[1]));
    const double u = surface.distance(vm.lattice_point_center(a, b, c));
    const double value = vm.lattice[vm.lattice_index(a, b, c)];
    ++checked;
    far += u > 300 * h;
    below += value < u * (1 - 1e-6);
    beyond_bound += value > (1 + vm.lattice_error[1]) * u + vm.lattice_error[0] * h;
    if (u > 16 * h) worst_ratio = std::max(worst_ratio, value / u);
  }
  std::printf("lattice of %zu points: %zu checked, %zu over 300 voxels from the surface, at most %.5f x the distance\n",
              vm.lattice_count(), checked, far, worst_ratio);
  EXPECT_GT(far, checked / 5);  // measured 24.8 %
  EXPECT_EQ(below, 0u);
  EXPECT_EQ(beyond_bound, 0u);
  EXPECT_EQ(full_errors(asset), std::vector<std::string>());
}

TEST(Bake, BandAndSidesAreExactAtEveryVoxel) {
  // Every voxel, not a sample: a distance is stored exactly where the exact distance is within the band (up to
  // float rounding at its edge), and every voxel more than half a voxel from the surface has a layer on the
  // exact side: the sign carried along rows outside the band and the band's culling leave nothing out.
  // Thin parts (femur, homer), sharp features (fandisk) and long oblique slivers (the cylinder) at a coarse
  // resolution.
  const std::string cylinder =
      write_tilted_cylinder((std::filesystem::temp_directory_path() / "voxfmt-tilted-cylinder.off").string(), 300);
  for (const std::string& path :
       {kMeshes + "/bunny00.off", kMeshes + "/femur.off", kMeshes + "/homer.off", kMeshes + "/fandisk.off", cylinder}) {
    const std::string name = std::filesystem::path(path).filename().string();
    Settings options;
    options.voxelmap.resolution = 40;
    options.point_shell.points = 200;
    BuildReport report;
    const Asset asset = build_asset(path, options, report);
    ASSERT_TRUE(report.repair.closed) << name;
    RepairReport again;
    const ExactSurface surface(repair_mesh(import_mesh(path), again, false));
    const Voxelmap& vm = asset.voxelmap;
    const double h = vm.voxel_size, edge = 1e-5;  // voxels
    size_t wrong_band = 0, wrong_side = 0, wrong_distance = 0;
    for (uint32_t k = 0; k < vm.dims[2]; ++k)
      for (uint32_t j = 0; j < vm.dims[1]; ++j)
        for (uint32_t i = 0; i < vm.dims[0]; ++i) {
          const double exact = surface.signed_distance(vm.voxel_center(i, j, k)) / h;
          const VoxelValue value = vm.voxel(i, j, k);
          if (std::abs(std::abs(exact) - vm.distance_band) > edge)
            wrong_band += value.stored != (std::abs(exact) <= vm.distance_band);
          if (value.stored) wrong_distance += std::abs(value.distance / h - exact) > 1e-4;
          if (exact < -0.5 - edge) wrong_side += vm.layer(i, j, k) < 1;
          if (exact > 0.5 + edge) wrong_side += vm.layer(i, j, k) > -1;
        }
    EXPECT_EQ(wrong_band, 0u) << name;
    EXPECT_EQ(wrong_distance, 0u) << name;
    EXPECT_EQ(wrong_side, 0u) << name;
  }
}

TEST(LibraryRegressions, IncompleteBandIsCompleted) {
  // A triangle through a tetrahedron: voxels next to ones 0.3 voxel from the surface had no stored distance.
  BuildReport report;
  const Asset asset = bake_default("tetra_intersected_by_triangle.off", report);
  EXPECT_EQ(full_errors(asset), std::vector<std::string>());
}

TEST(LibraryRegressions, OpenSurfacesGetTheMassOfTheirWindingInside) {
  // The divergence theorem over an open surface depends on the origin (open_cube gave 833,333 for a 100^3 cube,
  // negative.off a non-positive-definite inertia); the voxelmap's inside gives the closed solid.
  BuildReport report;
  const Asset cube = bake_default("open_cube.off", report);
  EXPECT_NEAR(cube.mass.volume, 1e6, 0.01 * 1e6);
  const Vec3 mid = {(cube.bounds_min[0] + cube.bounds_max[0]) / 2, (cube.bounds_min[1] + cube.bounds_max[1]) / 2,
                    (cube.bounds_min[2] + cube.bounds_max[2]) / 2};
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(cube.mass.center_of_mass[a], mid[a], 0.5);
  // A solid cube of edge 100: I = m a^2 / 6 on each axis.
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(cube.mass.inertia[a * 4], 1e6 * 1e4 / 6, 0.03 * 1e10 / 6);
  EXPECT_EQ(full_errors(cube), std::vector<std::string>());
  for (const char* name : {"negative.off", "fold.off", "b9_mesh.off", "elephant-with-holes.off"}) {
    BuildReport r;
    EXPECT_EQ(full_errors(bake_default(name, r)), std::vector<std::string>()) << name;
  }
}

// Spec §3 shell mode: the signed distance is the unsigned distance to the surface minus half the thickness.
void expect_shell_distances(const Asset& asset, const TriangleMesh& mesh, const std::string& name) {
  const Voxelmap& vm = asset.voxelmap;
  ASSERT_TRUE(vm.shell_thickness.has_value()) << name;
  const ExactSurface surface(mesh);
  std::vector<StoredVoxel> stored = stored_voxels(vm);
  std::mt19937_64 rng(21);
  std::shuffle(stored.begin(), stored.end(), rng);
  double worst = 0;
  size_t checked = 0, inside = 0;
  for (const StoredVoxel& v : stored) {
    if (checked == 3000) break;
    const double expected = surface.distance(vm.voxel_center(v.i, v.j, v.k)) - *vm.shell_thickness / 2;
    worst = std::max(worst, std::abs(v.d - expected) / vm.voxel_size);
    inside += v.d < 0;
    ++checked;
  }
  std::printf("%s: shell %.4g m, %zu band voxels checked (%zu inside), max error %.2e voxel\n", name.c_str(),
              *vm.shell_thickness, checked, inside, worst);
  EXPECT_GT(checked, 500u) << name;
  EXPECT_GT(inside, 0u) << name;
  EXPECT_LT(worst, 1e-4) << name;
  EXPECT_TRUE(full_errors(asset).empty()) << name;
}

TEST(Bake, OpenSheetsAndThinPartsBakeAsShells) {
  // They enclose nothing at resolution 128 (they used to fail with ZERO_VOLUME): a 2-voxel shell, with a warning.
  // The warning tells a sheet (no inside anywhere) from parts thinner than a voxel (blade.off: a thin closed part).
  for (const char* name : {"plane.off", "patch-13.off", "triangular_hole.off", "blade.off"}) {
    BuildReport report;
    const Asset asset = bake_default(name, report);
    std::string message;
    for (const BuildWarning& w : asset.provenance.build_warnings)
      if (w.code == "SHELL_MODE") message = w.message;
    EXPECT_NE(message.find(std::string(name) == "blade.off" ? "thinner than a voxel" : "open or flat sheet"),
              std::string::npos)
        << name << ": " << message;
    EXPECT_NEAR(*asset.voxelmap.shell_thickness, 2 * asset.voxelmap.voxel_size, 1e-12) << name;
    RepairReport again;
    expect_shell_distances(asset, repair_mesh(import_mesh(kMeshes + "/" + name), again, false), name);
    if (std::string(name) != "blade.off") {
      EXPECT_EQ(asset.point_shell.size(), 1000u) << name;  // 500 per sheet
    } else {  // each side's inner sheet lies in the blade's other half: inside the shell, dropped
      EXPECT_GE(asset.point_shell.size(), 500u);
      EXPECT_LT(asset.point_shell.size(), 600u);
    }
  }
}

TEST(Bake, ThickShellsKeepOnlyThePointsOnTheirSurface) {
  // A 1 m cube's shell: its sheets lie half the thickness out and in along each face's normal, but the inner sheet is
  // the smaller cube [T/2, 1 - T/2]^3: a face's points within T/2 of an edge land inside the walls, and with T over
  // the cube's size every inner point does. Those were kept (up to 48 voxels inside at T = 1.5 m), and a part that
  // reached them got contacts from inside the other's wall.
  TriangleMesh cube;
  append_box(cube, {0.5, 0.5, 0.5}, {0.5, 0.5, 0.5});
  const std::string path =
      write_off((std::filesystem::temp_directory_path() / "voxfmt-thick-shell.off").string(), cube);
  const ExactSurface surface(cube);
  for (double thickness : {0.2, 0.6, 1.5}) {
    Settings options;
    options.voxelmap.resolution = 64;
    options.voxelmap.shell_thickness = thickness;
    options.point_shell.points = 4000;
    BuildReport report;
    const Asset asset = build_asset(path, options, report);
    const double h = asset.voxelmap.voxel_size;
    size_t outer = 0;
    double deepest = 0;
    for (const Vec3& p : asset.point_shell.points) {
      deepest = std::max(deepest, thickness / 2 - surface.distance(p));
      outer += !surface.inside(p);
    }
    EXPECT_LE(deepest, 0.25 * h) << thickness;                // no point inside the shell by more than the tolerance
    EXPECT_EQ(outer, 2000u) << thickness;                     // the outer sheet whole
    EXPECT_LT(asset.point_shell.size(), 4000u) << thickness;  // and some of the inner one dropped
    if (thickness > 1) {
      EXPECT_EQ(asset.point_shell.size(), 2000u);  // all of it: the shell fills the cube
    }
    EXPECT_EQ(full_errors(asset), std::vector<std::string>()) << thickness;
  }
  std::filesystem::remove(path);
}

TEST(Bake, PartsThinnerThanAVoxelSaySoAndBakeAsAShell) {
  // A shelf of 1 mm boards through each other (closed, self-intersecting) at 8 mm voxels: the winding number has
  // an inside, but no voxel is more than half a voxel in it. The bake stops after its band, bakes a shell and says
  // why, with what to pass instead.
  TriangleMesh shelf;
  for (int i = 0; i < 4; ++i) append_box(shelf, {0.3 * i, 0.5, 0.15}, {0.0005, 0.5, 0.15});
  for (int j = 0; j < 4; ++j) append_box(shelf, {0.45, 0.02 + 0.3 * j, 0.15}, {0.47, 0.0005, 0.14});
  const std::string path =
      write_off((std::filesystem::temp_directory_path() / "voxfmt-thin-shelf.off").string(), shelf);
  Settings options;
  options.voxelmap.resolution = 128;
  options.point_shell.points = 2000;
  BuildReport report;
  const Asset asset = build_asset(path, options, report);
  std::filesystem::remove(path);
  std::string message;
  for (const BuildWarning& w : asset.provenance.build_warnings)
    if (w.code == "SHELL_MODE") message = w.message;
  EXPECT_NE(message.find("thinner than a voxel"), std::string::npos) << message;
  EXPECT_NE(message.find("--shell-thickness"), std::string::npos) << message;
  ASSERT_TRUE(asset.voxelmap.shell_thickness.has_value());
  EXPECT_NEAR(*asset.voxelmap.shell_thickness, 2 * asset.voxelmap.voxel_size, 1e-12);
  EXPECT_EQ(full_errors(asset), std::vector<std::string>());
}

TEST(Bake, SliverTetrahedraGetConsistentSigns) {
  // A closed tetrahedron whose apex lies a sliver above its base (a fuzzer's glTF): at the knife edge the two faces'
  // normals cancel, and a voxel straight above the edge took the edge's sign (inside) where the tilted face, nearer
  // by less than a float tells, says outside: SIGN_MISMATCH at the band's edge (the nearest triangle's distance was
  // a float). Thinner slivers turned every way also flipped rows beyond the band.
  std::mt19937_64 rng(7);
  std::normal_distribution<double> gauss;
  const std::string path = (std::filesystem::temp_directory_path() / "voxfmt-sliver.off").string();
  for (const double apex : {1e-1, 1e-3, 1e-5, 1e-6, 1e-7, 1e-9, 1e-11, 1e-13})
    for (int turn = 0; turn < 4; ++turn) {
      // A random rotation (a unit quaternion); the first of each thickness is the fuzzer's axis-aligned one.
      double q[4] = {1, 0, 0, 0};
      if (turn > 0) {
        for (double& c : q) c = gauss(rng);
        const double n = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        for (double& c : q) c /= n;
      }
      auto turned = [&](const Vec3& v) {
        const double w = q[0], x = q[1], y = q[2], z = q[3];
        return Vec3{(1 - 2 * (y * y + z * z)) * v[0] + 2 * (x * y - w * z) * v[1] + 2 * (x * z + w * y) * v[2],
                    2 * (x * y + w * z) * v[0] + (1 - 2 * (x * x + z * z)) * v[1] + 2 * (y * z - w * x) * v[2],
                    2 * (x * z - w * y) * v[0] + 2 * (y * z + w * x) * v[1] + (1 - 2 * (x * x + y * y)) * v[2]};
      };
      TriangleMesh sliver;
      sliver.vertices = {turned({0, 0, 0}), turned({1, 0, 0}), turned({0, apex, 0}), turned({0, 0, 1})};
      sliver.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
      write_off(path, sliver);
      Settings options;
      options.voxelmap.resolution = 24;
      options.point_shell.points = 300;
      const Result<Baked> baked = bake_mesh(path, options);
      if (!baked) {
        // Refusing a part with no inside is a fair answer; refusing its own output is not.
        EXPECT_NE(baked.error().code, IssueCode::InvalidAsset)
            << "apex " << apex << ", turn " << turn << ": " << baked.error().message;
        continue;
      }
      EXPECT_EQ(full_errors(baked.value().asset), std::vector<std::string>()) << "apex " << apex << ", turn " << turn;
    }
  std::filesystem::remove(path);
}

TEST(Bake, ShellThicknessOnAClosedMeshGivesAreaTimesThickness) {
  Settings options;
  options.voxelmap.resolution = 64;
  options.voxelmap.shell_thickness = 0.1;  // ~3 voxels of the cube
  options.point_shell.points = 2000;
  BuildReport report;
  const Asset asset = build_asset(kMeshes + "/cube.off", options, report);
  RepairReport again;
  const TriangleMesh mesh = repair_mesh(import_mesh(kMeshes + "/cube.off"), again, false);
  double area = 0;
  for (const auto& t : mesh.triangles)
    area += 0.5 * length(cross(mesh.vertices[t[1]] - mesh.vertices[t[0]], mesh.vertices[t[2]] - mesh.vertices[t[0]]));
  EXPECT_NEAR(asset.mass.volume, area * 0.1, 1e-12 * area);
  // The shell reaches half the thickness past the surface's box.
  const auto [lo, hi] = bounding_box(mesh);
  EXPECT_NEAR(asset.bounds_min[0], lo[0] - 0.05, 1e-12);
  EXPECT_NEAR(asset.bounds_max[2], hi[2] + 0.05, 1e-12);
  expect_shell_distances(asset, mesh, "cube.off shell 0.1");
}

TEST(Bake, AnAssetIsCurrentForItsOwnMeshAndSettingsOnly) {
  const std::string dir = ::testing::TempDir() + "/voxfmt-asset-is-current";
  std::filesystem::create_directories(dir);
  const std::string asset = dir + "/cube.vox.h5";
  Settings settings;
  settings.voxelmap.resolution = 16;
  settings.point_shell.points = 200;
  EXPECT_FALSE(asset_is_current(asset, kMeshes + "/cube.off", settings));  // not there yet
  ASSERT_TRUE(bake_to_file(kMeshes + "/cube.off", asset, settings));
  EXPECT_TRUE(asset_is_current(asset, kMeshes + "/cube.off", settings));
  EXPECT_FALSE(asset_is_current(asset, kMeshes + "/tetrahedron.off", settings));  // another mesh, same settings
  Settings finer = settings;
  finer.voxelmap.resolution = 24;
  EXPECT_FALSE(asset_is_current(asset, kMeshes + "/cube.off", finer));
  Settings faster = settings;
  faster.threads = 1;  // not a parameter of the data
  EXPECT_TRUE(asset_is_current(asset, kMeshes + "/cube.off", faster));
  std::filesystem::resize_file(asset, std::filesystem::file_size(asset) * 9 / 10);  // damaged past its provenance
  EXPECT_FALSE(asset_is_current(asset, kMeshes + "/cube.off", settings));
  std::filesystem::remove_all(dir);
}

// A shell's distances are the mesh's distance less T/2, rounded where the mesh's distance is: a thick shell's
// lattice and stored distances differ by that rounding, which is far more than a relative 1e-6 of themselves.
TEST(Bake, ThickShellsPassTheirOwnLatticeChecks) {
  for (const double thickness : {6.25, 20.0}) {  // 50 and 160 voxels half-thickness on the 2 m cube
    Settings options;
    options.voxelmap.resolution = 32;
    options.voxelmap.shell_thickness = thickness;
    options.point_shell.points = 500;
    BuildReport report;
    const Asset asset = build_asset(kMeshes + "/cube.off", options, report);
    EXPECT_EQ(full_errors(asset), std::vector<std::string>()) << "thickness " << thickness;
  }
}

}  // namespace
}  // namespace voxfmt::bake
