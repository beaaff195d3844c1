// Stage 3: layered distance-field voxelmap. OpenVDB computes exact signed distances in a narrow band; a
// two-pass 26-neighbour chamfer transform seeded with them gives the layers everywhere else.
#include <openvdb/openvdb.h>
#include <openvdb/tools/Dense.h>
#include <openvdb/tools/MeshToVolume.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "bake.h"

namespace voxfmt::bake {

namespace {

struct GridGeometry {
  Vec3 origin{};
  double voxel_size = 0;
  std::array<uint32_t, 3> dims{};
};

GridGeometry plan_grid(const TriangleMesh& mesh, const VoxelmapOptions& options) {
  Vec3 lo = mesh.vertices.front(), hi = lo;
  for (const Vec3& v : mesh.vertices)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], v[a]);
      hi[a] = std::max(hi[a], v[a]);
    }
  const double longest = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  GridGeometry g;
  if (options.voxel_size > 0) {
    g.voxel_size = options.voxel_size;
  } else {
    if (options.resolution == 0) throw BakeError("BAD_OPTION", "resolution must be >= 1");
    g.voxel_size = longest / options.resolution;
  }
  if (!(g.voxel_size > 0) || !std::isfinite(g.voxel_size))
    throw BakeError("ZERO_VOLUME", "the mesh has no extent (all vertices coincide)");
  // Voxels tile the bounding box exactly from its min corner, plus `margin` voxels on every side.
  uint64_t total = 1;
  for (int a = 0; a < 3; ++a) {
    const double cells = std::ceil((hi[a] - lo[a]) / g.voxel_size - 1e-9);
    const uint64_t n = uint64_t(std::max(1.0, cells)) + 2ull * options.margin;
    if (n > 65535) throw BakeError("GRID_TOO_LARGE", "the grid would have " + std::to_string(n) + " voxels along an axis");
    g.dims[a] = uint32_t(n);
    g.origin[a] = lo[a] + (0.5 - options.margin) * g.voxel_size;
    total *= n;
  }
  if (total > 0x7fffffffull)
    throw BakeError("GRID_TOO_LARGE", "the grid would have " + std::to_string(total) + " voxels (at most 2^31-1)");
  return g;
}

// Two raster passes over a 3x3x3 mask with weights 1, sqrt2, sqrt3 give the exact shortest-path distance in
// the 26-neighbour graph (every path can be reordered into forward moves then backward moves), so values of
// 6-neighbours never differ by more than 1. Voxels marked `fixed` keep their exact distance.
void chamfer_transform(std::vector<float>& f, const std::vector<uint8_t>& fixed, const std::array<uint32_t, 3>& dims) {
  const int64_t W = dims[0], H = dims[1], D = dims[2];
  struct Step { int di, dj, dk; float w; };
  std::vector<Step> forward;
  for (int dk = -1; dk <= 1; ++dk)
    for (int dj = -1; dj <= 1; ++dj)
      for (int di = -1; di <= 1; ++di) {
        if (dk > 0 || (dk == 0 && dj > 0) || (dk == 0 && dj == 0 && di >= 0)) continue;
        forward.push_back({di, dj, dk, float(std::sqrt(double(di * di + dj * dj + dk * dk)))});
      }
  auto relax = [&](int64_t i, int64_t j, int64_t k, int sign) {
    const int64_t v = (k * H + j) * W + i;
    if (fixed[v]) return;
    float best = f[v];
    for (const Step& s : forward) {
      const int64_t ni = i + sign * s.di, nj = j + sign * s.dj, nk = k + sign * s.dk;
      if (ni < 0 || ni >= W || nj < 0 || nj >= H || nk < 0 || nk >= D) continue;
      best = std::min(best, f[(nk * H + nj) * W + ni] + s.w);
    }
    f[v] = best;
  };
  for (int64_t k = 0; k < D; ++k)
    for (int64_t j = 0; j < H; ++j)
      for (int64_t i = 0; i < W; ++i) relax(i, j, k, +1);
  for (int64_t k = D - 1; k >= 0; --k)
    for (int64_t j = H - 1; j >= 0; --j)
      for (int64_t i = W - 1; i >= 0; --i) relax(i, j, k, -1);
}

}  // namespace

