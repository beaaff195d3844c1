// Signed distances from a world point to the shapes a VPS body meets in Bullet, each with the partner's outward
// unit normal at its nearest surface point: what a point shell is tested against. Negative inside the partner.
// The collision algorithm uses these; they are public for users who query partners themselves (haptics,
// planning) and for tests.
#pragma once

#include <BulletCollision/CollisionShapes/btConvexShape.h>
#include <LinearMath/btTransform.h>

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <vector>

namespace voxfmt::bullet {

/// Half-space below the plane n.x = c (n unit).
float plane_distance(const Eigen::Vector3f& normal, float constant, const Eigen::Vector3f& x, Eigen::Vector3f& outward);
/// Oriented box: `rotation` (box axes as columns), `centre`, `half` extents.
float box_distance(const Eigen::Matrix3f& rotation, const Eigen::Vector3f& centre, const Eigen::Vector3f& half,
                   const Eigen::Vector3f& x, Eigen::Vector3f& outward);
float sphere_distance(const Eigen::Vector3f& centre, float radius, const Eigen::Vector3f& x, Eigen::Vector3f& outward);
/// Capsule: all points within `radius` of the segment a-b.
float capsule_distance(const Eigen::Vector3f& a, const Eigen::Vector3f& b, float radius, const Eigen::Vector3f& x,
                       Eigen::Vector3f& outward);
/// Cylinder: `centre`, unit `axis`, `radius`, `half_height` along the axis.
float cylinder_distance(const Eigen::Vector3f& centre, const Eigen::Vector3f& axis, float radius, float half_height,
                        const Eigen::Vector3f& x, Eigen::Vector3f& outward);
/// Convex polyhedron given by outward face planes n.x + d <= 0 (world frame), rounded outward by `margin`:
/// exact inside (the nearest face plane); outside it returns false and leaves the distance to the caller.
bool polyhedron_inside_distance(const std::vector<Eigen::Vector4f>& planes, float margin, const Eigen::Vector3f& x,
                                float& distance, Eigen::Vector3f& outward);
/// Any btConvexShape, collision margin included, by Bullet's GJK (outside) and EPA (inside). Returns +infinity
/// where GJK gives up (a point on the surface, within GJK's tolerance).
float convex_distance(const btConvexShape& shape, const btTransform& world_from_shape, const Eigen::Vector3f& x,
                      Eigen::Vector3f& outward);

}  // namespace voxfmt::bullet
