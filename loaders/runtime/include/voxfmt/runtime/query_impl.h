// Template parts of query.h: the breadth-first sphere-tree traversal shared by every kind of partner.
#pragma once

#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <limits>
#include <type_traits>

namespace voxfmt::runtime {
namespace detail {

/// Breadth-first traversal of `tree` mapped into a target frame by u = M * x + m (lengths scale by
/// `radius_scale`). The target supplies `lower_bound(u)` (never above the true signed distance),
/// `distance(u, exact)`, both in target units; `kBoundBeforeDistance` says whether a point's bound is worth
/// testing before its distance. Calls emit(node, distance, exact) for every tested point closer than
/// `proximity` (target units).
///
/// A level is processed in batches of kBatch nodes, each in two passes (sphere bounds, then the points that
/// survive): the lookups of one pass are independent of each other, so their cache misses overlap instead of
/// being paid one after another as in a node-at-a-time loop. (Software prefetching was tried: it cost more
/// instructions than it saved in misses.)
template <class Target, class Emit>
void traverse_tree(const PointTree& tree, const Eigen::Matrix3f& M, const Eigen::Vector3f& m, float radius_scale,
                   float proximity, const Target& target, const QueryOptions& options, QueryStats& stats,
                   QueryScratch& scratch, Emit&& emit) {
  using Hit = QueryScratch::Hit;
  constexpr size_t kBatch = 32;
  std::vector<uint32_t>& frontier = scratch.queue;
  std::vector<uint32_t>& next = scratch.next_queue;
  // Sphere semantics hold a level's hits back until it is known whether the level ends the traversal: the
  // current level's (partial) and the last completed level's. A point whose children were queued but never
  // tested reports its sphere instead of itself.
  std::vector<Hit>& hits = scratch.level_hits;
  std::vector<uint32_t>& parents = scratch.level_parents;
  std::vector<Hit>& done_hits = scratch.done_hits;
  std::vector<uint32_t>& done_parents = scratch.done_parents;
  hits.clear();
  parents.clear();
  done_hits.clear();
  done_parents.clear();
  if (tree.size() == 0) return;
  // A level never holds more nodes than the tree: sized once, the queues are filled without capacity checks
  // (children are written unconditionally and kept by advancing the size, which leaves no branch to mispredict).
  if (frontier.size() < tree.size()) frontier.resize(tree.size());
  if (next.size() < tree.size()) next.resize(tree.size());
  size_t frontier_size = 0, next_size = 0;
  const PointTree::Node* nodes = tree.nodes.data();
  const Eigen::Vector3f* points = tree.points.data();
  const bool spheres = options.cut_level == CutLevel::Spheres;
  const bool timed = options.time_budget_us > 0.0;
  // Hits are held back until their level completes: a level the budget interrupts is dropped whatever the cut
  // level reports, so contacts never depend on where in a level time ran out.
  const bool hold = spheres || timed;
  const auto deadline =
      timed ? std::chrono::steady_clock::now() + std::chrono::nanoseconds(int64_t(options.time_budget_us * 1e3))
            : std::chrono::steady_clock::time_point::max();
  auto emit_points = [&](const std::vector<Hit>& level_hits) {
    for (const Hit& hit : level_hits) emit(hit.node, hit.distance, hit.exact);
  };
  // Ends the traversal at a completed level: its points with untested children report their spheres.
  auto emit_cut = [&](const std::vector<Hit>& level_hits, const std::vector<uint32_t>& level_parents) {
    for (const Hit& hit : level_hits)
      if (!std::binary_search(level_parents.begin(), level_parents.end(), hit.node))
        emit(hit.node, hit.distance, hit.exact);
    for (const uint32_t node : level_parents) {
      bool exact = false;
      const float radius = nodes[node].radius * radius_scale;
      const float d = target.distance(M * nodes[node].centre + m, exact) - radius;
      if (d < proximity) emit(node, d, false);
    }
  };
  // Batch buffers: sphere centres in the target frame, then the survivors with their bounds and points.
  Eigen::Vector3f centre[kBatch], point[kBatch];
  float bound[kBatch];
  uint32_t survivor[kBatch];

  frontier[frontier_size++] = 0;
  uint32_t level = 0;
  size_t tested = 0;
  bool out_of_time = false;
  bool level_done = false;  // the last level entered was completed
  for (;;) {
    level_done = false;
    // A level within min_points is tested whatever the limits say (the root level always is).
    const bool floor_level = level == 0 || tested + frontier_size <= options.min_points;
    for (size_t begin = 0; begin < frontier_size; begin += kBatch) {
      // The clock is read before each batch.
      if (timed && !floor_level && std::chrono::steady_clock::now() >= deadline) {
        out_of_time = true;
        break;
      }
      const size_t count = std::min(kBatch, frontier_size - begin);
      const uint32_t* batch = frontier.data() + begin;
      // Pass 1: every sphere against the target's lower bound. The sphere holds the node's point and all its
      // descendants; the distance is 1-Lipschitz, so if even the lower bound at the centre exceeds the radius
      // nothing below can be within reach.
      for (size_t i = 0; i < count; ++i) centre[i] = M * nodes[batch[i]].centre + m;
      size_t survivors = 0;
      for (size_t i = 0; i < count; ++i) {
        const float b = target.lower_bound(centre[i]);
        survivor[survivors] = batch[i];
        bound[survivors] = b;
        survivors += b <= nodes[batch[i]].radius * radius_scale + proximity;
      }
      stats.nodes_visited += count;

      // Pass 2: the survivors' own points, then their children that the bound, carried from the parent's
      // centre to each child's sphere, cannot rule out.
      for (size_t i = 0; i < survivors; ++i) point[i] = M * points[survivor[i]] + m;
      for (size_t i = 0; i < survivors; ++i) {
        const uint32_t node = survivor[i];
        const PointTree::Node& parent = nodes[node];
        if (scratch.tested_points) scratch.tested_points->push_back(point[i]);
        // A leaf's sphere is its point, whose bound pass 1 has just tested; an inner node's point is tested on
        // its own bound first where a distance costs more.
        float point_bound = -std::numeric_limits<float>::infinity();
        if (Target::kBoundBeforeDistance && parent.child_count > 0) point_bound = target.lower_bound(point[i]);
        if (point_bound < proximity) {
          bool exact = false;
          const float d = target.distance(point[i], exact);
          if (d < proximity) {
            if (hold)
              hits.push_back({node, d, exact});
            else
              emit(node, d, exact);
          }
        }
        const size_t queued = next_size;
        uint32_t* const out = next.data();
        for (uint32_t c = parent.first_child; c < parent.first_child + parent.child_count; ++c) {
          out[next_size] = c;
          next_size += std::max(bound[i] - nodes[c].reach_from_parent * radius_scale,
                                point_bound - nodes[c].reach_from_parent_point * radius_scale) <= proximity;
        }
        if (spheres && next_size > queued) parents.push_back(node);
      }
      tested += survivors;
    }
    if (out_of_time) break;
    level_done = true;
    // `level` is complete: go on to the next one unless it is empty, too deep or over the point budget.
    const bool next_in_floor = tested + next_size <= options.min_points;
    if (next_size == 0 ||
        (!next_in_floor && (level + 1 > options.max_level || tested + next_size > options.point_budget)))
      break;
    if (timed && !next_in_floor && std::chrono::steady_clock::now() >= deadline) {
      out_of_time = true;
      break;
    }
    if (spheres) {
      emit_points(done_hits);  // the level before is refined by this complete one
      done_hits.swap(hits);
      done_parents.swap(parents);
      hits.clear();
      parents.clear();
    } else if (hold) {
      emit_points(hits);
      hits.clear();
    }
    frontier.swap(next);
    frontier_size = next_size;
    next_size = 0;
    ++level;
  }
  uint32_t completed = level;
  if (out_of_time && !level_done) {
    // Stopped inside `level`: its partial hits are dropped, the level before is the cut.
    completed = level - 1;
    if (spheres) emit_cut(done_hits, done_parents);
  } else if (spheres) {
    emit_points(done_hits);
    if (next_size > 0)  // children of this level were queued but not tested
      emit_cut(hits, parents);
    else
      emit_points(hits);
  } else if (hold) {
    emit_points(hits);
  }
  if (out_of_time) stats.time_budget_hit = true;
  stats.points_tested += tested;
  stats.deepest_level = std::max(stats.deepest_level, completed);
}

/// Whether a query can use (and keep) a traversal front: full traversals only.
inline bool coherent_query_allowed(const QueryOptions& options) {
  return options.point_budget == std::numeric_limits<size_t>::max() &&
         options.max_level == std::numeric_limits<uint32_t>::max() && options.time_budget_us <= 0.0;
}

/// The traversal of traverse_tree, coherent with `front` (see TraversalFront): an entry is kept while the motion
/// since the front's anchor pose (Mr, mr against the front's) cannot have brought it within `proximity`, and
/// re-examined otherwise — a pruned subtree is traversed again from its node, a point looked up again. The
/// points closer than `proximity` are those a traversal from the root finds (its pruning only skips points whose
/// lower bound is beyond reach), reported in increasing node order as it reports them. (M, m) maps the shell
/// into the target's frame for lookups; (Mr, mr) into the frame in which the target is fixed, for displacements
/// (the same for a voxelmap; the partner's frame for a function given in world coordinates).
template <class Target, class Emit>
void traverse_coherent(const PointTree& tree, const Eigen::Matrix3f& M, const Eigen::Vector3f& m,
                       const Eigen::Matrix3f& Mr, const Eigen::Vector3f& mr, float radius_scale, float proximity,
                       const Target& target, QueryStats& stats, QueryScratch& scratch, TraversalFront& front,
                       Emit&& emit) {
  using Hit = QueryScratch::Hit;
  using Entry = TraversalFront::Entry;
  if (tree.size() == 0) return;
  const PointTree::Node* nodes = tree.nodes.data();
  const Eigen::Vector3f* points = tree.points.data();
  std::vector<Entry>& heap = front.heap;
  const auto later = [](const Entry& a, const Entry& b) { return a.bound > b.bound; };  // min-heap on bound
  // Back to the root when the scale changed, and once the front has grown well past a fresh one (entries only
  // split: a subtree traversed again never joins up), or after many queries, so that a pair that moved far
  // does not keep a needlessly fine front.
  const bool fresh = !front.valid || front.radius_scale != radius_scale || heap.size() > 2 * front.fresh_entries + 64 ||
                     front.queries >= 1024;
  if (fresh) {
    heap.assign(1, Entry::make(-std::numeric_limits<float>::infinity(), 0, false));
    front.M = Mr;
    front.m = mr;
    front.queries = 0;
  }
  // Float rounding of the poses and of the displacement products: a few ulps of the coordinates involved, so
  // that rounding never keeps an entry that moved within reach.
  const float rounding = 8e-7f * (mr.norm() + Mr.norm() * tree.extent + m.norm() + M.norm() * tree.extent) + 1e-6f;
  // How far a sphere (c, r) of the shell is from where it was at the anchor: |dM x + dm| for x in it is at most
  // |dM c + dm| + |dM|_F r; for anything of the shell at most |dm| + |dM|_F extent.
  Eigen::Matrix3f dM = Mr - front.M;
  Eigen::Vector3f dm = mr - front.m;
  float spin = dM.norm();
  // A bound from a sampled distance falls faster than the point moves: inside a voxel cell the interpolated field
  // has a slope of at most sqrt(3) times the largest difference of adjacent stored values (1 voxel per voxel,
  // plus quantisation). Bounds of the true distance (a subtree's, a point's lower bound) fall as fast as it moves.
  constexpr float kSampledSlope = 1.7321f * 1.001f;
  auto moved = [&](const Entry& e) {
    const uint32_t node = e.node();
    const Eigen::Vector3f& x = e.is_point() ? points[node] : nodes[node].centre;
    const float r = e.is_point() ? 0.0f : nodes[node].radius;
    const float distance = (dM * x + dm).norm() + spin * r + rounding;
    return e.is_sampled() ? kSampledSlope * distance : distance;
  };
  const float everywhere = kSampledSlope * (dm.norm() + spin * tree.extent + rounding);
  // The entries that may be within reach (always the contacts, whose bound is below it): popped one by one while
  // the motion is small and they are few. Otherwise one pass over the front carries every entry to this pose,
  // which becomes the anchor, and the front stays unordered (a pass each query) until the motion calms down.
  std::vector<Entry>& revisit = front.revisit;
  revisit.clear();
  // A fresh front is built unordered (one heap at the end, not one push per entry).
  bool ordered = front.ordered && !fresh;
  if (ordered) {
    // The contacts are popped every query whatever the motion: the limit is on the rest.
    const size_t pop_limit = front.last_hits + heap.size() / 32 + 16;
    while (!heap.empty() && heap.front().bound - everywhere <= proximity) {
      if (revisit.size() == pop_limit) {
        ordered = false;
        break;
      }
      std::pop_heap(heap.begin(), heap.end(), later);
      revisit.push_back(heap.back());
      heap.pop_back();
    }
    if (!ordered) {
      heap.insert(heap.end(), revisit.begin(), revisit.end());
      revisit.clear();
    }
  }
  if (!ordered) {
    // A cheap carry by the motion of the whole shell first, the entry's own displacement where that is not enough.
    size_t kept = 0;
    const size_t count = heap.size();
    Entry* entries = heap.data();
    for (size_t i = 0; i < count; ++i) {
      // Field by field: a whole entry rewritten after its bound made the store wait on the load (~15 cycles).
      const Entry e = entries[i];
      float carried = e.bound - everywhere;
      if (carried <= proximity) carried = e.bound - moved(e);
      if (carried > proximity) {
        entries[kept].bound = carried;
        entries[kept].packed = e.packed;
        ++kept;
      } else {
        revisit.push_back({carried, e.packed});
      }
    }
    heap.resize(kept);
    front.M = Mr;
    front.m = mr;
    dM.setZero();
    dm.setZero();
    spin = 0;
  }
  auto record = [&](uint32_t node, bool is_point, float bound, bool sampled = false) {
    Entry e = Entry::make(bound, node, is_point, sampled);
    e.bound -= moved(e);
    heap.push_back(e);
    if (ordered) std::push_heap(heap.begin(), heap.end(), later);
  };
  std::vector<Hit>& hits = scratch.level_hits;  // emitted at the end, in node order
  hits.clear();
  std::vector<uint32_t>& queue = scratch.queue;
  auto test_point = [&](uint32_t node, float point_bound) {
    // The point's distance where its bound allows a contact; its bound (or distance) goes to the front.
    float bound = point_bound;
    bool sampled = false;
    if (point_bound < proximity) {
      bool exact = false;
      bound = target.distance(M * points[node] + m, exact);
      ++stats.points_tested;
      if (bound < proximity) hits.push_back({node, bound, exact});
      // Interpolated from estimates (the band's edge and beyond), the distance has no useful slope bound:
      // looked up again at the next query.
      sampled = true;
      if (!exact) bound = -std::numeric_limits<float>::infinity();
    }
    record(node, true, bound, sampled);
  };
  // Traverses the subtree of `root` as traverse_tree does, recording where it stops.
  auto descend = [&](uint32_t root) {
    queue.clear();
    queue.push_back(root);
    for (size_t q = 0; q < queue.size(); ++q) {
      const uint32_t node = queue[q];
      const PointTree::Node& n = nodes[node];
      const float radius = n.radius * radius_scale;
      const float sphere_bound = target.lower_bound(M * n.centre + m);
      ++stats.nodes_visited;
      if (sphere_bound > radius + proximity) {
        record(node, false, sphere_bound - radius);
        continue;
      }
      float point_bound = -std::numeric_limits<float>::infinity();
      if (Target::kBoundBeforeDistance && n.child_count > 0) point_bound = target.lower_bound(M * points[node] + m);
      test_point(node, point_bound);
      for (uint32_t c = n.first_child; c < n.first_child + n.child_count; ++c) {
        const float carried = std::max(sphere_bound - nodes[c].reach_from_parent * radius_scale,
                                       point_bound - nodes[c].reach_from_parent_point * radius_scale);
        if (carried > proximity)
          record(c, false, carried);
        else
          queue.push_back(c);
      }
    }
  };
  for (const Entry& e : revisit) {
    // The entry's own displacement since the anchor often keeps it without a lookup.
    if (e.bound - moved(e) > proximity) {
      heap.push_back(e);
      if (ordered) std::push_heap(heap.begin(), heap.end(), later);
    } else if (!e.is_point()) {
      descend(e.node());
    } else {
      // The point again: its own bound first where a distance costs more (an inner node), as descend does.
      float point_bound = -std::numeric_limits<float>::infinity();
      if (Target::kBoundBeforeDistance && nodes[e.node()].child_count > 0)
        point_bound = target.lower_bound(M * points[e.node()] + m);
      test_point(e.node(), point_bound);
    }
  }
  // Ordered again once a pass finds little within reach.
  if (!ordered && revisit.size() <= hits.size() + heap.size() / 64 + 8) {
    std::make_heap(heap.begin(), heap.end(), later);
    ordered = true;
  }
  front.ordered = ordered;
  front.last_hits = hits.size();
  if (ordered) {
    front.busy = 0;
    front.next_skip = TraversalFront::kFirstSkip;
  } else if (++front.busy >= TraversalFront::kBusyQueries) {
    front.busy = 0;
    front.busy_step = everywhere / kSampledSlope;
    front.skip = front.next_skip;
    front.next_skip = std::min(2 * front.next_skip, TraversalFront::kMaxSkip);
  }
  front.radius_scale = radius_scale;
  front.valid = true;
  ++front.queries;
  if (fresh) front.fresh_entries = heap.size();
  // A traversal from the root reports its points level by level, in node order: so does this one.
  std::sort(hits.begin(), hits.end(), [](const Hit& a, const Hit& b) { return a.node < b.node; });
  for (const Hit& hit : hits) emit(hit.node, hit.distance, hit.exact);
  uint32_t deepest = 0;
  for (size_t l = 0; l + 1 < tree.level_offsets.size(); ++l) deepest = uint32_t(l);
  stats.deepest_level = std::max(stats.deepest_level, deepest);
}

/// Whether a lower bound says it is much cheaper than its distance (`static constexpr bool
/// kBoundBeforeDistance = true` in its type), so that inner nodes' points are bounded before their distance.
template <class LowerBound, class = void>
struct CheapBound : std::false_type {};
template <class LowerBound>
struct CheapBound<LowerBound, std::void_t<decltype(LowerBound::kBoundBeforeDistance)>>
    : std::bool_constant<LowerBound::kBoundBeforeDistance> {};

/// A signed-distance function in world coordinates seen as a traversal target, with a cheaper lower bound
/// for pruning (or the function itself).
template <class SignedDistance, class LowerBound>
struct FunctionTarget {
  SignedDistance& function;
  LowerBound& bound;
  float lower_bound(const Eigen::Vector3f& u) const { return bound(u); }
  static constexpr bool kBoundBeforeDistance = CheapBound<std::remove_cv_t<LowerBound>>::value;
  float distance(const Eigen::Vector3f& u, bool& exact) const {
    Eigen::Vector3f normal;
    exact = true;
    return function(u, normal);
  }
};

}  // namespace detail

template <class SignedDistance, class LowerBound>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, SignedDistance&& distance,
                            LowerBound&& lower_bound, const QueryOptions& options, ContactSet& out,
                            QueryScratch& scratch) {
  if (!shell_object.has_point_shell()) return;
  const PointTree& tree = shell_object.point_tree();
  const Eigen::Matrix3f M = (pose.rotation * pose.scale).cast<float>();
  const Eigen::Vector3f m = pose.translation.cast<float>();
  detail::FunctionTarget<std::remove_reference_t<SignedDistance>, std::remove_reference_t<LowerBound>> target{
      distance, lower_bound};
  const Eigen::Matrix3d rotation = pose.rotation;
  detail::traverse_tree(tree, M, m, float(pose.scale), float(options.proximity), target, options, out.stats, scratch,
                        [&](uint32_t node, float d, bool exact) {
                          Contact contact;
                          contact.point = pose.apply(tree.points[node].cast<double>());
                          Eigen::Vector3f outward;
                          distance(contact.point.cast<float>(), outward);
                          if (options.normal_source == NormalSource::PointShell || outward.squaredNorm() == 0.0f)
                            contact.normal = (rotation * tree.normals[node].cast<double>()).normalized();
                          else
                            contact.normal = outward.cast<double>().normalized();
                          contact.depth = -double(d);
                          contact.point_index = node;
                          contact.exact = exact;
                          out.contacts.push_back(contact);
                        });
}

