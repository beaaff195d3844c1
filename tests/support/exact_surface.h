// Exact references for tests: distance to a closed triangle mesh and an inside test (CGAL AABB tree).
#pragma once

#include <CGAL/AABB_face_graph_triangle_primitive.h>
#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Side_of_triangle_mesh.h>
#include <CGAL/Surface_mesh.h>

#include <cmath>
#include <memory>

#include "stages.h"

namespace voxfmt::test {

class ExactSurface {
 public:
  using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
  using Point = Kernel::Point_3;
  using Mesh = CGAL::Surface_mesh<Point>;

  explicit ExactSurface(const bake::TriangleMesh& m) {
    std::vector<Mesh::Vertex_index> v;
    for (const Vec3& p : m.vertices) v.push_back(mesh_.add_vertex(Point(p[0], p[1], p[2])));
    for (const auto& t : m.triangles) mesh_.add_face(v[t[0]], v[t[1]], v[t[2]]);
    tree_ = std::make_unique<Tree>(faces(mesh_).first, faces(mesh_).second, mesh_);
    tree_->accelerate_distance_queries();
    inside_ = std::make_unique<CGAL::Side_of_triangle_mesh<Mesh, Kernel>>(*tree_);
  }
  double distance(const Vec3& p) const { return std::sqrt(tree_->squared_distance(Point(p[0], p[1], p[2]))); }
  bool inside(const Vec3& p) const { return (*inside_)(Point(p[0], p[1], p[2])) == CGAL::ON_BOUNDED_SIDE; }
  /// The surface point nearest to p.
  Vec3 closest(const Vec3& p) const {
    const Point q = tree_->closest_point(Point(p[0], p[1], p[2]));
    return {q.x(), q.y(), q.z()};
  }
  /// Signed distance, negative inside (the spec's convention).
  double signed_distance(const Vec3& p) const { return inside(p) ? -distance(p) : distance(p); }

 private:
  using Primitive = CGAL::AABB_face_graph_triangle_primitive<Mesh>;
  using Tree = CGAL::AABB_tree<CGAL::AABB_traits<Kernel, Primitive>>;
  Mesh mesh_;
  std::unique_ptr<Tree> tree_;
  std::unique_ptr<CGAL::Side_of_triangle_mesh<Mesh, Kernel>> inside_;
};

}  // namespace voxfmt::test
