// Stage 3: layered distance-field voxelmap. Exact signed distances in a narrow band (every triangle rasterised
// into the voxels near it); an exact Euclidean feature transform to the band's nearest surface points gives the
// layers everywhere else.
#include <oneapi/tbb/blocked_range.h>
#include <oneapi/tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <unordered_map>

#include "stages.h"
#include "vec3_math.h"
#include "winding_number.h"

namespace voxfmt::bake {

namespace {

struct GridGeometry {
  Vec3 origin{};
  double voxel_size = 0;
  std::array<uint32_t, 3> dims{};
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
  uint64_t total = 1;
  for (int a = 0; a < 3; ++a) {
    const double cells = std::max(1.0, std::ceil((hi[a] - lo[a]) / g.voxel_size - 1e-9)) + 2.0 * options.margin;
    if (!(cells <= 65535)) {
      char count[32];
      std::snprintf(count, sizeof count, "%.3g", cells);
      throw BakeError(IssueCode::GridTooLarge, std::string("the grid would have ") + count +
                                                   " voxels along an axis (at most 65535): voxel size too small");
    }
    const uint64_t n = uint64_t(cells);
    g.dims[a] = uint32_t(n);
    g.origin[a] = lo[a] + (0.5 - options.margin) * g.voxel_size;
    total *= n;
  }
  if (total > 0x7fffffffull)
    throw BakeError(IssueCode::GridTooLarge,
                    "the grid would have " + std::to_string(total) + " voxels (at most 2^31-1)");
  return g;
}

// ---- layers beyond the band: an exact Euclidean feature transform. Every voxel finds the nearest *seed*
// voxel (one within sqrt(3)/2 voxel of the surface, whose nearest surface point the band computed exactly), by
// the separable lower-envelope algorithm of Felzenszwalb & Huttenlocher (2012) carried out on seed ids; its
// depth is the distance to that seed's surface point. That is a real surface point, so the depth is never too
// small. The surface point s nearest a voxel p lies in some voxel, whose centre is a seed within sqrt(3)/2 of s,
// so the nearest seed is at most |p - s| + sqrt(3)/2 away and its surface point at most sqrt(3)/2 beyond it:
// at most sqrt(3) voxels too deep (spec §3), and measured a small fraction of a voxel (the 26-neighbour chamfer
// used before overestimated by up to 15 % of the depth).

struct Seed {
  int32_t i, j, k;  // the seed voxel
  Vec3f closest;    // its nearest surface point, relative to the voxel, in voxels
};
constexpr uint32_t kNoSeed = ~uint32_t(0);

// One line of the transform: `line[q]` holds the seed chosen for position q by the previous axes (or kNoSeed)
// and `height(seed)` its squared distance across those axes; afterwards each position holds the seed that
// minimises (p - q)^2 + height. Integer arithmetic: positions and heights are exact.
struct EnvelopeScratch {
  std::vector<int64_t> position;  // parabolas of the lower envelope: their apex positions,
  std::vector<double> apex;       // their heights at the apex,
  std::vector<double> from;       // and where each starts to be the lowest
  std::vector<uint32_t> seed;     // the line's seeds before the pass
};

template <class Height>
void envelope_line(uint32_t* line, int64_t stride, int64_t n, const Height& height, EnvelopeScratch& e) {
  e.seed.resize(size_t(n));
  e.position.resize(size_t(n));
  e.apex.resize(size_t(n));
  e.from.resize(size_t(n) + 1);
  int64_t count = 0;
  for (int64_t q = 0; q < n; ++q) {
    const uint32_t seed = e.seed[size_t(q)] = line[q * stride];
    if (seed == kNoSeed) continue;
    const double fq = height(seed);  // each seed's height is looked up once (a random access)
    double s = 0;
    while (count > 0) {
      const int64_t r = e.position[size_t(count - 1)];
      s = ((fq + double(q) * double(q)) - (e.apex[size_t(count - 1)] + double(r) * double(r))) / (2.0 * double(q - r));
      if (s > e.from[size_t(count - 1)]) break;
      --count;
    }
    e.position[size_t(count)] = q;
    e.apex[size_t(count)] = fq;
    e.from[size_t(count)] = count == 0 ? -std::numeric_limits<double>::infinity() : s;
    ++count;
  }
  if (count == 0) return;
  e.from[size_t(count)] = std::numeric_limits<double>::infinity();
  int64_t k = 0;
  for (int64_t p = 0; p < n; ++p) {
    while (e.from[size_t(k + 1)] < double(p)) ++k;
    line[p * stride] = e.seed[size_t(e.position[size_t(k)])];
  }
}

// Depth (unsigned distance to the surface, voxels) of every voxel from its nearest seed, or the exact one
// where the band has it (|exact| < half_width), then made 1-Lipschitz along the axes (two city-block sweeps per axis:
// min with a 6-neighbour's value + 1, which keeps every value a distance to some surface point) so that 6-neighbouring
// layers never differ by more than one.
std::vector<float> feature_transform_depths(const std::vector<Seed>& seeds, const std::vector<float>& exact,
                                            float half_width, const std::array<uint32_t, 3>& dims) {
  const int64_t W = dims[0], H = dims[1], D = dims[2];
  std::vector<uint32_t> nearest(size_t(W * H * D), kNoSeed);
  for (size_t s = 0; s < seeds.size(); ++s)
    nearest[size_t((int64_t(seeds[s].k) * H + seeds[s].j) * W + seeds[s].i)] = uint32_t(s);
  // x: the first axis has no earlier axes (height 0).
  tbb::parallel_for(int64_t(0), D * H, [&](int64_t row) {
    thread_local EnvelopeScratch scratch;
    envelope_line(
        nearest.data() + row * W, 1, W, [](uint32_t) { return 0.0; }, scratch);
  });
  // y and z lines are strided in memory: they are processed 16 neighbouring lines (one cache line of each
  // plane) at a time, gathered into a contiguous buffer.
  constexpr int64_t kBlock = 16;
  auto strided_lines = [&](int64_t planes, int64_t plane_stride, int64_t stride, int64_t n, auto&& height_for) {
    tbb::parallel_for(int64_t(0), planes, [&](int64_t plane) {
      thread_local EnvelopeScratch scratch;
      thread_local std::vector<uint32_t> block;
      block.resize(size_t(kBlock * n));
      for (int64_t i0 = 0; i0 < W; i0 += kBlock) {
        const int64_t lines = std::min(kBlock, W - i0);
        uint32_t* base = nearest.data() + plane * plane_stride + i0;
        for (int64_t q = 0; q < n; ++q)
          for (int64_t l = 0; l < lines; ++l) block[size_t(l * n + q)] = base[q * stride + l];
        for (int64_t l = 0; l < lines; ++l)
          envelope_line(block.data() + l * n, 1, n, height_for(plane, i0 + l), scratch);
        for (int64_t q = 0; q < n; ++q)
          for (int64_t l = 0; l < lines; ++l) base[q * stride + l] = block[size_t(l * n + q)];
      }
    });
  };
  // y: height = squared x distance of the seed chosen in that row.
  strided_lines(D, H * W, W, H, [&](int64_t, int64_t i) {
    return [&seeds, i](uint32_t s) {
      const double dx = double(seeds[s].i - i);
      return dx * dx;
    };
  });
  // z: height = squared distance in the (x, y) plane of the seed chosen in that column.
  strided_lines(H, W, W * H, D, [&](int64_t j, int64_t i) {
    return [&seeds, i, j](uint32_t s) {
      const double dx = double(seeds[s].i - i), dy = double(seeds[s].j - j);
      return dx * dx + dy * dy;
    };
  });

  std::vector<float> depth(nearest.size());
  tbb::parallel_for(int64_t(0), D, [&](int64_t k) {
    for (int64_t j = 0; j < H; ++j)
      for (int64_t i = 0; i < W; ++i) {
        const size_t at = size_t((k * H + j) * W + i);
        const uint32_t s = nearest[at];
        if (std::abs(exact[at]) < half_width) {
          depth[at] = std::abs(exact[at]);
          continue;
        }
        if (s == kNoSeed) {
          depth[at] = std::numeric_limits<float>::infinity();
          continue;
        }
        const Seed& seed = seeds[s];
        const double dx = double(seed.i - i) + seed.closest[0], dy = double(seed.j - j) + seed.closest[1],
                     dz = double(seed.k - k) + seed.closest[2];
        depth[at] = float(std::sqrt(dx * dx + dy * dy + dz * dz));
      }
  });
  std::vector<uint32_t>().swap(nearest);

  // Rows are swept element by element; y and z steps compare whole rows at once (contiguous, vectorised).
  auto step = [](float* to, const float* from, int64_t n) {
    for (int64_t i = 0; i < n; ++i) to[i] = std::min(to[i], from[i] + 1.0f);
  };
  tbb::parallel_for(int64_t(0), D * H, [&](int64_t row) {
    float* line = depth.data() + row * W;
    for (int64_t i = 1; i < W; ++i) line[i] = std::min(line[i], line[i - 1] + 1.0f);
    for (int64_t i = W - 2; i >= 0; --i) line[i] = std::min(line[i], line[i + 1] + 1.0f);
  });
  tbb::parallel_for(int64_t(0), D, [&](int64_t k) {
    float* plane = depth.data() + k * H * W;
    for (int64_t j = 1; j < H; ++j) step(plane + j * W, plane + (j - 1) * W, W);
    for (int64_t j = H - 2; j >= 0; --j) step(plane + j * W, plane + (j + 1) * W, W);
  });
  tbb::parallel_for(int64_t(0), H, [&](int64_t j) {
    float* column = depth.data() + j * W;
    for (int64_t k = 1; k < D; ++k) step(column + k * H * W, column + (k - 1) * H * W, W);
    for (int64_t k = D - 2; k >= 0; --k) step(column + k * H * W, column + (k + 1) * H * W, W);
  });
  return depth;
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

// The feature of triangle abc that holds a closest point: a corner, an edge (named by its first corner, as in
// Pseudonormals::edge) or the face.
enum class Feature : uint8_t { kCornerA, kCornerB, kCornerC, kEdgeAB, kEdgeBC, kEdgeCA, kFace };

// Closest point on triangle abc to p (Ericson, Real-Time Collision Detection 5.1.5) and its feature.
inline Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, Feature& feature) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) {
    feature = Feature::kCornerA;
    return a;
  }
  const Vec3 bp = p - b;
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) {
    feature = Feature::kCornerB;
    return b;
  }
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    feature = Feature::kEdgeAB;
    return a + ab * (d1 / (d1 - d3));
  }
  const Vec3 cp = p - c;
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) {
    feature = Feature::kCornerC;
    return c;
  }
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    feature = Feature::kEdgeCA;
    return a + ac * (d2 / (d2 - d6));
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    feature = Feature::kEdgeBC;
    return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  }
  const double denom = 1 / (va + vb + vc);
  feature = Feature::kFace;
  return a + ab * (vb * denom) + ac * (vc * denom);
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

