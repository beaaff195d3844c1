// Private: a static triangle mesh indexed once in its shape frame (CollisionSettings::static_mesh_index), for the
// point queries of every VPS body that meets it.
#pragma once

#include <BulletCollision/CollisionShapes/btConcaveShape.h>

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "triangle_set.h"
#include "voxfmt/bullet/collision.h"

namespace voxfmt::bullet {

namespace detail {
/// Whether a mesh's local scaling mirrors it (an odd number of negative factors): every triangle then comes from
/// Bullet turned over, its winding, and so its outside, reversed.
inline bool mirrors(const btVector3& scaling) { return scaling.x() * scaling.y() * scaling.z() < 0; }
}  // namespace detail

/// What identifies a mesh shape's triangles cheaply: a shape object freed and another made at its address, or
/// a mesh rescaled or refitted to a new box, no longer matches.
struct MeshSignature {
  int type = -1;
  const void* mesh = nullptr;  ///< the striding mesh interface (or the scaled shape's child)
  float scaling[3] = {0, 0, 0};
  float lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  static MeshSignature of(const btConcaveShape& shape);
  bool operator==(const MeshSignature& o) const;
};

/// Every triangle of a static mesh in its shape frame (scaling applied), binned in a uniform grid of cells about
/// a triangle's size, with a ring map to the nearest occupied cell, a lower bound of the distance sampled at the
/// centre of each cell near the mesh, and the mesh's vertices by cell.
///
/// The distance it gives is the signed distance to the nearest triangle, signed as TriangleSet signs it, within
/// a band around the mesh; beyond the band (farther than it from every triangle) a point is outside and gets a
/// positive value not below the band instead (a point that deep behind a floor has tunnelled through it). The
/// band is `base_band()` plus the query's proximity, so that every contact and proximity contact is exact. The
/// exact search visits the cells nearest the point first and stops once no unvisited cell can hold a nearer
/// triangle; the lower bound reads one sample.
class StaticMeshIndex {
 public:
  struct Info {
    size_t triangles = 0, vertices = 0, cells = 0, samples = 0, memory_bytes = 0;
    double build_seconds = 0;
  };

  /// Collects every triangle of `shape` (processAllTriangles over its whole box) and indexes them.
  static std::shared_ptr<const StaticMeshIndex> build(const btConcaveShape& shape);

  const MeshSignature& signature() const { return signature_; }
  const Info& info() const { return info_; }
  bool empty() const { return triangles_.empty(); }
  /// The band every query gets beyond its proximity: two cells.
  float base_band() const { return 2.0f * grid_.cell; }

  /// The signed distance at x (shape frame) for a query with `proximity`, as above; `outward` is the mesh's
  /// outward unit normal at the nearest point (away from the mesh beyond the band).
  float distance(const Eigen::Vector3f& x, float proximity, Eigen::Vector3f& outward) const;
  /// A value that distance(y, proximity) is not below less |y - x| for any y where that distance is below the
  /// proximity (every contact), for pruning spheres.
  float lower_bound(const Eigen::Vector3f& x, float proximity) const;

  /// The vertices of the cells whose box overlaps [lo, hi] (shape frame), by blocks of 4 x 4 x 4 cells on a
  /// lattice fixed to the grid (so any two vertices come in the same order whatever the box): `keep(centre,
  /// radius)` says whether a block's ball may hold a vertex of interest, and `visit(vertex, id)` gets every vertex
  /// of the cells kept, each once, with its place in the index (vertex(id)).
  template <class Keep, class Visit>
  void vertices_in_box(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi, Keep&& keep, Visit&& visit) const;
  const Eigen::Vector3f& vertex(uint32_t id) const { return vertices_[id]; }

