// Stage 5: volume, centre of mass and inertia of a closed surface (divergence theorem over tetrahedra), or of
// the voxelmap's inside.
#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>

#include "closest_triangle.h"
#include "stages.h"
#include "vec3_math.h"

namespace voxfmt::bake {

namespace {

struct Moments {
  double volume = 0;
  Vec3 first{};              // integral of x dV
  double second[3][3] = {};  // integral of x x^T dV
};

// Moments about `ref` -> mass properties (centre of mass in the asset frame, inertia about it).
MassProperties from_moments(const Moments& s, const Vec3& ref) {
  MassProperties m;
  m.volume = s.volume;
  if (!(std::abs(s.volume) > 0)) return m;
  Vec3 c{};
  for (int a = 0; a < 3; ++a) c[a] = s.first[a] / s.volume;
  double central[3][3];
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) central[a][b] = s.second[a][b] - s.volume * c[a] * c[b];
  const double trace = central[0][0] + central[1][1] + central[2][2];
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) m.inertia[a * 3 + b] = (a == b ? trace : 0.0) - central[a][b];
  for (int a = 0; a < 3; ++a)
    for (int b = a + 1; b < 3; ++b) m.inertia[a * 3 + b] = m.inertia[b * 3 + a];  // exactly symmetric
  for (int a = 0; a < 3; ++a) m.center_of_mass[a] = c[a] + ref[a];
  return m;
}

}  // namespace

MassProperties compute_mass_properties(const TriangleMesh& mesh) {
  // Work relative to a point near the mesh to keep the sums well-conditioned far from the origin.
  Vec3 ref{};
  for (const Vec3& v : mesh.vertices)
    for (int a = 0; a < 3; ++a) ref[a] += v[a] / double(mesh.vertices.size());
  Moments sum;
  for (const auto& t : mesh.triangles) {
    Vec3 p[3];
    for (int i = 0; i < 3; ++i)
      for (int a = 0; a < 3; ++a) p[i][a] = mesh.vertices[t[i]][a] - ref[a];
    // Signed tetrahedron (ref, p0, p1, p2): det = 6 V.
    const double det = p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1]) -
                       p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0]) +
                       p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0]);
    sum.volume += det / 6;
    Vec3 s{};
    for (int i = 0; i < 3; ++i)
      for (int a = 0; a < 3; ++a) s[a] += p[i][a];
    for (int a = 0; a < 3; ++a) sum.first[a] += det / 24 * s[a];
    // Integral of x x^T over a tetrahedron with one vertex at the origin: det/120 (sum v v^T + s s^T).
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) {
        double vv = 0;
        for (int i = 0; i < 3; ++i) vv += p[i][a] * p[i][b];
        sum.second[a][b] += det / 120 * (vv + s[a] * s[b]);
      }
  }
  return from_moments(sum, ref);
}