// Layers round distances (in voxels) at half-integers, so ties matter. A distance within 1e-6 (relative, and
// so more than a float's half ulp) of a tie is put on it (a face half a voxel from the voxel centres, with float input
// coordinates, gives 0.49999995 here and 1.49999995 at the next voxel; exact ties round alike), and the float kept for
// the voxel stays on the double's side of every tie (1.49999995 would otherwise round to the float 1.5 and jump a
// layer).
float tie_safe_float(double distance) {
  const double tie = std::floor(distance) + 0.5;
  if (std::abs(distance - tie) < 1e-6 * std::max(1.0, std::abs(tie))) distance = tie;
  float f = float(distance);
  const double layer = std::floor(distance + 0.5);
  while (std::floor(double(f) + 0.5) > layer) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
  while (std::floor(double(f) + 0.5) < layer) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

// Signed distances (voxels, index space) of every voxel within `half_width` of the surface; every other voxel
// gets +-half_width with its inside/outside sign. That sign is carried along each x row from the last band
// voxel: a row starts outside (its first voxel centre is at most half a voxel inside the bounding box, so were
// it inside, a face would be within half a voxel: a band voxel), and a step between a band voxel and one
// outside the band stays more than half_width - 1 from the surface, so it cannot cross it.
// `seeds` receives every voxel within sqrt(3)/2 voxel of the surface with its nearest surface point.
std::vector<float> exact_band_distances(const TriangleMesh& mesh, const GridGeometry& g, float half_width,
                                        std::vector<Seed>& seeds) {
  const int64_t dims[3] = {g.dims[0], g.dims[1], g.dims[2]};
  const int64_t W = dims[0], H = dims[1], D = dims[2];
  const double r = half_width, r2 = r * r;
  struct IndexTriangle {
    Vec3 a, b, c, normal;
    // Unit in-plane normals of the edges, pointing away from the triangle, and their planes' offsets: a point
    // within r of the triangle is less than r beyond each edge's plane (and its own plane).
    Vec3 edge_normal[3];
    double edge_offset[3];
    int64_t lo[3], hi[3];  // voxels within r of the triangle's bounding box, clipped to the grid
  };
  const size_t triangle_count = mesh.triangles.size();
  std::vector<IndexTriangle> triangles(triangle_count);
  tbb::parallel_for(size_t(0), triangle_count, [&](size_t f) {
    auto to_index = [&](uint32_t v) {
      return Vec3{(mesh.vertices[v][0] - g.origin[0]) / g.voxel_size,
                  (mesh.vertices[v][1] - g.origin[1]) / g.voxel_size,
                  (mesh.vertices[v][2] - g.origin[2]) / g.voxel_size};
    };
    IndexTriangle& t = triangles[f];
    t.a = to_index(mesh.triangles[f][0]);
    t.b = to_index(mesh.triangles[f][1]);
    t.c = to_index(mesh.triangles[f][2]);
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
      t.hi[axis] = std::min<int64_t>(dims[axis] - 1, int64_t(std::floor(hi + r)));
    }
  });

  // Slabs of z layers, each listing the triangles that reach it (a counting sort: deterministic, and every
  // slab is written by one task only).
  constexpr int64_t kSlab = 4;
  const int64_t slabs = (D + kSlab - 1) / kSlab;
  std::vector<size_t> first(size_t(slabs) + 1, 0);
  auto reached = [&](const IndexTriangle& t, auto&& visit) {
    if (t.lo[0] > t.hi[0] || t.lo[1] > t.hi[1] || t.lo[2] > t.hi[2]) return;
    for (int64_t s = t.lo[2] / kSlab; s <= t.hi[2] / kSlab; ++s) visit(size_t(s));
  };
  for (const IndexTriangle& t : triangles) reached(t, [&](size_t s) { ++first[s + 1]; });
  for (size_t s = 0; s < size_t(slabs); ++s) first[s + 1] += first[s];
  std::vector<uint32_t> members(first.back());
  {
    std::vector<size_t> next(first.begin(), first.end() - 1);
    for (size_t f = 0; f < triangle_count; ++f)
      reached(triangles[f], [&](size_t s) { members[next[s]++] = uint32_t(f); });
  }

  const Pseudonormals pn = pseudonormals(mesh);
  std::vector<float> signed_voxels(size_t(W * H * D));
  std::vector<std::vector<Seed>> slab_seeds(static_cast<size_t>(slabs));
  constexpr uint64_t kNone = ~uint64_t(0);
  tbb::parallel_for(int64_t(0), slabs, [&](int64_t s) {
    const int64_t k0 = s * kSlab, k1 = std::min(D, k0 + kSlab);
    // Per voxel: (squared distance as float bits, triangle) packed so that the smallest key is the nearest
    // triangle, ties to the lower index; the order triangles arrive in does not matter.
    thread_local std::vector<uint64_t> nearest;
    nearest.assign(size_t((k1 - k0) * H * W), kNone);
    for (size_t m = first[size_t(s)]; m < first[size_t(s) + 1]; ++m) {
      const uint32_t f = members[m];
      const IndexTriangle& t = triangles[f];
      const Vec3& n = t.normal;
      for (int64_t k = std::max(k0, t.lo[2]); k <= std::min(k1 - 1, t.hi[2]); ++k)
        for (int64_t j = t.lo[1]; j <= t.hi[1]; ++j) {
          // Only voxels less than r beyond the triangle's plane (both sides) and its three edge planes: each a
          // constraint alpha * i + beta < r on the row. Long thin triangles (CAD fans) would otherwise scan
          // their whole bounding box.
          int64_t i0 = t.lo[0], i1 = t.hi[0];
          auto below_r = [&](const Vec3& outward, double offset) {
            const double alpha = outward[0], beta = outward[1] * double(j) + outward[2] * double(k) - offset;
            if (alpha > 1e-12) {
              i1 = std::min(i1, int64_t(std::floor((r - beta) / alpha + 1e-9)));
            } else if (alpha < -1e-12) {
              i0 = std::max(i0, int64_t(std::ceil((r - beta) / alpha - 1e-9)));
            } else if (beta >= r + 1e-9) {
              i1 = i0 - 1;
            }
          };
          const double plane = dot(n, t.a);
          below_r(n, plane);
          below_r(n * -1.0, -plane);
          for (int e = 0; e < 3; ++e) below_r(t.edge_normal[e], t.edge_offset[e]);
          if (i0 > i1) continue;
          uint64_t* row = nearest.data() + ((k - k0) * H + j) * W;
          for (int64_t i = i0; i <= i1; ++i) {
            const Vec3 p{double(i), double(j), double(k)};
            Feature feature;
            const double d2 = distance2(p, closest_on_triangle(p, t.a, t.b, t.c, feature));
            if (!(d2 < r2)) continue;
            uint32_t bits;
            const float d2f = float(d2);
            std::memcpy(&bits, &d2f, sizeof bits);
            row[i] = std::min(row[i], uint64_t(bits) << 32 | f);
          }
        }
    }
    for (int64_t k = k0; k < k1; ++k)
      for (int64_t j = 0; j < H; ++j) {
        const uint64_t* row = nearest.data() + ((k - k0) * H + j) * W;
        float* out = signed_voxels.data() + (k * H + j) * W;
        float side_of_row = 1;  // outside until a band voxel says otherwise
        for (int64_t i = 0; i < W; ++i) {
          if (row[i] == kNone) {
            out[i] = side_of_row * half_width;
            continue;
          }
          const size_t f = size_t(row[i] & 0xffffffffu);
          const IndexTriangle& t = triangles[f];
          const Vec3 p{double(i), double(j), double(k)};
          Feature feature;
          const Vec3 d = p - closest_on_triangle(p, t.a, t.b, t.c, feature);
          const double sign = dot(d, feature_pseudonormal(pn, mesh, f, feature)) < 0 ? -1 : 1;
          out[i] = tie_safe_float(sign * length(d));
          side_of_row = float(sign);
          if (dot(d, d) <= 0.75 + 1e-9)
            slab_seeds[size_t(s)].push_back(
                {int32_t(i), int32_t(j), int32_t(k), Vec3f{float(-d[0]), float(-d[1]), float(-d[2])}});
        }
      }
  });
  seeds.clear();
  for (const auto& slab : slab_seeds) seeds.insert(seeds.end(), slab.begin(), slab.end());
  return signed_voxels;
}

