// The convex-hull peer of the benchmarks: Bullet's btShapeHull reduction (~42 vertices) of a mesh's hull.
#pragma once

#include <LinearMath/btVector3.h>

#include <vector>

namespace voxfmt_bench {

/// The vertices btShapeHull keeps of the convex hull of `points` (the hull taken without Bullet's default 4 cm
/// margin, so the reduction samples the mesh's own hull).
std::vector<btVector3> reduced_hull_points(const std::vector<btVector3>& points);

}  // namespace voxfmt_bench
