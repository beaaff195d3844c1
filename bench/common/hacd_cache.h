// An HACD convex decomposition (Bullet's extras) with a disk cache: computing it takes minutes, so every
// benchmark run after the first reuses it.
#pragma once

#include <LinearMath/btVector3.h>

#include <string>
#include <vector>

namespace voxfmt_bench {

using Hulls = std::vector<std::vector<btVector3>>;

/// Decomposes the mesh (vertices, triangle indices) into at most 8 hulls of <= 100 vertices, or reads them
/// from `cache` when it exists (written atomically after a decomposition). `seconds` gets the decomposition
/// time (0 from the cache). Progress goes to stderr as one line, updated in place on a terminal.
Hulls hacd_decomposition(const std::vector<btVector3>& vertices, const std::vector<int>& indices,
                         const std::string& cache, double& seconds);

}  // namespace voxfmt_bench
