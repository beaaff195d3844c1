// The manifest of a `voxfmt batch` output directory: JSON Lines, one record per mesh, the last record of an
// output wins.
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "report.h"

namespace voxfmt::cli {

class Manifest {
 public:
  /// Takes the manifest's lock (`PATH.lock`, flock: released by the kernel however the process ends; a second
  /// batch on the same manifest is refused), reads the records already there (a line torn by a crash is
  /// dropped), rewrites the file atomically with only the last record of each output (sorted by output; none for
  /// an output whose last record says it was removed), and opens it for appending. Throws std::runtime_error.
  explicit Manifest(const std::string& path);
  ~Manifest();
  Manifest(const Manifest&) = delete;
  Manifest& operator=(const Manifest&) = delete;

  /// The last record for `output`, or nullptr.
  const nlohmann::json* last(const std::string& output) const;
  /// Every output's last record, by key_of(output).
  const std::map<std::string, nlohmann::json>& records() const { return last_; }
  /// The key of `output` among records(): report::manifest_output_key, its folders resolved once.
  std::string key_of(const std::string& output) const { return report::manifest_output_key(output, &folders_); }
  /// Appends one line and flushes it to disk before returning, so a killed run keeps every finished record.
  void append(const nlohmann::json& record);
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  int lock_fd_ = -1;
  int fd_ = -1;
  std::map<std::string, nlohmann::json> last_;
  mutable std::map<std::string, std::string> folders_;  ///< manifest_output_key's resolved folders
};

/// One JSON Lines line (no newline): compact, invalid UTF-8 replaced.
std::string json_line(const nlohmann::json& value);

// Fields of a manifest record, read defensively: a record edited by hand or written by another tool must not
// stop the batch, it just does not count.
std::string text_field(const nlohmann::json& record, const char* key);
int64_t integer_field(const nlohmann::json& record, const char* key);
/// True when recorded build parameters (an object, or provenance's JSON text) equal `wanted`.
bool same_parameters(const nlohmann::json& stored, const nlohmann::json& wanted);
/// Failures that depend on the machine or the moment, not on the mesh (TIMEOUT, CRASHED, OUT_OF_MEMORY,
/// INTERNAL, WRITE_FAILED, INPUT_NOT_FOUND, or a code this version does not know): always retried.
bool transient_failure(const std::string& code);

/// Size and modification time of an output, as the manifest records them to tell it unchanged.
struct FileStamp {
  bool exists = false;
  uint64_t size = 0;
  int64_t mtime_ns = 0;
};
FileStamp stamp(const std::string& path);

/// Removes the temporaries (`NAME.partial-*`) beside each of `outputs` left by bakes killed mid-write. Only
/// these outputs': shards sharing a folder never touch each other's files. Returns how many were removed.
size_t remove_stale_partials(const std::vector<std::string>& outputs);

}  // namespace voxfmt::cli
