// The pair tests of a VPS shape (A) against each kind of Bullet partner (B), private to the Bullet integration:
// convex partners (convex_partners.cpp) and static meshes and terrain (mesh_partners.cpp). The collision algorithm
// (collision.cpp) picks one per pair and reduces what it finds.
#pragma once

#include <BulletCollision/CollisionShapes/btBoxShape.h>
#include <BulletCollision/CollisionShapes/btCapsuleShape.h>
#include <BulletCollision/CollisionShapes/btConcaveShape.h>
#include <BulletCollision/CollisionShapes/btCylinderShape.h>
#include <BulletCollision/CollisionShapes/btMultiSphereShape.h>
#include <BulletCollision/CollisionShapes/btPolyhedralConvexShape.h>
#include <BulletCollision/CollisionShapes/btSphereShape.h>

#include <Eigen/Geometry>

#include <cstdint>
#include <vector>

#include "bt_eigen.h"
#include "static_mesh.h"
#include "traversal/function_query.h"
#include "triangle_set.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::bullet::detail {

// Runs A's points against a partner's distance function (world coordinates), coherently with the pair's front
// when there is one (the partner's pose `partner` fixes its function).
template <class Distance>
void points_against(const VpsShape& a, const runtime::Pose& pose_a, const runtime::Pose& partner, Distance&& distance,
                    const runtime::QueryOptions& options, runtime::ContactSet& contacts, runtime::QueryScratch& scratch,
                    runtime::TraversalFront* front) {
  if (front)
    runtime::query_against_function(a.object(), pose_a, partner, distance, options, contacts, scratch, *front);
  else
    runtime::query_against_function(a.object(), pose_a, distance, options, contacts, scratch);
}

inline runtime::Pose partner_pose(const btTransform& t) {
  runtime::Pose pose;
  pose.rotation = to_eigen(t.getBasis());
  pose.translation = to_eigen(t.getOrigin());
  return pose;
}

// A VPS shape (A) against a convex partner (B), both ways: A's points against B's distance function, and B's
// extreme points (corners, centres, vertices or support points, each with a radius) in A's voxelmap — a small or
// sharp partner can poke between A's points. One handler per partner kind below does both, so each kind's two
// halves sit side by side; VpsCollisionAlgorithm::collide picks the handler.
struct ConvexPair {
  const VpsShape& a;
  const runtime::Pose& pose_a;
  const btTransform& tb;
  const runtime::QueryOptions& options;
  runtime::ContactSet& contacts;
  runtime::QueryScratch& scratch;
  runtime::TraversalFront* front;

  Eigen::Matrix3d rotation_b() const { return to_eigen(tb.getBasis()); }
  Eigen::Vector3d origin_b() const { return to_eigen(tb.getOrigin()); }
  Eigen::Vector3d world(const btVector3& local) const { return origin_b() + rotation_b() * to_eigen(local); }
  /// A's points against `distance` (x, outward) -> signed distance, when A has points: a voxelmap-role shape's
  /// too, where it has them, since a partner without points of its own is otherwise seen only by its corners or
  /// centre in A's voxelmap, which beyond the band says nothing (a large box fell through a static VPS floor).
  template <class Distance>
  void points_against_b(Distance&& distance) const {
    if (a.uses_points() || a.object().has_point_shell())
      points_against(a, pose_a, partner_pose(tb), distance, options, contacts, scratch, front);
  }
  /// Points of B, each with `radius`, in A's voxelmap.
  void in_voxelmap(const Eigen::Vector3d* points, size_t count, double radius) const {
    if (count) runtime::query_points_in_voxelmap(a.object(), pose_a, points, count, radius, options, contacts);
  }
  void in_voxelmap(const std::vector<Eigen::Vector3d>& points, double radius) const {
    in_voxelmap(points.data(), points.size(), radius);
  }
  /// B's support points in 26 directions (margin included), for shapes with neither corners nor a centre.
  void support_points_in_voxelmap(const btConvexShape& b) const {
    thread_local std::vector<Eigen::Vector3d> points;
    points.clear();
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          if (dx == 0 && dy == 0 && dz == 0) continue;
          points.push_back(world(b.localGetSupportingVertex(btVector3(btScalar(dx), btScalar(dy), btScalar(dz)))));
        }
    in_voxelmap(points, 0.0);
  }
};

void collide_box(const ConvexPair& pair, const btBoxShape& b);
void collide_sphere(const ConvexPair& pair, const btSphereShape& b);
void collide_capsule(const ConvexPair& pair, const btCapsuleShape& b);
void collide_cylinder(const ConvexPair& pair, const btCylinderShape& b);
void collide_multi_sphere(const ConvexPair& pair, const btMultiSphereShape& b);
void collide_polyhedron(const ConvexPair& pair, const btPolyhedralConvexShape& b);
/// Cones and any other convex shape: Bullet's GJK/EPA distance, and B's support points in A's voxelmap.
void collide_curved_convex(const ConvexPair& pair, const btConvexShape& b);

/// A's points against the triangles of a static mesh or terrain that overlap A's box (grown by the proximity),
/// signed by the triangles' sides; and those triangles' corners in A's voxelmap. With a pair's `kept` set (and
/// front): while a test gathers exactly the triangles the last one did, the distance is the same function, so the
/// built set and the front are kept (a body at rest queries coherently); other triangles replace them, and the
/// test queries from the root and starts the front afresh.
void collide_concave(const VpsShape& a, const runtime::Pose& pose_a, const btTransform& ta, const btConcaveShape& b,
                     const btTransform& tb, const runtime::QueryOptions& options, runtime::ContactSet& contacts,
                     runtime::QueryScratch& scratch, TriangleSet* kept = nullptr,
                     runtime::TraversalFront* front = nullptr);

/// A static mesh's vertices that were near a VPS body (A) at an anchor pose, for coherent queries.
struct VertexCache {
  bool valid = false;
  Eigen::Matrix3d rotation;  ///< A's shape frame from the mesh's at the anchor
  Eigen::Vector3d translation;
  Eigen::Vector3d centre;  ///< the box scanned (mesh frame): centre and half diagonal
  double radius = 0;
  double to_voxels = 0;            ///< A's voxels per metre then
  double threshold = 0;            ///< vertices kept: A's distance bound below this (voxels) ...
  double pad = 0;                  ///< ... within A's box grown by this (metres)
  std::vector<uint32_t> vertices;  ///< their ids in the index, in scan order
};

/// A's points against a static mesh's index (which holds the whole mesh in its shape frame, so nothing is gathered
/// per query), coherently with the pair's front when there is one; and the mesh's vertices near A in A's voxelmap.
void collide_indexed(const VpsShape& a, const runtime::Pose& pose_a, const btTransform& ta, const StaticMeshIndex& mesh,
                     const btTransform& tb, const runtime::QueryOptions& options, runtime::ContactSet& contacts,
                     runtime::QueryScratch& scratch, runtime::TraversalFront* front, VertexCache* cache);

}  // namespace voxfmt::bullet::detail
