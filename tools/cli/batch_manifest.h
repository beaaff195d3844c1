// The manifest of a `voxfmt batch` output directory: JSON Lines, one record per mesh, the last record of an
// output wins.
#pragma once

#include <nlohmann/json.hpp>

#include <map>
#include <string>

namespace voxfmt::cli {

class Manifest {
 public:
  /// Takes the manifest's lock (`PATH.lock`, flock: released by the kernel however the process ends; a second
  /// batch on the same manifest is refused), reads the records already there (a line torn by a crash is
  /// dropped), rewrites the file atomically with only the last record of each output (sorted by output), and
  /// opens it for appending. Throws std::runtime_error.
  explicit Manifest(const std::string& path);
  ~Manifest();
  Manifest(const Manifest&) = delete;
  Manifest& operator=(const Manifest&) = delete;

  /// The last record for `output`, or nullptr.
  const nlohmann::json* last(const std::string& output) const;
  /// Appends one line and flushes it to disk before returning, so a killed run keeps every finished record.
  void append(const nlohmann::json& record);
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  int lock_fd_ = -1;
  int fd_ = -1;
  std::map<std::string, nlohmann::json> last_;
};

/// One JSON Lines line (no newline): compact, invalid UTF-8 replaced.
std::string json_line(const nlohmann::json& value);

}  // namespace voxfmt::cli
