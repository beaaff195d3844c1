// Template parts of query.h: the breadth-first sphere-tree traversal shared by every kind of partner.
#pragma once

#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>

namespace voxfmt::runtime {
namespace detail {

/// Breadth-first traversal of `tree` mapped into a target frame by u = M * x + m (lengths scale by
/// `radius_scale`). The target supplies `lower_bound(u)` (never above the true signed distance) and
/// `distance(u, exact)`, both in target units. Calls emit(node, distance, exact) for every tested point
/// closer than `proximity` (target units).
template <class Target, class Emit>
void traverse_tree(const PointTree& tree, const Eigen::Matrix3f& M, const Eigen::Vector3f& m, float radius_scale,
                   float proximity, const Target& target, const QueryOptions& options, QueryStats& stats,
                   QueryScratch& scratch, Emit&& emit) {
  using Hit = QueryScratch::Hit;
  std::vector<uint32_t>& queue = scratch.queue;
  // Sphere semantics hold a level's hits back until it is known whether the level ends the traversal: the
  // current level's (partial) and the last completed level's. A point whose children were queued but never
  // tested reports its sphere instead of itself.
  std::vector<Hit>& hits = scratch.level_hits;
  std::vector<uint32_t>& parents = scratch.level_parents;
  std::vector<Hit>& done_hits = scratch.done_hits;
  std::vector<uint32_t>& done_parents = scratch.done_parents;
  queue.clear();
  hits.clear();
  parents.clear();
  done_hits.clear();
  done_parents.clear();
  if (tree.size() == 0) return;
  const bool spheres = options.cut_level == CutLevel::Spheres;
  const bool has_reach = tree.reach_from_parent.size() == tree.size();
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
      const float radius = tree.sphere_radii[node] * radius_scale;
      const float d = target.distance(M * tree.sphere_centers[node] + m, exact) - radius;
      if (d < proximity) emit(node, d, false);
    }
  };
  queue.push_back(0);
  size_t head = 0;
  size_t level_end = 1;  // queue position where the current level ends
  uint32_t level = 0;
  size_t tested = 0;
  bool out_of_time = false;
  while (head < queue.size()) {
    if (head == level_end) {  // `level` is complete
      const size_t next_level_size = queue.size() - head;
      if (level + 1 > options.max_level || tested + next_level_size > options.point_budget) break;
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
      ++level;
      level_end = queue.size();
    }
    // The clock is read every 32 nodes (a few ns each) and at level ends; the root level always completes.
    if (timed && level > 0 && (stats.nodes_visited & 31u) == 0 && std::chrono::steady_clock::now() >= deadline) {
      out_of_time = true;
      break;
    }
    const uint32_t node = queue[head++];
    ++stats.nodes_visited;
    const Eigen::Vector3f centre = M * tree.sphere_centers[node] + m;
    // The sphere holds the node's point and all its descendants; the distance is 1-Lipschitz, so if even
    // the lower bound at the centre exceeds the radius nothing below can be within reach.
    const float bound = target.lower_bound(centre);
    if (bound > tree.sphere_radii[node] * radius_scale + proximity) continue;
    ++tested;
    bool exact = false;
    const Eigen::Vector3f u = M * tree.points[node] + m;
    if (scratch.tested_points) scratch.tested_points->push_back(u);
    const float d = target.distance(u, exact);
    if (d < proximity) {
      if (spheres)
        hits.push_back({node, d, exact});
      else
        emit(node, d, exact);
    }
    // The same bound, carried from this centre to each child's sphere, drops children out of reach before any
    // lookup of theirs.
    const uint32_t begin = tree.child_begin[node], count = tree.child_count[node];
    const size_t queued = queue.size();
    for (uint32_t c = begin; c < begin + count; ++c)
      if (!has_reach || bound - tree.reach_from_parent[c] * radius_scale <= proximity) queue.push_back(c);
    if (spheres && queue.size() > queued) parents.push_back(node);
  }
  uint32_t completed = level;
  if (out_of_time && head != level_end) {
    // Stopped inside `level`: its partial hits are dropped, the level before is the cut (sphere semantics).
    completed = level - 1;
    if (spheres) emit_cut(done_hits, done_parents);
  } else if (spheres) {
    emit_points(done_hits);
    if (queue.size() > level_end)  // children of this level were queued but not tested
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
