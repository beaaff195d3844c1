// Template parts of query.h: the breadth-first sphere-tree traversal shared by every kind of partner.
#pragma once

#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>

namespace voxfmt::runtime {
namespace detail {

/// Breadth-first traversal of `tree` mapped into a target frame by u = M * x + m (lengths scale by
/// `radius_scale`). The target supplies `lower_bound(u)` (never above the true signed distance),
/// `distance(u, exact)`, both in target units; `kBoundBeforeDistance` says whether a point's bound is worth
/// testing before its distance, `prefetch_header(u)` and `prefetch_voxel(u)` start loading what a lookup at u
/// reads (no-ops for analytic targets). Calls emit(node, distance, exact) for every tested point closer than
/// `proximity` (target units).
///
/// A level is processed in batches of kBatch nodes, each in two passes (sphere bounds, then the points that
/// survive): the lookups of one pass are independent of each other, and prefetched in two steps before it, so
/// their cache misses overlap instead of being paid one after another as in a node-at-a-time loop.
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
  frontier.clear();
  next.clear();
  hits.clear();
  parents.clear();
  done_hits.clear();
  done_parents.clear();
  if (tree.size() == 0) return;
  const PointTree::Node* nodes = tree.nodes.data();
  const Eigen::Vector3f* points = tree.points.data();
  const bool spheres = options.cut_level == CutLevel::Spheres;
  const bool timed = options.time_budget_us > 0.0;
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

  frontier.push_back(0);
  uint32_t level = 0;
  size_t tested = 0;
  bool out_of_time = false;
  bool level_done = false;  // the last level entered was completed
  for (;;) {
    level_done = false;
    for (size_t begin = 0; begin < frontier.size(); begin += kBatch) {
      // The clock is read before each batch; the root level always completes.
      if (timed && level > 0 && std::chrono::steady_clock::now() >= deadline) {
        out_of_time = true;
        break;
      }
      const size_t count = std::min(kBatch, frontier.size() - begin);
      const uint32_t* batch = frontier.data() + begin;
      // Pass 1: every sphere against the target's lower bound. The sphere holds the node's point and all its
      // descendants; the distance is 1-Lipschitz, so if even the lower bound at the centre exceeds the radius
      // nothing below can be within reach.
      for (size_t i = 0; i < count; ++i) {
        centre[i] = M * nodes[batch[i]].centre + m;
        target.prefetch_header(centre[i]);
      }
      for (size_t i = 0; i < count; ++i) target.prefetch_voxel(centre[i]);
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
      for (size_t i = 0; i < survivors; ++i) {
        __builtin_prefetch(&nodes[nodes[survivor[i]].first_child]);  // the children's reach, read below
        point[i] = M * points[survivor[i]] + m;
        target.prefetch_header(point[i]);
      }
      for (size_t i = 0; i < survivors; ++i) target.prefetch_voxel(point[i]);
      for (size_t i = 0; i < survivors; ++i) {
        const uint32_t node = survivor[i];
        const PointTree::Node& parent = nodes[node];
        if (scratch.tested_points) scratch.tested_points->push_back(point[i]);
        // A leaf's sphere is its point, whose bound pass 1 has just tested; an inner node's point is tested on
        // its own bound first where a distance costs more.
        if (!Target::kBoundBeforeDistance || parent.child_count == 0 || target.lower_bound(point[i]) < proximity) {
          bool exact = false;
          const float d = target.distance(point[i], exact);
          if (d < proximity) {
            if (spheres)
              hits.push_back({node, d, exact});
            else
              emit(node, d, exact);
          }
        }
        const size_t queued = next.size();
        for (uint32_t c = parent.first_child; c < parent.first_child + parent.child_count; ++c)
          if (bound[i] - nodes[c].reach_from_parent * radius_scale <= proximity) next.push_back(c);
        if (spheres && next.size() > queued) parents.push_back(node);
      }
      tested += survivors;
    }
    if (out_of_time) break;
    level_done = true;
    // `level` is complete: go on to the next one unless it is empty, too deep or over the point budget.
    if (next.empty() || level + 1 > options.max_level || tested + next.size() > options.point_budget) break;
    if (timed && std::chrono::steady_clock::now() >= deadline) {
      out_of_time = true;
      break;
    }
    if (spheres) {
      emit_points(done_hits);  // the level before is refined by this complete one
      done_hits.swap(hits);
      done_parents.swap(parents);
      hits.clear();
      parents.clear();
    }
    frontier.swap(next);
    next.clear();
    ++level;
  }
  uint32_t completed = level;
  if (out_of_time && !level_done) {
    // Stopped inside `level`: its partial hits are dropped, the level before is the cut (sphere semantics).
    completed = level - 1;
    if (spheres) emit_cut(done_hits, done_parents);
  } else if (spheres) {
    emit_points(done_hits);
    if (!next.empty())  // children of this level were queued but not tested
      emit_cut(hits, parents);
    else
      emit_points(hits);
  }
  if (out_of_time) stats.time_budget_hit = true;
  stats.points_tested += tested;
  stats.deepest_level = std::max(stats.deepest_level, completed);
}

/// A signed-distance function in world coordinates seen as a traversal target, with a cheaper lower bound
/// for pruning (or the function itself).
template <class SignedDistance, class LowerBound>
struct FunctionTarget {
  SignedDistance& function;
  LowerBound& bound;
  float lower_bound(const Eigen::Vector3f& u) const { return bound(u); }
  static constexpr bool kBoundBeforeDistance = false;
  void prefetch_header(const Eigen::Vector3f&) const {}
  void prefetch_voxel(const Eigen::Vector3f&) const {}
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
