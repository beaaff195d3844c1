// The coherent traversal (traversal.h): a query that starts from the front its pair's last query left.
#pragma once

#include <Eigen/Geometry>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <type_traits>
#include <utility>
#include <vector>

#include "../core/prune.h"
#include "eigen.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {

/// What a traversal leaves for the next one of the same pair, so that a step costs what changed: the nodes where
/// it stopped — subtrees it pruned, and the points of the nodes it opened — each with a lower bound of its distance
/// at an anchor pose (a recent relative pose of the pair). A query at another pose bounds how far anything of the
/// shell is from where it was at the anchor; an entry whose bound exceeds that (plus the proximity) cannot be
/// within reach and is not touched. The entries are a min-heap on their bound, so a query pops only those that may
/// be (the contacts, and what the motion brought close), checks each against its own displacement and looks up the
/// rest: a body at rest costs about its contacts whatever the size of the front. When much of the front would be
/// popped, every entry's bound is carried to the current pose in one pass, which becomes the anchor.
struct TraversalFront::State {
  struct Entry {
    /// A lower bound (target units) of the distance at the anchor pose of the subtree's spheres' points (a subtree:
    /// its sphere's bound less its radius) or of the node's own point.
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
  /// While the pair moves a lot, the front costs more than it saves (a pass over it every query, lookups one by
  /// one): after kBusyQueries such queries in a row the next `skip` queries traverse from the root (batched) and
  /// keep no front, then try again, skipping twice as long each time it is still busy (up to kMaxSkip). Skipping
  /// ends early once a step moves the shell less than an eighth of what a busy step moved.
  uint32_t busy = 0;
  uint32_t skip = 0;
  uint32_t next_skip = kFirstSkip;
  float busy_step = 0;                               ///< the motion of the step that started the skip
  Eigen::Matrix3f last_M = Eigen::Matrix3f::Zero();  ///< the relative pose of the last query
  Eigen::Vector3f last_m = Eigen::Vector3f::Zero();
  static constexpr uint32_t kBusyQueries = 4, kFirstSkip = 8, kMaxSkip = 256;
  bool valid = false;

  uint64_t shell = 0;   ///< CollisionObject::id of the object whose point tree the front is of
  uint64_t target = 0;  ///< and of the object whose field it was walked against (0: a function, no identity)
  int reading = 0;      ///< how the field was read (QueryOptions::interpolation): its bounds are of that

