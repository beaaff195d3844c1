// vps-bench methods: one collision method set up for one scenario, queried pose by pose.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "scenarios.h"

namespace vps_bench {

/// What one query found.
struct QueryOutcome {
  size_t contacts = 0;       ///< contact points the method reported (Bullet: accepted by the manifold)
  double deepest = -1e30;    ///< largest penetration among them, metres (negative: all separated)
  size_t nodes_visited = 0;  ///< VPS: sphere-tree nodes looked up
  size_t points_tested = 0;  ///< VPS: points whose distance was looked up
};

struct MethodSettings {
  /// Collision margin of Bullet's shapes, and the proximity of vps-fine-prox (metres).
  double margin = 0.001;
  /// vps-coarse: the deepest tree level with at most about this many points.
  size_t coarse_points = 800;
  std::string cache_dir;  ///< HACD decompositions
  /// false: hacd runs only where a cached decomposition exists (computing one takes minutes per mesh).
  bool compute_decompositions = true;
};

class Method {
 public:
  virtual ~Method() = default;
  /// Sets `pose` and runs one narrow-phase query. Only this call is timed.
  virtual void query(const PosePair& pose) = 0;
  /// What the last query found (read after the timing).
  virtual QueryOutcome outcome() = 0;
  /// A note for the table (e.g. the tree level of vps-coarse, the number of hulls).
  virtual std::string note() const { return {}; }
};

/// Method names in table order.
const std::vector<std::string>& method_names();

/// Sets up `name` for `scenario`; null with `why` set when the method cannot run that scenario. Throws
/// std::runtime_error for real failures.
std::unique_ptr<Method> make_method(const std::string& name, const Scenario& scenario, const MethodSettings& settings,
                                    std::string& why);

}  // namespace vps_bench
