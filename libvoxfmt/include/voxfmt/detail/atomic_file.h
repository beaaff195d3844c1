// The one way every voxfmt library writes a file: into a temporary beside the target, flushed to disk, renamed
// over the target, then the folder flushed. A failed or killed write never leaves a partial file under the
// target's name, and an earlier file there stays untouched until the new one is complete.
#pragma once

#include <filesystem>
#include <functional>
#include <string>
#include <string_view>

#include "voxfmt/result.h"

namespace voxfmt {

/// Marker of temporaries: `PATH.partial-<pid>-<n>`. Tools that clean up after killed runs look for it.
inline constexpr std::string_view kPartialMarker = ".partial-";

/// What a temporary's name starts with, before the marker, for a target named `target_name` (a name, no folder):
/// the name itself, or where the name and a temporary's longest suffix would pass the file system's 255 bytes,
/// its first bytes, `~` and a hash of the whole name: a name of up to 255 bytes is writable where the file system
/// allows that much (check_output_path refuses, before any work, a name the output's file system cannot hold).
std::string temporary_stem(const std::string& target_name);

/// Removes the temporaries of `path` (regular files named exactly `STEM.partial-<pid>-<n>`, beside a link's
/// target) whose process is gone: what a write killed by a signal left. Returns how many. A command that writes
/// one file calls it once; a write does not, nor does `build` (run once per mesh by `batch`, which sweeps its
/// library itself: a scan of a folder of thousands of files per write would cost more than the write).
size_t remove_dead_temporaries(const std::string& path);

/// Whether `entry` is a temporary of the file named `target_name` (in the same folder) left by a process that has
/// ended: a regular file (not a link) named exactly `STEM.partial-<pid>-<n>` (temporary_stem), `pid` gone. Processes
/// are those of this machine: a writer on another host sharing the folder cannot be told from a dead one.
bool dead_temporary_of(const std::filesystem::directory_entry& entry, const std::string& target_name);

/// Whether `pid`, decimal digits as a temporary's name holds them (at most 9, > 0), names a process that has
/// ended (a zombie too: it writes nothing more). Anything else (not digits, a live process, one of another user) is
/// not gone: its files are kept.
bool process_is_gone(const std::string& pid);

struct AtomicWrite {
  /// Produces the file's content at the temporary path it is given (any library may write there).
  std::function<Status(const std::string& temporary_path)> write;
  /// Runs after the temporary is complete and on disk, just before the rename: an error aborts the write
  /// (the temporary is removed, the target left as it was) and is returned.
  std::function<Status()> before_commit;
};

/// "" where `path` is a regular file (links followed) or names nothing; otherwise what it is, as every error says
/// it ("is a folder, not a regular file", "is a pipe, ..."). Readers and writers alike take only regular files: a
/// FIFO blocks a read forever, a folder's read fails deep in a library, a rename would replace a device.
std::string not_a_regular_file(const std::string& path);

/// Whether a file could be written at `path` (its folder exists and is a folder, the path is not a folder), as
/// WRITE_FAILED naming the problem. Cheap: long jobs call it before their work, so a typo costs no bake.
Status check_output_path(const std::string& path);
/// Where writing `path` lands: through the symbolic links it names (this user's or root's only), to the file the
/// rename will replace; `path` itself where it is no link.
Result<std::string> output_target(const std::string& path);
/// check_output_path, and BAD_OPTION where `path` names the file `input` (the same file by any name): the output
/// would replace what it is made from.
Status check_output_path(const std::string& path, const std::string& input);

/// Writes `path` atomically. Errors are WRITE_FAILED (naming `path` and the reason) unless `write` or
/// `before_commit` return their own.
Status write_file_atomically(const std::string& path, const AtomicWrite& steps);
/// The same for bytes already in memory.
Status write_file_atomically(const std::string& path, std::string_view bytes);

}  // namespace voxfmt
