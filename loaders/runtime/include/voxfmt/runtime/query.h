// The Voxmap-PointShell query: one object's point-sphere tree against the other's voxelmap, breadth-first.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <vector>

#include "voxfmt/result.h"
#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::runtime {

/// Rigid placement of an object with uniform scale: world = rotation * (scale * asset) + translation. The rotation
/// must be one (orthonormal, determinant +1) and the scale a finite number > 0: the per-pair queries run at
/// kilohertz rates and do not check (a sheared matrix is used as if it were a rotation; a scale <= 0 finds
/// nothing). BatchScene checks every pose and refuses others with an error per environment.
struct Pose {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  double scale = 1.0;

  Eigen::Vector3d apply(const Eigen::Vector3d& asset_point) const {
    return rotation * (scale * asset_point) + translation;
  }
};

/// A time budget of this many microseconds (a day) or more is none (QueryOptions::time_budget_us).
inline constexpr double kNoTimeBudgetUs = 86400e6;

/// Which point shell is tested against which voxelmap.
enum class QueryDirection {
  APointsInB,  ///< A's points against B's voxelmap
  BPointsInA,  ///< B's points against A's voxelmap
  Both,        ///< both, contacts of both in one set
  Auto,        ///< the smaller object's points in the larger one's voxelmap; within 10% in size, the one with
               ///< fewer points, then the lower position: the same choice whichever object is A
};

/// Where a contact's normal comes from. DistanceGradient is the default everywhere (the runtime's query, the
/// Bullet pair tests, the batched query on CPU and GPU): the partner's field gradient is its surface normal, the
/// direction that separates the pair, where a point's own normal pushes sideways on a slope of the partner and
/// flips across a thin part. Flat fields fall back to the point's normal. PointShell is classical VPS: the
/// haptic renderer uses it (its forces sum the tool's own normals, as the paper's).
enum class NormalSource {
  PointShell,        ///< the point's own inward normal (classical VPS)
  DistanceGradient,  ///< gradient of the other object's distance field (the true separating direction)
};

/// What the points of the last level of a cut query (one stopped by `max_level` or `point_budget` above the
/// leaves) report.
enum class CutLevel {
  /// Each point stands for its sphere (the point and everything below it): contact when the sphere reaches
  /// the partner, depth = radius - distance(sphere centre). Conservative: wherever the full tree has a contact,
  /// a cut level has one, and its depth d_cut satisfies d_fine <= d_cut <= d_fine + 2 * (largest radius of the
  /// level). The default: a coarse level that misses contacts is no use to a physics engine.
  Spheres,
  /// Each point only stands for itself (the seed's coarse shell): cheaper and shallower, but a contact between
  /// the level's points is missed.
  Points,
};

/// How a point's distance is read between the voxel centres of the partner's field.
enum class Interpolation {
  /// The 8 voxels around the point (the default everywhere, on CPU and GPU): the cheapest. On the convex side of a
  /// curved surface it lies above the exact distance by about t (1 - t) / 2 voxels times the curvature (a bunny
  /// pressed 0.1-2 voxels into a bunny: its force's magnitude 1.1 % low at the median step, 6.4 % off at the 95th
  /// percentile; bench/force_quality.py).
  Trilinear,
  /// Catmull-Rom over the 4^3 voxels around the point where all hold stored distances (near the surface: with the
  /// default band of 3, nearly every point on it, three in four half a voxel deep, one in four a voxel deep; a
  /// wider band reaches deeper), trilinear elsewhere: the same bunny within 1.2 % at the 95th percentile, for 64
  /// voxel reads per point sampled instead of 8. For haptic forces (docs/haptics.md); the CPU queries only
  /// (BatchScene too: BatchEnvironments::interpolation; not the CUDA batch). A coherent query looks its sampled
  /// points up again each time, as the reading steps where it gives way to trilinear.
  Tricubic,
};

