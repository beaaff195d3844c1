// What `voxfmt batch` shows while it runs: on a terminal a bar with counts, elapsed time, an ETA and the meshes
// in flight (failures printed as they happen); otherwise one line per mesh, for logs.
#pragma once

#include <nlohmann/json.hpp>

#include <cstddef>
#include <string>
#include <vector>

namespace voxfmt::cli {

/// Per-mesh time model for the ETA: seconds = a + b * input bytes, least squares over the finished meshes.
class EtaModel {
 public:
  void add(double bytes, double seconds);
  bool ready() const { return n_ >= 1; }
  double predict(double bytes) const;

 private:
  double n_ = 0, sx_ = 0, sy_ = 0, sxx_ = 0, sxy_ = 0;
};

/// "m:ss" or "h:mm:ss".
std::string clock_text(double seconds);

class BatchProgress {
 public:
  struct Running {
    std::string name;  ///< file name of the mesh
    double input_bytes;
    double elapsed_s;
  };
  struct Snapshot {
    size_t total = 0, finished = 0, failed = 0;
    size_t lanes = 1;                  ///< meshes baked at once
    std::vector<double> queued_bytes;  ///< input sizes of the meshes not started yet
    std::vector<Running> running;
    double elapsed_s = 0;
  };

  /// `bar`: draw the bar (stderr is a terminal); `quiet`: print nothing at all.
  BatchProgress(bool bar, bool quiet) : bar_(bar && !quiet), quiet_(quiet) {}
  /// Feeds the ETA model with a finished mesh.
  void finished(double input_bytes, double seconds) { eta_.add(input_bytes, seconds); }
  /// Redraws the bar (no-op without one).
  void draw(const Snapshot& now) const;
  /// Removes the bar from the terminal.
  void clear() const;
  /// One finished mesh (a manifest record): a log line, or on a terminal only failures (above the bar).
  void report(const nlohmann::json& record, size_t done, size_t total) const;

 private:
  bool bar_, quiet_;
  EtaModel eta_;
};

}  // namespace voxfmt::cli