// Inside = winding number >= 1/2. Evaluated per voxel near the surface, where it changes fast; farther away it
// is smooth, so it is evaluated on a coarser lattice and interpolated trilinearly. The lattice is fine enough
// that every corner of an interpolated voxel's cell lies no farther from it than the band it is outside of.
// In the band, where a wrong sign is a wrong contact, a value near 1/2 is evaluated again until its side is
// certain (WindingNumber::inside: a stricter far field, then the exact sum). Farther away
// an open surface can leave wide regions near 1/2 (across a hole), where the inside is a matter of closure and
// exact sums would cost seconds.
void sign_by_winding_number(const TriangleMesh& mesh, const GridGeometry& g, float half_width,
                            std::vector<float>& signed_voxels) {
  const WindingNumber winding(mesh);
  const int64_t W = g.dims[0], H = g.dims[1], D = g.dims[2];
  // Outside the surface's bounding box a plane separates the point from the whole surface, which then covers at
  // most a hemisphere of directions: |winding number| <= 1/2, never inside. Approximation error (far field,
  // interpolation) must not make it so.
  const Bounds box = bounding_box(mesh);  // not a structured binding: C++17 lambdas cannot capture those (clang)
  const Vec3& lo = box.lo;
  const Vec3& hi = box.hi;
  auto inside_bounds = [&](int64_t i, int64_t j, int64_t k) {
    const double p[3] = {g.origin[0] + g.voxel_size * double(i), g.origin[1] + g.voxel_size * double(j),
                         g.origin[2] + g.voxel_size * double(k)};
    for (int a = 0; a < 3; ++a)
      if (p[a] < lo[a] || p[a] > hi[a]) return false;
    return true;
  };
  const int64_t kStride = std::clamp<int64_t>(int64_t(std::floor(2.0 * half_width / std::sqrt(3.0))), 1, 4);
  auto lattice = [&](int64_t n) { return (n - 1 + kStride - 1) / kStride + 1; };
  const int64_t cw = lattice(W), ch = lattice(H), cd = lattice(D);
  auto at = [&](int64_t a, int64_t n) { return std::min(a * kStride, n - 1); };
  std::vector<float> coarse(size_t(cw * ch * cd));
  tbb::parallel_for(int64_t(0), cd, [&](int64_t c) {
    for (int64_t b = 0; b < ch; ++b)
      for (int64_t a = 0; a < cw; ++a) {
        const Vec3 p = {g.origin[0] + g.voxel_size * double(at(a, W)), g.origin[1] + g.voxel_size * double(at(b, H)),
                        g.origin[2] + g.voxel_size * double(at(c, D))};
        coarse[size_t((c * ch + b) * cw + a)] = float(winding(p));
      }
  });
  auto weight = [&](int64_t i, int64_t n, int64_t& a) {
    a = std::min(i / kStride, lattice(n) - 2 < 0 ? 0 : lattice(n) - 2);
    const int64_t x0 = at(a, n), x1 = at(a + 1, n);
    return x1 > x0 ? double(i - x0) / double(x1 - x0) : 0.0;
  };
  tbb::parallel_for(int64_t(0), D, [&](int64_t k) {
    for (int64_t j = 0; j < H; ++j)
      for (int64_t i = 0; i < W; ++i) {
        float& value = signed_voxels[size_t((k * H + j) * W + i)];
        double w;
        if (std::abs(value) < half_width) {
          w = winding(Vec3{g.origin[0] + g.voxel_size * double(i), g.origin[1] + g.voxel_size * double(j),
                           g.origin[2] + g.voxel_size * double(k)});
        } else {
          int64_t a, b, c;
          const double u = weight(i, W, a), v = weight(j, H, b), t = weight(k, D, c);
          auto C = [&](int64_t da, int64_t db, int64_t dc) {
            const int64_t aa = std::min(a + da, cw - 1), bb = std::min(b + db, ch - 1), cc = std::min(c + dc, cd - 1);
            return double(coarse[size_t((cc * ch + bb) * cw + aa)]);
          };
          w = (1 - t) *
                  ((1 - v) * ((1 - u) * C(0, 0, 0) + u * C(1, 0, 0)) + v * ((1 - u) * C(0, 1, 0) + u * C(1, 1, 0))) +
              t * ((1 - v) * ((1 - u) * C(0, 0, 1) + u * C(1, 0, 1)) + v * ((1 - u) * C(0, 1, 1) + u * C(1, 1, 1)));
        }
        const Vec3 p{g.origin[0] + g.voxel_size * double(i), g.origin[1] + g.voxel_size * double(j),
                     g.origin[2] + g.voxel_size * double(k)};
        const bool in_band = std::abs(value) < half_width;
        value =
            inside_bounds(i, j, k) && (in_band ? winding.inside(p, w) : w >= 0.5) ? -std::abs(value) : std::abs(value);
      }
  });
}