struct QueryOptions {
  QueryDirection direction = QueryDirection::Auto;
  NormalSource normal_source = NormalSource::DistanceGradient;
  /// How a point's distance is interpolated (see Interpolation).
  Interpolation interpolation = Interpolation::Trilinear;
  /// Also report points that are outside the other object but closer than this (metres); their depth is
  /// negative. 0 reports penetrating points only.
  double proximity = 0.0;
  /// Stop before a tree level whose points would take the tested points above this budget (the coarse shell
  /// of the seed is a budget of ~800). Whole levels are always finished.
  size_t point_budget = std::numeric_limits<size_t>::max();
  /// Deepest tree level tested (0 = root only).
  uint32_t max_level = std::numeric_limits<uint32_t>::max();
  /// What the last level of a cut query reports (see CutLevel).
  CutLevel cut_level = CutLevel::Spheres;
  /// With CutLevel::Points: where `max_level` or `point_budget` stops the walk at a level, the walk goes on
  /// below it in the spheres of that level whose points are nearest the partner, level by level to the leaves,
  /// within as many points again as the cut's shell holds (the points up to `max_level`, at most `point_budget`,
  /// at least `min_points`). Every point reported is a surface point at its true depth, as at the cut; but a
  /// body rests on its surface's own points where it touches, not on the few of a coarse level, whose base is
  /// narrower than the surface's (a bunny rocked on three such points for seconds). Not below a time budget's
  /// cut. Physics defaults turn it on.
  bool refine_cut_contacts = false;
  /// Time budget of each tree traversal in microseconds (0, infinity or a day and more = none), for haptic loops and
  /// physics steps: the clock is read at level ends and every 32 nodes. A level the budget interrupts is dropped and
  /// the last completed level is the cut, reported as `cut_level` says: contacts are those of whole levels (the same as
  /// a `max_level` query stopping there), so they do not depend on where in a level time ran out, and with
  /// CutLevel::Spheres no contact found by the full tree is lost. The root level always completes.
  double time_budget_us = 0.0;
  /// Levels are tested whatever `max_level`, `point_budget` and `time_budget_us` say while the points tested,
  /// with the next level's, number at most this: the coarsest shell a limit may leave (a physics engine needs
  /// enough points to hold a body up). 0: only the root level is sure to be tested.
  size_t min_points = 0;
};

/// One colliding (or near) point, world frame.
struct Contact {
  Eigen::Vector3d point;   ///< the shell point, on the surface of the object that carries it
  Eigen::Vector3d normal;  ///< unit; the direction in which A must move to separate from B
  double depth = 0.0;      ///< penetration depth, metres; negative for proximity points
  uint32_t point_index = 0;
  bool point_of_b = false;  ///< true: the point is B's, tested in A's voxelmap
  bool exact = false;       ///< depth from stored distances (true) or from layers (false)
};

struct QueryStats {
  size_t nodes_visited = 0;      ///< sphere-tree nodes popped from the queue
  size_t points_tested = 0;      ///< points whose distance was looked up
  uint32_t deepest_level = 0;    ///< deepest tree level completed (and reported)
  size_t points_refined = 0;     ///< of points_tested, those below a cut level (QueryOptions::refine_cut_contacts)
  bool time_budget_hit = false;  ///< a traversal stopped at QueryOptions::time_budget_us
};

struct ContactSet {
  std::vector<Contact> contacts;
  QueryStats stats;
  void clear() {
    contacts.clear();
    stats = QueryStats{};
  }
};

/// Reusable traversal buffers; keep one per thread (they are not shared) to avoid allocations in the loop.
class QueryScratch {
 public:
  QueryScratch();
  ~QueryScratch();
  QueryScratch(QueryScratch&&) noexcept;
  QueryScratch& operator=(QueryScratch&&) noexcept;
  /// Testing hook, for benchmarks and tests (not part of the query's contract): while set, every point whose
  /// distance a query looks up is appended to `into`, in the target's coordinates (a voxelmap's grid), so the
  /// cost of the lookups alone can be measured. nullptr stops it.
  void record_tested_points(std::vector<Eigen::Vector3f>* into);

  struct Buffers;  ///< the traversal's own (opaque)
  Buffers& buffers() { return *buffers_; }

 private:
  std::unique_ptr<Buffers> buffers_;
};

/// What a pair's last traversal in one direction left for the next one, so that a step costs what changed
/// (temporal coherence): the nodes where it stopped, with bounds at a recent relative pose. Valid for full
/// traversals (no point budget, level limit or time budget); a query with one starts afresh.
class TraversalFront {
 public:
  TraversalFront();
  ~TraversalFront();
  TraversalFront(TraversalFront&&) noexcept;
  TraversalFront& operator=(TraversalFront&&) noexcept;
  /// Forgets the front: the next query starts from the root.
  void reset();

  struct State;  ///< the coherent traversal's own (opaque)
  State& state() { return *state_; }

 private:
  std::unique_ptr<State> state_;
};

