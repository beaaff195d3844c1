// Stage 3: the layered distance-field voxelmap, built sparsely (spec §3): memory and time follow the surface, not
// the volume. The stages, in order:
//   plan_grid            the grid, and the memory the bake will need, checked before anything is allocated
//   bin_triangles        each 8^3 brick's triangles: those within reach of one of its voxels
//   ClosestTriangle      a hierarchy over the triangles, for the band's dense rows and the far lattice
//   bake_brick_rows      exact band distances per brick (nearest triangle, pseudonormal sign), the sign carried
//                        along each row of bricks to the voxels and bricks beyond the band; value bricks coded.
//                        A row's nearest triangles come from its triangles' voxels or, where many small
//                        triangles reach each voxel, from a search of the hierarchy per voxel: the same
//                        distances (a tie may name another of the tied triangles)
//   propagate_lattice    the unsigned distance at every brick corner: exact near the surface, nearest triangles
//                        carried across the lattice farther away
//   fill estimates       the codes of value-brick voxels without a stored distance: settled from the lattice
//                        seeds and their neighbours (spec §3.1, format 2.2)
#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/enumerable_thread_specific.h>
#include <oneapi/tbb/global_control.h>
#include <oneapi/tbb/parallel_for.h>
#include <oneapi/tbb/parallel_reduce.h>
#include <oneapi/tbb/parallel_sort.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <limits>
#include <optional>
#include <thread>
#include <tuple>
#include <unordered_map>

#include "boundary_winding.h"
#include "closest_triangle.h"
#include "stages.h"
#include "triangle_closest_point.h"
#include "voxfmt/detail/cores.h"
#include "winding_number.h"

namespace voxfmt::bake {

namespace {

constexpr int64_t kEdge = Voxelmap::kBrickEdge;
constexpr size_t kBrickVoxels = Voxelmap::kBrickVoxels;

struct GridGeometry {
  Vec3 origin{};
  double voxel_size = 0;
  std::array<uint32_t, 3> dims{};
  std::array<int64_t, 3> bricks{};  // bricks along x, y, z
  int64_t brick_count() const { return bricks[0] * bricks[1] * bricks[2]; }
  int64_t lattice_count() const { return (bricks[0] + 1) * (bricks[1] + 1) * (bricks[2] + 1); }
};

GridGeometry plan_grid(const TriangleMesh& mesh, const VoxelmapSettings& options) {
  const auto [lo, hi] = bounding_box(mesh);
  const double longest = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  GridGeometry g;
  if (options.voxel_size > 0) {
    g.voxel_size = options.voxel_size;
  } else {
    if (options.resolution == 0) throw BakeError(IssueCode::BadOption, "resolution must be >= 1");
    g.voxel_size = longest / options.resolution;
  }
  // Finite coordinates whose span overflows a double (1.7e308 and -1.7e308) are out of scale, not coincident.
  if (!std::isfinite(longest))
    throw BakeError(IssueCode::ScaleOutOfRange,
                    "the mesh's extent overflows a double (coordinates near 1.8e308): is it in metres (unit scale)?");
  if (!(g.voxel_size > 0) || !std::isfinite(g.voxel_size))
    throw BakeError(IssueCode::ZeroVolume, "the mesh has no extent (all vertices coincide)");
  // Checked before the grid is made, so a mesh in the wrong unit fails at once and says so, rather than as an
  // asset the spec refuses after the whole bake.
  if (!(g.voxel_size >= kMinVoxelSize && g.voxel_size <= kMaxVoxelSize)) {
    char text[320];
    std::snprintf(text, sizeof text,
                  "the mesh is %.3g m across, so a voxel would be %.3g m, outside the format's range [%g, %g] m: is "
                  "the mesh in metres (unit scale)? Otherwise %s",
                  longest, g.voxel_size, kMinVoxelSize, kMaxVoxelSize,
                  g.voxel_size < kMinVoxelSize ? "use fewer voxels (a lower resolution or a larger voxel size)"
                                               : "use more voxels (a higher resolution or a smaller voxel size)");
    throw BakeError(IssueCode::ScaleOutOfRange, text);
  }
  // Voxels tile the bounding box exactly from its min corner, plus `margin` voxels on every side.
  for (int a = 0; a < 3; ++a) {
    const double cells = std::max(1.0, std::ceil((hi[a] - lo[a]) / g.voxel_size - 1e-9)) + 2.0 * options.margin;
    if (!(cells <= 65535)) {
      char count[32];
      std::snprintf(count, sizeof count, "%.3g", cells);
      throw BakeError(IssueCode::GridTooLarge, std::string("the grid would have ") + count +
                                                   " voxels along an axis (at most 65535): voxel size too small");
    }
    g.dims[a] = uint32_t(cells);
    g.bricks[a] = (int64_t(g.dims[a]) + kEdge - 1) / kEdge;
    g.origin[a] = lo[a] + (0.5 - options.margin) * g.voxel_size;
  }
  if (g.lattice_count() > 0x7fffffffll)
    throw BakeError(IssueCode::GridTooLarge, "the grid would have " + std::to_string(g.lattice_count()) +
                                                 " bricks (at most 2^31-1): voxel size too small");
  return g;
}

// What the sparse bake holds at its peak, estimated before it starts: the brick table and the lattice (with its
// propagation keys) grow with the volume / 512; the value bricks, their codes and the triangles binned to them with
// the surface (a brick of 8^3 voxels per ~30 voxel^2 of surface, measured on CGAL's sample meshes, at the default
// band; a wider band or a shell, `reach` voxels from the surface, takes a slab that much thicker); and the
// triangle-brick pairs of the binning (bin_triangles: 8 bytes each, twice while they are merged), a ball of bricks
// about each triangle (a band of 64 voxels took 1.3 GB at 96^3, refused by nothing). A bake that would not fit is
// refused here, with the figures, instead of being killed halfway.
void check_memory(const TriangleMesh& mesh, const GridGeometry& g, const VoxelmapSettings& options, double half_shell) {
  const double area_voxels = surface_area(mesh) / (g.voxel_size * g.voxel_size);
  const double reach = options.distance_band + half_shell + 0.5 + 3.5 * std::sqrt(3.0);
  const double default_reach = 3 + 0.5 + 3.5 * std::sqrt(3.0);  // the band of 3 the 1/30 was measured at
  const double value_bricks =
      std::min(double(g.brick_count()), area_voxels / 30.0 * std::max(1.0, reach / default_reach) + 64);
  const double ball = 3.14159265358979 / 6 * std::pow(2 * reach / kEdge + 1, 3);
  const double pairs_per_triangle = std::min(double(g.brick_count()), ball);
  const double bytes = double(g.brick_count()) * 4 + double(g.lattice_count()) * (8 + 4) +
                       value_bricks * (2 * kBrickVoxels * 2 + 8 * 64) +
                       double(mesh.triangles.size()) * std::max(400.0, 16 * pairs_per_triangle);
  const double limit = memory_limit_bytes(options.max_memory_bytes);
  if (bytes <= limit) return;
  char text[512];
  std::snprintf(
      text, sizeof text,
      "the voxelmap (%u x %u x %u voxels, ~%.0f value bricks) would need about %.1f MiB, more than the %.1f MiB "
      "allowed (--max-memory, max_memory_mib in Python; default 3/4 of this machine's memory): use a lower "
      "resolution, a larger voxel size, a narrower band or a thinner shell",
      g.dims[0], g.dims[1], g.dims[2], value_bricks, bytes / 1048576.0, limit / 1048576.0);
  throw BakeError(IssueCode::OutOfMemory, text);
}

// ---- exact near-surface distances. Every triangle is rasterised into the voxels within `half_width` of it
// (closest-point distance in double precision) and each voxel keeps its nearest triangle, so the band is exact
// by construction, also between thin walls and in folds, where a local closest-triangle search (OpenVDB's
// meshToVolume, used before) picks wrong ones. The sign comes from the angle-weighted pseudonormal of the
// closest feature (face, edge or vertex; Baerentzen & Aanaes 2005), exact for closed, oriented surfaces.

struct Pseudonormals {
  std::vector<Vec3> face, vertex;
  std::vector<std::array<Vec3, 3>> edge;  // edge e of a face runs from corner e to corner (e+1)%3
};

Pseudonormals pseudonormals(const TriangleMesh& mesh) {
  Pseudonormals pn;
  pn.face.resize(mesh.triangles.size());
  pn.vertex.assign(mesh.vertices.size(), Vec3{0, 0, 0});
  pn.edge.resize(mesh.triangles.size());
  auto vtx = [&](uint32_t i) { return Vec3{mesh.vertices[i][0], mesh.vertices[i][1], mesh.vertices[i][2]}; };
  std::unordered_map<uint64_t, Vec3> edge_sum;
  auto key = [](uint32_t a, uint32_t b) { return a < b ? (uint64_t(a) << 32 | b) : (uint64_t(b) << 32 | a); };
  for (size_t f = 0; f < mesh.triangles.size(); ++f) {
    const auto& t = mesh.triangles[f];
    const Vec3 p[3] = {vtx(t[0]), vtx(t[1]), vtx(t[2])};
    pn.face[f] = normalized(cross(p[1] - p[0], p[2] - p[0]));
    for (int c = 0; c < 3; ++c) {
      const Vec3 a = normalized(p[(c + 1) % 3] - p[c]), b = normalized(p[(c + 2) % 3] - p[c]);
      const double angle = std::acos(std::clamp(dot(a, b), -1.0, 1.0));
      pn.vertex[t[c]] = pn.vertex[t[c]] + pn.face[f] * angle;
      Vec3& e = edge_sum[key(t[c], t[(c + 1) % 3])];
      e = e + pn.face[f];
    }
  }
  for (size_t f = 0; f < mesh.triangles.size(); ++f)
    for (int c = 0; c < 3; ++c) pn.edge[f][c] = edge_sum[key(mesh.triangles[f][c], mesh.triangles[f][(c + 1) % 3])];
  return pn;
}

Vec3 feature_pseudonormal(const Pseudonormals& pn, const TriangleMesh& mesh, size_t f, Feature feature) {
  switch (feature) {
    case Feature::kCornerA:
      return pn.vertex[mesh.triangles[f][0]];
    case Feature::kCornerB:
      return pn.vertex[mesh.triangles[f][1]];
    case Feature::kCornerC:
      return pn.vertex[mesh.triangles[f][2]];
    case Feature::kEdgeAB:
      return pn.edge[f][0];
    case Feature::kEdgeBC:
      return pn.edge[f][1];
    case Feature::kEdgeCA:
      return pn.edge[f][2];
    case Feature::kFace:
      break;
  }
  return pn.face[f];
}

// ---- triangles in index space (voxel centres at integer coordinates)

struct IndexTriangle {
  Vec3 a, b, c, normal;
  // Unit in-plane normals of the edges, pointing away from the triangle, and their planes' offsets: a point
  // within r of the triangle is less than r beyond each edge's plane (and its own plane).
  Vec3 edge_normal[3];
  double edge_offset[3];
  int64_t lo[3], hi[3];  // voxels within r of the triangle's bounding box, clipped to the grid
};

// The vertices in index space. Every use takes them from here, so that the corners two triangles share are the
// same numbers (the winding rule's exact predicates rely on it).
std::vector<Vec3> index_vertices(const TriangleMesh& mesh, const GridGeometry& g) {
  std::vector<Vec3> out(mesh.vertices.size());
  tbb::parallel_for(size_t(0), out.size(), [&](size_t v) {
    out[v] = {(mesh.vertices[v][0] - g.origin[0]) / g.voxel_size, (mesh.vertices[v][1] - g.origin[1]) / g.voxel_size,
              (mesh.vertices[v][2] - g.origin[2]) / g.voxel_size};
  });
  return out;
}

std::vector<IndexTriangle> index_triangles(const TriangleMesh& mesh, const std::vector<Vec3>& vertices,
                                           const GridGeometry& g, double r) {
  std::vector<IndexTriangle> triangles(mesh.triangles.size());
  tbb::parallel_for(size_t(0), triangles.size(), [&](size_t f) {
    IndexTriangle& t = triangles[f];
    t.a = vertices[mesh.triangles[f][0]];
    t.b = vertices[mesh.triangles[f][1]];
    t.c = vertices[mesh.triangles[f][2]];
    t.normal = normalized(cross(t.b - t.a, t.c - t.a));
    const Vec3* corner[3] = {&t.a, &t.b, &t.c};
    for (int e = 0; e < 3; ++e) {
      const Vec3 &from = *corner[e], &to = *corner[(e + 1) % 3], &opposite = *corner[(e + 2) % 3];
      Vec3 m = normalized(cross(to - from, t.normal));  // zero for a degenerate triangle: no constraint
      if (dot(m, opposite - from) > 0) m = m * -1.0;
      t.edge_normal[e] = m;
      t.edge_offset[e] = dot(m, from);
    }
    for (int axis = 0; axis < 3; ++axis) {
      const double lo = std::min({t.a[axis], t.b[axis], t.c[axis]}), hi = std::max({t.a[axis], t.b[axis], t.c[axis]});
      t.lo[axis] = std::max<int64_t>(0, int64_t(std::ceil(lo - r)));
      t.hi[axis] = std::min<int64_t>(int64_t(g.dims[size_t(axis)]) - 1, int64_t(std::floor(hi + r)));
    }
  });
  return triangles;
}

// Narrows [i0, i1] to the positions i of a row where alpha * i + beta < reach, for each of a triangle's five
// planes (its own, both sides, and its three edges' outward planes). Long thin triangles (CAD fans) would
// otherwise scan their whole bounding box.
struct RowClip {
  int64_t i0, i1;
  void below(double alpha, double beta, double reach) {
    if (alpha > 1e-12)
      i1 = std::min(i1, int64_t(std::floor((reach - beta) / alpha + 1e-9)));
    else if (alpha < -1e-12)
      i0 = std::max(i0, int64_t(std::ceil((reach - beta) / alpha - 1e-9)));
    else if (beta >= reach + 1e-9)
      i1 = i0 - 1;
  }
  // Position i maps to the point (x0 + step * i, y, z).
  void planes(const IndexTriangle& t, double x0, double step, double y, double z, double reach) {
    auto plane = [&](const Vec3& outward, double offset) {
      below(outward[0] * step, outward[0] * x0 + outward[1] * y + outward[2] * z - offset, reach);
    };
    const double own = dot(t.normal, t.a);
    plane(t.normal, own);
    plane(t.normal * -1.0, -own);
    for (int e = 0; e < 3; ++e) plane(t.edge_normal[e], t.edge_offset[e]);
  }
};

// ---- bin_triangles: each brick that a triangle reaches (one of its voxels within r of it) lists the triangle.

struct BrickLists {
  std::vector<int64_t> bricks;    // linear brick indices ((bk * BH + bj) * BW + bi), ascending
  std::vector<uint64_t> first;    // members of bricks[n]: [first[n], first[n + 1])
  std::vector<uint32_t> members;  // triangle indices
  // Position of `brick` in `bricks`, or -1.
  int64_t find(int64_t brick) const {
    const auto it = std::lower_bound(bricks.begin(), bricks.end(), brick);
    return it != bricks.end() && *it == brick ? int64_t(it - bricks.begin()) : -1;
  }
};

BrickLists bin_triangles(const std::vector<IndexTriangle>& triangles, const GridGeometry& g, double r) {
  // A brick's voxel centres lie within 3.5 sqrt(3) of its centre: a triangle within r of one of them is within
  // r + 6.07 of the centre, on the near side of each of its planes.
  const double reach = r + 3.5 * std::sqrt(3.0) + 1e-6;
  tbb::enumerable_thread_specific<std::vector<uint64_t>> pairs;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, triangles.size(), 256), [&](const tbb::blocked_range<size_t>& range) {
    std::vector<uint64_t>& out = pairs.local();
    for (size_t f = range.begin(); f < range.end(); ++f) {
      const IndexTriangle& t = triangles[f];
      if (t.lo[0] > t.hi[0] || t.lo[1] > t.hi[1] || t.lo[2] > t.hi[2]) continue;
      for (int64_t bk = t.lo[2] / kEdge; bk <= t.hi[2] / kEdge; ++bk)
        for (int64_t bj = t.lo[1] / kEdge; bj <= t.hi[1] / kEdge; ++bj) {
          RowClip clip{t.lo[0] / kEdge, t.hi[0] / kEdge};
          clip.planes(t, 3.5, double(kEdge), double(bj * kEdge) + 3.5, double(bk * kEdge) + 3.5, reach);
          for (int64_t bi = clip.i0; bi <= clip.i1; ++bi)
            out.push_back(uint64_t((bk * g.bricks[1] + bj) * g.bricks[0] + bi) << 32 | f);
        }
    }
  });
  std::vector<uint64_t> all;
  size_t total = 0;
  for (const auto& p : pairs) total += p.size();
  all.reserve(total);
  for (auto& p : pairs) {
    all.insert(all.end(), p.begin(), p.end());
    std::vector<uint64_t>().swap(p);
  }
  tbb::parallel_sort(all.begin(), all.end());
  BrickLists lists;
  lists.members.resize(all.size());
  for (size_t n = 0; n < all.size(); ++n) {
    const int64_t brick = int64_t(all[n] >> 32);
    if (lists.bricks.empty() || lists.bricks.back() != brick) {
      lists.bricks.push_back(brick);
      lists.first.push_back(n);
    }
    lists.members[n] = uint32_t(all[n]);
  }
  lists.first.push_back(all.size());
  return lists;
}

