// Queries of a point shell against an analytic partner's signed-distance function (planes, boxes, spheres,
// triangle meshes): the same traversal as against a voxelmap (traversal.h), for the loaders built with the
// runtime (Bullet's partners). Private: not installed.
#pragma once

#include <type_traits>

#include "traversal.h"

namespace voxfmt::runtime {

/// One sphere-tree traversal of `shell_object`'s points against a signed distance function given in world
/// coordinates. `distance(world_point, outward_normal)` returns the signed distance (negative inside the
/// partner) and writes the partner's outward unit normal. Contacts are reported with A = `shell_object` (normal:
/// the direction in which it must move).
template <class SignedDistance>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, SignedDistance&& distance,
                            const QueryOptions& options, ContactSet& out, QueryScratch& scratch);
/// The same with a cheaper `lower_bound(world_point)` (never above the signed distance) used to prune sphere-tree
/// clusters, for partners whose exact distance is expensive far away (triangle meshes). A bound much cheaper than
/// the distance everywhere says so in its type (`static constexpr bool kBoundBeforeDistance = true`): inner
/// nodes' points are then tested on their bound before their distance, as against a voxelmap.
template <class SignedDistance, class LowerBound>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, SignedDistance&& distance,
                            LowerBound&& lower_bound, const QueryOptions& options, ContactSet& out,
                            QueryScratch& scratch);
/// The same, coherent with the pair's earlier queries (`front`): `partner` is the rigid partner's pose in the
/// world (its distance function moves with it), so that only their relative motion counts. Coherence carries the
/// bound's values (and the function's) from pose to pose as the motion allows, so both must keep the partner's
/// pose fixed between calls: `distance(y)` is not below `lower_bound(x) - |y - x|` for any y.
template <class SignedDistance>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, const Pose& partner,
                            SignedDistance&& distance, const QueryOptions& options, ContactSet& out,
                            QueryScratch& scratch, TraversalFront& front);
template <class SignedDistance, class LowerBound>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, const Pose& partner,
                            SignedDistance&& distance, LowerBound&& lower_bound, const QueryOptions& options,
                            ContactSet& out, QueryScratch& scratch, TraversalFront& front);

namespace detail {

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
  /// The function's value and outward normal (kept in the hit: a contact needs no second evaluation, which for a
  /// triangle set or a convex shape is a search).
  void sample(const Eigen::Vector3f& u, QueryScratch::Buffers::Hit& hit) const {
    Eigen::Vector3f normal = Eigen::Vector3f::Zero();
    hit.distance = function(u, normal);
    hit.exact = true;
    hit.has_gradient = true;
    hit.gradient = normal;
  }
};

/// What a walk against a partner's function reports: each point as a contact of A (the shell), its normal the
/// point's own or the partner's outward one where it was sampled (QueryOptions::normal_source; a cut level's sphere,
/// sampled at its centre, takes it at the point).
template <class SignedDistance>
auto function_contacts(const PointTree& tree, const Pose& pose, SignedDistance& distance, const QueryOptions& options,
                       ContactSet& out) {
  return [&tree, &pose, &distance, &options, &out](const QueryScratch::Buffers::Hit& hit) {
    const uint32_t node = hit.node;
    Contact contact;
    contact.point = pose.apply(tree.points[node].cast<double>());
    Eigen::Vector3f outward = hit.gradient;
    if (!hit.has_gradient) distance(contact.point.cast<float>(), outward);
    if (options.normal_source == NormalSource::PointShell || outward.squaredNorm() == 0.0f)
      contact.normal = (pose.rotation * tree.normals[node].cast<double>()).normalized();
    else
      contact.normal = outward.cast<double>().normalized();
    contact.depth = -double(hit.distance);
    contact.point_index = node;
    contact.exact = hit.exact;
    out.contacts.push_back(contact);
  };
}

}  // namespace detail

template <class SignedDistance, class LowerBound>
void query_against_function(const CollisionObject& shell_object, const Pose& pose, SignedDistance&& distance,
                            LowerBound&& lower_bound, const QueryOptions& options, ContactSet& out,
                            QueryScratch& scratch) {
  if (!shell_object.has_point_shell()) return;
  const PointTree& tree = shell_object.point_tree();
  const Pose placed = core::anchored(pose, tree);  // the points are from the tree's anchor
  const Eigen::Matrix3f M = (placed.rotation * placed.scale).cast<float>();
  const Eigen::Vector3f m = placed.translation.cast<float>();
  detail::FunctionTarget<std::remove_reference_t<SignedDistance>, std::remove_reference_t<LowerBound>> target{
      distance, lower_bound};
  detail::traverse_tree(tree, core::frame_from(M, m, float(placed.scale), float(options.proximity)), target, options,
                        out.stats, scratch.buffers(), detail::function_contacts(tree, placed, distance, options, out));
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
  const Pose placed = core::anchored(pose, tree);  // the points are from the tree's anchor
  const Eigen::Matrix3f M = (placed.rotation * placed.scale).cast<float>();
  const Eigen::Vector3f m = placed.translation.cast<float>();
  // Displacements in the partner's frame, where its distance function is fixed.
  const Eigen::Matrix3f Mr = (partner.rotation.transpose() * placed.rotation * placed.scale).cast<float>();
  const Eigen::Vector3f mr = (partner.rotation.transpose() * (placed.translation - partner.translation)).cast<float>();
  // The partner's function has no identity here (0): its pair keeps its front.
  front.state().bind(shell_object.id(), 0);
  if (!front.state().take_turn(Mr, mr, tree.extent)) {
    query_against_function(shell_object, pose, distance, lower_bound, options, out, scratch);
    return;
  }
  detail::FunctionTarget<std::remove_reference_t<SignedDistance>, std::remove_reference_t<LowerBound>> target{
      distance, lower_bound};
  detail::traverse_coherent(tree, core::frame_from(M, m, float(placed.scale), float(options.proximity)), Mr, mr, target,
                            out.stats, scratch.buffers(), front.state(),
                            detail::function_contacts(tree, placed, distance, options, out));
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
