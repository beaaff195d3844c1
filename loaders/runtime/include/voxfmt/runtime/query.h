// The Voxmap-PointShell query: one object's point-sphere tree against the other's voxelmap, breadth-first.
#pragma once

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::runtime {

/// Rigid placement of an object with uniform scale: world = rotation * (scale * asset) + translation.
struct Pose {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  double scale = 1.0;

  Eigen::Vector3d apply(const Eigen::Vector3d& asset_point) const {
    return rotation * (scale * asset_point) + translation;
  }
};

/// Which point shell is tested against which voxelmap.
enum class QueryDirection {
  APointsInB,  ///< A's points against B's voxelmap
  BPointsInA,  ///< B's points against A's voxelmap
  Both,        ///< both, contacts of both in one set
  Auto,        ///< the smaller object's points in the larger one's voxelmap; within 10% in size, the one with
               ///< fewer points, then the lower position: the same choice whichever object is A
};

/// Where a contact's normal comes from.
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

struct QueryOptions {
  QueryDirection direction = QueryDirection::Auto;
  NormalSource normal_source = NormalSource::PointShell;
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
  /// Time budget of each tree traversal in microseconds (0 = none), for haptic loops and physics steps: the
  /// clock is read at level ends and every 32 nodes. A level the budget interrupts is dropped and the last
  /// completed level is the cut, reported as `cut_level` says: contacts are those of whole levels (the same as a
  /// `max_level` query stopping there), so they do not depend on where in a level time ran out, and with
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

/// Reusable traversal buffers; keep one per thread to avoid allocations in the loop.
struct QueryScratch {
  std::vector<uint32_t> queue;       ///< the level being traversed
  std::vector<uint32_t> next_queue;  ///< the children it queues
  /// Hits of the level being traversed, held back until it is known whether the level is the last one.
  struct Hit {
    uint32_t node;
    float distance;
    bool exact;
  };
  std::vector<Hit> level_hits;
  /// Nodes of the level being traversed that queued children (what a cut level reports as spheres).
  std::vector<uint32_t> level_parents;
  /// The same for the last completed level, held while the next one runs (a time budget may end it).
  std::vector<Hit> done_hits;
  std::vector<uint32_t> done_parents;
  /// For benchmarks and tests only (not part of the query's contract): when set, every point whose distance is
  /// looked up is appended here, in the target's coordinates (a voxelmap's grid), so the cost of the lookups
  /// alone can be measured.
  std::vector<Eigen::Vector3f>* tested_points = nullptr;
};

/// What a traversal leaves for the next one of the same pair, so that a step costs what changed (temporal
/// coherence): the nodes where it stopped — subtrees it pruned, and the points of the nodes it opened — each with
/// a lower bound of its distance at an anchor pose (a recent relative pose of the pair). A query at another pose
/// bounds how far anything of the shell is from where it was at the anchor; an entry whose bound exceeds that
/// (plus the proximity) cannot be within reach and is not touched. The entries are a min-heap on their bound, so
/// a query pops only those that may be (the contacts, and what the motion brought close), checks each against
/// its own displacement and looks up the rest: a body at rest, or rocking about where it was, costs about its
/// contacts whatever the size of the front. When much of the front would be popped, every entry's bound is
/// carried to the current pose in one pass, which becomes the anchor. Valid for full traversals (no point
/// budget, level limit or time budget); a query with one starts the front afresh.
struct TraversalFront {
  struct Entry {
    /// A lower bound (target units) of the distance at the anchor pose of the subtree's spheres' points (a
    /// subtree: its sphere's bound less its radius) or of the node's own point.
    float bound;
    /// The node; in the top bit whether the entry is its point rather than its subtree, in the next whether the
    /// bound is the point's interpolated distance (which falls faster than a true-distance bound). One word: the
    /// passes over the front copy entries as two plain words.
    uint32_t packed;
    static Entry make(float bound, uint32_t node, bool is_point, bool sampled = false) {
      return {bound, node | (is_point ? 0x80000000u : 0u) | (sampled ? 0x40000000u : 0u)};
    }
    uint32_t node() const { return packed & 0x3fffffffu; }
    bool is_point() const { return (packed & 0x80000000u) != 0; }
    bool is_sampled() const { return (packed & 0x40000000u) != 0; }
  };
  std::vector<Entry> heap;     ///< a min-heap on bound while `ordered`
  bool ordered = true;         ///< false while the motion is large: every query makes one pass over the front
  std::vector<Entry> revisit;  ///< scratch: the entries a query pops
  Eigen::Matrix3f M = Eigen::Matrix3f::Zero();  ///< the anchor: shell asset -> target frame
  Eigen::Vector3f m = Eigen::Vector3f::Zero();
  float radius_scale = 0;    ///< target units per shell asset unit
  size_t fresh_entries = 0;  ///< entries after the last traversal from the root
  uint32_t queries = 0;      ///< queries since then
  size_t last_hits = 0;      ///< points within reach at the last query (popped every query)
  /// While the pair moves a lot, the front costs more than it saves (a pass over it every query, lookups one
  /// by one): after `kBusyQueries` such queries in a row the next `skip` queries traverse from the root (batched)
  /// and keep no front, then try again, skipping twice as long each time it is still busy (up to kMaxSkip).
  /// Skipping ends early once a step moves the shell less than an eighth of what a busy step moved.
  uint32_t busy = 0;
  uint32_t skip = 0;
  uint32_t next_skip = kFirstSkip;
  float busy_step = 0;                               ///< the motion of the step that started the skip
  Eigen::Matrix3f last_M = Eigen::Matrix3f::Zero();  ///< the relative pose of the last query
  Eigen::Vector3f last_m = Eigen::Vector3f::Zero();
  static constexpr uint32_t kBusyQueries = 4, kFirstSkip = 8, kMaxSkip = 256;
  bool valid = false;
  void reset() {
    valid = false;
    heap.clear();
  }
  /// Whether the query at relative pose (Mr, mr) uses the front (false while skipping; the front is rebuilt
  /// after). `extent`: the shell's largest distance from its origin.
  bool take_turn(const Eigen::Matrix3f& Mr, const Eigen::Vector3f& mr, float extent) {
    const float step = (mr - last_m).norm() + (Mr - last_M).norm() * extent;
    last_M = Mr;
    last_m = mr;
    if (skip == 0) return true;
    if (step < busy_step / 8 || --skip == 0) {
      skip = 0;
      reset();
      return step < busy_step / 8;
    }
    return false;
  }
};

/// Per-pair state for coherent queries: one front per direction. Keep one per pair of objects (a physics
/// engine's pair, a haptic tool and an object) and drop it when the pair separates for good.
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

/// The direction Auto resolves to for these objects and poses (never Auto).
QueryDirection resolve_direction(const CollisionObject& a, const Pose& pose_a, const CollisionObject& b,
                                 const Pose& pose_b, QueryDirection requested);

/// Single world points of a partner B (box corners, a sphere's centre with its `radius`) against A's
/// voxelmap: reported like B's points (point_of_b, normal = where A must move), the contact point being the
/// partner's surface point deepest in A. Normals always follow A's distance gradient. A point far outside A
/// (where A's voxelmap keeps only a lower bound of the distance) reports nothing, whatever its radius: test
/// large partners with A's points (query_against_function).
void query_points_in_voxelmap(const CollisionObject& a, const Pose& pose_a, const Eigen::Vector3d* points, size_t count,
                              double radius, const QueryOptions& options, ContactSet& out);

/// One sphere-tree traversal of `shell_object`'s points against a signed distance function given in world
/// coordinates — for analytic partners (planes, boxes, spheres). `distance(world_point)` returns the signed
/// distance (negative inside the partner) and writes the partner's outward unit normal. Contacts are
/// reported with A = `shell_object` (normal: the direction in which it must move).
template <class SignedDistance>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, SignedDistance&& distance,
                            const QueryOptions& options, ContactSet& out, QueryScratch& scratch);
/// The same with a cheaper `lower_bound(world_point)` (never above the signed distance) used to prune
/// sphere-tree clusters, for partners whose exact distance is expensive far away (triangle meshes). A bound much
/// cheaper than the distance everywhere says so in its type (`static constexpr bool kBoundBeforeDistance =
/// true`): inner nodes' points are then tested on their bound before their distance, as against a voxelmap.
template <class SignedDistance, class LowerBound>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, SignedDistance&& distance,
                            LowerBound&& lower_bound, const QueryOptions& options, ContactSet& out,
                            QueryScratch& scratch);
/// The same, coherent with the pair's earlier queries (`front`): `partner` is the rigid partner's pose in the
/// world (its distance function moves with it), so that only their relative motion counts.
template <class SignedDistance>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, const Pose& partner,
                            SignedDistance&& distance, const QueryOptions& options, ContactSet& out,
                            QueryScratch& scratch, TraversalFront& front);
/// The same with a cheaper `lower_bound` for pruning. Coherence carries its values (and the function's) from
/// pose to pose as the motion allows, so both must keep the partner's pose fixed between calls: a function
/// `distance(y)` is not below `lower_bound(x) - |y - x|` for any y.
template <class SignedDistance, class LowerBound>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, const Pose& partner,
                            SignedDistance&& distance, LowerBound&& lower_bound, const QueryOptions& options,
                            ContactSet& out, QueryScratch& scratch, TraversalFront& front);

}  // namespace voxfmt::runtime

#include "voxfmt/runtime/query_impl.h"