// ---- bake_brick_rows

enum class SignRule {
  Closed,   // a closed, outward-oriented surface: the pseudonormal's sign in the band, carried along rows beyond it
  Winding,  // open, non-manifold or self-intersecting: inside = generalized winding number >= 1/2
  Shell,    // shell mode: inside = within half the thickness of the surface
};

// Voxel states in a brick's scratch arrays besides a distance: farther than r from the surface, or past the grid.
constexpr float kFar = std::numeric_limits<float>::quiet_NaN();
constexpr float kPastGrid = std::numeric_limits<float>::infinity();

struct BrickRowsInput {
  const TriangleMesh& mesh;
  const GridGeometry& g;
  const std::vector<IndexTriangle>& triangles;
  const BrickLists& lists;
  const Pseudonormals& pn;
  const WindingNumber* winding;      // SignRule::Winding only: beyond the band
  const BoundaryWinding* boundary;   // SignRule::Winding only: exact sides in the band
  const ClosestTriangle& hierarchy;  // over `triangles`: the band's search by voxel, the lattice's beyond it
  SignRule rule;
  double r;           // voxels: distances are computed within this reach of the surface
  double band;        // voxels: and stored within the band
  double half_shell;  // voxels: shell mode's half thickness
  Bounds mesh_box;    // asset frame
};

// A voxel's nearest triangle so far: its squared distance (voxels^2) and index, ties to the lower index. Double,
// not float: a sliver's two faces can lie nearer to each other than a float tells at the band's distances, and
// the side comes from the nearer one.
struct NearestKey {
  double d2 = std::numeric_limits<double>::infinity();
  uint32_t triangle = ~uint32_t(0);
  bool found() const { return triangle != ~uint32_t(0); }
  bool operator<(const NearestKey& other) const { return d2 != other.d2 ? d2 < other.d2 : triangle < other.triangle; }
};

// Every triangle that the candidate bricks lists.bricks[first, end) of a row list, once each, ascending.
std::vector<uint32_t> row_triangles(const BrickRowsInput& in, int64_t first, int64_t end) {
  std::vector<uint32_t> triangles;
  for (int64_t slot = first; slot < end; ++slot)
    triangles.insert(triangles.end(), in.lists.members.begin() + int64_t(in.lists.first[size_t(slot)]),
                     in.lists.members.begin() + int64_t(in.lists.first[size_t(slot) + 1]));
  std::sort(triangles.begin(), triangles.end());
  triangles.erase(std::unique(triangles.begin(), triangles.end()), triangles.end());
  return triangles;
}

constexpr double kSmallTriangle = 1.0;  // voxels: the bounding sphere's radius below which its bound is tried

