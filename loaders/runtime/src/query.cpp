#include "voxfmt/runtime/query.h"

#include <Eigen/Geometry>

#include <cmath>
#include <functional>

#include "core/field.h"
#include "traversal/eigen.h"
#include "traversal/field_simd.h"
#include "traversal/traversal.h"

namespace voxfmt::runtime {

QueryScratch::QueryScratch() : buffers_(std::make_unique<Buffers>()) {}
QueryScratch::~QueryScratch() = default;
QueryScratch::QueryScratch(QueryScratch&&) noexcept = default;
QueryScratch& QueryScratch::operator=(QueryScratch&&) noexcept = default;
void QueryScratch::record_tested_points(std::vector<Eigen::Vector3f>* into) { buffers_->tested_points = into; }

TraversalFront::TraversalFront() : state_(std::make_unique<State>()) {}
TraversalFront::~TraversalFront() = default;
TraversalFront::TraversalFront(TraversalFront&&) noexcept = default;
TraversalFront& TraversalFront::operator=(TraversalFront&&) noexcept = default;
void TraversalFront::reset() { state_->reset(); }

namespace {

// A voxelmap as a traversal target: the core's lookups, inlined into the walk.
struct VoxelmapTarget {
  core::Field field;
  float lower_bound(const Eigen::Vector3f& u) const { return core::lower_bound(field, core::to_core(u)); }
  void lower_bounds(const Eigen::Vector3f* u, size_t n, float* out) const {
    core::lower_bounds_dispatched(field, reinterpret_cast<const core::Vec3*>(u), n, out);
  }
  /// A bound costs one voxel, a sample up to eight: test a point's bound before sampling it.
  static constexpr bool kBoundBeforeDistance = true;
  /// Whether a sample computes the gradient too (gradient normals: the contact's normal then needs no second
  /// sample at the same point).
  bool gradients = false;
  bool tricubic = false;  ///< QueryOptions::interpolation
  /// Tricubic steps where it gives way to trilinear: no slope bound for a coherent query (traverse_coherent).
  bool sampled_bounds_hold() const { return !tricubic; }
  void sample(const Eigen::Vector3f& u, QueryScratch::Buffers::Hit& hit) const {
    core::Vec3 g = core::make_vec3(0, 0, 0);
    const core::Sample s = tricubic ? core::sample_tricubic(field, core::to_core(u), gradients ? &g : nullptr)
                                    : core::sample(field, core::to_core(u), gradients ? &g : nullptr);
    hit.distance = s.distance;
    hit.exact = s.exact;
    hit.has_gradient = gradients;
    hit.gradient = core::to_eigen(g);
  }
};

// `shell` carries the points, `field` the voxelmap. Contacts are expressed for the pair (A, B) given by the
// caller: if the shell is B's, the separating direction for A is the opposite of the shell object's.
void shell_in_field(const CollisionObject& shell, const Pose& shell_pose, const CollisionObject& field,
                    const Pose& field_pose, bool shell_is_b, const QueryOptions& options, ContactSet& out,
                    QueryScratch& scratch, TraversalFront* front) {
  if (!shell.has_point_shell() || !field.has_voxelmap()) return;
  const SparseVoxelmap& map = field.voxelmap();
  const PointTree& tree = shell.point_tree();
  // shell points (from its anchor) -> world -> field asset frame -> field grid (voxel units): the query core's frame.
  const double origin[3] = {map.origin().x(), map.origin().y(), map.origin().z()};
  const core::Shell core_shell = core::shell_of(tree);
  const core::RigidPose core_shell_pose = core::anchored(core::to_core(shell_pose), core_shell.anchor),
                        core_field_pose = core::to_core(field_pose);
  const Pose points_pose = core::to_eigen(core_shell_pose);
  const core::Frame frame =
      core::frame_of(core_shell_pose, core_field_pose, origin, map.voxel_size(), options.proximity);
  const double metres_per_unit = frame.metres_per_unit;
  const double sign = shell_is_b ? -1.0 : 1.0;

  // Normals as the batched core computes them (one definition: core::contact_normal).
  const core::Field core_field = field_of(map);
  const bool gradient_normals = options.normal_source == NormalSource::DistanceGradient;
  auto emit = [&](const QueryScratch::Buffers::Hit& hit) {
    Contact contact;
    contact.point = points_pose.apply(tree.points[hit.node].cast<double>());
    double normal[3];
    const core::Vec3 gradient = core::to_core(hit.gradient);
    core::contact_normal(core_field, frame, core_field_pose, core_shell, core_shell_pose, hit.node, gradient_normals,
                         hit.has_gradient ? &gradient : nullptr, normal);
    contact.normal = sign * Eigen::Vector3d(normal[0], normal[1], normal[2]);
    contact.depth = -double(hit.distance) * metres_per_unit;
    contact.point_index = hit.node;
    contact.point_of_b = shell_is_b;
    contact.exact = hit.exact;
    out.contacts.push_back(contact);
  };
  const VoxelmapTarget target{core_field, gradient_normals, options.interpolation == Interpolation::Tricubic};
  const bool allowed = front && detail::coherent_query_allowed(options);
  // The voxelmap is fixed in its own grid: displacements are measured there too.
  const Eigen::Matrix3f M = core::to_eigen(frame.to_grid);
  const Eigen::Vector3f m = core::to_eigen(frame.to_grid.m);
  // A pose that is not finite (a simulation that blew up) never anchors a front: its bounds would hold nothing.
  const bool coherent = allowed && M.allFinite() && m.allFinite();
  if (coherent) front->state().bind(shell.id(), field.id(), int(options.interpolation));
  if (coherent && front->state().take_turn(M, m, tree.extent)) {
    detail::traverse_coherent(tree, frame, M, m, target, out.stats, scratch.buffers(), front->state(), emit);
  } else {
    if (front && !coherent) front->reset();
    detail::traverse_tree(tree, frame, target, options, out.stats, scratch.buffers(), emit);
  }
}

}  // namespace

QueryDirection resolve_direction(const CollisionObject& a, const Pose& pose_a, const CollisionObject& b,
                                 const Pose& pose_b, QueryDirection requested, DirectionTie tie) {
  if (requested != QueryDirection::Auto) return requested;
  const double ta[3] = {pose_a.translation[0], pose_a.translation[1], pose_a.translation[2]};
  const double tb[3] = {pose_b.translation[0], pose_b.translation[1], pose_b.translation[2]};
  const int choice =
      core::auto_direction(a.has_point_shell() && b.has_voxelmap(), b.has_point_shell() && a.has_voxelmap(),
                           a.bounding_radius() * pose_a.scale, b.bounding_radius() * pose_b.scale,
                           a.point_tree().size(), b.point_tree().size(), ta, tb);
  const bool b_points =
      choice != 0 ? choice > 0 : tie == DirectionTie::ByAddress && std::less<const CollisionObject*>()(&b, &a);
  return b_points ? QueryDirection::BPointsInA : QueryDirection::APointsInB;
}

void query_contacts(const CollisionObject& a, const Pose& pose_a, const CollisionObject& b, const Pose& pose_b,
                    const QueryOptions& options, ContactSet& out, QueryScratch& scratch) {
  const QueryDirection direction = resolve_direction(a, pose_a, b, pose_b, options.direction);
  if (direction == QueryDirection::APointsInB || direction == QueryDirection::Both)
    shell_in_field(a, pose_a, b, pose_b, false, options, out, scratch, nullptr);
  if (direction == QueryDirection::BPointsInA || direction == QueryDirection::Both)
    shell_in_field(b, pose_b, a, pose_a, true, options, out, scratch, nullptr);
}

void query_contacts(const CollisionObject& a, const Pose& pose_a, const CollisionObject& b, const Pose& pose_b,
                    const QueryOptions& options, ContactSet& out, QueryScratch& scratch, QueryState& state) {
  const QueryDirection direction = resolve_direction(a, pose_a, b, pose_b, options.direction);
  // A direction not queried keeps its front: it measures motion from its own pose, whenever it is used again.
  if (direction == QueryDirection::APointsInB || direction == QueryDirection::Both)
    shell_in_field(a, pose_a, b, pose_b, false, options, out, scratch, &state.a_in_b);
  if (direction == QueryDirection::BPointsInA || direction == QueryDirection::Both)
    shell_in_field(b, pose_b, a, pose_a, true, options, out, scratch, &state.b_in_a);
}

void query_points_in_voxelmap(const CollisionObject& a, const Pose& pose_a, const Eigen::Vector3d* points, size_t count,
                              double radius, const QueryOptions& options, ContactSet& out) {
  if (!a.has_voxelmap()) return;
  const SparseVoxelmap& map = a.voxelmap();
  const double metres_per_unit = pose_a.scale * map.voxel_size();
  const bool tricubic = options.interpolation == Interpolation::Tricubic && !map.empty();
  const core::Field field = field_of(map);
  for (size_t i = 0; i < count; ++i) {
    const Eigen::Vector3d asset = pose_a.rotation.transpose() * (points[i] - pose_a.translation) / pose_a.scale;
    Eigen::Vector3f gradient;
    core::Vec3 g = core::make_vec3(0, 0, 0);
    const FieldSample s = tricubic ? core::sample_tricubic(field, core::to_core(map.to_grid(asset)), &g)
                                   : map.sample(map.to_grid(asset), &gradient);
    if (tricubic) gradient = core::to_eigen(g);
    ++out.stats.points_tested;
    const double distance = double(s.distance) * metres_per_unit - radius;
    if (!(distance < options.proximity) || gradient.squaredNorm() == 0.0f) continue;  // NaN radius or proximity: none
    // A lower bound cannot confirm a contact (a large sphere's centre far outside A); A's own points against
    // the partner find those.
    if (s.bound && s.distance > 0.0f) continue;
    const Eigen::Vector3d outward = pose_a.rotation * gradient.cast<double>().normalized();
    Contact contact;
    contact.point = points[i] - radius * outward;
    contact.normal = -outward;
    contact.depth = -distance;
    contact.point_index = uint32_t(i);
    contact.point_of_b = true;
    contact.exact = s.exact;
    out.contacts.push_back(contact);
  }
}

void query_contacts(const CollisionObject& a, const Pose& pose_a, const CollisionObject& b, const Pose& pose_b,
                    const QueryOptions& options, ContactSet& out) {
  QueryScratch scratch;
  query_contacts(a, pose_a, b, pose_b, options, out, scratch);
}

}  // namespace voxfmt::runtime
