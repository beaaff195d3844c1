// Template parts of query.h: the breadth-first sphere-tree traversal shared by every kind of partner.
#pragma once

#include <Eigen/Geometry>

#include <algorithm>

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
  std::vector<uint32_t>& queue = scratch.queue;
  std::vector<QueryScratch::Hit>& hits = scratch.level_hits;
  std::vector<uint32_t>& parents = scratch.level_parents;
  queue.clear();
  hits.clear();
  parents.clear();
  if (tree.size() == 0) return;
  const bool spheres = options.cut_level == CutLevel::Spheres;
  const bool has_reach = tree.reach_from_parent.size() == tree.size();
  // With sphere semantics a level's hits wait for the level's end: if the traversal stops there, a point whose
  // children were queued (never tested) reports its sphere instead.
  auto flush = [&]() {
    for (const QueryScratch::Hit& hit : hits) emit(hit.node, hit.distance, hit.exact);
    hits.clear();
    parents.clear();
  };
  queue.push_back(0);
  size_t head = 0;
  size_t level_end = 1;  // queue position where the current level ends
  uint32_t level = 0;
  size_t tested = 0;
  while (head < queue.size()) {
    if (head == level_end) {
      const size_t next_level_size = queue.size() - head;
      if (level + 1 > options.max_level || tested + next_level_size > options.point_budget) break;
      if (spheres) flush();
      ++level;
      level_end = queue.size();
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
  if (spheres) {
    const bool cut = queue.size() > level_end;  // children of this level were queued but not tested
    if (cut) {
      // The level's points with untested children report their spheres (which hold those points' hits).
      for (const QueryScratch::Hit& hit : hits)
        if (!std::binary_search(parents.begin(), parents.end(), hit.node)) emit(hit.node, hit.distance, hit.exact);
      for (const uint32_t node : parents) {
        bool exact = false;
        const float radius = tree.sphere_radii[node] * radius_scale;
        const float d = target.distance(M * tree.sphere_centers[node] + m, exact) - radius;
        if (d < proximity) emit(node, d, false);
      }
      hits.clear();
      parents.clear();
    } else {
      flush();
    }
  }
  stats.points_tested += tested;
  stats.deepest_level = std::max(stats.deepest_level, level);
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
