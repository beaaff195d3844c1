// `voxfmt batch` inputs: what to bake, under which output name, on which shard.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "voxfmt/result.h"

namespace voxfmt::cli {

/// A bad command line or input set (exit 2), with a message for the user and the error model's code (BAD_OPTION
/// unless named: FILE_NOT_FOUND for an input that is not there, WRITE_FAILED for an output that cannot be made).
struct UsageError : std::runtime_error {
  explicit UsageError(const std::string& message, IssueCode code = IssueCode::BadOption)
      : std::runtime_error(message), code(code) {}
  IssueCode code;
};

struct BatchItem {
  std::string input;   ///< path of the mesh (as given, or joined to its directory / list file's directory)
  std::string key;     ///< stable name relative to the output directory, e.g. "chairs/model.obj" ('/'-separated)
  std::string output;  ///< OUTDIR/key.vox.h5
  uint64_t input_bytes = 0;
};

/// Expands the inputs into meshes, sorted by key. Output names mirror each mesh's path below the root it was
/// found from, keeping the source extension (model.obj and model.ply in one folder are distinct assets):
///  - a directory D: every file below D (recursively, hidden entries skipped) with an extension assimp reads;
///    key = path relative to D;
///  - `@LIST` or a file ending in .txt/.lst/.list: one path per line ('#' comments, blank lines ignored),
///    relative to the list file's directory (to the working directory for a list read from a pipe or a
///    descriptor: `@<(find ...)`, `@/dev/stdin`); a listed file keeps its relative path as key (or its file name
///    when the entry is absolute or leaves that directory), a listed directory is scanned as above;
///  - any other file: a mesh; key = its file name.
/// The same file reached twice under one key is baked once; under two keys (a link beside its target, a folder and
/// a file in it both given) it is baked once per key, each asset named as asked. Two different files with one key
/// throw UsageError (nothing is ever overwritten by another input), as does an input that does not exist. Links to
/// folders are not followed, and a folder that cannot be read is skipped; `skipped`, when given, receives what a
/// folder scan left out that a user may miss ("PATH: why": an unreadable folder, a link to a folder, a mesh's name
/// that links to nothing).
std::vector<BatchItem> collect_inputs(const std::vector<std::string>& inputs, const std::string& output_dir,
                                      std::vector<std::string>* skipped = nullptr);

/// `--shard I/N`: a mesh belongs to shard hash(key) mod N. The hash (64-bit FNV-1a of the key's UTF-8 bytes)
/// depends on the key alone, so machines that see the same library agree, and adding a mesh moves no other.
uint64_t shard_hash(const std::string& key);

struct Shard {
  unsigned index = 0, count = 1;
  bool contains(const std::string& key) const { return shard_hash(key) % count == index; }
};
/// Parses "I/N" with 0 <= I < N; throws UsageError.
Shard parse_shard(const std::string& text);

}  // namespace voxfmt::cli
