// An HACD convex decomposition (Bullet's extras) with a disk cache: computing it takes minutes, so every
// benchmark run after the first reuses it. A cache file starts with a key made of the mesh's hash and HACD's
// parameters; a file with another key (another mesh, other parameters, an older file) is not used.
#pragma once

#include <LinearMath/btVector3.h>

#include <string>
#include <vector>

namespace voxfmt_bench {

using Hulls = std::vector<std::vector<btVector3>>;

/// Decomposes the mesh (vertices, triangle indices) into at most 8 hulls of <= 100 vertices, or reads them
/// from `cache` when it holds this mesh's key, else from `shipped` (a read-only copy, e.g. the repository's
/// bench/data/, then copied to `cache`). A decomposition is written to `cache` atomically. `seconds` gets the
/// decomposition time (0 from a cache). Progress goes to stderr as one line, updated in place on a terminal.
Hulls hacd_decomposition(const std::vector<btVector3>& vertices, const std::vector<int>& indices,
                         const std::string& cache, double& seconds, const std::string& shipped = "");

/// The key of a cache file for this mesh: a hash of its vertices (to 7 significant digits, so that the last
/// bit of a float computed elsewhere does not matter) and triangles, and HACD's parameters.
std::string hacd_cache_key(const std::vector<btVector3>& vertices, const std::vector<int>& indices);

}  // namespace voxfmt_bench