/// Per-pair state for coherent queries: one front per direction. Keep one per pair of objects (a physics engine's
/// pair, a haptic tool and an object) and drop it when the pair separates for good.
struct QueryState {
  TraversalFront a_in_b;  ///< A's points against B's voxelmap (or against an analytic partner)
  TraversalFront b_in_a;  ///< B's points against A's voxelmap
  void reset() {
    a_in_b.reset();
    b_in_a.reset();
  }
};

/// Appends to `out` (call out.clear() first for a fresh set). Objects without the needed structure (no point
/// shell on the querying side, no voxelmap on the other) contribute nothing for that direction.
void query_contacts(const CollisionObject& a, const Pose& pose_a, const CollisionObject& b, const Pose& pose_b,
                    const QueryOptions& options, ContactSet& out, QueryScratch& scratch);
void query_contacts(const CollisionObject& a, const Pose& pose_a, const CollisionObject& b, const Pose& pose_b,
                    const QueryOptions& options, ContactSet& out);
/// The same, coherent with the pair's earlier queries (`state`; see TraversalFront): the same contacts, in the
/// same order, as without.
void query_contacts(const CollisionObject& a, const Pose& pose_a, const CollisionObject& b, const Pose& pose_b,
                    const QueryOptions& options, ContactSet& out, QueryScratch& scratch, QueryState& state);

/// Who takes Auto's tie (objects alike in size, point count and position): the lower address, the same object
/// whichever order the pair comes in (engines hand pairs either way); or A's points, as the batches do on the CPU
/// and the GPU alike (an environment's pair has one order, and addresses differ from device to host).
enum class DirectionTie { ByAddress, APoints };

/// The direction Auto resolves to for these objects and poses (never Auto).
QueryDirection resolve_direction(const CollisionObject& a, const Pose& pose_a, const CollisionObject& b,
                                 const Pose& pose_b, QueryDirection requested,
                                 DirectionTie tie = DirectionTie::ByAddress);

/// Single world points of a partner B (box corners, a sphere's centre with its `radius`) against A's
/// voxelmap: reported like B's points (point_of_b, normal = where A must move), the contact point being the
/// partner's surface point deepest in A. Normals always follow A's distance gradient. A point far outside A
/// (where A's voxelmap keeps only a lower bound of the distance) reports nothing, whatever its radius: large
/// partners are found by A's points against the partner's own distance (as voxfmt::bullet does for every kind).
void query_points_in_voxelmap(const CollisionObject& a, const Pose& pose_a, const Eigen::Vector3d* points, size_t count,
                              double radius, const QueryOptions& options, ContactSet& out);

// ---- Classical VPS penalty force and torque from a contact set (McNeely et al.; the DLR seed's haptic rendering).

struct Wrench {
  Eigen::Vector3d force = Eigen::Vector3d::Zero();   ///< newtons, on object A
  Eigen::Vector3d torque = Eigen::Vector3d::Zero();  ///< newton-metres about `reference`, on object A
};

/// F = sum_i k * depth_i * n_i and T = sum_i (P_i - reference) x F_i over the penetrating contacts
/// (depth > 0) of `contacts`, with stiffness k in N/m. The normals of a ContactSet point where A must move,
/// so the wrench acts on A; B receives the opposite force (and the torque about its own reference point).
inline Wrench penalty_wrench(const ContactSet& contacts, const Eigen::Vector3d& reference, double stiffness) {
  Wrench w;
  for (const Contact& c : contacts.contacts) {
    if (!(c.depth > 0.0)) continue;  // a NaN depth too
    const Eigen::Vector3d f = stiffness * c.depth * c.normal;
    w.force += f;
    w.torque += (c.point - reference).cross(f);
  }
  return w;
}

// ---- Batches: thousands of environments, each a pair of objects at a pair of poses, in one call on worker threads.

/// E environments: row-major arrays in host memory (gpu::Scene takes the same struct with device pointers).
struct BatchEnvironments {
  size_t count = 0;
  const float* poses_a = nullptr;       ///< E x 4 x 4 body-to-world matrices of A (rigid: else error 2..5), or:
  const float* poses_b = nullptr;       ///< E x 4 x 4 of B
  const double* poses_a_f64 = nullptr;  ///< the same in double (either both float or both double)
  const double* poses_b_f64 = nullptr;
  const int32_t* pair = nullptr;  ///< E indices into the scene's pairs, or nullptr: pair 0 for every one
  double proximity = 0.0;         ///< metres: also report points outside but nearer than this (negative depth)
  double stiffness = 1.0;         ///< N/m of the penalty wrench
  /// How points' distances are read (QueryOptions::interpolation): Tricubic on the CPU only (gpu::Scene refuses
  /// it with BAD_OPTION).
  Interpolation interpolation = Interpolation::Trilinear;
  /// Who takes Auto's tie (resolve_direction): A's points, as the GPU batch does (gpu::Scene takes no other);
  /// ByAddress gives an environment the contacts a single query_contacts gives.
  DirectionTie tie = DirectionTie::APoints;
};

