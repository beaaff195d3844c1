#include "reduced_hull.h"

#include <BulletCollision/CollisionShapes/btConvexHullShape.h>
#include <BulletCollision/CollisionShapes/btShapeHull.h>

namespace voxfmt_bench {

std::vector<btVector3> reduced_hull_points(const std::vector<btVector3>& points) {
  btConvexHullShape full;
  for (const btVector3& v : points) full.addPoint(v, false);
  full.recalcLocalAabb();
  full.setMargin(0);
  btShapeHull reducer(&full);
  reducer.buildHull(0);
  return std::vector<btVector3>(reducer.getVertexPointer(), reducer.getVertexPointer() + reducer.numVertices());
}

}  // namespace voxfmt_bench
