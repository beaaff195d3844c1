// vps-bench scenarios: the bodies of each scene (one geometry shared by every method) and its pose set.
#pragma once

#include <fcl/geometry/bvh/BVH_model.h>
#include <fcl/math/bv/OBBRSS.h>
#include <Eigen/Geometry>

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "voxfmt/runtime/collision_object.h"

namespace vps_bench {

/// A triangle mesh in the body's shape frame (VPS shapes: the asset's principal frame).
struct Mesh {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<std::array<int, 3>> triangles;
};

/// FCL's bounding-volume hierarchy of a mesh (FCL computes the scenarios' exact mesh distances and is a peer).
std::shared_ptr<fcl::BVHModel<fcl::OBBRSSd>> fcl_mesh(const Mesh& mesh);

/// FCL's bounding-volume hierarchy of a mesh (FCL computes the scenarios' exact mesh distances and is a peer).
std::shared_ptr<fcl::BVHModel<fcl::OBBRSSd>> fcl_mesh(const Mesh& mesh);

/// One body of a scenario. Dynamic bodies are meshes with a baked asset; static partners are a plane, a box
/// or a triangle-mesh floor.
struct Body {
  enum class Kind { BakedMesh, Plane, Box, StaticMesh };
  Kind kind = Kind::BakedMesh;
  std::string name;
  Mesh mesh;  ///< BakedMesh and StaticMesh
  /// What HACD decomposes when not `mesh` (a coarser tessellation of the same surface, same frame).
  Mesh decomposition_mesh;
  std::shared_ptr<const voxfmt::runtime::CollisionObject> vps;  ///< BakedMesh
  std::string mesh_path;   ///< BakedMesh: the mesh file the asset was baked from (HACD cache key)
  std::string asset_path;  ///< BakedMesh
  Eigen::Vector3d half_extents = Eigen::Vector3d::Zero();  ///< Box; Plane: the normal is +y through the origin
};

/// Both bodies' shape frames in the world, for one query.
struct PosePair {
  Eigen::Isometry3d a = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d b = Eigen::Isometry3d::Identity();
  /// The exact deepest penetration of A's surface into B (metres), where known by construction.
  std::optional<double> exact_depth;
};

struct Scenario {
  std::string name;
  std::string description;
  std::shared_ptr<Body> a, b;
  std::vector<PosePair> poses;
};

struct ScenarioSettings {
  std::string cache_dir;   ///< baked assets, generated meshes, decompositions
  std::string bunny_mesh;  ///< CGAL's bunny00.off
  size_t poses = 200;      ///< per scenario
  uint64_t seed = 20261123;
  bool verbose = true;
};

/// Names in the order the program runs them.
const std::vector<std::string>& scenario_names();

/// Builds one scenario (baking or loading the assets it needs from the cache). Throws std::runtime_error with
/// a message naming the problem.
Scenario make_scenario(const std::string& name, const ScenarioSettings& settings);

/// The bunny asset used for the memory figure (resolution 306, 35k points).
std::shared_ptr<Body> bunny_body(const ScenarioSettings& settings);

/// bunny-static-mesh's floor baked offline into an asset (what a user can do for level geometry instead of a
/// triangle mesh): the wavy floor closed into a solid slab (vertical sides down to a flat bottom 20 mm below) and
/// baked with `voxel_size` voxels, once into the cache; loaded as a voxelmap only. The bake's figures are those
/// of the run that baked it (kept beside the asset).
struct BakedFloor {
  std::shared_ptr<const voxfmt::runtime::CollisionObject> object;
  double voxel_size = 0;
  double bake_s = 0;        ///< the whole bake (import, repair, voxelmap, point shell, write)
  double bake_peak_mb = 0;  ///< the baking process's peak memory (the benchmark's own included)
  double file_mb = 0, runtime_mb = 0;
  size_t triangles = 0;  ///< of the closed slab
};
BakedFloor baked_floor(const std::string& cache_dir, double voxel_size, bool verbose = true);

}  // namespace vps_bench
