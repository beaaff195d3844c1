// Reading, writing and validating voxfmt asset files (HDF5). Thread-compatible: do not call concurrently unless the
// system HDF5 library was built thread-safe.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/result.h"

namespace voxfmt {

// ---- Validation of assets against spec/voxfmt-format.md.

enum class ValidationLevel {
  Quick,  ///< structure, dtypes, shapes, ranges, tree structure
  Full,   ///< plus semantic rules: layers vs distances, neighbours, normals, spheres, mass properties
};

/// Rules that can be checked on the in-memory asset (ranges, tree structure, JSON, ...).
std::vector<Issue> validate_asset(const Asset& asset, ValidationLevel level = ValidationLevel::Quick);

struct ReadOptions;

/// Opens `path` and reports every finding: structural ones found while reading, then validate_asset's.
/// Never throws; a file that cannot be opened yields FILE_NOT_FOUND or NOT_HDF5, one whose read would exceed
/// the read budget OUT_OF_MEMORY (voxfmt/io.h: ReadOptions).
std::vector<Issue> validate_file(const std::string& path, ValidationLevel level = ValidationLevel::Quick);
std::vector<Issue> validate_file(const std::string& path, const ReadOptions& options);

// ---- Reading and writing.

struct WriteOptions {
  int deflate_level = 4;     ///< 0..9 for the voxel grids; 0 = no compression
  unsigned chunk_edge = 32;  ///< chunk edge of the brick table and the lattice, in entries (clamped to their extents)
  /// What must hold before the file replaces the target. Full (the default): every rule of
  /// `validate --level full`, checked on a thread of its own while the file is written and compressed; Quick:
  /// structure, ranges and the tree only.
  ValidationLevel validation = ValidationLevel::Full;
  /// Runs once the temporary file is complete, flushed and validated, just before it replaces the target: an
  /// error aborts the write (the temporary is removed, the target left as it was) and is returned.
  std::function<Status()> before_commit;
  /// Told the share of the write done (0..1: the grids compressed, the value bricks checked) on the calling
  /// thread, at once, then at most every `progress_interval_s` until the file is complete. An exception it throws
  /// stops the write (the temporary is removed, the target left as it was) and leaves write_asset.
  std::function<void(double done)> progress;
  double progress_interval_s = 0.2;
};

/// Writes `asset` to `path` atomically (write_file_atomically: a temporary `PATH.partial-<pid>-<n>` beside it,
/// flushed, renamed over `path`), so neither a failed write nor a crash ever leaves a partial file under
/// `path`. An asset that breaks a rule of `options.validation` is refused with INVALID_ASSET naming the rule
/// (the earlier file at `path`, if any, stays); a file that cannot be written is WRITE_FAILED, and memory the
/// write cannot get (the file is built in memory first) OUT_OF_MEMORY.
Status write_asset(const std::string& path, const Asset& asset, const WriteOptions& options = {});

/// How a file is read (read_asset, validate_file): what it may cost and which rules it must pass.
struct ReadOptions {
  /// The memory a read may take, in bytes. It is decided from the file's metadata before anything is decoded
  /// (spec §1, "Limits"): a file that would need more is refused with OUT_OF_MEMORY, the figure in the message,
  /// whatever the machine has. The default is fixed, not the machine's, so that a file's verdict is the same
  /// everywhere; it reads every asset up to ~2048^3 (a 4096^3 bake needs ~2.1 GB: raise it).
  uint64_t max_memory_bytes = kDefaultReadMemoryBytes;
  /// The rules the file must pass. Full (read_asset's default): every rule `voxfmt validate` checks, so no
  /// consumer accepts what validate refuses; Quick: structure, ranges and the tree only.
  ValidationLevel level = ValidationLevel::Full;
  static constexpr uint64_t kDefaultReadMemoryBytes = uint64_t(768) << 20;
};

/// Reading a file parses it in a child process by default (POSIX): HDF5 1.10 crashes or hangs on some damaged
/// files, and the child's death becomes a READ_FAILED error instead of the caller's. Costs a fork and a copy of
/// the data through a pipe. Turn it off for trusted files, debuggers and fuzzers (in-process crashes are what a
/// fuzzer looks for), or when another thread of the process may be inside the same HDF5 library through other code
/// at the time of a read (a forked child cannot take HDF5's lock from it; this library's own writes and reads take
/// turns): set_read_isolation(false), or VOXFMT_READ_ISOLATION=0 in the
/// environment. Not thread-safe; set it before reading. The bake's mesh import follows the same switch (assimp's
/// importers crash on some malformed meshes; in the child that is IMPORT_FAILED).
void set_read_isolation(bool enabled);
bool read_isolation();

/// Reads an asset and checks it against the rules of `options.level` (by default every rule of `voxfmt validate`).
/// Any error-severity finding fails the read (its message names the file, the object and the reason); warnings
/// (e.g. a newer minor version) go to `warnings` if given.
Result<Asset> read_asset(const std::string& path, std::vector<Issue>* warnings = nullptr,
                         const ReadOptions& options = {});

/// Reads only the format header and `/provenance` (no grids): a cheap look at where an asset came from, e.g.
/// to decide whether it is up to date. Fails like read_asset on a file that is not a readable voxfmt asset.
Result<Provenance> read_provenance(const std::string& path);

/// Version of the HDF5 library libvoxfmt runs with, e.g. "1.10.8" (for provenance records).
std::string hdf5_library_version();

}  // namespace voxfmt