// For every voxel of the candidate bricks lists.bricks[first, end) of the row of bricks (bj, bk), the nearest
// triangle within r, whatever order the triangles come in. Each triangle's voxel rows are clipped once for the
// whole row of bricks (a small triangle reaches several bricks of it), then its voxels go to their bricks.
void row_nearest_keys(const BrickRowsInput& in, int64_t first, int64_t end, int64_t bj, int64_t bk,
                      const std::vector<uint32_t>& triangles, std::vector<NearestKey>& keys,
                      std::vector<int32_t>& slot_of_brick) {
  const GridGeometry& g = in.g;
  keys.assign(size_t(end - first) * kBrickVoxels, NearestKey{});
  slot_of_brick.assign(size_t(g.bricks[0]), -1);
  for (int64_t slot = first; slot < end; ++slot)
    slot_of_brick[size_t(in.lists.bricks[size_t(slot)] % g.bricks[0])] = int32_t(slot - first);
  const int64_t j0 = bj * kEdge, k0 = bk * kEdge;
  const int64_t j1 = std::min<int64_t>(j0 + kEdge, g.dims[1]), k1 = std::min<int64_t>(k0 + kEdge, g.dims[2]);
  const double r2 = in.r * in.r;
  for (const uint32_t f : triangles) {
    const IndexTriangle& t = in.triangles[f];
    // The triangle's bounding sphere (centroid, farthest corner, padded past rounding): |p - centre| - radius is
    // a second lower bound on the distance, tight where the triangle is small against a voxel (a dense mesh at a
    // coarse resolution), where the plane's says nothing about voxels beside the triangle in its plane. Larger
    // triangles skip it: there it rarely beats the plane's and costs a square root a voxel (+10 % at 1024).
    const Vec3 centre = (t.a + t.b + t.c) * (1.0 / 3.0);
    const double radius =
        std::sqrt(std::max({distance2(centre, t.a), distance2(centre, t.b), distance2(centre, t.c)})) * (1 + 1e-9) +
        1e-9;
    const bool small = radius < kSmallTriangle;
    for (int64_t k = std::max(k0, t.lo[2]); k <= std::min(k1 - 1, t.hi[2]); ++k)
      for (int64_t j = std::max(j0, t.lo[1]); j <= std::min(j1 - 1, t.hi[1]); ++j) {
        RowClip clip{t.lo[0], t.hi[0]};
        clip.planes(t, 0.0, 1.0, double(j), double(k), in.r);
        const size_t row = size_t(((k - k0) * kEdge + (j - j0)) * kEdge);
        // The distance to the triangle's plane along the row: a lower bound that skips the closest point where a
        // nearer triangle is already known (small triangles overlap every voxel many times).
        const double plane_at_0 = t.normal[1] * double(j) + t.normal[2] * double(k) - dot(t.normal, t.a);
        const double across2 =
            (double(j) - centre[1]) * (double(j) - centre[1]) + (double(k) - centre[2]) * (double(k) - centre[2]);
        for (int64_t i = clip.i0; i <= clip.i1; ++i) {
          const int32_t slot = slot_of_brick[size_t(i / kEdge)];
          if (slot < 0) {  // a brick with no voxel within r of this triangle: on to the next brick
            i = (i / kEdge + 1) * kEdge - 1;
            continue;
          }
          NearestKey& nearest = keys[size_t(slot) * kBrickVoxels + row + size_t(i % kEdge)];
          const double plane = plane_at_0 + t.normal[0] * double(i);
          if (nearest.found()) {
            double bound = std::abs(plane);
            if (small)
              bound = std::max(bound, std::sqrt(across2 + (double(i) - centre[0]) * (double(i) - centre[0])) - radius);
            // Strictly farther, past the bound's rounding: cannot win even a tie.
            if (bound * bound > nearest.d2 * (1 + 1e-12)) continue;
          }
          const Vec3 p{double(i), double(j), double(k)};
          Feature feature;
          const double d2 = distance2(p, closest_on_triangle(p, t.a, t.b, t.c, feature));
          if (!(d2 < r2)) continue;
          nearest = std::min(nearest, NearestKey{d2, f});
        }
      }
  }
}

// The row's voxels the triangle-driven search visits (each triangle's box of voxels within r, clipped to the row),
// in units of one search of the hierarchy: a search costs about as much as kVisitsPerSearch visits (measured on a
// 2 M-triangle sphere at 128, where small triangles overlap each voxel hundreds of times, and on the bunny).
constexpr double kVisitsPerSearch = 64;
bool search_row_by_voxel(const BrickRowsInput& in, const std::vector<uint32_t>& triangles, int64_t first, int64_t end,
                         int64_t bj, int64_t bk) {
  const int64_t j0 = bj * kEdge, k0 = bk * kEdge;
  const int64_t j1 = std::min<int64_t>(j0 + kEdge, in.g.dims[1]), k1 = std::min<int64_t>(k0 + kEdge, in.g.dims[2]);
  const double searches = double(end - first) * double(kBrickVoxels);
  double visits = 0;
  for (const uint32_t f : triangles) {
    const IndexTriangle& t = in.triangles[f];
    const int64_t rows = std::max<int64_t>(0, std::min(j1 - 1, t.hi[1]) - std::max(j0, t.lo[1]) + 1) *
                         std::max<int64_t>(0, std::min(k1 - 1, t.hi[2]) - std::max(k0, t.lo[2]) + 1);
    visits += double(rows) * double(t.hi[0] - t.lo[0] + 1);
    if (visits > kVisitsPerSearch * searches) return true;
  }
  return false;
}

// row_nearest_keys' result by a search of the hierarchy from each voxel of the candidate bricks: cheaper where
// many small triangles reach each voxel (a dense mesh at a coarse resolution). The band's own closest point
// decides whether a triangle is within r, as in row_nearest_keys.
void row_nearest_keys_by_voxel(const BrickRowsInput& in, int64_t first, int64_t end, int64_t bj, int64_t bk,
                               std::vector<NearestKey>& keys) {
  const GridGeometry& g = in.g;
  keys.assign(size_t(end - first) * kBrickVoxels, NearestKey{});
  const double r2 = in.r * in.r;
  constexpr uint32_t kNone = ~uint32_t(0);
  for (int64_t slot = first; slot < end; ++slot) {
    const int64_t bi = in.lists.bricks[size_t(slot)] % g.bricks[0];
    for (size_t v = 0; v < kBrickVoxels; ++v) {
      const int64_t i = bi * kEdge + int64_t(v) % kEdge, j = bj * kEdge + int64_t(v) / kEdge % kEdge,
                    k = bk * kEdge + int64_t(v) / (kEdge * kEdge);
      if (i >= g.dims[0] || j >= g.dims[1] || k >= g.dims[2]) continue;
      const Vec3 p{double(i), double(j), double(k)};
      const uint32_t f = in.hierarchy.nearest(p, r2, kNone).second;
      if (f == kNone) continue;
      const IndexTriangle& t = in.triangles[f];
      Feature feature;
      const double d2 = distance2(p, closest_on_triangle(p, t.a, t.b, t.c, feature));
      if (d2 < r2) keys[size_t(slot - first) * kBrickVoxels + v] = NearestKey{d2, f};
    }
  }
}

// From a brick's keys: the unsigned distance (voxels) of every voxel within r of the surface (kFar beyond,
// kPastGrid past the grid), and for those within r the sign of the nearest feature's angle-weighted pseudonormal
// (exact for a closed, oriented surface; Baerentzen & Aanaes 2005).
void brick_band(const BrickRowsInput& in, const NearestKey* key, int64_t bi, int64_t bj, int64_t bk, float* distance,
                float* pseudonormal_sign) {
  const int64_t i0 = bi * kEdge, j0 = bj * kEdge, k0 = bk * kEdge;
  const int64_t i1 = std::min<int64_t>(i0 + kEdge, in.g.dims[0]), j1 = std::min<int64_t>(j0 + kEdge, in.g.dims[1]),
                k1 = std::min<int64_t>(k0 + kEdge, in.g.dims[2]);
  for (size_t v = 0; v < kBrickVoxels; ++v) {
    const int64_t i = i0 + int64_t(v) % kEdge, j = j0 + int64_t(v) / kEdge % kEdge,
                  k = k0 + int64_t(v) / (kEdge * kEdge);
    pseudonormal_sign[v] = 0;
    if (i >= i1 || j >= j1 || k >= k1) {
      distance[v] = kPastGrid;
      continue;
    }
    if (!key[v].found()) {
      distance[v] = kFar;
      continue;
    }
    const size_t f = key[v].triangle;
    const IndexTriangle& t = in.triangles[f];
    const Vec3 p{double(i), double(j), double(k)};
    Feature feature;
    const Vec3 d = p - closest_on_triangle(p, t.a, t.b, t.c, feature);
    distance[v] = float(length(d));
    pseudonormal_sign[v] = dot(d, feature_pseudonormal(in.pn, in.mesh, f, feature)) < 0 ? -1.0f : 1.0f;
  }
}

Vec3 voxel_point(const GridGeometry& g, double i, double j, double k) {
  return {g.origin[0] + g.voxel_size * i, g.origin[1] + g.voxel_size * j, g.origin[2] + g.voxel_size * k};
}

bool inside_box(const Bounds& box, const Vec3& p) {
  for (int a = 0; a < 3; ++a)
    if (p[a] < box.lo[a] || p[a] > box.hi[a]) return false;
  return true;
}

