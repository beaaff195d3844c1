// voxfmt::bake — a mesh file becomes a voxfmt asset: import (assimp), repair (CGAL), exact band distances and
// layers, point shell and sphere tree, mass properties, provenance. The library behind `voxfmt build`, for
// any caller: every fallible call returns a Result, and writing always validates first (see bake_to_file).
//
//   voxfmt::bake::Settings settings;
//   settings.voxelmap.resolution = 128;
//   auto summary = voxfmt::bake::bake_to_file("bunny.off", "bunny.vox.h5", settings);
//   if (!summary) std::cerr << summary.error().describe() << "\n";
//
// Licence: this target links CGAL's GPL-3 mesh-processing packages, so a binary that contains it is GPL-3
// (see the README); libvoxfmt and the runtime are not affected.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/result.h"

namespace voxfmt::bake {

/// A triangle soup in metres, as the import reads it (all meshes of a scene merged, node transforms applied).
struct TriangleMesh {
  std::vector<Vec3> vertices;
  std::vector<std::array<uint32_t, 3>> triangles;
};

struct ImportSettings {
  double unit_scale = 1.0;  ///< multiply coordinates by this to get metres (e.g. 0.001 for millimetres)
  /// Seconds the isolated import may take before it is stopped as hung (IMPORT_FAILED; 0: 30 s plus 1 s per 5 MB
  /// of file), and the isolated soup repair (REPAIR_FAILED; 0: 30 s plus 1 s per 50,000 triangles). The fuzzers set
  /// a few seconds so that a hanging stage is not taken for a slow input.
  double time_limit_s = 0;
};

struct VoxelmapSettings {
  uint32_t resolution = 128;   ///< voxels along the longest bounding-box axis (used if voxel_size is 0)
  double voxel_size = 0.0;     ///< metres; overrides resolution when > 0
  uint32_t margin = 4;         ///< outer voxels around the bounding box on each side
  double distance_band = 3.0;  ///< voxels; exact distances stored within ±band
  /// Inside = generalized winding number >= 1/2 (open, non-manifold or self-intersecting surfaces); off: the
  /// sign of a closed surface. The whole bake chooses it from the repair report; set it only when calling the
  /// voxelmap stage alone.
  bool winding_number_sign = false;
  /// Shell mode: > 0 bakes the surface as a solid shell of this thickness (metres; signed distance = unsigned
  /// distance - thickness/2), for thin walls, sheets and open scans. 0: the surface's inside; a surface that
  /// encloses nothing at the resolution is then baked as a shell of two voxels, with a SHELL_MODE warning.
  double shell_thickness = 0.0;
  /// Bytes the voxelmap (and, by the same limit, the point shell of `points`) may need at its peak; a bake that
  /// would need more is refused up front with OUT_OF_MEMORY and the estimate. 0: three quarters of this machine's
  /// memory.
  uint64_t max_memory_bytes = 0;
};

struct PointShellSettings {
  uint32_t points = 10000;     ///< target number of points (used if point_spacing is 0)
  double point_spacing = 0.0;  ///< metres; overrides points when > 0
  double branching = 6.5;      ///< mean children per tree node (6.5 gives ~800 points two levels above 35k)
  uint64_t seed = 24301;       ///< sampling is deterministic for a given seed
};

/// Worker threads a bake may be given: 0 (every core) up to this; more would only exhaust memory on thread stacks.
constexpr unsigned kMaxThreads = 1024;

/// Everything a bake can be told. The defaults are `voxfmt build`'s.
struct Settings {
  ImportSettings import;
  VoxelmapSettings voxelmap;
  PointShellSettings point_shell;
  bool check_self_intersections = true;  ///< false skips CGAL's test on huge meshes (a warning says so)
  std::string up_axis = "+Y";            ///< recorded in the asset (informative)
  unsigned threads = 0;                  ///< worker threads; 0 = all cores (at most kMaxThreads)
  int deflate = 4;                       ///< gzip level 0..9 of the voxel grids in the file
};

/// The stages of a bake, in the order they run (kBakeStages describes each).
enum class BakeStage : uint8_t {
  Import,
  Repair,
  VoxelmapAndPointShell,
  Voxelmap,
  VoxelmapBand,
  VoxelmapLattice,
  VoxelmapEstimates,
  PointShell,
  SphereTree,
  Assemble,
  Write,
};

/// One stage: its name is the key of its time in Summary::timings (`voxfmt build --json`'s and the manifest's
/// `timings_s`), what a ProgressCallback is told, and its row in docs/cli.md (scripts/check-docs.py compares the
/// two). This list is the one place a stage's name is written.
struct BakeStageInfo {
  BakeStage stage;
  const char* name;
  BakeStage within;       ///< the stage whose time includes this one's (itself for a stage of the whole bake)
  double progress_start;  ///< share of a typical bake done when it starts; < 0: not reported as progress
};

/// The progress shares are CGAL's bunny at resolution 306: repair 11 %, voxelmap and point shell 60 %, assemble
/// 2 %, write (with its check) 26 %, so that a progress bar moves at an even pace.
inline constexpr BakeStageInfo kBakeStages[] = {
    {BakeStage::Import, "import", BakeStage::Import, 0.0},
    {BakeStage::Repair, "repair", BakeStage::Repair, 0.01},
    {BakeStage::VoxelmapAndPointShell, "voxelmap + point shell", BakeStage::VoxelmapAndPointShell, 0.12},
    {BakeStage::Voxelmap, "voxelmap", BakeStage::VoxelmapAndPointShell, -1},
    {BakeStage::VoxelmapBand, "voxelmap: band", BakeStage::Voxelmap, -1},
    {BakeStage::VoxelmapLattice, "voxelmap: lattice", BakeStage::Voxelmap, -1},
    {BakeStage::VoxelmapEstimates, "voxelmap: estimates", BakeStage::Voxelmap, -1},
    {BakeStage::PointShell, "point shell", BakeStage::VoxelmapAndPointShell, -1},
    {BakeStage::SphereTree, "sphere tree", BakeStage::VoxelmapAndPointShell, -1},
    {BakeStage::Assemble, "assemble", BakeStage::Assemble, 0.72},
    {BakeStage::Write, "write", BakeStage::Write, 0.74},
};

static_assert(
    [] {
      for (size_t i = 0; i < sizeof kBakeStages / sizeof kBakeStages[0]; ++i)
        if (size_t(kBakeStages[i].stage) != i) return false;
      return true;
    }(),
    "kBakeStages lists the stages in BakeStage's order");

constexpr const BakeStageInfo& stage_info(BakeStage stage) { return kBakeStages[size_t(stage)]; }
constexpr const char* stage_name(BakeStage stage) { return stage_info(stage).name; }

struct StageTiming {
  std::string stage;  ///< a name of kBakeStages
  double seconds = 0;
};

/// What a bake did, in one struct: what `voxfmt build --json` prints, what a batch manifest records, what the
/// Python `bake()` returns (to_json() is the one serialisation).
struct Summary {
  std::string input;
  std::string output;  ///< empty for a bake kept in memory
  std::string source_sha256;
  uint64_t input_vertices = 0, input_triangles = 0;
  bool closed = false;  ///< the repaired surface has no border edges
  std::vector<StageTiming> timings;
  double total_s = 0;
  uint64_t peak_memory_bytes = 0;  ///< of the whole process so far
  uint64_t file_size_bytes = 0;    ///< 0 for a bake kept in memory
  std::array<uint32_t, 3> dims{};
  double voxel_size = 0;
  uint64_t stored_distances = 0;
  uint64_t points = 0;
  std::vector<uint32_t> points_per_level;
  double volume = 0;
  std::vector<BuildWarning> warnings;
};

/// The bake's stages as they start (the names of kBakeStages with a progress share), with the share of the whole
/// bake done so far (0..1, by the typical cost of each stage), for progress bars; then "done" at 1. The long
/// "voxelmap + point shell" and "write" are told again as they go (at most 5 times a second), their share rising
/// toward the next stage's. Every call is on the thread that called the bake; an exception the callback throws stops
/// the bake.
using ProgressCallback = std::function<void(std::string_view stage, double fraction)>;

struct Baked {
  Asset asset;
  Summary summary;
};

/// Checks every setting against the range `voxfmt build` accepts (resolution 1..4096, points 1..50,000,000,
/// branching 2..64, margin 0..1024, band 1..64 voxels, deflate 0..9, threads 0..kMaxThreads, up axis one of +X..-Z,
/// sizes and the time limit finite and positive where given): BAD_OPTION naming the setting otherwise. bake_mesh checks
/// first, so every caller (the CLI, the Python package) is refused the same way.
Status check_settings(const Settings& settings);

/// Bakes `mesh_path` (any format assimp reads; all meshes of a scene merged with their node transforms) into
/// an asset in memory. Errors: INPUT_NOT_FOUND, UNSUPPORTED_FORMAT, IMPORT_FAILED, EMPTY_SCENE,
/// NON_FINITE_COORDINATES, ZERO_VOLUME, GRID_TOO_LARGE, SCALE_OUT_OF_RANGE, BAD_OPTION, OUT_OF_MEMORY, INTERNAL.
Result<Baked> bake_mesh(const std::string& mesh_path, const Settings& settings, const ProgressCallback& progress = {});

/// Bakes `mesh_path` and writes the asset to `output_path`: every rule of `voxfmt validate --level full` is
/// checked in memory (beside the write) and the file replaces `output_path` atomically only when it passes.
/// Errors: those of bake_mesh, INVALID_ASSET (a bake bug: nothing is written), WRITE_FAILED. An exception the
/// progress callback throws stops the bake (INTERNAL, naming it); up to and within "write" nothing is written, at
/// "done" the file is already in place and stays.
Result<Summary> bake_to_file(const std::string& mesh_path, const std::string& output_path, const Settings& settings,
                             const ProgressCallback& progress = {});

/// Reads a mesh as the bake's first stage does (no repair), e.g. for a render mesh or another collision method.
/// Errors: INPUT_NOT_FOUND, UNSUPPORTED_FORMAT, IMPORT_FAILED, EMPTY_SCENE, NON_FINITE_COORDINATES.
Result<TriangleMesh> read_mesh(const std::string& mesh_path, const ImportSettings& settings = {});

/// The summary as a JSON object (`"status": "ok"`), and a failure as `{"status": "error", "input", "code",
/// "message"}`: the one place either is serialised.
std::string to_json(const Summary& summary);
std::string error_json(const std::string& input, const Error& error);

/// The options that change the data, as the JSON object an asset's provenance records (`build_parameters`);
/// not `threads` or `deflate`. Up-to-date checks compare it.
std::string build_parameters_json(const Settings& settings);
/// Versions of the libraries the bake uses (provenance `dependency_versions`).
std::map<std::string, std::string> dependency_versions();
/// True when `asset` is a bake of `mesh` as it is now (its provenance's source SHA-256) with `settings` (its build
/// parameters) by this version of voxfmt, and still reads (quick validation): what a program that caches its bakes
/// checks before it reuses one (a cache named by the settings alone silently kept another mesh's asset). False for
/// a missing, damaged or older asset (what `voxfmt batch` checks of an asset its manifest cannot vouch for).
bool asset_is_current(const std::string& asset, const std::string& mesh, const Settings& settings);
/// Lowercase hex SHA-256 of a regular file's bytes; INPUT_NOT_FOUND when it is none (a folder, a pipe) or cannot be
/// read, READ_FAILED when a read fails part way.
Result<std::string> sha256_file(const std::string& path);
/// The current time as ISO 8601 UTC, e.g. "2026-11-22T04:00:14Z" (provenance, manifests).
std::string utc_now();
/// True when `path`'s extension (case-insensitive, e.g. ".obj", ".mesh.xml") is a mesh format assimp reads.
/// Formats without surfaces (animation, camera) and suffixes too generic to mean a mesh in a folder scan
/// (".xml", ".raw") are left out; the bake still accepts them.
bool is_mesh_file_name(const std::string& path);

}  // namespace voxfmt::bake