 private:
  void index();
  void size_grid(double edges);
  void index_vertices();
  Eigen::Vector3i cell_of(const Eigen::Vector3f& x) const { return grid_.cell_of(x); }
  size_t cell_index(int i, int j, int k) const { return grid_.cell_index(i, j, k); }
  /// The exact search (x within the band of some occupied cell): returns false when every triangle is farther
  /// than `band`, with `beyond` a lower bound of the distance not below the band.
  bool search(const Eigen::Vector3f& x, const Eigen::Vector3i& c, int first_ring, float box, float band,
              float& distance, Eigen::Vector3f& outward, float& beyond,
              float seed = std::numeric_limits<float>::infinity()) const;
  /// lower_bound() without samples: the exact distance within `band`; beyond it, the bound less twice the band
  /// where x may be behind the mesh (distance() is at least -band there, so a ball around x reaches such points
  /// only across that much more), or the bound itself beyond the mesh's box on the side every triangle faces.
  /// `seed`: a distance the nearest triangle is not farther than (a search knowing it skips farther cells);
  /// `exact` says whether the value is the distance (within the band).
  float exact_lower_bound(const Eigen::Vector3f& x, float band, float seed = std::numeric_limits<float>::infinity(),
                          bool* exact = nullptr) const;
  void sample();

  MeshSignature signature_;
  Info info_;
  std::vector<detail::BoxedTriangle> triangles_;
  std::vector<Eigen::Vector3f> vertices_;  ///< sorted by cell: cell c holds vertex_first_[c] .. vertex_first_[c + 1]
  TriangleGrid grid_;  ///< the triangles binned in cells about a triangle's size, with the rings to them
  Eigen::Vector3f common_normal_ = Eigen::Vector3f::Zero();  ///< zero unless every normal has n . c > 0
  std::vector<uint32_t> vertex_first_;
  static constexpr int kEmptyRings = 255;
  /// Cells within kSampledRings of a triangle: exact_lower_bound(., base_band()) at their centre, in
  /// samples_[sample_block_[c]] (kNoSamples elsewhere). (Eight per cell, at half cells, made queries 7 % faster
  /// and the index 5x slower to build.)
  static constexpr int kSampledRings = 3;
  static constexpr uint32_t kNoSamples = 0xffffffffu;
  std::vector<uint32_t> sample_block_;
  std::vector<float> samples_;
};

template <class Keep, class Visit>
void StaticMeshIndex::vertices_in_box(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi, Keep&& keep,
                                      Visit&& visit) const {
  if (vertices_.empty() || (lo.array() > grid_.hi.array()).any() || (hi.array() < grid_.lo.array()).any()) return;
  const Eigen::Vector3i c0 = cell_of(lo), c1 = cell_of(hi);
  constexpr int kBlock = 4;
  const float radius = 0.5f * std::sqrt(3.0f) * kBlock * grid_.cell;
  for (int bk = c0.z() / kBlock * kBlock; bk <= c1.z(); bk += kBlock)
    for (int bj = c0.y() / kBlock * kBlock; bj <= c1.y(); bj += kBlock)
      for (int bi = c0.x() / kBlock * kBlock; bi <= c1.x(); bi += kBlock) {
        const Eigen::Vector3f centre = grid_.lo + grid_.cell * (Eigen::Vector3f(float(bi), float(bj), float(bk)) +
                                                                Eigen::Vector3f::Constant(0.5f * kBlock));
        if (!keep(centre, radius)) continue;
        const int i0 = std::max(bi, c0.x()), i1 = std::min(bi + kBlock - 1, c1.x());
        for (int k = std::max(bk, c0.z()); k <= std::min(bk + kBlock - 1, c1.z()); ++k)
          for (int j = std::max(bj, c0.y()); j <= std::min(bj + kBlock - 1, c1.y()); ++j) {
            const size_t row = cell_index(0, j, k);
            for (uint32_t v = vertex_first_[row + size_t(i0)]; v < vertex_first_[row + size_t(i1) + 1]; ++v)
              visit(vertices_[v], v);
          }
      }
}

}  // namespace voxfmt::bullet