namespace {

// A box of whole voxels inside (a coarse brick), `first` its least voxel, `count` voxels along each axis: its sums
// of 1, x and x^2 along each axis multiply. Voxel units, about `centre`.
void add_inside_box(const uint32_t first[3], const uint32_t count[3], const Vec3& centre, Moments& m) {
  double s0[3], s1[3], s2[3];
  for (int a = 0; a < 3; ++a) {
    s0[a] = count[a];
    s1[a] = s2[a] = 0;
    for (uint32_t l = 0; l < count[a]; ++l) {
      const double x = double(first[a] + l) - centre[size_t(a)];
      s1[a] += x;
      s2[a] += x * x;
    }
  }
  const double volume = s0[0] * s0[1] * s0[2];
  m.volume += volume;
  for (int a = 0; a < 3; ++a) {
    const double others = volume / s0[a];
    m.first[a] += s1[a] * others;
    for (int b = 0; b < 3; ++b) m.second[a][b] += a == b ? s2[a] * others : s1[a] * s1[b] * (volume / (s0[a] * s0[b]));
    m.second[a][a] += volume / 12.0;  // the voxels' own extent: the integral of x^2 over a unit cube
  }
}

// A value brick's voxels, each with its inside fraction: a plane at distance d from its centre cuts off 1/2 - d/h
// of it (exact for axis-aligned planes); whole voxels away from the surface.
void add_value_brick(const Voxelmap& vm, const int16_t* codes, const uint32_t first[3], const uint32_t count[3],
                     const Vec3& centre, Moments& m) {
  const double h = vm.voxel_size;
  for (uint32_t lk = 0; lk < count[2]; ++lk)
    for (uint32_t lj = 0; lj < count[1]; ++lj)
      for (uint32_t li = 0; li < count[0]; ++li) {
        const int16_t code = codes[Voxelmap::local_index(li, lj, lk)];
        const double d = vm.decode(code);
        const double w = Voxelmap::code_is_stored(code) ? std::clamp(0.5 - d / h, 0.0, 1.0) : (d < 0 ? 1.0 : 0.0);
        if (w == 0) continue;
        const double x[3] = {first[0] + li - centre[0], first[1] + lj - centre[1], first[2] + lk - centre[2]};
        m.volume += w;
        for (int a = 0; a < 3; ++a) {
          m.first[a] += w * x[a];
          for (int b = 0; b < 3; ++b) m.second[a][b] += w * x[a] * x[b];
          m.second[a][a] += w / 12.0;
        }
      }
}

Moments merged(Moments a, const Moments& b) {
  a.volume += b.volume;
  for (int i = 0; i < 3; ++i) {
    a.first[i] += b.first[i];
    for (int j = 0; j < 3; ++j) a.second[i][j] += b.second[i][j];
  }
  return a;
}

}  // namespace

MassProperties voxelmap_mass_properties(const Voxelmap& vm) {
  const uint32_t W = vm.dims[0], H = vm.dims[1], D = vm.dims[2];
  const double h = vm.voxel_size;
  // Moments in voxel units about the grid's centre (well-conditioned), scaled to metres at the end.
  const Vec3 centre = {(W - 1) / 2.0, (H - 1) / 2.0, (D - 1) / 2.0};
  const auto bd = vm.brick_dims();
  constexpr uint32_t E = Voxelmap::kBrickEdge;
  // Deterministic: the same sums in the same order on any number of threads, so a bake repeats bit for bit.
  Moments sum = tbb::parallel_deterministic_reduce(
      tbb::blocked_range<size_t>(0, vm.bricks.size(), 1024), Moments{},
      [&](const tbb::blocked_range<size_t>& r, Moments m) {
        for (size_t n = r.begin(); n < r.end(); ++n) {
          const int32_t entry = vm.bricks[n];
          if (entry == Voxelmap::kCoarseOutside) continue;
          const uint32_t first[3] = {uint32_t(n % bd[0]) * E, uint32_t(n / bd[0] % bd[1]) * E,
                                     uint32_t(n / (size_t(bd[0]) * bd[1])) * E};
          uint32_t count[3];
          for (int a = 0; a < 3; ++a) count[a] = std::min(E, vm.dims[size_t(a)] - first[a]);
          if (entry == Voxelmap::kCoarseInside)
            add_inside_box(first, count, centre, m);
          else
            add_value_brick(vm, vm.brick_values.data() + size_t(entry) * Voxelmap::kBrickVoxels, first, count, centre,
                            m);
        }
        return m;
      },
      merged);
  const double h3 = h * h * h;
  sum.volume *= h3;
  for (int a = 0; a < 3; ++a) {
    sum.first[a] *= h3 * h;
    for (int b = 0; b < 3; ++b) sum.second[a][b] *= h3 * h * h;
  }
  return from_moments(sum, {vm.origin[0] + h * centre[0], vm.origin[1] + h * centre[1], vm.origin[2] + h * centre[2]});
}