// Winding rule: the surface's crossings of the 64 voxel lines {(x, j, k)} of a row of bricks, in x order, and for
// voxels asked in increasing x along each line, the signed count of the crossings before them (BoundaryWinding's
// I). Every triangle crossing one of these lines lists a brick of the row: the voxel nearest the crossing is within
// half a voxel of it.
class RowCrossings {
 public:
  RowCrossings(const BrickRowsInput& in, const std::vector<uint32_t>& triangles, int64_t bj, int64_t bk)
      : in_(in), j0_(bj * kEdge), k0_(bk * kEdge) {
    const int64_t j1 = std::min<int64_t>(j0_ + kEdge, in.g.dims[1]), k1 = std::min<int64_t>(k0_ + kEdge, in.g.dims[2]);
    for (const uint32_t f : triangles) {
      const IndexTriangle& t = in.triangles[f];
      const double ylo = std::min({t.a[1], t.b[1], t.c[1]}), yhi = std::max({t.a[1], t.b[1], t.c[1]});
      const double zlo = std::min({t.a[2], t.b[2], t.c[2]}), zhi = std::max({t.a[2], t.b[2], t.c[2]});
      for (int64_t k = std::max<int64_t>(k0_, int64_t(std::ceil(zlo))); k < k1 && double(k) <= zhi; ++k)
        for (int64_t j = std::max<int64_t>(j0_, int64_t(std::ceil(ylo))); j < j1 && double(j) <= yhi; ++j) {
          LineCrossing c;
          if (!BoundaryWinding::line_crossing(t.a, t.b, t.c, double(j), double(k), c)) continue;
          c.triangle = f;
          lines_[size_t((k - k0_) * kEdge + (j - j0_))].push_back(c);
        }
    }
    // The fans that cap small boundary components are crossed like the surface.
    std::vector<uint32_t> fans;
    in.boundary->row_fan_triangles(bj, bk, fans);
    for (const uint32_t name : fans) {
      Vec3 a, b, c;
      int32_t multiplicity;
      in.boundary->fan_triangle(name, a, b, c, multiplicity);
      const double ylo = std::min({a[1], b[1], c[1]}), yhi = std::max({a[1], b[1], c[1]});
      const double zlo = std::min({a[2], b[2], c[2]}), zhi = std::max({a[2], b[2], c[2]});
      for (int64_t k = std::max<int64_t>(k0_, int64_t(std::ceil(zlo))); k < k1 && double(k) <= zhi; ++k)
        for (int64_t j = std::max<int64_t>(j0_, int64_t(std::ceil(ylo))); j < j1 && double(j) <= yhi; ++j) {
          LineCrossing crossing;
          if (!BoundaryWinding::line_crossing(a, b, c, double(j), double(k), crossing)) continue;
          crossing.triangle = name;
          crossing.step *= multiplicity;
          lines_[size_t((k - k0_) * kEdge + (j - j0_))].push_back(crossing);
        }
    }
    for (auto& line : lines_)
      std::sort(line.begin(), line.end(), [](const LineCrossing& x, const LineCrossing& y) {
        return x.x - x.slack != y.x - y.slack ? x.x - x.slack < y.x - y.slack : x.triangle < y.triangle;
      });
  }
  // The count at voxel (i, j0 + line % 8, k0 + line / 8); i must not decrease from one call to the next on a line.
  int32_t count(size_t line, int64_t i) {
    const std::vector<LineCrossing>& crossings = lines_[line];
    const double x = double(i);
    while (next_[line] < crossings.size() && crossings[next_[line]].x - crossings[next_[line]].slack <= x)
      pending_[line].push_back(uint32_t(next_[line]++));
    int32_t uncertain = 0;
    auto& pending = pending_[line];
    for (size_t n = 0; n < pending.size();) {
      const LineCrossing& c = crossings[pending[n]];
      if (c.x + c.slack < x) {  // before the voxel, certainly
        before_[line] += c.step;
        pending[n] = pending.back();
        pending.pop_back();
        continue;
      }
      // Within rounding of the voxel centre (or a triangle nearly parallel to the line): the exact side test.
      const Vec3 p{x, double(j0_ + int64_t(line) % kEdge), double(k0_ + int64_t(line) / kEdge)};
      Vec3 a, b, d;
      if (c.triangle >= BoundaryWinding::kFanTriangle) {
        int32_t multiplicity;
        in_.boundary->fan_triangle(c.triangle, a, b, d, multiplicity);
      } else {
        const IndexTriangle& t = in_.triangles[c.triangle];
        a = t.a, b = t.b, d = t.c;
      }
      if (BoundaryWinding::past_plane(a, b, d, p)) uncertain += c.step;
      ++n;
    }
    return before_[line] + uncertain;
  }

 private:
  const BrickRowsInput& in_;
  int64_t j0_, k0_;
  std::vector<LineCrossing> lines_[kEdge * kEdge];
  size_t next_[kEdge * kEdge] = {};
  int32_t before_[kEdge * kEdge] = {};
  std::vector<uint32_t> pending_[kEdge * kEdge];
};

// Winding rule, a brick with voxels within r of the surface: the exact side of 1/2 of each such voxel's winding
// number (BoundaryWinding): the row's crossing count plus the boundary's caps, the far caps interpolated. Most
// voxels lie far from 1/2 and are decided with a loose bound (few caps per voxel); the rest with a tight one, and
// those it does not separate from 1/2 sum every cap.
constexpr double kLooseBound = 0.05, kTightBound = 1e-3;
void winding_band_signs(const BrickRowsInput& in, RowCrossings& crossings, int64_t bi, int64_t bj, int64_t bk,
                        const float* distance, float* sign) {
  const BoundaryWinding& boundary = *in.boundary;
  int32_t count[kBrickVoxels];
  size_t undecided[kBrickVoxels], n_undecided = 0;
  for (size_t v = 0; v < kBrickVoxels; ++v) {
    if (std::isinf(distance[v]) || std::isnan(distance[v])) continue;
    const int64_t i = bi * kEdge + int64_t(v) % kEdge, j = bj * kEdge + int64_t(v) / kEdge % kEdge,
                  k = bk * kEdge + int64_t(v) / (kEdge * kEdge);
    count[v] = crossings.count(v / kEdge, i);
    // The object stays within its surface's box, as beyond the band: a plane separates such a voxel from the
    // surface (one sheet then covers at most a hemisphere of it, though stacked open sheets can add up past 1/2).
    if (!inside_box(in.mesh_box, voxel_point(in.g, double(i), double(j), double(k)))) {
      sign[v] = 1.0f;
    } else if (boundary.closed()) {
      sign[v] = count[v] >= 1 ? -1.0f : 1.0f;  // an integer
    } else {
      undecided[n_undecided++] = v;
    }
  }
  if (n_undecided == 0) return;
  auto point = [&](size_t v) {
    return Vec3{double(bi * kEdge + int64_t(v) % kEdge), double(bj * kEdge + int64_t(v) / kEdge % kEdge),
                double(bk * kEdge + int64_t(v) / (kEdge * kEdge))};
  };
  BoundaryWinding::Cell cell;
  for (const double target : {kLooseBound, kTightBound}) {
    boundary.prepare_cell(bi, bj, bk, target, cell);
    size_t left = 0;
    for (size_t n = 0; n < n_undecided; ++n) {
      const size_t v = undecided[n];
      const double w = count[v] + boundary.cell_caps(cell, point(v));
      if (std::abs(w - 0.5) > cell.bound)
        sign[v] = w >= 0.5 ? -1.0f : 1.0f;
      else
        undecided[left++] = v;
    }
    n_undecided = left;
    if (n_undecided == 0) return;
  }
  for (size_t n = 0; n < n_undecided; ++n) {
    const size_t v = undecided[n];
    sign[v] = count[v] + boundary.caps(point(v)) >= 0.5 ? -1.0f : 1.0f;
  }
}

// The sign (+1 outside, -1 inside) of a brick none of whose voxels lies within r of the surface: all of them are
// on one side (two 6-neighbours farther than r >= 1 from the surface cannot have it between them).
float coarse_sign(const BrickRowsInput& in, int64_t bi, int64_t bj, int64_t bk, float carried) {
  switch (in.rule) {
    case SignRule::Closed:
      return carried;
    case SignRule::Shell:
      return 1;  // farther than r = band + half the thickness from the surface: outside the shell
    case SignRule::Winding:
      break;  // winding_brick_signs decides
  }
  (void)bi, (void)bj, (void)bk;
  return 1;
}

// Winding rule, a brick without a voxel within r of the surface: no surface passes through it (its voxel centres'
// hull lies more than r - sqrt(3)/2 from it), so the winding number is smooth there and changes side only across
// the closure of a hole. The middle voxel decides a brick far from 1/2; nearer, the brick's 8 corner voxels do,
// and where they disagree each voxel takes the side of their trilinear interpolation (spec §3.1: beyond the band
// the winding number may be interpolated). Returns true if every voxel is on the side `sign[0]` says.
bool winding_brick_signs(const BrickRowsInput& in, int64_t bi, int64_t bj, int64_t bk, float* sign) {
  const GridGeometry& g = in.g;
  int64_t first[3] = {bi * kEdge, bj * kEdge, bk * kEdge}, last[3];
  for (int a = 0; a < 3; ++a) last[a] = std::min<int64_t>(first[a] + kEdge, g.dims[size_t(a)]) - 1;
  auto point = [&](int64_t i, int64_t j, int64_t k) { return voxel_point(g, double(i), double(j), double(k)); };
  // The approximate winding number itself (no bounding-box rule: that applies to each voxel's decision below, and
  // the value is what says how far the brick is from 1/2).
  const double middle =
      (*in.winding)(point((first[0] + last[0]) / 2, (first[1] + last[1]) / 2, (first[2] + last[2]) / 2));
  const bool whole_brick_in_box = inside_box(in.mesh_box, point(first[0], first[1], first[2])) &&
                                  inside_box(in.mesh_box, point(last[0], last[1], last[2]));
  if (std::abs(middle - 0.5) >= 0.4 && (whole_brick_in_box || middle < 0.5)) {
    std::fill(sign, sign + kBrickVoxels, middle >= 0.5 ? -1.0f : 1.0f);
    return true;
  }
  double corner[8];
  bool corners_known = false;
  if (std::abs(middle - 0.5) < 0.4) {
    for (int c = 0; c < 8; ++c)
      corner[c] =
          (*in.winding)(point(c & 1 ? last[0] : first[0], c & 2 ? last[1] : first[1], c & 4 ? last[2] : first[2]));
    corners_known = true;
  }
  bool uniform = true;
  for (size_t v = 0; v < kBrickVoxels; ++v) {
    const int64_t l[3] = {int64_t(v) % kEdge, int64_t(v) / kEdge % kEdge, int64_t(v) / (kEdge * kEdge)};
    double w = middle;
    if (corners_known) {
      double t[3];
      for (int a = 0; a < 3; ++a)
        t[a] = last[a] > first[a] ? std::min(1.0, double(l[a]) / double(last[a] - first[a])) : 0.0;
      w = 0;
      for (int c = 0; c < 8; ++c)
        w += corner[c] * (c & 1 ? t[0] : 1 - t[0]) * (c & 2 ? t[1] : 1 - t[1]) * (c & 4 ? t[2] : 1 - t[2]);
    }
    const bool inside = w >= 0.5 && inside_box(in.mesh_box, point(first[0] + l[0], first[1] + l[1], first[2] + l[2]));
    sign[v] = inside ? -1.0f : 1.0f;
    uniform = uniform && sign[v] == sign[0];
  }
  return uniform;
}

// Winding rule: signs of a brick's voxels farther than r from the surface. Each takes the sign of the band voxels
// it reaches through such voxels (the surface cannot pass between them); where those disagree (across a hole, which
// the winding number closes) or there are none, the winding number decides, interpolated from the brick's points
// 4 voxels apart (as 1.x producers did): every corner of such a voxel's cell lies within 2 sqrt(3) < r of it, on its
// side of the surface, where the winding number varies smoothly.
// The winding number inside a brick interpolated from its points (0, 4, 8)^3 (clamped to the grid), evaluated when
// first needed.
class BrickWinding {
 public:
  BrickWinding(const BrickRowsInput& in, int64_t bi, int64_t bj, int64_t bk)
      : in_(in), first_{bi * kEdge, bj * kEdge, bk * kEdge} {}

