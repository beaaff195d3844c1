// The bake library behind `voxfmt build`: mesh file -> voxfmt asset. Each stage is a function of its own so
// tests and other front ends can call it. Errors are thrown as BakeError (one kind per layer: the CLI turns
// them into messages and exit codes).
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "voxfmt/asset.h"

namespace voxfmt::bake {

/// Why a bake failed: a stable UPPER_SNAKE code and a message naming the input.
class BakeError : public std::runtime_error {
 public:
  BakeError(std::string code, const std::string& message) : std::runtime_error(message), code_(std::move(code)) {}
  const std::string& code() const { return code_; }

 private:
  std::string code_;
};

struct TriangleMesh {
  std::vector<Vec3> vertices;
  std::vector<std::array<uint32_t, 3>> triangles;
};

struct Bounds {
  Vec3 lo, hi;
};
/// Axis-aligned bounding box of the mesh's vertices (the mesh must have at least one vertex).
Bounds bounding_box(const TriangleMesh& mesh);

// ---------------------------------------------------------------- 1. import

struct ImportOptions {
  double unit_scale = 1.0;  ///< multiply coordinates by this (e.g. 0.001 for a mesh in millimetres)
};
/// Reads every mesh of the scene (any format assimp reads), applies node transforms, merges them into one
/// triangle soup. Throws BakeError: INPUT_NOT_FOUND, UNSUPPORTED_FORMAT, IMPORT_FAILED, EMPTY_SCENE,
/// NON_FINITE_COORDINATES.
TriangleMesh import_mesh(const std::string& path, const ImportOptions& options = {});
/// True when `path`'s extension (case-insensitive, e.g. ".obj", ".mesh.xml") is a mesh format assimp reads.
/// Formats without surfaces (animation, camera) and suffixes too generic to mean a mesh in a directory scan
/// (".xml", ".raw") are left out; import_mesh still accepts them.
bool is_mesh_file_name(const std::string& path);

// ---------------------------------------------------------------- 2. check and repair

struct RepairReport {
  bool closed = false;            ///< no border edges after repair
  bool consistently_oriented = false;
  size_t merged_vertices = 0;     ///< duplicate vertices merged
  size_t removed_faces = 0;       ///< degenerate or duplicate faces dropped
  size_t border_edges = 0;
  size_t non_manifold_vertices = 0;
  size_t components = 0;
  size_t self_intersecting_pairs = 0;
  std::vector<BuildWarning> warnings;
};
/// Merges duplicate vertices, drops degenerate faces, orients consistently (outward when closed), and
/// reports defects as warnings. Throws BakeError EMPTY_SCENE when nothing is left.
TriangleMesh repair_mesh(const TriangleMesh& mesh, RepairReport& report, bool check_self_intersections = true);

// ---------------------------------------------------------------- 3. voxelmap

struct VoxelmapOptions {
  uint32_t resolution = 128;            ///< voxels along the longest bounding-box axis (used if voxel_size is 0)
  double voxel_size = 0.0;              ///< metres; overrides resolution when > 0
  uint32_t margin = 4;                  ///< outer voxels around the bounding box on each side
  double distance_band = 3.0;           ///< voxels; exact distances stored within ±band
  /// Inside = generalized winding number >= 1/2 (for open, non-manifold or self-intersecting surfaces).
  /// Off: the sign of a closed surface (pseudonormals near it, carried along grid rows elsewhere).
  bool winding_number_sign = false;
};
/// Builds the layered distance-field voxelmap of a repaired (outward-oriented) mesh: exact distances in the band,
/// chamfer layers beyond it.
Voxelmap build_voxelmap(const TriangleMesh& mesh, const VoxelmapOptions& options);

// ---------------------------------------------------------------- 4. point shell

struct PointShellOptions {
  uint32_t points = 10000;     ///< target number of points (used if point_spacing is 0)
  double point_spacing = 0.0;  ///< metres; overrides points when > 0
  double branching = 6.5;      ///< mean children per tree node
  uint64_t seed = 0x5eed;      ///< sampling is deterministic for a given seed
};
/// Samples evenly spread surface points (Poisson-disk by dart throwing over area-weighted candidates) with
/// inward face normals. Returns points and normals only (tree fields empty).
PointShell sample_point_shell(const TriangleMesh& mesh, const PointShellOptions& options);
/// Clusters the points bottom-up into a breadth-first point-sphere tree (reorders the points).
void build_sphere_tree(PointShell& shell, double branching);

// ---------------------------------------------------------------- 5. mass properties

/// Volume, centre of mass and inertia (unit density) of a closed, outward-oriented mesh.
MassProperties compute_mass_properties(const TriangleMesh& mesh);
/// The same for the voxelmap's inside, for surfaces whose inside is the winding number's (open, non-manifold,
/// self-intersecting: a surface integral would depend on the origin or count overlaps twice). A voxel counts
/// with the fraction clamp(1/2 - d/h, 0, 1) where its distance d is stored, wholly where its layer is > 0.
MassProperties voxelmap_mass_properties(const Voxelmap& voxelmap);

// ---------------------------------------------------------------- the whole bake

struct BuildOptions {
  ImportOptions import;
  VoxelmapOptions voxelmap;
  PointShellOptions point_shell;
  bool check_self_intersections = true;
  std::string up_axis = "+Y";
  unsigned threads = 0;  ///< 0 = all cores
};

struct StageTiming {
  std::string stage;
  double seconds = 0;
};

struct BuildReport {
  std::vector<StageTiming> timings;
  RepairReport repair;
  size_t input_vertices = 0, input_triangles = 0;
};

/// Called when a stage starts: (index from 1, count, name).
using ProgressCallback = std::function<void(int, int, const std::string&)>;

/// Runs every stage and returns the asset (not yet written).
Asset build_asset(const std::string& mesh_path, const BuildOptions& options, BuildReport& report,
                  const ProgressCallback& progress = {});

/// Build options as the JSON object stored in provenance.
std::string build_parameters_json(const BuildOptions& options);
/// Versions of the libraries the bake uses.
std::map<std::string, std::string> dependency_versions();
/// Lowercase hex SHA-256 of a file's bytes.
std::string sha256_file(const std::string& path);
/// The current time as ISO 8601 UTC, e.g. "2026-11-22T04:00:14Z" (provenance, manifests).
std::string utc_now();

}  // namespace voxfmt::bake
