#include "static_mesh.h"

#include <BulletCollision/CollisionShapes/btBvhTriangleMeshShape.h>
#include <BulletCollision/CollisionShapes/btScaledBvhTriangleMeshShape.h>
#include <BulletCollision/CollisionShapes/btTriangleCallback.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <tuple>
#include <utility>

#include "triangle_distance.h"

namespace voxfmt::bullet {

MeshSignature MeshSignature::of(const btConcaveShape& shape) {
  MeshSignature s;
  s.type = shape.getShapeType();
  if (s.type == TRIANGLE_MESH_SHAPE_PROXYTYPE)
    s.mesh = static_cast<const btBvhTriangleMeshShape&>(shape).getMeshInterface();
  else if (s.type == SCALED_TRIANGLE_MESH_SHAPE_PROXYTYPE)
    s.mesh = static_cast<const btScaledBvhTriangleMeshShape&>(shape).getChildShape();
  const btVector3& scaling = shape.getLocalScaling();
  btVector3 lo, hi;
  shape.getAabb(btTransform::getIdentity(), lo, hi);
  for (int a = 0; a < 3; ++a) {
    s.scaling[a] = float(scaling[a]);
    s.lo[a] = float(lo[a]);
    s.hi[a] = float(hi[a]);
  }
  return s;
}

bool MeshSignature::operator==(const MeshSignature& o) const {
  return type == o.type && mesh == o.mesh && std::equal(scaling, scaling + 3, o.scaling) &&
         std::equal(lo, lo + 3, o.lo) && std::equal(hi, hi + 3, o.hi);
}

namespace {

class Collector : public btTriangleCallback {
 public:
  explicit Collector(std::vector<Eigen::Vector3f>& corners) : corners_(corners) {}
  void processTriangle(btVector3* triangle, int, int) override {
    for (int k = 0; k < 3; ++k)
      corners_.emplace_back(float(triangle[k].x()), float(triangle[k].y()), float(triangle[k].z()));
  }