  double at(int v) {
    constexpr int E = int(kEdge);
    if (!known_) {
      for (int n = 0; n < 27; ++n)
        lattice_[n] =
            (*in_.winding)(voxel_point(in_.g, coordinate(0, n % 3), coordinate(1, n / 3 % 3), coordinate(2, n / 9)));
      known_ = true;
    }
    const int l[3] = {v % E, v / E % E, v / (E * E)};
    int cell[3];
    double t[3];
    for (int a = 0; a < 3; ++a) {
      cell[a] = l[a] / 4;
      const double x0 = coordinate(a, cell[a]), x1 = coordinate(a, cell[a] + 1);
      t[a] = x1 > x0 ? (double(first_[a] + l[a]) - x0) / (x1 - x0) : 0.0;
    }
    double w = 0;
    for (int c = 0; c < 8; ++c) {
      const int da = c & 1, db = (c >> 1) & 1, dc = c >> 2;
      w += lattice_[(cell[2] + dc) * 9 + (cell[1] + db) * 3 + cell[0] + da] * (da ? t[0] : 1 - t[0]) *
           (db ? t[1] : 1 - t[1]) * (dc ? t[2] : 1 - t[2]);
    }
    return w;
  }
  Vec3 voxel(int v) const {
    constexpr int E = int(kEdge);
    return voxel_point(in_.g, double(first_[0] + v % E), double(first_[1] + v / E % E),
                       double(first_[2] + v / (E * E)));
  }

 private:
  double coordinate(int a, int step) const {
    return double(std::min<int64_t>(first_[a] + 4 * step, in_.g.dims[size_t(a)] - 1));
  }
  const BrickRowsInput& in_;
  const int64_t first_[3];
  double lattice_[27] = {};
  bool known_ = false;
};

