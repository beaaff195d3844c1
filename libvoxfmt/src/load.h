// Internal: one pass that reads a file and collects structural findings.
#pragma once

#include <atomic>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "h5.h"
#include "voxfmt/asset.h"
#include "voxfmt/io.h"
#include "voxfmt/result.h"

namespace voxfmt::detail {

/// Reads every object of `path` it can, appending findings to `issues`. Returns the asset only when no
/// error-severity finding was made while reading (value rules are validate_asset's job). Runs the parse in a
/// child process unless read isolation is off (isolated_read.cpp says why). `level` Full also checks the
/// per-voxel rules of a 1.x file while its dense grids are converted to bricks (they are not kept).
std::optional<Asset> load_asset(const std::string& path, std::vector<Issue>& issues, const ReadOptions& options);
/// The one way every consumer judges a file (read_asset, validate_file): the read, then validate_asset at
/// `options.level`. Appends every finding to `issues`; returns the asset when none of them is an error.
std::optional<Asset> read_and_check(const std::string& path, const ReadOptions& options, std::vector<Issue>& issues);

/// How far a check has come, and a way to stop it: validate_asset with `progress`, counting the value bricks whose
/// rules are checked (WriteOptions::progress) and stopping early, its findings incomplete, once `stop` is set.
struct CheckProgress {
  std::atomic<uint64_t> bricks_checked{0};
  std::atomic<bool> stop{false};
};
std::vector<Issue> validate_asset(const Asset& asset, ValidationLevel level, CheckProgress* progress);

/// Reads only the root header (format name, version) and the provenance group; isolated like load_asset.
std::optional<Provenance> load_provenance(const std::string& path, std::vector<Issue>& issues);

/// The same, in this process.
std::optional<Asset> load_asset_in_process(const std::string& path, std::vector<Issue>& issues,
                                           const ReadOptions& options);
std::optional<Provenance> load_provenance_in_process(const std::string& path, std::vector<Issue>& issues);

/// What the 1.x conversion may spend (legacy_voxelmap.cpp): its value bricks grow as it goes, so the plan gives
/// them what the budget leaves once the fixed costs are paid.
struct DenseReadBudget {
  uint64_t value_brick_bytes = 0;
  uint64_t chunk_cache_bytes = 0;  ///< per dense dataset: two bands of its chunks, so that each is decoded once
};

/// Spec §1 "Limits", from the metadata alone, before any data is decoded: the size of chunks, how many there are,
/// what the file declares against what it stores, and what reading it will cost against `options`' budget.
/// Reports VALUE_OUT_OF_RANGE or OUT_OF_MEMORY and returns nothing when the file must not be read further.
std::optional<DenseReadBudget> check_read_cost(h5::Reader& r, const FormatVersion& version, uint64_t file_bytes,
                                               const ReadOptions& options);

/// Tells a watchdog (the parent of an isolated read) that the read moved on; no-op elsewhere.
void report_read_progress();

/// Whether `dims` is a grid the format version allows (spec §3): 1.x at most 2^31-1 voxels; 2.0 at most
/// 2^31-1 bricks and lattice points. `grid_size_limit` says it in words.
bool grid_size_allowed(const std::array<uint32_t, 3>& dims, const FormatVersion& version);
std::string grid_size_limit(const FormatVersion& version);

/// Format 1.x: reads the dense `layers` and `distances` of group `g` a slab of bricks at a time and converts
/// them to bricks (legacy_voxelmap.cpp). With `level` Full, the 1.x per-voxel rules are checked on the way (the
/// neighbour rules only for a `closed_surface`, spec 1.1 §3), their findings going to `findings` (value rules,
/// which do not stop the read).
void read_dense_voxelmap(h5::Reader& r, hid_t g, const std::string& path, const FormatVersion& version,
                         ValidationLevel level, bool closed_surface, const DenseReadBudget& budget, Voxelmap& vm,
                         std::vector<Issue>& findings);

/// True unless the provenance records surface defects (OPEN_BORDER, NON_MANIFOLD, SELF_INTERSECTIONS), across
/// whose closure layers may jump.
bool closed_surface(const Provenance& provenance);

}  // namespace voxfmt::detail
