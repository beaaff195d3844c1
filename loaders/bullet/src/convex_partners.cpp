// A VPS shape against Bullet's convex partners, one handler per kind (partner_pairs.h).
#include <BulletCollision/CollisionShapes/btConvexPolyhedron.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "partner_pairs.h"
#include "voxfmt/bullet/collision.h"

namespace voxfmt::bullet::detail {

void collide_box(const ConvexPair& pair, const btBoxShape& b) {
  const btVector3 half = b.getHalfExtentsWithMargin();
  const Eigen::Matrix3f rbf = pair.rotation_b().cast<float>();
  const Eigen::Vector3f obf = pair.origin_b().cast<float>(), halff = to_eigen(half).cast<float>();
  pair.points_against_b(
      [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return box_distance(rbf, obf, halff, x, outward); });
  if (!pair.a.uses_voxelmap()) return;
  thread_local std::vector<Eigen::Vector3d> corners;
  corners.clear();
  for (int k = 0; k < 8; ++k)
    corners.push_back(pair.world(
        btVector3((k & 1) ? half.x() : -half.x(), (k & 2) ? half.y() : -half.y(), (k & 4) ? half.z() : -half.z())));
  pair.in_voxelmap(corners, 0.0);
}

void collide_sphere(const ConvexPair& pair, const btSphereShape& b) {
  const Eigen::Vector3f centre = pair.origin_b().cast<float>();
  const float radius = float(b.getRadius());
  pair.points_against_b(
      [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return sphere_distance(centre, radius, x, outward); });
  const Eigen::Vector3d centre_d = pair.origin_b();
  if (pair.a.uses_voxelmap()) pair.in_voxelmap(&centre_d, 1, double(b.getRadius()));
}

void collide_capsule(const ConvexPair& pair, const btCapsuleShape& b) {
  btVector3 tip(0, 0, 0);
  tip[b.getUpAxis()] = b.getHalfHeight();
  const Eigen::Vector3f top = pair.world(tip).cast<float>(), bottom = pair.world(-tip).cast<float>();
  const float radius = float(b.getRadius());
  pair.points_against_b([&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
    return capsule_distance(bottom, top, radius, x, outward);
  });
  if (!pair.a.uses_voxelmap()) return;
  // Spheres along the axis, no farther apart than a voxel of A.
  const double voxel = pair.a.object().voxelmap().voxel_size() * pair.a.scale();
  const int steps = std::clamp(int(std::ceil(2 * double(b.getHalfHeight()) / voxel)), 1, 64);
  thread_local std::vector<Eigen::Vector3d> centres;
  centres.clear();
  for (int k = 0; k <= steps; ++k) centres.push_back(pair.world(tip * btScalar(2.0 * k / steps - 1.0)));
  pair.in_voxelmap(centres, double(b.getRadius()));
}

void collide_cylinder(const ConvexPair& pair, const btCylinderShape& b) {
  const int up = b.getUpAxis();
  const Eigen::Vector3f centre = pair.origin_b().cast<float>(), axis = pair.rotation_b().col(up).cast<float>();
  const float radius = float(b.getRadius()), half = float(b.getHalfExtentsWithMargin()[up]);
  pair.points_against_b([&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
    return cylinder_distance(centre, axis, radius, half, x, outward);
  });
  if (pair.a.uses_voxelmap()) pair.support_points_in_voxelmap(b);
}

void collide_multi_sphere(const ConvexPair& pair, const btMultiSphereShape& b) {
  pair.points_against_b(
      [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return convex_distance(b, pair.tb, x, outward); });
  if (!pair.a.uses_voxelmap()) return;
  // Its spheres are stored unscaled (Bullet scales them in its support function: centres per axis, radii by x; the
  // largest factor here, never smaller than the shape).
  const btVector3 scaling = b.getLocalScaling();
  const btVector3 magnitude = scaling.absolute();
  const double radius_scale = double(magnitude[magnitude.maxAxis()]);
  for (int k = 0; k < b.getSphereCount(); ++k) {
    const Eigen::Vector3d centre = pair.world(b.getSpherePosition(k) * scaling);
    pair.in_voxelmap(&centre, 1, double(b.getSphereRadius(k)) * radius_scale);
  }
}

void collide_polyhedron(const ConvexPair& pair, const btPolyhedralConvexShape& b) {
  if (const btConvexPolyhedron* polyhedron = b.getConvexPolyhedron()) {
    // Hulls with polyhedral features (initializePolyhedralFeatures): exact inside, GJK outside (EPA's
    // tolerance would make resting contacts jitter).
    const Eigen::Matrix3d rb = pair.rotation_b();
    const Eigen::Vector3d ob = pair.origin_b();
    thread_local std::vector<Eigen::Vector4f> planes;
    planes.clear();
    for (int f = 0; f < polyhedron->m_faces.size(); ++f) {
      const btScalar* plane = polyhedron->m_faces[f].m_plane;
      const Eigen::Vector3d n = rb * Eigen::Vector3d(plane[0], plane[1], plane[2]);
      planes.emplace_back(float(n.x()), float(n.y()), float(n.z()), float(double(plane[3]) - n.dot(ob)));
    }
    const float margin = float(b.getMargin());
    pair.points_against_b([&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
      float d;
      if (polyhedron_inside_distance(planes, margin, x, d, outward)) return d;
      return convex_distance(b, pair.tb, x, outward);
    });
  } else {
    pair.points_against_b(
        [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return convex_distance(b, pair.tb, x, outward); });
  }
  if (!pair.a.uses_voxelmap()) return;
  // Its vertices; the margin rounds the hull outward.
  thread_local std::vector<Eigen::Vector3d> vertices;
  vertices.clear();
  for (int k = 0; k < b.getNumVertices(); ++k) {
    btVector3 v;
    b.getVertex(k, v);
    vertices.push_back(pair.world(v));
  }
  pair.in_voxelmap(vertices, double(b.getMargin()));
}

// Curved convex shapes without a closed form here (cone, ...): GJK, and support points.
void collide_curved_convex(const ConvexPair& pair, const btConvexShape& b) {
  pair.points_against_b(
      [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return convex_distance(b, pair.tb, x, outward); });
  if (pair.a.uses_voxelmap()) pair.support_points_in_voxelmap(b);
}

}  // namespace voxfmt::bullet::detail