MassProperties shell_mass_properties(const TriangleMesh& mesh, double thickness) {
  // A thin shell of uniform thickness T: each triangle of area A is a slab of volume A*T, its moments those of
  // the triangle times T (exact for T -> 0; the rims and the curvature terms, O(T^2), are left out). Triangle
  // moments about a reference point near the mesh (its first vertex) keep the sums well conditioned:
  // integral of x dA = A (a + b + c)/3, of x x^T dA = A/12 (a a^T + b b^T + c c^T + s s^T), s = a + b + c.
  Moments total;
  const Vec3 ref = mesh.vertices.empty() ? Vec3{0, 0, 0} : mesh.vertices[0];
  for (const auto& t : mesh.triangles) {
    const Vec3 v[3] = {mesh.vertices[t[0]] - ref, mesh.vertices[t[1]] - ref, mesh.vertices[t[2]] - ref};
    const double area = 0.5 * length(cross(v[1] - v[0], v[2] - v[0]));
    const Vec3 s = v[0] + v[1] + v[2];
    total.volume += area * thickness;
    for (int a = 0; a < 3; ++a) {
      total.first[a] += area * thickness * s[a] / 3;
      for (int b = 0; b < 3; ++b)
        total.second[a][b] +=
            area * thickness / 12 * (v[0][a] * v[0][b] + v[1][a] * v[1][b] + v[2][a] * v[2][b] + s[a] * s[b]);
    }
  }
  return from_moments(total, ref);
}

void offset_to_shell_sheets(PointShell& shell, double half_thickness) {
  // Each surface point becomes two, on the shell's two sheets, each with its inward normal pointing back
  // toward the surface.
  const size_t n = shell.points.size();
  std::vector<Vec3> points;
  std::vector<Vec3f> normals;
  points.reserve(2 * n);
  normals.reserve(2 * n);
  for (size_t i = 0; i < n; ++i) {
    const Vec3f& inward = shell.normals[i];
    const Vec3 m{double(inward[0]), double(inward[1]), double(inward[2])};
    points.push_back(shell.points[i] - m * half_thickness);  // the sheet on the outward side
    normals.push_back(inward);
    points.push_back(shell.points[i] + m * half_thickness);  // the sheet on the inward side
    normals.push_back(Vec3f{-inward[0], -inward[1], -inward[2]});
  }
  shell.points = std::move(points);
  shell.normals = std::move(normals);
}

size_t drop_points_inside_shell(PointShell& shell, const TriangleMesh& mesh, double half_thickness, double tolerance) {
  const ClosestTriangle closest = [&] {  // the corners' copy freed once the tree holds its own
    std::vector<std::array<Vec3, 3>> corners(mesh.triangles.size());
    for (size_t t = 0; t < corners.size(); ++t)
      for (int c = 0; c < 3; ++c) corners[t][size_t(c)] = mesh.vertices[mesh.triangles[t][size_t(c)]];
    return ClosestTriangle(corners);
  }();
  const double inside = std::max(0.0, half_thickness - tolerance);
  const size_t n = shell.points.size();
  std::vector<uint8_t> keep(n);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 256), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i < r.end(); ++i)
      keep[i] = closest.nearest(shell.points[i], inside * inside, 0).first >= inside * inside;
  });
  size_t kept = 0;
  for (size_t i = 0; i < n; ++i)
    if (keep[i]) {
      shell.points[kept] = shell.points[i];
      shell.normals[kept] = shell.normals[i];
      ++kept;
    }
  if (kept == 0)  // a few points on a crumpled surface, all swallowed by the sheets of its folds
    throw BakeError(IssueCode::BadOption,
                    "every one of the " + std::to_string(n) +
                        " sampled sheet points lies inside the shell: use more points (--points) or a thinner shell "
                        "(--shell-thickness)");
  shell.points.resize(kept);
  shell.normals.resize(kept);
  return n - kept;
}

}  // namespace voxfmt::bake