Voxelmap build_voxelmap(const TriangleMesh& mesh, const VoxelmapOptions& options) {
  if (!(options.distance_band >= 1)) throw BakeError("BAD_OPTION", "distance band must be >= 1 voxel");
  openvdb::initialize();
  const GridGeometry g = plan_grid(mesh, options);

  // Mesh in index space: voxel (i,j,k) centre sits at integer coordinates, so OpenVDB's grid is ours.
  std::vector<openvdb::Vec3s> points;
  points.reserve(mesh.vertices.size());
  for (const Vec3& v : mesh.vertices)
    points.emplace_back(float((v[0] - g.origin[0]) / g.voxel_size), float((v[1] - g.origin[1]) / g.voxel_size),
                        float((v[2] - g.origin[2]) / g.voxel_size));
  std::vector<openvdb::Vec3I> triangles;
  triangles.reserve(mesh.triangles.size());
  for (const auto& t : mesh.triangles) triangles.emplace_back(t[0], t[1], t[2]);
  const auto transform = openvdb::math::Transform::createLinearTransform(1.0);
  const float half_width = float(options.distance_band) + 1.5f;  // a little past the band, for exact values at its edge
  openvdb::tools::QuadAndTriangleDataAdapter<openvdb::Vec3s, openvdb::Vec3I> adapter(points, triangles);
  openvdb::FloatGrid::Ptr sdf = openvdb::tools::meshToVolume<openvdb::FloatGrid>(adapter, *transform, half_width, half_width);

  Voxelmap vm;
  vm.origin = g.origin;
  vm.voxel_size = g.voxel_size;
  vm.dims = g.dims;
  vm.distance_band = options.distance_band;
  vm.margin = options.margin;
  const size_t count = vm.voxel_count();

  // Dense copy, x fastest like the file: inactive voxels hold +-background with the inside/outside sign.
  std::vector<float> signed_voxels(count);
  {
    openvdb::tools::Dense<float, openvdb::tools::LayoutXYZ> dense(
        openvdb::CoordBBox(openvdb::Coord(0, 0, 0), openvdb::Coord(int(g.dims[0]) - 1, int(g.dims[1]) - 1, int(g.dims[2]) - 1)),
        signed_voxels.data());
    openvdb::tools::copyToDense(*sdf, dense);
  }
  sdf.reset();

  const float band = float(options.distance_band);
  std::vector<float> magnitude(count);
  std::vector<uint8_t> fixed(count);
  vm.distances.resize(count);
  for (size_t v = 0; v < count; ++v) {
    const float d = signed_voxels[v];
    const bool in_band = std::abs(d) <= band;
    fixed[v] = in_band;
    magnitude[v] = in_band ? std::abs(d) : std::numeric_limits<float>::infinity();
    vm.distances[v] = in_band ? float(d * g.voxel_size) : std::numeric_limits<float>::quiet_NaN();
  }
  chamfer_transform(magnitude, fixed, g.dims);

  vm.layers.resize(count);
  for (size_t v = 0; v < count; ++v) {
    // Penetration in voxels is positive inside (negative signed distance).
    // In the band the layer follows the stored distance exactly (spec §3).
    const double depth = fixed[v] ? -double(vm.distances[v]) / g.voxel_size
                                  : signed_voxels[v] < 0 ? double(magnitude[v]) : -double(magnitude[v]);
    vm.layers[v] = int16_t(std::clamp(std::floor(depth + 0.5), -32767.0, 32767.0));
  }
  return vm;
}

}  // namespace voxfmt::bake