// The voxels beyond the band reachable from `start` through such voxels (appended to `members`, marked in
// `component`), and the sides of the band voxels they touch.
void flood_beyond_band(const float* distance, const float* sign, int start, int* component, std::vector<int>& members,
                       bool& seen_inside, bool& seen_outside) {
  constexpr int E = int(kEdge);
  members.clear();
  members.push_back(start);
  component[start] = start;
  for (size_t next = 0; next < members.size(); ++next) {
    const int v = members[next];
    const int li = v % E, lj = v / E % E, lk = v / (E * E);
    const int steps[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    for (const auto& s : steps) {
      const int ni = li + s[0], nj = lj + s[1], nk = lk + s[2];
      if (ni < 0 || nj < 0 || nk < 0 || ni >= E || nj >= E || nk >= E) continue;
      const int n = (nk * E + nj) * E + ni;
      if (std::isinf(distance[n])) continue;  // past the grid
      if (!std::isnan(distance[n])) {
        (sign[n] < 0 ? seen_inside : seen_outside) = true;
      } else if (component[n] < 0) {
        component[n] = start;
        members.push_back(n);
      }
    }
  }
}

// Winding rule: signs of a brick's voxels farther than r from the surface. Each takes the sign of the band voxels
// it reaches through such voxels (the surface cannot pass between them); where those disagree (across a hole, which
// the winding number closes) or there are none, the winding number decides, interpolated from the brick's points
// 4 voxels apart (as 1.x producers did): every corner of such a voxel's cell lies within 2 sqrt(3) < r of it, on its
// side of the surface, where the winding number varies smoothly.
void winding_signs_beyond_band(const BrickRowsInput& in, int64_t bi, int64_t bj, int64_t bk, const float* distance,
                               float* sign) {
  int component[kBrickVoxels];
  std::fill(component, component + kBrickVoxels, -1);
  std::vector<int> members;
  members.reserve(kBrickVoxels);
  BrickWinding winding(in, bi, bj, bk);
  for (int start = 0; start < int(kBrickVoxels); ++start) {
    if (!std::isnan(distance[start]) || component[start] >= 0) continue;
    bool seen_inside = false, seen_outside = false;
    flood_beyond_band(distance, sign, start, component, members, seen_inside, seen_outside);
    for (int v : members) {
      if (seen_inside != seen_outside)
        sign[v] = seen_inside ? -1.0f : 1.0f;
      else
        sign[v] = winding.at(v) >= 0.5 && inside_box(in.mesh_box, winding.voxel(v)) ? -1.0f : 1.0f;
    }
  }
}

// One row of bricks' value bricks: linear brick indices and 512 codes each, in row order.
struct RowOutput {
  std::vector<int64_t> bricks;
  std::vector<int16_t> codes;
};

// The signs of a brick with band voxels: a band voxel's by the rule (the closed surface's pseudonormal or the winding
// number, both in `near_sign`; a shell's by its distance to the sheets), carried along each voxel row (`carried`,
// the row's sign at the last voxel reached) to the voxels beyond the band and past the grid. The winding rule
// decides the voxels beyond its band afterwards (winding_signs_beyond_band).
void band_brick_signs(const BrickRowsInput& in, const float* distance, const float* near_sign, float* carried,
                      float* sign) {
  for (size_t v = 0; v < kBrickVoxels; ++v) {
    float& row_sign = carried[v / kEdge];
    if (std::isinf(distance[v])) {
      sign[v] = row_sign;
    } else if (std::isnan(distance[v])) {
      sign[v] = in.rule == SignRule::Shell ? 1.0f : row_sign;  // Winding: decided after
    } else {
      sign[v] = in.rule == SignRule::Shell ? (distance[v] < in.half_shell ? -1.0f : 1.0f) : near_sign[v];
      row_sign = sign[v];
    }
  }
}

struct BrickSides {
  bool stored = false, inside = false, outside = false;
};

// A brick's codes: the distances within the band stored, every other voxel in the grid an estimate's sign (its value
// comes from the lattice), 0 past the grid; and which kinds it has.
BrickSides encode_brick(const BrickRowsInput& in, const Voxelmap& vm, const float* distance, const float* sign,
                        int16_t* codes) {
  BrickSides sides;
  for (size_t v = 0; v < kBrickVoxels; ++v) {
    codes[v] = 0;
    if (std::isinf(distance[v])) continue;
    (sign[v] < 0 ? sides.inside : sides.outside) = true;
    if (!std::isnan(distance[v])) {
      const double d = in.rule == SignRule::Shell ? double(distance[v]) - in.half_shell : sign[v] * double(distance[v]);
      if (std::abs(d) <= in.band) {
        codes[v] = vm.encode_stored(d * in.g.voxel_size);
        sides.stored = true;
        continue;
      }
    }
    codes[v] = int16_t(sign[v] < 0 ? -2 : 2);
  }
  return sides;
}

// Bakes the row of bricks (bj, bk) whose candidate bricks (those listing triangles) are lists.bricks[first, end):
// value bricks are coded into `out`; coarse bricks inside the object are marked in `table` (which starts as all
// coarse, outside).
void bake_brick_row(const BrickRowsInput& in, const Voxelmap& vm, int64_t bj, int64_t bk, int64_t first, int64_t end,
                    std::vector<int32_t>& table, RowOutput& out) {
  const GridGeometry& g = in.g;
  const int64_t BW = g.bricks[0];
  float carried[kEdge * kEdge];                       // each voxel row's sign at the last voxel reached
  std::fill(carried, carried + kEdge * kEdge, 1.0f);  // a row starts outside: its first voxel lies in the margin
  float distance[kBrickVoxels], near_sign[kBrickVoxels], sign[kBrickVoxels];
  std::fill(sign, sign + kBrickVoxels, 1.0f);
  auto set_coarse = [&](int64_t bi, float s) {
    if (s < 0) table[size_t((bk * g.bricks[1] + bj) * BW + bi)] = Voxelmap::kCoarseInside;
    std::fill(carried, carried + kEdge * kEdge, s);
  };
  // A brick with no voxel within r of the surface: coarse, unless the winding number's closure of a hole passes
  // through it (then a value brick of estimates only, each voxel with its own sign).
  auto beyond_band = [&](int64_t bi) {
    if (in.rule != SignRule::Winding) return set_coarse(bi, coarse_sign(in, bi, bj, bk, carried[0]));
    if (winding_brick_signs(in, bi, bj, bk, sign)) return set_coarse(bi, sign[0]);
    out.bricks.push_back((bk * g.bricks[1] + bj) * BW + bi);
    for (size_t v = 0; v < kBrickVoxels; ++v) {
      const bool in_grid = bi * kEdge + int64_t(v) % kEdge < g.dims[0] &&
                           bj * kEdge + int64_t(v) / kEdge % kEdge < g.dims[1] &&
                           bk * kEdge + int64_t(v) / (kEdge * kEdge) < g.dims[2];
      out.codes.push_back(in_grid ? int16_t(sign[v] < 0 ? -2 : 2) : int16_t(0));
    }
  };
  std::vector<NearestKey> keys;
  std::vector<int32_t> slot_of_brick;
  const std::vector<uint32_t> triangles = row_triangles(in, first, end);
  if (end > first) {
    if (search_row_by_voxel(in, triangles, first, end, bj, bk))
      row_nearest_keys_by_voxel(in, first, end, bj, bk, keys);
    else
      row_nearest_keys(in, first, end, bj, bk, triangles, keys, slot_of_brick);
  }
  std::optional<RowCrossings> crossings;
  if (in.rule == SignRule::Winding && end > first) crossings.emplace(in, triangles, bj, bk);
  int64_t next = 0;  // the first brick of the row not yet decided
  for (int64_t slot = first; slot <= end; ++slot) {
    const int64_t bi = slot < end ? in.lists.bricks[size_t(slot)] % BW : BW;
    for (; next < bi; ++next) beyond_band(next);
    if (slot == end) break;
    next = bi + 1;
    brick_band(in, keys.data() + size_t(slot - first) * kBrickVoxels, bi, bj, bk, distance, near_sign);
    if (in.rule == SignRule::Winding) winding_band_signs(in, *crossings, bi, bj, bk, distance, near_sign);
    band_brick_signs(in, distance, near_sign, carried, sign);
    if (in.rule == SignRule::Winding) winding_signs_beyond_band(in, bi, bj, bk, distance, sign);
    int16_t codes[kBrickVoxels];
    const BrickSides sides = encode_brick(in, vm, distance, sign, codes);
    // A value brick stores the distances within the band; a brick without any, all on one side, is coarse.
    if (sides.stored || (sides.inside && sides.outside)) {
      out.bricks.push_back((bk * g.bricks[1] + bj) * BW + bi);
      out.codes.insert(out.codes.end(), codes, codes + kBrickVoxels);
    } else {
      set_coarse(bi, sides.inside ? -1.0f : 1.0f);
    }
    if (in.rule == SignRule::Winding)  // the next coarse brick decides by itself
      std::fill(carried, carried + kEdge * kEdge, 1.0f);
  }
}

// ---- propagate_lattice: the exact unsigned distance to the surface at every lattice point (brick corner). A
// point within r of the surface takes the nearest of the triangles its brick lists, which hold every triangle
// within r of it. Farther away, nearest triangles are first carried from point to neighbouring point in sweeps
// along each axis (vector propagation, Danielsson 1980), round after round until no point changes: a distance to
// a real triangle, nearly always the nearest one. A hierarchy over the triangles then searches within that bound
// for a nearer one, which keeps its search small.

constexpr uint64_t kNoTriangle = ~uint64_t(0);
// Within kExactReach voxels of the surface lattice values are exact; beyond, they may exceed the exact distance by
// kFarSlack of it (spec §3.3): a search that needs only that much opens far fewer boxes far from the surface, where
// the lattice serves deep penetrations and distant pruning only.
constexpr double kExactReach = 16.0;
constexpr double kFarSlack = 0.1;

// Rounds of sweeps at most: one round leaves the far lattice up to 10 % off the exact distance on the bunny at
// 1024 (p99 23 voxels), three p99 1 voxel, six 0.4; most points stop changing within a few rounds.
constexpr int kMaxSweepRounds = 8;

// A dense 3-D grid's shape: x fastest.
struct GridShape {
  std::array<int64_t, 3> dims{};
  size_t index(int64_t a, int64_t b, int64_t c) const { return size_t((c * dims[1] + b) * dims[0] + a); }
};

// The lines of a grid along one axis, for passes that run each line in order and the lines in parallel.
struct AxisLines {
  int axis, u_axis, v_axis;
  int64_t length, lines_u, count;
  AxisLines(const GridShape& s, int along)
      : axis(along),
        u_axis(along == 0 ? 1 : 0),
        v_axis(along == 2 ? 1 : 2),
        length(s.dims[size_t(along)]),
        lines_u(s.dims[size_t(u_axis)]),
        count(lines_u * s.dims[size_t(v_axis)]) {}
  /// Line `line`'s first point (0 along the axis).
  void first(int64_t line, int64_t at[3]) const {
    at[u_axis] = line % lines_u;
    at[v_axis] = line / lines_u;
    at[axis] = 0;
  }
};

struct Lattice : GridShape {
  std::vector<uint64_t> keys;  // (squared distance in voxels^2 as float bits, triangle), kNoTriangle if none yet
  // 1 + the last sweep (0, 1, ... over the rounds, three per round) that changed the point; 0 if none did.
  std::vector<uint8_t> changed;
};

uint64_t distance_key(const IndexTriangle& t, const Vec3& p, uint32_t f) {
  Feature feature;
  const float d2 = float(distance2(p, closest_on_triangle(p, t.a, t.b, t.c, feature)));
  uint32_t bits;
  std::memcpy(&bits, &d2, sizeof bits);
  return uint64_t(bits) << 32 | f;
}

// A lattice point (a, b, c) in voxel coordinates: a brick corner, the last one along an axis clamped to the grid.
Vec3 lattice_point(const GridGeometry& g, int64_t a, int64_t b, int64_t c) {
  auto coordinate = [&](int64_t n, int axis) { return double(std::min<int64_t>(n * kEdge, g.dims[size_t(axis)] - 1)); };
  return Vec3{coordinate(a, 0), coordinate(b, 1), coordinate(c, 2)};
}

// Each lattice point is a voxel of one brick (the last brick along an axis holds the grid's last voxel): that
// brick's list has every triangle within r of the point, and so its nearest if that is within r.
void lattice_near_surface(const GridGeometry& g, const std::vector<IndexTriangle>& triangles, const BrickLists& lists,
                          Lattice& L) {
  tbb::parallel_for(size_t(0), lists.bricks.size(), [&](size_t slot) {
    const int64_t brick = lists.bricks[slot];
    const int64_t bi = brick % g.bricks[0], bj = brick / g.bricks[0] % g.bricks[1],
                  bk = brick / (g.bricks[0] * g.bricks[1]);
    for (int64_t c = bk; c <= (bk + 1 == g.bricks[2] ? bk + 1 : bk); ++c)
      for (int64_t b = bj; b <= (bj + 1 == g.bricks[1] ? bj + 1 : bj); ++b)
        for (int64_t a = bi; a <= (bi + 1 == g.bricks[0] ? bi + 1 : bi); ++a) {
          const Vec3 p = lattice_point(g, a, b, c);
          uint64_t best = kNoTriangle;
          for (uint64_t m = lists.first[slot]; m < lists.first[slot + 1]; ++m)
            best = std::min(best, distance_key(triangles[lists.members[m]], p, lists.members[m]));
          L.keys[L.index(a, b, c)] = best;
        }
  });
}

// A parallel loop's progress: every worker adds its work, and the thread that made the ticker (which works in the
// loop too) reports at most every 0.2 s, its first piece of work at once. So the callback runs where the bake was
// called, as every other report does (Python checks Ctrl-C there), and a report that throws cancels the loop (TBB
// rethrows it).
class ProgressTicker {
 public:
  ProgressTicker(const VoxelmapProgress& report, double from, double to, uint64_t total)
      : report_(report), from_(from), to_(to), total_(std::max<uint64_t>(total, 1)) {}
  void add(uint64_t work) {
    const uint64_t done = done_.fetch_add(work, std::memory_order_relaxed) + work;
    if (!report_ || std::this_thread::get_id() != caller_) return;
    const auto now = std::chrono::steady_clock::now();
    if (now < next_) return;
    next_ = now + std::chrono::milliseconds(200);
    report_(from_ + (to_ - from_) * std::min(1.0, double(done) / double(total_)));
  }

 private:
  const VoxelmapProgress& report_;
  const double from_, to_;
  const uint64_t total_;
  const std::thread::id caller_ = std::this_thread::get_id();
  std::atomic<uint64_t> done_{0};
  std::chrono::steady_clock::time_point next_{};  // the caller's alone
};

// Shares of a voxelmap's time its parts start at, for its progress: CGAL's bunny spends 49 / 36 / 16 % in the band,
// lattice and estimates at 1024 and 24 / 73 / 2 % at 4096, a sphere at 1000 35 / 42 / 22 %, a 2 M triangle sphere
// at 256 seconds preparing its triangles and then 90 % in the band. The lattice's share is its sweeps', then its
// search's beyond the band (at 2048: 8 and 10 s of the voxelmap's 34 s).
constexpr double kBinnedShare = 0.03, kBandShare = 0.06, kLatticeShare = 0.45, kSweptShare = 0.6,
                 kPropagatedShare = 0.75, kEstimatesShare = 0.8;

// Carries nearest triangles along one axis, both ways, every line in parallel; `sweep` counts the sweeps so far
// (three per round). Two neighbours compared in this axis's previous sweep and unchanged since are not compared
// again: that changed neither. Returns how many points changed.
size_t sweep_lattice(const GridGeometry& g, const std::vector<IndexTriangle>& triangles, int axis, int sweep,
                     Lattice& L, const VoxelmapProgress& progress) {
  const AxisLines lines(L, axis);
  // Each of the rounds' sweeps an equal part of the lattice's share until it is propagated.
  const double part = (kSweptShare - kLatticeShare) / (3 * kMaxSweepRounds);
  ProgressTicker ticker(progress, kLatticeShare + part * sweep, kLatticeShare + part * (sweep + 1),
                        uint64_t(lines.count));
  const int64_t n = lines.length;
  const int settled_before = sweep - 2;  // a stamp below this: unchanged since this axis's previous sweep began
  return tbb::parallel_reduce(
      tbb::blocked_range<int64_t>(0, lines.count), size_t(0),
      [&](const tbb::blocked_range<int64_t>& range, size_t changes) {
        for (int64_t line = range.begin(); line != range.end(); ++line) {
          int64_t at[3];
          lines.first(line, at);
          auto visit = [&](int64_t s, int64_t from) {
            at[axis] = from;
            const size_t from_index = L.index(at[0], at[1], at[2]);
            at[axis] = s;
            const size_t own_index = L.index(at[0], at[1], at[2]);
            if (L.changed[from_index] < settled_before && L.changed[own_index] < settled_before) return;
            const uint64_t neighbour = L.keys[from_index];
            uint64_t& own = L.keys[own_index];
            if (neighbour == kNoTriangle || uint32_t(neighbour) == uint32_t(own)) return;
            const uint32_t f = uint32_t(neighbour);
            const uint64_t carried = distance_key(triangles[f], lattice_point(g, at[0], at[1], at[2]), f);
            if (carried >= own) return;
            own = carried;
            L.changed[own_index] = uint8_t(sweep + 1);
            ++changes;
          };
          for (int64_t s = 1; s < n; ++s) visit(s, s - 1);
          for (int64_t s = n - 2; s >= 0; --s) visit(s, s + 1);
        }
        ticker.add(uint64_t(range.end() - range.begin()));
        return changes;
      },
      std::plus<size_t>());
}

// A lower bound of the distance to the surface anywhere in the grid, from cells of kCell voxels: the cells the
// triangles' boxes touch, and for every cell the Euclidean distance (in cells) to the nearest of them. A point far
// from the surface whose carried distance is already within kFarSlack of this bound needs no search; at 4096 that
// is most of the lattice, and the search was half the bake.
constexpr int64_t kCell = 16;

struct SurfaceCells : GridShape {
  std::vector<float> distance2;  // cells^2 to the nearest touched cell; empty if the bound is not available
  // Voxel coordinate x (>= -1) lies in cell floor((x + 1) / kCell), whose box is [kCell c - 1, kCell c + kCell - 1].
  static int64_t cell_of(double x) { return int64_t(std::floor((x + 1) / double(kCell))); }
  /// Voxels: at most the distance from voxel coordinates p to any triangle. A point and a surface point each lie
  /// within half a cell's diagonal of their cells' centres, which are at least the cell distance apart.
  double lower_bound(const Vec3& p) const {
    const double cells = std::sqrt(double(distance2[index(cell_of(p[0]), cell_of(p[1]), cell_of(p[2]))]));
    return (double(kCell) * cells - double(kCell) * std::sqrt(3.0)) * (1 - 1e-9) - 1e-6;
  }
};

// Squared Euclidean distance transform of one line of cells (Felzenszwalb and Huttenlocher, "Distance Transforms
// of Sampled Functions", 2012): the lower envelope of the parabolas rooted at the finite entries of f.
void distance_transform_line(float* f, int64_t n, int64_t stride, std::vector<int64_t>& v, std::vector<double>& z,
                             std::vector<double>& in) {
  in.resize(size_t(n));
  for (int64_t q = 0; q < n; ++q) in[size_t(q)] = double(f[q * stride]);
  v.resize(size_t(n));
  z.resize(size_t(n) + 1);
  int64_t k = -1;
  for (int64_t q = 0; q < n; ++q) {
    if (!std::isfinite(in[size_t(q)])) continue;
    double s = -std::numeric_limits<double>::infinity();
    while (k >= 0) {
      const int64_t p = v[size_t(k)];
      s = ((in[size_t(q)] + double(q * q)) - (in[size_t(p)] + double(p * p))) / double(2 * (q - p));
      if (s > z[size_t(k)]) break;
      --k;
    }
    ++k;
    v[size_t(k)] = q;
    z[size_t(k)] = k == 0 ? -std::numeric_limits<double>::infinity() : s;
    z[size_t(k) + 1] = std::numeric_limits<double>::infinity();
  }
  if (k < 0) return;  // no finite entry: the line stays infinite
  for (int64_t q = 0, j = 0; q < n; ++q) {
    while (z[size_t(j) + 1] < double(q)) ++j;
    const int64_t p = v[size_t(j)];
    f[q * stride] = float(double((q - p) * (q - p)) + in[size_t(p)]);
  }
}

SurfaceCells surface_cells(const GridGeometry& g, const std::vector<IndexTriangle>& triangles) {
  SurfaceCells cells;
  for (int a = 0; a < 3; ++a) cells.dims[size_t(a)] = (int64_t(g.dims[size_t(a)]) + 1) / kCell + 1;
  const float far = std::numeric_limits<float>::infinity();
  std::vector<float> distance2(size_t(cells.dims[0] * cells.dims[1] * cells.dims[2]), far);
  for (const IndexTriangle& t : triangles) {
    int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
      lo[a] = SurfaceCells::cell_of(std::min({t.a[a], t.b[a], t.c[a]}));
      hi[a] = SurfaceCells::cell_of(std::max({t.a[a], t.b[a], t.c[a]}));
      if (!(lo[a] >= 0 && hi[a] < cells.dims[size_t(a)])) return cells;  // outside the cells: no bound
    }
    for (int64_t c = lo[2]; c <= hi[2]; ++c)
      for (int64_t b = lo[1]; b <= hi[1]; ++b)
        for (int64_t a = lo[0]; a <= hi[0]; ++a) distance2[cells.index(a, b, c)] = 0;
  }
  for (int axis = 0; axis < 3; ++axis) {
    const AxisLines lines(cells, axis);
    const int64_t stride = axis == 0 ? 1 : axis == 1 ? cells.dims[0] : cells.dims[0] * cells.dims[1];
    tbb::parallel_for(tbb::blocked_range<int64_t>(0, lines.count), [&](const tbb::blocked_range<int64_t>& range) {
      std::vector<int64_t> v;
      std::vector<double> z, in;
      for (int64_t line = range.begin(); line != range.end(); ++line) {
        int64_t at[3];
        lines.first(line, at);
        distance_transform_line(distance2.data() + cells.index(at[0], at[1], at[2]), lines.length, stride, v, z, in);
      }
    });
  }
  cells.distance2 = std::move(distance2);
  return cells;
}