// Exact distances of 6-neighbours differ by at most one voxel, so their layers (rounded at half-integers)
// differ by at most one. Computed distances can exceed that by ~1e-6 voxel (tie snapping moves values by up to
// 1e-6; the nearest triangle is chosen by a float key; the feature transform's depths beyond the band are float
// sums), enough to straddle two ties and step two layers. Such a pair has one value within `kSlack` of its tie;
// that value is moved across it (by <= kSlack). A voxel's penetration (voxels, positive inside) is -d in the band
// and its feature-transform depth, signed by d, beyond it, so pairs beyond the band and across its edge are
// repaired too (fuzz_mesh_off found a box whose depths 3.49999976 and 4.5, just past a band of 3, rounded to
// layers 3 and 5). Larger inconsistencies are real errors and are left for the validator to report. Returns the
// number of values moved.
// `layers` are the layers rounded from d and depth; `refresh(v)` rounds voxel v's again after a move. The scan
// compares those integers, so the common case (no step of two) costs one pass over 16-bit values.
template <class Refresh>
size_t repair_layer_steps(std::vector<float>& d, std::vector<float>& depth, float band,
                          const std::array<uint32_t, 3>& dims, const std::vector<int16_t>& layers, Refresh&& refresh) {
  constexpr double kSlack = 1e-4;
  const int64_t W = dims[0], H = dims[1], D = dims[2];
  auto in_band = [&](size_t v) { return std::abs(d[v]) <= band; };
  auto penetration = [&](size_t v) {
    return in_band(v) ? -double(d[v]) : d[v] < 0 ? double(depth[v]) : -double(depth[v]);
  };
  auto set_penetration = [&](size_t v, float p) {
    if (in_band(v))
      d[v] = -p;
    else
      depth[v] = std::abs(p);
  };
  auto layer = [&](size_t v) { return std::floor(penetration(v) + 0.5); };
  size_t moved = 0;
  for (int pass = 0; pass < 4; ++pass) {
    size_t moved_now = 0;
    for (int64_t k = 0; k < D; ++k)
      for (int64_t j = 0; j < H; ++j)
        for (int64_t i = 0; i < W; ++i) {
          const size_t v = size_t((k * H + j) * W + i);
          const size_t next[3] = {i + 1 < W ? v + 1 : v, j + 1 < H ? v + size_t(W) : v,
                                  k + 1 < D ? v + size_t(W * H) : v};
          for (size_t n : next) {
            if (n == v || std::abs(int(layers[v]) - int(layers[n])) < 2) continue;
            const size_t lo = layer(v) < layer(n) ? v : n, hi = lo == v ? n : v;
            const double gap_lo = layer(lo) + 0.5 - penetration(lo);    // below the tie that would raise it
            const double gap_hi = penetration(hi) - (layer(hi) - 0.5);  // above the tie that would lower it
            if (std::min(gap_lo, gap_hi) > kSlack) continue;
            const size_t moved_voxel = gap_lo <= gap_hi ? lo : hi;
            if (gap_lo <= gap_hi)
              set_penetration(lo, float(layer(lo) + 0.5));  // exactly on the tie: rounds up
            else
              set_penetration(hi, std::nextafter(float(layer(hi) - 0.5), -std::numeric_limits<float>::infinity()));
            refresh(moved_voxel);
            ++moved_now;
          }
        }
    moved += moved_now;
    if (moved_now == 0) break;
  }
  return moved;
}

}  // namespace