 private:
  std::vector<Eigen::Vector3f>& corners_;
};

}  // namespace

std::shared_ptr<const StaticMeshIndex> StaticMeshIndex::build(const btConcaveShape& shape) {
  const auto start = std::chrono::steady_clock::now();
  auto index = std::make_shared<StaticMeshIndex>();
  index->signature_ = MeshSignature::of(shape);
  std::vector<Eigen::Vector3f> corners;
  Collector collect(corners);
  btVector3 lo, hi;
  shape.getAabb(btTransform::getIdentity(), lo, hi);
  const btVector3 pad = (hi - lo) * btScalar(0.01) + btVector3(1, 1, 1) * btScalar(1e-6);
  shape.processAllTriangles(&collect, lo - pad, hi + pad);
  index->triangles_.reserve(corners.size() / 3);
  // A mirroring scale (an odd number of negative factors) turns every triangle over: turned back, its outside
  // stays the side the mesh's winding says.
  const bool mirrored = detail::mirrors(shape.getLocalScaling());
  for (size_t t = 0; t + 2 < corners.size(); t += 3)
    index->triangles_.push_back(
        detail::BoxedTriangle::of(corners[t], corners[t + (mirrored ? 2 : 1)], corners[t + (mirrored ? 1 : 2)]));
  index->vertices_ = std::move(corners);
  index->index();
  index->info_.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return index;
}

void StaticMeshIndex::index() {
  info_.triangles = triangles_.size();
  if (triangles_.empty()) {
    vertices_.clear();
    return;
  }
  const double edges = bound_triangles(triangles_, grid_);
  // One-sided (a floor, a terrain): beyond the box on that side is outside.
  common_normal_ = common_normal(triangles_);
  size_grid(edges);
  info_.cells = size_t(grid_.dims.prod());
  grid_.fill(
      triangles_.size(), [&](size_t t) -> const Eigen::Vector3f& { return triangles_[t].lo; },
      [&](size_t t) -> const Eigen::Vector3f& { return triangles_[t].hi; }, kEmptyRings);
  index_vertices();
  sample();
  info_.vertices = vertices_.size();
  info_.memory_bytes =
      triangles_.capacity() * sizeof(detail::BoxedTriangle) + vertices_.capacity() * sizeof(Eigen::Vector3f) +
      (grid_.first.capacity() + grid_.members.capacity() + vertex_first_.capacity() + sample_block_.capacity()) *
          sizeof(uint32_t) +
      samples_.capacity() * sizeof(float) + grid_.ring.capacity();
}

// Cells about a triangle's size (a few triangles each), coarser where a mesh of very unequal triangles would need
// too many cells or put a large triangle into too many.
void StaticMeshIndex::size_grid(double edges) {
  const Eigen::Vector3f extent = grid_.hi - grid_.lo;
  const size_t n = triangles_.size();
  grid_.cell = std::max({float(edges / double(3 * n)), extent.maxCoeff() / 4096.0f, 1e-30f});
  for (;;) {
    for (int a = 0; a < 3; ++a) grid_.dims[a] = std::max(1, int(std::ceil(extent[a] / grid_.cell)));
    const double cells = double(grid_.dims.x()) * double(grid_.dims.y()) * double(grid_.dims.z());
    double members = 0;
    if (cells <= std::max(64.0 * 64 * 64, 8.0 * double(n))) {
      for (const detail::BoxedTriangle& t : triangles_) {
        const Eigen::Vector3i c0 = cell_of(t.lo), c1 = cell_of(t.hi);
        members += double(c1.x() - c0.x() + 1) * double(c1.y() - c0.y() + 1) * double(c1.z() - c0.z() + 1);
      }
      if (members <= 32.0 * double(n)) return;
    }
    grid_.cell *= 1.5f;
  }
}

// Vertices: each once, sorted by cell.
void StaticMeshIndex::index_vertices() {
  const size_t cells = size_t(grid_.dims.prod());
  std::vector<std::pair<uint32_t, Eigen::Vector3f>> keyed;
  keyed.reserve(vertices_.size());
  for (const Eigen::Vector3f& v : vertices_) {
    const Eigen::Vector3i c = cell_of(v);
    keyed.emplace_back(uint32_t(cell_index(c.x(), c.y(), c.z())), v);
  }
  auto tied = [](const std::pair<uint32_t, Eigen::Vector3f>& p) {
    return std::make_tuple(p.first, p.second.x(), p.second.y(), p.second.z());
  };
  std::sort(keyed.begin(), keyed.end(), [&](const auto& a, const auto& b) { return tied(a) < tied(b); });
  keyed.erase(std::unique(keyed.begin(), keyed.end(), [&](const auto& a, const auto& b) { return tied(a) == tied(b); }),
              keyed.end());
  vertices_.clear();
  vertices_.shrink_to_fit();
  vertices_.reserve(keyed.size());
  vertex_first_.assign(cells + 1, 0);
  for (const auto& [cell, v] : keyed) {
    vertices_.push_back(v);
    ++vertex_first_[cell + 1];
  }
  for (size_t c = 0; c < cells; ++c) vertex_first_[c + 1] += vertex_first_[c];
}

bool StaticMeshIndex::search(const Eigen::Vector3f& x, const Eigen::Vector3i& c, int first_ring, float box, float band,
                             float& distance, Eigen::Vector3f& outward, float& beyond, float seed) const {
  detail::NearestTriangle nearest(x);
  if (seed < band) nearest.best2 = seed * seed;  // cells farther than the seed are passed over
  const float reach = nearest_by_rings(grid_, triangles_, x, c, first_ring, box, band, nearest);
  if (nearest.settled_within(reach)) {
    if (nearest.best_alignment < 0.0f)  // the seed was too small (rounding): no triangle taken
      return search(x, c, first_ring, box, band, distance, outward, beyond);
    const float d = std::sqrt(nearest.best2);
    if (d > band) {
      beyond = d;
      return false;
    }
    distance = nearest.signed_distance();
    outward = nearest.outward;
    return true;
  }
  // Not settled: every triangle not seen is beyond the band, and so is the nearest seen.
  beyond = std::min(std::sqrt(nearest.best2), reach);
  return false;
}

float StaticMeshIndex::distance(const Eigen::Vector3f& x, float proximity, Eigen::Vector3f& outward) const {
  if (triangles_.empty()) {
    outward = Eigen::Vector3f::UnitY();
    return std::numeric_limits<float>::infinity();
  }
  const float band = base_band() + proximity;
  const Eigen::Vector3i c = cell_of(x);
  const Eigen::Vector3f off = x - x.cwiseMax(grid_.lo).cwiseMin(grid_.hi);
  const float box = off.norm();
  const int ring = grid_.ring[cell_index(c.x(), c.y(), c.z())];
  auto away = [&] {
    return box > 0.0f ? Eigen::Vector3f(off / box)
                      : (common_normal_.squaredNorm() > 0.0f ? common_normal_ : Eigen::Vector3f::UnitY());
  };
  // No triangle within ring - 1 cells (x's projection onto the box lies in its cell; projecting onto a convex
  // set brings nothing of it nearer) nor nearer than the box.
  const float bound = std::max(box, float(ring - 1) * grid_.cell);
  if (bound > band) {
    outward = away();
    return bound;
  }
  float d, beyond;
  if (search(x, c, ring, box, band, d, outward, beyond)) return d;
  outward = away();
  return beyond;
}

float StaticMeshIndex::exact_lower_bound(const Eigen::Vector3f& x, float band, float seed, bool* exact) const {
  if (exact) *exact = false;
  if (triangles_.empty()) return std::numeric_limits<float>::infinity();
  const Eigen::Vector3i c = cell_of(x);
  const Eigen::Vector3f off = x - x.cwiseMax(grid_.lo).cwiseMin(grid_.hi);
  const float box = off.norm();
  const int ring = grid_.ring[cell_index(c.x(), c.y(), c.z())];
  const bool facing = common_normal_.squaredNorm() > 0.0f && off.dot(common_normal_) > 0.0f;
  const float bound = std::max(box, float(ring - 1) * grid_.cell);
  if (bound > band) return facing ? bound : bound - 2.0f * band;
  float d, beyond;
  Eigen::Vector3f outward;
  if (search(x, c, ring, box, band, d, outward, beyond, seed)) {
    if (exact) *exact = true;
    return d;
  }
  return facing ? beyond : beyond - 2.0f * band;
}

float StaticMeshIndex::lower_bound(const Eigen::Vector3f& x, float proximity) const {
  if (triangles_.empty()) return std::numeric_limits<float>::infinity();
  const float band = base_band() + proximity;
  const Eigen::Vector3i c = cell_of(x);
  const size_t cell = cell_index(c.x(), c.y(), c.z());
  const Eigen::Vector3f off = x - x.cwiseMax(grid_.lo).cwiseMin(grid_.hi);
  const float box = off.norm();
  const bool facing = common_normal_.squaredNorm() > 0.0f && off.dot(common_normal_) > 0.0f;
  const float bound = std::max(box, float(grid_.ring[cell] - 1) * grid_.cell);
  if (bound > band) return facing ? bound : bound - 2.0f * band;
  const uint32_t block = sample_block_[cell];
  if (block == kNoSamples) return exact_lower_bound(x, band);
  // The cell's sample s (at its centre): distance() is not below its value less |y - s| wherever it has a
  // contact (within the base band the sample is the exact distance; a sample beyond it may hold a point behind the
  // mesh at most the proximity deeper than the base band, which twice the proximity more covers).
  const Eigen::Vector3f s = grid_.lo + grid_.cell * (c.cast<float>() + Eigen::Vector3f::Constant(0.5f));
  const float value = samples_[size_t(block)] - (x - s).norm() - 2.0f * proximity;
  return facing ? std::max(value, bound) : value;
}

void StaticMeshIndex::sample() {
  const size_t cells = grid_.ring.size();
  sample_block_.assign(cells, kNoSamples);
  uint32_t blocks = 0;
  for (size_t c = 0; c < cells; ++c)
    if (grid_.ring[c] <= kSampledRings) sample_block_[c] = blocks++;
  samples_.resize(size_t(blocks));
  const float band = base_band();
  bool have_last = false;
  float last = 0;
  Eigen::Vector3f last_at = Eigen::Vector3f::Zero();
  for (int k = 0; k < grid_.dims.z(); ++k)
    for (int j = 0; j < grid_.dims.y(); ++j)
      for (int i = 0; i < grid_.dims.x(); ++i) {
        const uint32_t block = sample_block_[cell_index(i, j, k)];
        if (block == kNoSamples) continue;
        const Eigen::Vector3f corner = grid_.lo + grid_.cell * Eigen::Vector3f(float(i), float(j), float(k));
        // The sample before bounds this one's nearest triangle: |its distance| + the step, rounding aside.
        const Eigen::Vector3f s = corner + Eigen::Vector3f::Constant(0.5f * grid_.cell);
        const float seed = have_last ? (std::abs(last) + (s - last_at).norm()) * (1 + 1e-4f) + 1e-6f * grid_.cell
                                     : std::numeric_limits<float>::infinity();
        float& value = samples_[size_t(block)];
        value = exact_lower_bound(s, band, seed, &have_last);
        last = value;
        last_at = s;
      }
  info_.samples = samples_.size();
}

}  // namespace voxfmt::bullet