  void reset() {
    valid = false;
    heap.clear();
  }
  /// The front belongs to one pair: queried for another shell or target, it starts afresh (its entries index
  /// another tree's nodes, its bounds another field's). Objects are known by their ids, not their addresses, which
  /// an object loaded after another was destroyed may reuse.
  void bind(uint64_t shell_object, uint64_t target_object, int target_reading = 0) {
    if (shell_object == shell && target_object == target && target_reading == reading) return;
    reset();
    shell = shell_object;
    target = target_object;
    reading = target_reading;
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

namespace detail {

/// Whether a target's sampled distances change no faster than kSampledSlope times the distance a point moves, so
/// that a sampled point keeps a bound (a target's `sampled_bounds_hold()` where it has one, else true). A reading
/// that switches between two interpolations where its inputs change (tricubic near the surface, trilinear beyond)
/// steps where it switches: its points are looked up again at every query, as estimates are.
template <class Target, class = void>
struct SampledBounds {
  static bool hold(const Target&) { return true; }
};
template <class Target>
struct SampledBounds<Target, std::void_t<decltype(std::declval<const Target&>().sampled_bounds_hold())>> {
  static bool hold(const Target& target) { return target.sampled_bounds_hold(); }
};

/// The traversal of LevelTraversal, coherent with `front`: an entry is kept while the motion since the front's
/// anchor pose (Mr, mr against the front's) cannot have brought it within `proximity`, and re-examined otherwise —
/// a pruned subtree is traversed again from its node, a point looked up again. The points closer than `proximity`
/// are those a traversal from the root finds (its pruning only skips points whose lower bound is beyond reach),
/// reported in increasing node order as it reports them. The frame maps the shell into the target's frame for
/// lookups; (Mr, mr) into the frame in which the target is fixed, for displacements (the frame's own map for a
/// voxelmap; the partner's frame for a function given in world coordinates).
template <class Target, class Emit>
class CoherentTraversal {
 public:
  using Front = TraversalFront::State;
  using Entry = Front::Entry;
  using Hit = QueryScratch::Buffers::Hit;
  // A bound from a sampled distance falls faster than the point moves: inside a voxel cell the interpolated field
  // has a slope of at most sqrt(3) times the largest difference of adjacent stored values (1 voxel per voxel, plus
  // quantisation). Bounds of the true distance (a subtree's, a point's lower bound) fall as fast as it moves.
  static constexpr float kSampledSlope = 1.7321f * 1.001f;

  CoherentTraversal(const PointTree& tree, const core::Frame& frame, const Eigen::Matrix3f& Mr,
                    const Eigen::Vector3f& mr, const Target& target, QueryStats& stats, QueryScratch::Buffers& b,
                    Front& front, Emit& emit)
      : tree_(tree),
        nodes_(tree.nodes.data()),
        points_(tree.points.data()),
        M_(core::to_eigen(frame.to_grid)),
        m_(core::to_eigen(frame.to_grid.m)),
        to_target_(frame.to_grid),
        Mr_(Mr),
        mr_(mr),
        radius_scale_(frame.radius_scale),
        proximity_(frame.proximity),
        target_(target),
        sampled_bounds_hold_(SampledBounds<Target>::hold(target)),
        stats_(stats),
        b_(b),
        front_(front),
        emit_(emit) {}

  void run() {
    if (tree_.size() == 0) return;
    anchor();
    if (ordered_) pop_reachable();
    if (!ordered_) carry_all();
    b_.level_hits.clear();
    for (const Entry& e : front_.revisit) revisit(e);
    settle();
    report();
  }

 private:
  // Stage 1, anchor: back to the root when the scale changed, once the front has grown well past a fresh one
  // (entries only split: a subtree traversed again never joins up), or after many queries, so that a pair that
  // moved far does not keep a needlessly fine front. Then the motion since the anchor.
  void anchor() {
    fresh_ = !front_.valid || front_.radius_scale != radius_scale_ ||
             front_.heap.size() > 2 * front_.fresh_entries + 64 || front_.queries >= 1024;
    if (fresh_) {
      front_.heap.assign(1, Entry::make(-std::numeric_limits<float>::infinity(), 0, false));
      front_.M = Mr_;
      front_.m = mr_;
      front_.queries = 0;
    }
    // Float rounding of the poses and of the displacement products: a few ulps of the coordinates involved, so
    // that rounding never keeps an entry that moved within reach.
    rounding_ = 8e-7f * (mr_.norm() + Mr_.norm() * tree_.extent + m_.norm() + M_.norm() * tree_.extent) + 1e-6f;
    // How far a sphere (c, r) of the shell is from where it was at the anchor: |dM x + dm| for x in it is at most
    // |dM c + dm| + |dM|_F r; for anything of the shell at most |dm| + |dM|_F extent.
    dM_ = Mr_ - front_.M;
    dm_ = mr_ - front_.m;
    spin_ = dM_.norm();
    everywhere_ = kSampledSlope * (dm_.norm() + spin_ * tree_.extent + rounding_);
    front_.revisit.clear();
    // A fresh front is built unordered (one heap at the end, not one push per entry).
    ordered_ = front_.ordered && !fresh_;
  }

  float moved(const Entry& e) const {
    const uint32_t node = e.node();
    const Eigen::Vector3f x = e.is_point() ? points_[node] : to_eigen(nodes_[node].centre);
    const float r = e.is_point() ? 0.0f : nodes_[node].radius;
    const float distance = (dM_ * x + dm_).norm() + spin_ * r + rounding_;
    return e.is_sampled() ? kSampledSlope * distance : distance;
  }

  // Stage 2, pop: the entries that may be within reach (always the contacts, whose bound is below it), one by one
  // while the motion is small and they are few; past a limit on the rest, the front goes unordered (stage 3).
  void pop_reachable() {
    std::vector<Entry>& heap = front_.heap;
    const size_t pop_limit = front_.last_hits + heap.size() / 32 + 16;
    while (!heap.empty() && heap.front().bound - everywhere_ <= proximity_) {
      if (front_.revisit.size() == pop_limit) {
        ordered_ = false;
        heap.insert(heap.end(), front_.revisit.begin(), front_.revisit.end());
        front_.revisit.clear();
        return;
      }
      std::pop_heap(heap.begin(), heap.end(), later);
      front_.revisit.push_back(heap.back());
      heap.pop_back();
    }
  }

  // Stage 3, carry: one pass carries every entry to this pose, which becomes the anchor; what may be within reach
  // is revisited. The motion of the whole shell first, the entry's own displacement where that is not enough.
  void carry_all() {
    std::vector<Entry>& heap = front_.heap;
    size_t kept = 0;
    const size_t count = heap.size();
    Entry* entries = heap.data();
    for (size_t i = 0; i < count; ++i) {
      // Field by field: a whole entry rewritten after its bound made the store wait on the load (~15 cycles).
      const Entry e = entries[i];
      float carried = e.bound - everywhere_;
      if (carried <= proximity_) carried = e.bound - moved(e);
      if (carried > proximity_) {
        entries[kept].bound = carried;
        entries[kept].packed = e.packed;
        ++kept;
      } else {
        front_.revisit.push_back({carried, e.packed});
      }
    }
    heap.resize(kept);
    front_.M = Mr_;
    front_.m = mr_;
    dM_.setZero();
    dm_.setZero();
    spin_ = 0;
  }

  void record(uint32_t node, bool is_point, float bound, bool sampled = false) {
    Entry e = Entry::make(bound, node, is_point, sampled);
    e.bound -= moved(e);
    keep(e);
  }

  void keep(const Entry& e) {
    front_.heap.push_back(e);
    if (ordered_) std::push_heap(front_.heap.begin(), front_.heap.end(), later);
  }

  // Stage 4, revisit an entry: its own displacement since the anchor often keeps it without a lookup; else a
  // subtree is descended again, a point looked up again.
  void revisit(const Entry& e) {
    if (e.bound - moved(e) > proximity_) {
      keep(e);
    } else if (!e.is_point()) {
      descend(e.node());
    } else {
      revisit_point(e.node());
    }
  }

  // A point is tested behind its node's sphere, as the level walk tests it: an interpolated distance may lie a
  // little below the bound of the true distance, so a point sampled without that gate could be a contact the
  // walk from the root never reaches. (Its ancestors' tests are not repeated: a point whose parent the walk culls
  // while its own sphere passes could still differ.) Then its own bound first where a distance costs more. Only
  // for voxelmaps: a function's distance is its bound.
  void revisit_point(uint32_t node) {
    if (!Target::kBoundBeforeDistance) return test_point(node, -std::numeric_limits<float>::infinity());
    const NodeTest t = test_node(node);
    if (!t.in_reach) return record(node, true, t.sphere_bound - nodes_[node].radius * radius_scale_);
    test_point(node, t.point_bound);
  }

  // A node's sphere against the target, as the level walk tests it: in reach or not, the sphere's bound, and,
  // where a distance costs more than a bound, the bound at the node's own point (-inf otherwise).
  struct NodeTest {
    bool in_reach;
    float sphere_bound;
    float point_bound;
  };
  NodeTest test_node(uint32_t node) {
    const PointTree::Node& n = nodes_[node];
    NodeTest t{false, target_.lower_bound(map(to_eigen(n.centre))), -std::numeric_limits<float>::infinity()};
    ++stats_.nodes_visited;
    t.in_reach = core::sphere_in_reach(t.sphere_bound, n.radius, radius_scale_, proximity_);
    if (t.in_reach && Target::kBoundBeforeDistance && n.child_count > 0)
      t.point_bound = target_.lower_bound(map(points_[node]));
    return t;
  }

  // Stage 5, descend: the subtree of `root` as the level walk traverses it, recording where it stops.
  void descend(uint32_t root) {
    std::vector<uint32_t>& queue = b_.queue;
    queue.clear();
    queue.push_back(root);
    for (size_t q = 0; q < queue.size(); ++q) {
      const uint32_t node = queue[q];
      const PointTree::Node& n = nodes_[node];
      const NodeTest t = test_node(node);
      if (!t.in_reach) {
        record(node, false, t.sphere_bound - n.radius * radius_scale_);
        continue;
      }
      test_point(node, t.point_bound);
      for (uint32_t c = n.first_child; c < n.first_child + n.child_count; ++c) {
        const float carried = core::carried_bound(t.sphere_bound, t.point_bound, nodes_[c].reach_from_parent,
                                                  nodes_[c].reach_from_parent_point, radius_scale_);
        if (carried > proximity_)
          record(c, false, carried);
        else
          queue.push_back(c);
      }
    }
  }

  // The point's distance where its bound allows a contact; its bound (or distance) goes to the front.
  void test_point(uint32_t node, float point_bound) {
    float bound = point_bound;
    bool sampled = false;
    if (point_bound < proximity_) {
      const Hit hit = sample_hit(target_, node, map(points_[node]));
      const bool exact = hit.exact;
      bound = hit.distance;
      ++stats_.points_tested;
      if (bound < proximity_) b_.level_hits.push_back(hit);
      // Interpolated from estimates (the band's edge and beyond), or by a reading that steps (SampledBounds), the
      // distance has no useful slope bound: looked up again at the next query.
      sampled = true;
      if (!exact || !sampled_bounds_hold_) bound = -std::numeric_limits<float>::infinity();
    }
    record(node, true, bound, sampled);
  }

  // Stage 6, settle: ordered again once a pass finds little within reach; while it stays busy, the next queries
  // skip the front (TraversalFront::State::take_turn).
  void settle() {
    std::vector<Entry>& heap = front_.heap;
    if (!ordered_ && front_.revisit.size() <= b_.level_hits.size() + heap.size() / 64 + 8) {
      std::make_heap(heap.begin(), heap.end(), later);
      ordered_ = true;
    }
    front_.ordered = ordered_;
    front_.last_hits = b_.level_hits.size();
    if (ordered_) {
      front_.busy = 0;
      front_.next_skip = Front::kFirstSkip;
    } else if (++front_.busy >= Front::kBusyQueries) {
      front_.busy = 0;
      front_.busy_step = everywhere_ / kSampledSlope;
      front_.skip = front_.next_skip;
      front_.next_skip = std::min(2 * front_.next_skip, Front::kMaxSkip);
    }
    front_.radius_scale = radius_scale_;
    front_.valid = true;
    ++front_.queries;
    if (fresh_) front_.fresh_entries = heap.size();
  }

  // Stage 7, report: as a traversal from the root reports its points, level by level in node order.
  void report() {
    std::vector<Hit>& hits = b_.level_hits;
    std::sort(hits.begin(), hits.end(), [](const Hit& a, const Hit& b) { return a.node < b.node; });
    for (const Hit& hit : hits) emit_(hit);
    uint32_t deepest = 0;
    for (size_t l = 0; l + 1 < tree_.level_offsets.size(); ++l) deepest = uint32_t(l);
    stats_.deepest_level = std::max(stats_.deepest_level, deepest);
  }

  static bool later(const Entry& a, const Entry& b) { return a.bound > b.bound; }  // a min-heap on bound
  // Into the target's frame: the query core's map (the device walk's, core/walk.h).
  Eigen::Vector3f map(const Eigen::Vector3f& x) const { return core::to_eigen(to_target_.apply(core::to_core(x))); }

  const PointTree& tree_;
  const PointTree::Node* nodes_;
  const Eigen::Vector3f* points_;
  const Eigen::Matrix3f M_;
  const Eigen::Vector3f m_;
  const core::Affine to_target_;
  const Eigen::Matrix3f& Mr_;
  const Eigen::Vector3f& mr_;
  float radius_scale_, proximity_;
  const Target& target_;
  const bool sampled_bounds_hold_;
  QueryStats& stats_;
  QueryScratch::Buffers& b_;
  Front& front_;
  Emit& emit_;
  bool fresh_ = false, ordered_ = true;
  float rounding_ = 0, spin_ = 0, everywhere_ = 0;
  Eigen::Matrix3f dM_;
  Eigen::Vector3f dm_;
};

template <class Target, class Emit>
void traverse_coherent(const PointTree& tree, const core::Frame& frame, const Eigen::Matrix3f& Mr,
                       const Eigen::Vector3f& mr, const Target& target, QueryStats& stats,
                       QueryScratch::Buffers& buffers, TraversalFront::State& front, Emit&& emit) {
  CoherentTraversal<Target, std::remove_reference_t<Emit>>(tree, frame, Mr, mr, target, stats, buffers, front, emit)
      .run();
}

}  // namespace detail
}  // namespace voxfmt::runtime