Voxelmap build_voxelmap(const TriangleMesh& mesh, const VoxelmapSettings& options) {
  if (!(options.distance_band >= 1)) throw BakeError(IssueCode::BadOption, "distance band must be >= 1 voxel");
  GridGeometry g = plan_grid(mesh, options);

  // Shell mode: the object is every point within half the thickness of the surface; the grid's margin grows
  // by that much so that the shell's outer sheets keep the margin's outer voxels around them.
  const bool shell = options.shell_thickness > 0;
  if (shell && !std::isfinite(options.shell_thickness))
    throw BakeError(IssueCode::BadOption, "shell thickness must be a finite number > 0");
  const double half_shell = shell ? 0.5 * options.shell_thickness / g.voxel_size : 0.0;  // voxels
  if (half_shell > 1e4) throw BakeError(IssueCode::BadOption, "shell thickness is more than 20,000 voxels");
  VoxelmapSettings grid_options = options;
  if (shell) {
    grid_options.margin += uint32_t(std::ceil(half_shell));
    grid_options.voxel_size = g.voxel_size;  // the same voxels, more of them
    g = plan_grid(mesh, grid_options);
  }
  // Exact distances just past the band (voxels at exactly `band` must be exact too).
  const float half_width = float(options.distance_band + half_shell) + 0.5f;
  std::vector<Seed> seeds;
  std::vector<float> signed_voxels = exact_band_distances(mesh, g, half_width, seeds);

  Voxelmap vm;
  vm.origin = g.origin;
  vm.voxel_size = g.voxel_size;
  vm.dims = g.dims;
  vm.distance_band = options.distance_band;
  vm.margin = grid_options.margin;
  const size_t count = vm.voxel_count();

  if (shell) {
    vm.shell_thickness = options.shell_thickness;
    for (float& d : signed_voxels) d = std::abs(d);  // the feature transform takes the unsigned distances
  } else if (options.winding_number_sign) {
    sign_by_winding_number(mesh, g, half_width, signed_voxels);
  }

  // Distances are stored in the band. Layers are rounded from the distances in voxel units, where a voxel
  // centre exactly half a voxel off a face (common: the grid is aligned to the bounding box) is an exact tie,
  // so neighbours round alike. Converting to metres in float would turn such ties into +-1 ulp noise and
  // round 2.5 up but 1.5 down (a step of 2), so each stored value is then nudged by ulps until the spec's
  // floor(-d/h + 1/2), evaluated on the stored float as a reader does, gives the layer chosen here.
  const float band = float(options.distance_band);
  vm.distances.resize(count);
  vm.layers.resize(count);
  const double h = g.voxel_size;
  auto layer_of = [](double depth) { return std::clamp(std::floor(depth + 0.5), -32767.0, 32767.0); };
  std::vector<float> depth = feature_transform_depths(seeds, signed_voxels, half_width, g.dims);
  std::vector<Seed>().swap(seeds);
  if (shell) {  // the shell's signed distance, everywhere: exact wherever the band's distances are
    tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 1 << 16), [&](const tbb::blocked_range<size_t>& r) {
      for (size_t v = r.begin(); v < r.end(); ++v) {
        signed_voxels[v] = tie_safe_float(double(depth[v]) - half_shell);
        depth[v] = std::abs(signed_voxels[v]);
      }
    });
  }
  // Rounds voxel v's layer and stores its distance (in the band).
  auto finalize = [&](size_t v) {
    const float d = signed_voxels[v];
    if (!(std::abs(d) <= band)) {
      // Penetration in voxels is positive inside.
      vm.distances[v] = std::numeric_limits<float>::quiet_NaN();
      vm.layers[v] = int16_t(layer_of(d < 0 ? double(depth[v]) : -double(depth[v])));
      return;
    }
    const double layer = layer_of(-double(d));
    float stored = float(double(d) * h);
    for (int step = 0; step < 8; ++step) {  // one or two ulps at most in practice
      const double read = layer_of(-double(stored) / h);
      if (read == layer) break;
      // A larger distance gives a smaller layer.
      stored = std::nextafter(
          stored, read > layer ? std::numeric_limits<float>::infinity() : -std::numeric_limits<float>::infinity());
    }
    vm.distances[v] = stored;
    vm.layers[v] = int16_t(layer);
  };
  tbb::parallel_for(tbb::blocked_range<size_t>(0, count, 1 << 16), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t v = r.begin(); v < r.end(); ++v) finalize(v);
  });
  repair_layer_steps(signed_voxels, depth, band, g.dims, vm.layers, finalize);
  return vm;
}

}  // namespace voxfmt::bake