// Every point beyond r has an upper bound after the sweeps, the distance to a real triangle: unless the surface's
// cells already bound it within kFarSlack, the hierarchy searches only within it for the nearest one.
void search_lattice_beyond_band(const GridGeometry& g, const ClosestTriangle& hierarchy, const SurfaceCells& cells,
                                double r, Lattice& L, const VoxelmapProgress& progress) {
  const double r2 = r * r;
  ProgressTicker ticker(progress, kSweptShare, kPropagatedShare, uint64_t(L.dims[2]));
  tbb::parallel_for(int64_t(0), L.dims[2], [&](int64_t c) {
    for (int64_t b = 0; b < L.dims[1]; ++b)
      for (int64_t a = 0; a < L.dims[0]; ++a) {
        uint64_t& key = L.keys[L.index(a, b, c)];
        float d2f;
        const uint32_t bits = uint32_t(key >> 32);
        std::memcpy(&d2f, &bits, sizeof d2f);
        if (key != kNoTriangle && double(d2f) < r2) continue;  // exact already
        const Vec3 p = lattice_point(g, a, b, c);
        if (key != kNoTriangle && !cells.distance2.empty()) {
          const double below = cells.lower_bound(p);
          if (below > kExactReach && double(d2f) <= (1 + kFarSlack) * (1 + kFarSlack) * below * below) continue;
        }
        const double bound2 = key == kNoTriangle ? std::numeric_limits<double>::infinity() : double(d2f) * (1 + 1e-6);
        // A search with slack finds a distance d within (1 + slack) of the exact one: if d is beyond
        // kExactReach (1 + slack), the point is beyond kExactReach and may keep it; otherwise it is searched exactly.
        const double reach2 = kExactReach * kExactReach * (1 + kFarSlack) * (1 + kFarSlack);
        auto [d2, f] = hierarchy.nearest(p, bound2, uint32_t(key), bound2 > reach2 ? kFarSlack : 0.0);
        if (bound2 > reach2 && d2 <= reach2) std::tie(d2, f) = hierarchy.nearest(p, d2 * (1 + 1e-9), f, 0.0);
        if (!(d2 < bound2)) continue;
        const float nearest = float(d2);
        uint32_t nearest_bits;
        std::memcpy(&nearest_bits, &nearest, sizeof nearest_bits);
        key = std::min(key, uint64_t(nearest_bits) << 32 | f);
      }
    ticker.add(1);
  });
}

Lattice propagate_lattice(const GridGeometry& g, const std::vector<IndexTriangle>& triangles, const BrickLists& lists,
                          const ClosestTriangle& hierarchy, double r, const VoxelmapProgress& progress) {
  Lattice L;
  for (int a = 0; a < 3; ++a) L.dims[size_t(a)] = g.bricks[size_t(a)] + 1;
  L.keys.assign(size_t(L.dims[0] * L.dims[1] * L.dims[2]), kNoTriangle);
  L.changed.assign(L.keys.size(), 0);
  lattice_near_surface(g, triangles, lists, L);
  for (int round = 0, sweep = 0; round < kMaxSweepRounds; ++round) {
    size_t changes = 0;
    for (int axis = 0; axis < 3; ++axis) changes += sweep_lattice(g, triangles, axis, sweep++, L, progress);
    if (changes == 0) break;
  }
  std::vector<uint8_t>().swap(L.changed);
  if (progress) progress(kSweptShare);
  search_lattice_beyond_band(g, hierarchy, surface_cells(g, triangles), r, L, progress);
  return L;
}