template <class SignedDistance, class LowerBound>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, const Pose& partner,
                            SignedDistance&& distance, LowerBound&& lower_bound, const QueryOptions& options,
                            ContactSet& out, QueryScratch& scratch, TraversalFront& front) {
  if (!detail::coherent_query_allowed(options) || !shell_object.has_point_shell()) {
    front.reset();
    query_against_function(shell_object, pose, distance, lower_bound, options, out, scratch);
    return;
  }
  const PointTree& tree = shell_object.point_tree();
  const Eigen::Matrix3f M = (pose.rotation * pose.scale).cast<float>();
  const Eigen::Vector3f m = pose.translation.cast<float>();
  // Displacements in the partner's frame, where its distance function is fixed.
  const Eigen::Matrix3f Mr = (partner.rotation.transpose() * pose.rotation * pose.scale).cast<float>();
  const Eigen::Vector3f mr = (partner.rotation.transpose() * (pose.translation - partner.translation)).cast<float>();
  if (!front.take_turn(Mr, mr, tree.extent)) {
    query_against_function(shell_object, pose, distance, lower_bound, options, out, scratch);
    return;
  }
  detail::FunctionTarget<std::remove_reference_t<SignedDistance>, std::remove_reference_t<LowerBound>> target{
      distance, lower_bound};
  const Eigen::Matrix3d rotation = pose.rotation;
  detail::traverse_coherent(tree, M, m, Mr, mr, float(pose.scale), float(options.proximity), target, out.stats, scratch,
                            front, [&](uint32_t node, float d, bool exact) {
                              Contact contact;
                              contact.point = pose.apply(tree.points[node].cast<double>());
                              Eigen::Vector3f outward;
                              distance(contact.point.cast<float>(), outward);
                              if (options.normal_source == NormalSource::PointShell || outward.squaredNorm() == 0.0f)
                                contact.normal = (rotation * tree.normals[node].cast<double>()).normalized();
                              else
                                contact.normal = outward.cast<double>().normalized();
                              contact.depth = -double(d);
                              contact.point_index = node;
                              contact.exact = exact;
                              out.contacts.push_back(contact);
                            });
}

template <class SignedDistance>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, const Pose& partner,
                            SignedDistance&& distance, const QueryOptions& options, ContactSet& out,
                            QueryScratch& scratch, TraversalFront& front) {
  auto bound = [&](const Eigen::Vector3f& u) {
    Eigen::Vector3f normal;
    return distance(u, normal);
  };
  query_against_function(shell_object, pose, partner, distance, bound, options, out, scratch, front);
}

template <class SignedDistance>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, SignedDistance&& distance,
                            const QueryOptions& options, ContactSet& out, QueryScratch& scratch) {
  auto bound = [&](const Eigen::Vector3f& u) {
    Eigen::Vector3f normal;
    return distance(u, normal);
  };
  query_against_function(shell_object, pose, distance, bound, options, out, scratch);
}

}  // namespace voxfmt::runtime
