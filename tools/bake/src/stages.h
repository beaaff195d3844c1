// Internal to voxfmt::bake: the stages of the bake, one function each, so the bake and its tests can call
// them alone. A stage reports failure by throwing BakeError; bake_mesh/bake_to_file turn it into an Error at
// the library's edge (nothing throws across the public API).
#pragma once

#include <atomic>

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/result.h"

namespace voxfmt::bake {

/// Why a stage failed: a stable code and a message naming the input.
class BakeError : public std::runtime_error {
 public:
  BakeError(IssueCode code, const std::string& message) : std::runtime_error(message), code_(code) {}
  IssueCode code() const { return code_; }

 private:
  IssueCode code_;
};

struct Bounds {
  Vec3 lo, hi;
};
/// Axis-aligned bounding box of the mesh's vertices (the mesh must have at least one vertex).
Bounds bounding_box(const TriangleMesh& mesh);
/// The triangles' area summed in their order (m^2): what sizes the point shell and the bake's memory estimate.
double surface_area(const TriangleMesh& mesh);

// ---------------------------------------------------------------- 1. import

/// Reads every mesh of the scene (any format assimp reads), applies node transforms, merges them into one
/// triangle soup. Throws BakeError: INPUT_NOT_FOUND, UNSUPPORTED_FORMAT, IMPORT_FAILED, EMPTY_SCENE,
/// NON_FINITE_COORDINATES.
TriangleMesh import_mesh(const std::string& path, const ImportSettings& settings = {});

// ---------------------------------------------------------------- 2. check and repair

struct RepairReport {
  bool closed = false;  ///< no border edges after repair
  bool consistently_oriented = false;
  size_t merged_vertices = 0;  ///< duplicate vertices merged
  size_t removed_faces = 0;    ///< degenerate or duplicate faces dropped
  size_t border_edges = 0;
  size_t non_manifold_vertices = 0;
  size_t components = 0;
  size_t self_intersecting_pairs = 0;
  std::vector<BuildWarning> warnings;
};
/// Merges duplicate vertices, drops degenerate faces, orients consistently (outward when closed), and
/// reports defects as warnings. Throws BakeError EMPTY_SCENE when nothing is left.
/// The soup steps (CGAL's merge and orientation, which has looped on hostile input) run in a child process when
/// read isolation is on, stopped after `time_limit_s` (0: 30 s plus 1 s per 50,000 triangles): REPAIR_FAILED.
TriangleMesh repair_mesh(const TriangleMesh& mesh, RepairReport& report, bool check_self_intersections = true,
                         double time_limit_s = 0);

// ---------------------------------------------------------------- 3. voxelmap

/// Builds the layered distance-field voxelmap of a repaired (outward-oriented) mesh, sparsely: exact distances in
/// the band (value bricks), exact unsigned distances at the brick corners (the lattice) for everything beyond.
/// `timings`, if given, receives the sub-stages ("voxelmap: band", "voxelmap: lattice", "voxelmap: estimates").
/// What the band found (build_voxelmap's `report`; not for a shell): voxel centres inside the surface, and those more
/// than half a voxel inside (layer >= 1), counted in full only where none is deep. With `stop_if_shallow`, a bake where
/// none is deep returns right after the band (`stopped`, the voxelmap incomplete): the caller bakes a shell instead and
/// need not wait for the rest.
struct VoxelmapReport {
  bool stop_if_shallow = false;
  bool stopped = false;
  uint64_t inside_centres = 0, deep_centres = 0;
};
/// `progress`, if given, is told the share of the voxelmap done (0 to 1) now and then, on the calling thread; an
/// exception it throws stops the bake and leaves build_voxelmap.
using VoxelmapProgress = std::function<void(double share)>;
Voxelmap build_voxelmap(const TriangleMesh& mesh, const VoxelmapSettings& settings,
                        std::vector<StageTiming>* timings = nullptr, VoxelmapReport* report = nullptr,
                        const VoxelmapProgress& progress = {});
/// The voxel size build_voxelmap will use (a shell's too); throws as it would on a mesh or settings it refuses.
double planned_voxel_size(const TriangleMesh& mesh, const VoxelmapSettings& settings);
/// The bytes a bake may use at its peak: `max_memory_bytes` (--max-memory), or 0: 3/4 of this machine's memory.
double memory_limit_bytes(uint64_t max_memory_bytes);

// ---------------------------------------------------------------- 4. point shell

/// Samples evenly spread surface points (Poisson-disk by dart throwing over area-weighted candidates) with
/// inward face normals. Returns points and normals only (tree fields empty). Once `*abandon` is set (the bake it
/// serves failed beside it) it stops within some 65,000 candidates, throwing BakeError INTERNAL.
PointShell sample_point_shell(const TriangleMesh& mesh, const PointShellSettings& settings,
                              const std::atomic<bool>* abandon = nullptr);
/// How many points sample_point_shell aims for: `points`, or with a point spacing the surface's area over
/// 0.75 spacing^2 (so a spacing's count is known, and judged, before any sampling).
double point_shell_target(const TriangleMesh& mesh, const PointShellSettings& settings);
/// Clusters the points bottom-up into a breadth-first point-sphere tree (reorders the points).
void build_sphere_tree(PointShell& shell, double branching);

// ---------------------------------------------------------------- 5. mass properties

/// Volume, centre of mass and inertia (unit density) of a closed, outward-oriented mesh.
MassProperties compute_mass_properties(const TriangleMesh& mesh);
/// The same for the voxelmap's inside, for surfaces whose inside is the winding number's (open, non-manifold,
/// self-intersecting: a surface integral would depend on the origin or count overlaps twice). A voxel counts
/// with the fraction clamp(1/2 - d/h, 0, 1) where its distance d is stored, wholly where its layer is > 0.
MassProperties voxelmap_mass_properties(const Voxelmap& voxelmap);
/// Shell mode: a shell of uniform `thickness` around the surface (volume = area x thickness).
MassProperties shell_mass_properties(const TriangleMesh& mesh, double thickness);
/// Shell mode: every point of a sampled surface (tree not built yet) becomes two, half the thickness to either
/// side along its normal, on the shell's two sheets.
void offset_to_shell_sheets(PointShell& shell, double half_thickness);
/// Shell mode: drops the sheet points (tree not built yet) nearer the surface than `half_thickness - tolerance`. They
/// lie inside the shell, where a sheet does not exist: on the inner side of a part thinner than the shell, or across
/// a fold or a concave edge. Returns how many were dropped; BAD_OPTION if none would be left.
size_t drop_points_inside_shell(PointShell& shell, const TriangleMesh& mesh, double half_thickness, double tolerance);

}  // namespace voxfmt::bake

namespace voxfmt::bake {

// ---------------------------------------------------------------- the whole bake

struct BuildReport {
  std::vector<StageTiming> timings;
  RepairReport repair;
  size_t input_vertices = 0, input_triangles = 0;
};

/// Runs every stage and returns the asset (not yet written). `progress` gets each stage as it starts.
Asset build_asset(const std::string& mesh_path, const Settings& settings, BuildReport& report,
                  const ProgressCallback& progress = {});

}  // namespace voxfmt::bake