/// Per-environment outputs the caller sized (only `count` is required; null arrays are skipped); gpu::Scene takes
/// the same struct with device pointers.
/// Contacts: E x `max_contacts` (points and normals E x max_contacts x 3); those that did not fit are counted in
/// `overflow`, never dropped silently.
struct BatchOutputs {
  int32_t* count = nullptr;     ///< E: contacts found
  float* max_depth = nullptr;   ///< E: metres, 0 without penetration
  float* force = nullptr;       ///< E x 3: on A, sum of stiffness * depth * normal over penetrating contacts
  float* torque = nullptr;      ///< E x 3: on A, about A's centre of mass in the world
  int32_t* overflow = nullptr;  ///< E: contacts found beyond max_contacts
  int32_t* error = nullptr;     ///< E: 0, or why the environment has no result (2..5 bad pose, 6 pair out of range)
  uint32_t max_contacts = 0;
  float* points = nullptr;
  float* normals = nullptr;
  float* depths = nullptr;
  int32_t* point_index = nullptr;
  uint8_t* point_of_b = nullptr;
};

/// The objects environments may hold and the pairs (A, B) they may be, for batched queries on the CPU: the twin of
/// gpu::Scene (the same environments and outputs), so that a learning loop's code runs on either. Each environment
/// is query_contacts in the direction Auto picks, normals from the distance gradient, reduced to its count, deepest
/// penetration and penalty wrench, its contacts in the order query_contacts gives them.
class BatchScene {
 public:
  using Pair = std::array<uint32_t, 2>;  ///< (A, B): indices into the scene's objects
  /// BAD_OPTION without objects or pairs, for a null object or a pair naming an object the scene does not have.
  static Result<BatchScene> create(std::vector<std::shared_ptr<const CollisionObject>> objects,
                                   std::vector<Pair> pairs);
  size_t object_count() const { return objects_.size(); }
  size_t pair_count() const { return pairs_.size(); }

  /// Every environment on `threads` workers (0: every usable core), taken in chunks in turn. BAD_OPTION (nothing
  /// written) without a `count` output, without poses for a non-empty batch, or for a proximity or stiffness that
  /// is negative or not finite; a bad environment is its `error`, the others are still answered. `after`, if
  /// given, is called on its worker once an environment's outputs are written (a caller's cancellation, e.g.
  /// Python's Ctrl-C): an exception it throws stops the workers and is thrown again here.
  struct Visit;
  Status contacts(const BatchEnvironments& in, const BatchOutputs& out, unsigned threads = 0,
                  const std::function<void(const Visit&)>& after = {}) const;

  /// One environment's query, handed to each_environment's visitor on the worker that ran it.
  struct Visit {
    unsigned worker;     ///< 0 .. workers(...) - 1: one visit at a time per worker
    size_t environment;  ///< its index in the batch
    int32_t error;       ///< 0, or why it has no result (as BatchOutputs::error; `contacts` is then empty)
    const ContactSet& contacts;
    Eigen::Vector3d reference;  ///< A's centre of mass in the world (the wrench's reference)
  };
  /// A trajectory: the environments in order on one worker, each query coherent with the one before (a pair's
  /// QueryState and the scratch it was built with).
  struct Trajectory {
    QueryScratch& scratch;
    QueryState& state;
  };
  /// The worker loop under contacts(): every environment queried with `options` (any QueryOptions: a cut, a
  /// budget, a direction) on workers(in.count, threads) workers, its contacts handed to `visit`. BAD_OPTION for
  /// poses missing or both kinds given, OUT_OF_MEMORY if a worker ran out; an exception `visit` throws stops the
  /// workers and is thrown again here.
  Status each_environment(const BatchEnvironments& in, const QueryOptions& options, unsigned threads,
                          const std::function<void(const Visit&)>& visit, const Trajectory* trajectory = nullptr) const;
  /// How many workers each_environment runs for `environments` on `threads` (0: every usable core).
  static unsigned workers(size_t environments, unsigned threads);

 private:
  std::vector<std::shared_ptr<const CollisionObject>> objects_;
  std::vector<Pair> pairs_;
};

}  // namespace voxfmt::runtime