float float_not_below(double value) {
  float f = float(value);
  if (double(f) < value) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

// The grid a bake fills, checked against the settings' limits and the memory it would take. Shell mode: the object
// is every point within half the thickness of the surface; the grid's margin grows by that much so that the shell's
// outer sheets keep the margin's outer voxels around them.
struct GridPlan {
  GridGeometry g;
  uint32_t margin = 0;
  double half_shell = 0;  ///< voxels; 0 unless a shell
};

GridPlan plan_voxelmap_grid(const TriangleMesh& mesh, const VoxelmapSettings& options) {
  if (!(options.distance_band >= 1)) throw BakeError(IssueCode::BadOption, "distance band must be >= 1 voxel");
  GridPlan plan{plan_grid(mesh, options), options.margin, 0.0};
  const bool shell = options.shell_thickness > 0;
  if (shell && !std::isfinite(options.shell_thickness))
    throw BakeError(IssueCode::BadOption, "shell thickness must be a finite number > 0");
  plan.half_shell = shell ? 0.5 * options.shell_thickness / plan.g.voxel_size : 0.0;
  if (plan.half_shell > 1e4) throw BakeError(IssueCode::BadOption, "shell thickness is more than 20,000 voxels");
  if (shell) {
    VoxelmapSettings grid_options = options;
    grid_options.margin += uint32_t(std::ceil(plan.half_shell));
    grid_options.voxel_size = plan.g.voxel_size;  // the same voxels, more of them
    plan.g = plan_grid(mesh, grid_options);
    plan.margin = grid_options.margin;
  }
  check_memory(mesh, plan.g, options, plan.half_shell);
  return plan;
}

// The voxelmap's geometry and quanta, its arrays empty.
Voxelmap empty_voxelmap(const GridPlan& plan, const VoxelmapSettings& options) {
  Voxelmap vm;
  vm.origin = plan.g.origin;
  vm.voxel_size = plan.g.voxel_size;
  vm.dims = plan.g.dims;
  vm.distance_band = options.distance_band;
  vm.margin = plan.margin;
  if (options.shell_thickness > 0) vm.shell_thickness = options.shell_thickness;
  vm.choose_quanta();
  return vm;
}

// The rows of bricks to bake, as (row, first slot, end slot) into lists.bricks. Under the closed and shell rules a
// row without candidate bricks is outside; the winding rule decides every brick within the surface's bounding box.
std::vector<std::array<int64_t, 3>> brick_rows(const BrickLists& lists, const GridGeometry& g, SignRule rule) {
  std::vector<std::array<int64_t, 3>> rows;
  for (size_t slot = 0; slot < lists.bricks.size();) {
    const int64_t row = lists.bricks[slot] / g.bricks[0];
    size_t end = slot;
    while (end < lists.bricks.size() && lists.bricks[end] / g.bricks[0] == row) ++end;
    rows.push_back({row, int64_t(slot), int64_t(end)});
    slot = end;
  }
  if (rule != SignRule::Winding) return rows;
  std::vector<std::array<int64_t, 3>> all;
  size_t n = 0;
  for (int64_t row = 0; row < g.bricks[1] * g.bricks[2]; ++row) {
    if (n < rows.size() && rows[n][0] == row) {
      all.push_back(rows[n++]);
    } else {
      const int64_t first = n < rows.size() ? rows[n][1] : int64_t(lists.bricks.size());
      all.push_back({row, first, first});
    }
  }
  return all;
}

// The band: every row of bricks in parallel, then their value bricks gathered into the voxelmap in row order.
void bake_band(const BrickRowsInput& in, Voxelmap& vm, const VoxelmapProgress& progress) {
  const GridGeometry& g = in.g;
  const std::vector<std::array<int64_t, 3>> rows = brick_rows(in.lists, g, in.rule);
  vm.bricks.assign(size_t(g.brick_count()), Voxelmap::kCoarseOutside);
  std::vector<RowOutput> outputs(rows.size());
  // A row's work: its candidate bricks, and a little for the row itself.
  const auto work = [&](size_t n) { return uint64_t(rows[n][2] - rows[n][1]) + 1; };
  uint64_t total = 0;
  for (size_t n = 0; n < rows.size(); ++n) total += work(n);
  ProgressTicker ticker(progress, kBandShare, kLatticeShare, total);
  tbb::parallel_for(size_t(0), rows.size(), [&](size_t n) {
    const int64_t row = rows[n][0];
    bake_brick_row(in, vm, row % g.bricks[1], row / g.bricks[1], rows[n][1], rows[n][2], vm.bricks, outputs[n]);
    ticker.add(work(n));
  });
  size_t value_bricks = 0;
  for (const RowOutput& o : outputs) value_bricks += o.bricks.size();
  vm.brick_values.reserve(value_bricks * kBrickVoxels);
  for (RowOutput& o : outputs) {
    for (size_t n = 0; n < o.bricks.size(); ++n) vm.bricks[size_t(o.bricks[n])] = int32_t(vm.value_brick_count() + n);
    vm.brick_values.insert(vm.brick_values.end(), o.codes.begin(), o.codes.end());
    std::vector<int64_t>().swap(o.bricks);
    std::vector<int16_t>().swap(o.codes);
  }
}

// Inside voxel centres, and those more than half a voxel deep: a stored distance <= -h/2, an estimate (at least
// band - 1/2 voxels deep) or a coarse brick inside.
// Counted in full only where no voxel is deep (the shell's warning says how many are inside): a solid, every closed
// mesh's common case, ends at its first deep voxel.
void count_inside(const Voxelmap& vm, VoxelmapReport& report) {
  uint64_t inside = 0, deep = 0;
  for (size_t n = 0; n < vm.bricks.size() && deep == 0; ++n) {
    const int32_t entry = vm.bricks[n];
    if (entry == Voxelmap::kCoarseInside) {
      inside += kBrickVoxels;
      deep += kBrickVoxels;
    }
    if (entry < 0) continue;
    const int16_t* codes = vm.brick_values.data() + size_t(entry) * kBrickVoxels;
    for (size_t v = 0; v < kBrickVoxels; ++v) {
      if (codes[v] >= 0) continue;  // outside, or past the grid (0)
      ++inside;
      deep += !Voxelmap::code_is_stored(codes[v]) || vm.decode(codes[v]) <= -0.5 * vm.voxel_size;
    }
  }
  report.inside_centres = inside;
  report.deep_centres = deep;
}

// Each value no larger than its neighbour's along an axis plus their distance (min-plus passes forward and back
// along each axis): every value is a distance to a real triangle, so never below the exact one, and the exact
// distance is 1-Lipschitz, so a value lowered this way stays above it (sums rounded up). It takes back part of the
// far search's slack (CGAL's bunny: ~400 values lowered, by up to 2.8 voxels at 306) and holds spec §3.3's rule
// between neighbours whatever a search misses, for 0.06 s at 1024 (0.8 % of the bake) and 0.4 s at 2048.
// `metres`: the lattice, x fastest.
void relax_lattice(const GridGeometry& g, const GridShape& shape, std::vector<float>& metres) {
  for (int axis = 0; axis < 3; ++axis) {
    const AxisLines lines(shape, axis);
    const int64_t stride = axis == 0 ? 1 : axis == 1 ? shape.dims[0] : shape.dims[0] * shape.dims[1];
    tbb::parallel_for(int64_t(0), lines.count, [&](int64_t line) {
      int64_t at[3];
      lines.first(line, at);
      float* v = metres.data() + shape.index(at[0], at[1], at[2]);
      // Lattice points along the axis lie kEdge voxels apart, the last clamped to the grid's last voxel.
      const auto step = [&](int64_t i) {
        return double(std::min<int64_t>((i + 1) * kEdge, g.dims[size_t(axis)] - 1) - i * kEdge) * g.voxel_size;
      };
      for (int64_t i = 0; i + 1 < lines.length; ++i)
        v[(i + 1) * stride] = std::min(v[(i + 1) * stride], float_not_below(double(v[i * stride]) + step(i)));
      for (int64_t i = lines.length - 2; i >= 0; --i)
        v[i * stride] = std::min(v[i * stride], float_not_below(double(v[(i + 1) * stride]) + step(i)));
    });
  }
}

// The lattice's values (metres; a shell's distance to its sheets) and their error bounds: within kExactReach of the
// surface, or within kFarSlack beyond it (spec §3.3), but for rounding: squared distances compared as floats
// (2^-24 relative) and values kept as floats.
void fill_lattice(const BrickRowsInput& in, Voxelmap& vm, const VoxelmapProgress& progress) {
  const GridGeometry& g = in.g;
  const Lattice L = propagate_lattice(g, in.triangles, in.lists, in.hierarchy, in.r, progress);
  if (progress) progress(kPropagatedShare);
  vm.lattice.resize(L.keys.size());
  tbb::parallel_for(size_t(0), L.keys.size(), [&](size_t n) {
    float d2;
    const uint32_t bits = uint32_t(L.keys[n] >> 32);
    std::memcpy(&d2, &bits, sizeof d2);
    vm.lattice[n] = float_not_below((L.keys[n] == kNoTriangle ? 1e9 : std::sqrt(double(d2))) * g.voxel_size);
  });
  relax_lattice(g, L, vm.lattice);
  if (in.rule == SignRule::Shell) {
    const double half_shell = in.half_shell * g.voxel_size;
    tbb::parallel_for(size_t(0), vm.lattice.size(),
                      [&](size_t n) { vm.lattice[n] = float_not_below(std::abs(double(vm.lattice[n]) - half_shell)); });
  }
  vm.lattice_error = {1e-4 + 3e-7 * double(std::max({g.dims[0], g.dims[1], g.dims[2]})), kFarSlack};
}

// The winding rule's sides (SignRule::Winding; none under another rule): the winding number beyond the band, and the
// boundary's exact sides in it.
struct WindingSides {
  std::unique_ptr<WindingNumber> winding;
  std::unique_ptr<BoundaryWinding> boundary;
};
WindingSides winding_sides(const TriangleMesh& mesh, const std::vector<Vec3>& vertices, const BrickLists& lists,
                           const GridGeometry& g, SignRule rule) {
  WindingSides sides;
  if (rule != SignRule::Winding) return sides;
  sides.winding = std::make_unique<WindingNumber>(mesh);
  sides.boundary = std::make_unique<BoundaryWinding>(mesh.triangles, vertices);
  sides.boundary->prepare(lists.bricks, g.bricks);
  return sides;
}

// The nearest-triangle hierarchy over the grid's triangles (it keeps its own copy of their corners), shared by the
// band's dense rows and the lattice.
ClosestTriangle triangle_hierarchy(const std::vector<IndexTriangle>& triangles) {
  std::vector<std::array<Vec3, 3>> corners(triangles.size());
  for (size_t f = 0; f < triangles.size(); ++f) corners[f] = {triangles[f].a, triangles[f].b, triangles[f].c};
  return ClosestTriangle(corners);
}

}  // namespace

Voxelmap build_voxelmap(const TriangleMesh& mesh, const VoxelmapSettings& options, std::vector<StageTiming>* timings,
                        VoxelmapReport* report, const VoxelmapProgress& progress) {
  auto clock = std::chrono::steady_clock::now();
  auto lap = [&](BakeStage stage) {
    const auto now = std::chrono::steady_clock::now();
    if (timings) timings->push_back({stage_name(stage), std::chrono::duration<double>(now - clock).count()});
    clock = now;
  };
  const GridPlan plan = plan_voxelmap_grid(mesh, options);
  const GridGeometry& g = plan.g;
  const bool shell = options.shell_thickness > 0;
  Voxelmap vm = empty_voxelmap(plan, options);

  // Distances are computed half a voxel past the band, so that the band's edge is exact.
  const double r = options.distance_band + plan.half_shell + 0.5;
  std::vector<Vec3> vertices = index_vertices(mesh, g);
  const std::vector<IndexTriangle> triangles = index_triangles(mesh, vertices, g, r);
  const BrickLists lists = bin_triangles(triangles, g, r);
  if (progress) progress(kBinnedShare);
  const Pseudonormals pn = pseudonormals(mesh);
  const SignRule rule = shell ? SignRule::Shell : options.winding_number_sign ? SignRule::Winding : SignRule::Closed;
  const WindingSides sides = winding_sides(mesh, vertices, lists, g, rule);
  std::vector<Vec3>().swap(vertices);
  const ClosestTriangle hierarchy = triangle_hierarchy(triangles);
  if (progress) progress(kBandShare);
  const BrickRowsInput in{mesh,
                          g,
                          triangles,
                          lists,
                          pn,
                          sides.winding.get(),
                          sides.boundary.get(),
                          hierarchy,
                          rule,
                          r,
                          options.distance_band,
                          plan.half_shell,
                          bounding_box(mesh)};
  bake_band(in, vm, progress);
  lap(BakeStage::VoxelmapBand);
  if (report && rule != SignRule::Shell) {
    count_inside(vm, *report);
    if (report->stop_if_shallow && report->deep_centres == 0) {
      report->stopped = true;
      return vm;
    }
  }
  if (progress) progress(kLatticeShare);
  fill_lattice(in, vm, progress);
  lap(BakeStage::VoxelmapLattice);
  if (progress) progress(kEstimatesShare);
  // As many threads as the bake's other stages may use (--threads limits TBB's parallelism).
  fill_estimates(vm, unsigned(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)));
  lap(BakeStage::VoxelmapEstimates);
  return vm;
}

double planned_voxel_size(const TriangleMesh& mesh, const VoxelmapSettings& settings) {
  return plan_grid(mesh, settings).voxel_size;
}

double memory_limit_bytes(uint64_t max_memory_bytes) {
  return max_memory_bytes > 0 ? double(max_memory_bytes) : double(default_memory_limit_bytes());
}

}  // namespace voxfmt::bake
