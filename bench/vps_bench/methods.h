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
  /// vps-fine-baked-floor: the floor's voxel (metres); 0: the bunny's.
  double baked_floor_voxel = 0;
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
  /// On a trajectory the method keeps what it keeps across the steps of a world (Bullet's persistent
  /// manifolds); on a pose set every query starts afresh.
  virtual void keep_state(bool) {}
};

/// Method names in table order (pose sets: every query from scratch, VPS without coherence).
const std::vector<std::string>& method_names();
/// Method names for trajectories: also vps-fine-coherent (the pair keeps its last traversal, as in a world).
/// vps-fine-baked-floor (bunny-static-mesh only) is in both: the floor baked offline into a voxelmap.
const std::vector<std::string>& trajectory_method_names();

/// A trajectory: consecutive poses of a scenario's pair and the rate they were taken at.
struct Trajectory {
  std::string scenario, kind, description;
  double rate_hz = 1000;
  std::vector<PosePair> steps;
};

/// A from 10 mm above the scenario's first pose falls onto B (down onto a plane, box or floor; towards B's
/// centre onto a baked B), bounces, slides and settles, simulated at 1 kHz by Bullet with VPS; B stays put.
Trajectory simulated_drop(const Scenario& s, size_t steps, double margin);
/// A haptic path at 5 kHz: from 5 mm off the scenario's first (touching) pose A approaches B, presses 2 mm in,
/// slides 20 mm along B's surface while turning 0.3 rad, and pulls out.
Trajectory haptic_path(const Scenario& s, size_t steps);

/// Sets up `name` for `scenario`; null with `why` set when the method cannot run that scenario. Throws
/// std::runtime_error for real failures.
std::unique_ptr<Method> make_method(const std::string& name, const Scenario& scenario, const MethodSettings& settings,
                                    std::string& why);

}  // namespace vps_bench
