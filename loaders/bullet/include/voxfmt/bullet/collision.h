// Registration of the VPS collision algorithm in a Bullet dispatcher.
//
//   btDefaultCollisionConstructionInfo info;
//   voxfmt::bullet::prepare_construction_info(info);           // pool slots large enough for the algorithm
//   btDefaultCollisionConfiguration config(info);
//   btCollisionDispatcher dispatcher(&config);
//   auto vps = voxfmt::bullet::register_vps_collision(dispatcher);  // keep alive as long as the dispatcher
//
// Pairs handled (both orders, simulation and closest-point tables): VPS-VPS; VPS against any convex shape
// (box, sphere, capsule, cylinder, cone, convex hull, multi-sphere, ...), a static plane, a static triangle
// mesh (btBvhTriangleMeshShape, scaled or not) or a terrain (btHeightfieldTerrainShape); compounds through
// Bullet's compound algorithm, child by child, with VPS or convex children. Any other pair with a VPS shape
// produces no contacts and is reported once per shape type (CollisionSettings::on_unsupported_pair).
#pragma once

#include <BulletCollision/CollisionDispatch/btCollisionDispatcher.h>
#include <BulletCollision/CollisionDispatch/btDefaultCollisionConfiguration.h>
#include <BulletCollision/CollisionShapes/btConvexShape.h>
#include <LinearMath/btTransform.h>

#include <Eigen/Core>

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "voxfmt/runtime/query.h"

namespace voxfmt::bullet {

/// The query a pair test runs unless CollisionSettings::query says otherwise: the runtime's defaults but for one,
/// for a physics engine's sake: a cut level reports the level's own points with their true depths, not spheres
/// (CollisionSettings::query, cut_level). Normals are the runtime's default, the partner's distance gradient
/// (runtime::NormalSource says why).
runtime::QueryOptions physics_query_defaults();

struct CollisionSettings {
  /// The query of every pair test (runtime::QueryOptions), held whole rather than copied field by field:
  /// - direction: which object's points go against which voxelmap in a VPS-VPS pair (Auto: the smaller object's).
  /// - normal_source: DistanceGradient (the runtime's default; runtime::NormalSource says why), PointShell for
  ///   classical VPS.
  /// - proximity: points closer than this (metres) become speculative contacts with positive distance, so the
  ///   solver slows an approaching body before it penetrates. 0 = penetrating points only. A pair uses the largest
  ///   of this, Bullet's closest-point threshold, either shape's own and the speculative distance of the step.
  /// - cut_level: what the last level of a shell cut above its leaves (VpsShape::set_max_level, set_point_budget,
  ///   the step budget, or max_level / point_budget here) reports. Points (default here): the level's own surface
  ///   points, with their true depths: a coarse body rests a little deeper between its points but never deeper
  ///   than its surface is. Spheres: each point stands for its sphere, up to two sphere radii deeper than the
  ///   surface; the solver turns that extra depth into energy (a coarse bunny dropped on a bunny was thrown off at
  ///   51 m/s), so use it for detection, not for dynamics.
  /// - max_level, point_budget, time_budget_us, min_points: limits of every shell's traversal; a shape's own
  ///   limits (VpsShape::set_max_level, set_point_budget) and the step budget apply on top (the tighter wins).
  runtime::QueryOptions query = physics_query_defaults();
  /// Speculative contacts against tunnelling: during a dynamics step, points as close as the pair can come in
  /// that step (relative speed plus spin times radius, times the step) become contacts with a positive
  /// distance, which Bullet's solver lets close only that gap. A body at 10 m/s at 1 kHz stays in front of a
  /// 2-voxel wall. Off: only `query.proximity` applies, and a fast body can pass through a wall thinner than its
  /// motion in one step.
  bool speculative_contacts = true;
  /// Contacts handed to Bullet's persistent manifold per pair, region and step (at most 4, Bullet keeps 4).
  size_t manifold_points = 4;
  /// Contact regions per pair (1-4), each with a persistent manifold of its own: a pair touching in several
  /// places (a body across another, a peg against a hole's wall) keeps points in each, where one manifold's four
  /// points would leave the others to sink in before they are seen. Contacts fall into regions by their cell
  /// in the point-carrying body's frame (cells as wide as its bounding radius), so a contact keeps its region
  /// and its manifold from step to step.
  size_t contact_regions = 4;
  /// Time budget of one step's VPS pair tests together, microseconds (0 = none): a frame rate the narrow phase
  /// keeps whatever piles up. It moves a level cap shared by every shell, as a haptic loop's does: after a step
  /// whose pair tests took longer, every shell is tested one tree level less deep; after 50 steps under half the
  /// budget, one level deeper again, up to the leaves. A cap reports its level as `query.cut_level` says (Points, the
  /// default: the level's own points at their true depths, so a cut body never reports a contact deeper than its
  /// surface and a moving cap never adds depth the surface does not have), and holds for many steps, so a body
  /// rests on a fixed set of points. Within the budget the pairs are full and coherent; a step may overrun by what
  /// changed since the one before. Steps start at VpsCollisionRegistration::begin_step(), which World calls as its
  /// narrow phase starts; with a world of your own, call it before each step (e.g. from a pre-tick callback).
  double step_time_budget_us = 0.0;
  /// Under a step time budget, the tree levels within this many points tested are always tested, however late
  /// the steps run (the seed's coarse shell is ~800 points): a budget never leaves a body too few points to stand
  /// on. Shapes with a level or point budget of their own (VpsShape::set_max_level, set_point_budget) keep it and
  /// are not cut further.
  size_t step_budget_min_points = 1000;
  /// Temporal coherence: each pair keeps the sphere-tree front of its last query (runtime::QueryState, dropped
  /// with the pair when it leaves the broadphase) and looks up only what the motion since can have brought within
  /// reach: the same contacts, and a body at rest costs about its contact points a step. Pairs against a terrain
  /// or an unindexed static mesh (static_mesh_index off) keep their front while they gather the same triangles
  /// near the body (at rest) and query from the root when those change; shapes limited to a tree level or point
  /// budget query from the root.
  bool coherent = true;
  /// Static triangle meshes (btBvhTriangleMeshShape, scaled or not) are indexed once, the first time a VPS body
  /// meets one (or ahead of time: VpsCollisionRegistration::prepare_static_mesh, which World::add_body calls for
  /// static meshes): every triangle in the shape's frame, binned in cells about a triangle's size, shared by every
  /// pair and thread. A pair's points then look up the nearest triangle in the index (coherently) and nothing is
  /// gathered per step. A mesh whose triangles change must be forgotten (forget_static_mesh) to be indexed anew;
  /// a rescaled or refitted mesh (a new box) is noticed. Off: each test gathers the triangles in the body's box
  /// through Bullet and grids them (terrains always do: their heights may change under Bullet's feet).
  bool static_mesh_index = true;
  /// Called with every pair test's contacts before they are reduced to the manifold's points (tests, debugging
  /// views): `a` is the VPS body the contacts' normals push (Contact::normal), `b` its partner. Empty: not called.
  /// With a multi-threaded dispatcher it is called on the dispatcher's threads.
  std::function<void(const btCollisionObject* a, const btCollisionObject* b, const runtime::ContactSet& contacts)>
      on_contacts;
  /// Called once per Bullet shape type that meets a VPS shape without an algorithm for the pair (such pairs
  /// produce no contacts). Default (empty): the message goes to stderr. With a multi-threaded dispatcher it is
  /// called on the dispatcher's threads, possibly on two at once for two shape types.
  std::function<void(const std::string& message)> on_unsupported_pair;
};

/// A count that several threads may add to at once and that reads, copies and resets like a plain integer.
/// Relaxed atomic: the sum is exact, no ordering is implied (read it once the threads are done, e.g. between
/// steps).
class SharedCount {
 public:
  constexpr SharedCount(uint64_t value = 0) noexcept : value_(value) {}
  SharedCount(const SharedCount& other) noexcept : value_(other.load()) {}
  SharedCount& operator=(const SharedCount& other) noexcept {
    value_.store(other.load(), std::memory_order_relaxed);
    return *this;
  }
  uint64_t load() const noexcept { return value_.load(std::memory_order_relaxed); }
  operator uint64_t() const noexcept { return load(); }
  SharedCount& operator+=(uint64_t n) noexcept {
    value_.fetch_add(n, std::memory_order_relaxed);
    return *this;
  }
  SharedCount& operator++() noexcept { return *this += 1; }

 private:
  std::atomic<uint64_t> value_;
};

/// Narrow-phase counters, summed over all VPS pairs since the last reset (`counters = {}`), whichever threads
/// the dispatcher runs the pairs on.
struct CollisionCounters {
  SharedCount pair_tests = 0;
  SharedCount raw_contacts = 0;        ///< contacts found by the queries before reduction
  SharedCount points_tested = 0;       ///< point-shell points whose distance was looked up
  SharedCount nodes_visited = 0;       ///< sphere-tree nodes whose bound was looked up (pruning)
  SharedCount unsupported_pairs = 0;   ///< pair tests with a partner shape the algorithm cannot handle
  SharedCount budget_cuts = 0;         ///< pair tests whose shell the step time budget cut above its leaves
  SharedCount static_mesh_builds = 0;  ///< static mesh indexes built (CollisionSettings::static_mesh_index)
};

/// A static mesh's index (CollisionSettings::static_mesh_index).
struct StaticMeshInfo {
  size_t triangles = 0;
  size_t vertices = 0;       ///< distinct vertices (tested in the VPS bodies' voxelmaps)
  size_t cells = 0;          ///< cells of its grid
  size_t memory_bytes = 0;   ///< what it holds
  double build_seconds = 0;  ///< what building it took
};

/// Thread safety: the algorithm's only shared mutable state is these atomic counters, and its scratch memory is
/// per thread, so a multi-threaded dispatcher (btCollisionDispatcherMt, voxfmt/bullet/world.h) may run any
/// pairs at once, many bodies sharing one CollisionObject. Change the settings between steps only: every pair
/// test reads them.
class VpsCollisionRegistration {
 public:
  virtual ~VpsCollisionRegistration() = default;
  virtual CollisionSettings& settings() = 0;
  virtual CollisionCounters& counters() = 0;
  /// Marks the start of a step's narrow phase, for CollisionSettings::step_time_budget_us (World calls it). Not
  /// to be called while pairs are being tested.
  virtual void begin_step() = 0;
  /// Indexes a static triangle mesh now rather than when a VPS body first meets it (CollisionSettings::
  /// static_mesh_index); an index already built for it is reused. Other shapes: nothing is built (all zero).
  virtual StaticMeshInfo prepare_static_mesh(const btCollisionShape& shape) = 0;
  /// Drops the mesh's index: after its triangles changed, or before the shape is deleted (an index holds no
  /// pointer into the mesh, but keeps its memory until forgotten or the registration goes). Pairs that use it
  /// index it again at their next test. Not to be called while pairs are being tested.
  virtual void forget_static_mesh(const btCollisionShape& shape) = 0;
};

/// Registers the VPS algorithm for every supported pair in `dispatcher`. The returned object owns the create
/// functions and settings: keep it alive while the dispatcher is in use.
std::unique_ptr<VpsCollisionRegistration> register_vps_collision(btCollisionDispatcher& dispatcher,
                                                                 const CollisionSettings& settings = {});

/// Makes the dispatcher's algorithm pool slots large enough for the VPS algorithm (Bullet silently overruns
/// a slot that is too small). Call before constructing btDefaultCollisionConfiguration.
void prepare_construction_info(btDefaultCollisionConstructionInfo& info);

// ---- The partners' distances. Signed distances from a world point to the shapes a VPS body meets in Bullet, each
// with the partner's outward unit normal at its nearest surface point: what a point shell is tested against.
// Negative inside the partner. The collision algorithm uses these; they are public for users who query partners
// themselves (haptics, planning) and for tests.

/// Half-space below the plane n.x = c (n unit).
float plane_distance(const Eigen::Vector3f& normal, float constant, const Eigen::Vector3f& x, Eigen::Vector3f& outward);
/// Oriented box: `rotation` (box axes as columns), `centre`, `half` extents.
float box_distance(const Eigen::Matrix3f& rotation, const Eigen::Vector3f& centre, const Eigen::Vector3f& half,
                   const Eigen::Vector3f& x, Eigen::Vector3f& outward);
float sphere_distance(const Eigen::Vector3f& centre, float radius, const Eigen::Vector3f& x, Eigen::Vector3f& outward);
/// Capsule: all points within `radius` of the segment a-b.
float capsule_distance(const Eigen::Vector3f& a, const Eigen::Vector3f& b, float radius, const Eigen::Vector3f& x,
                       Eigen::Vector3f& outward);
/// Cylinder: `centre`, unit `axis`, `radius`, `half_height` along the axis.
float cylinder_distance(const Eigen::Vector3f& centre, const Eigen::Vector3f& axis, float radius, float half_height,
                        const Eigen::Vector3f& x, Eigen::Vector3f& outward);
/// Convex polyhedron given by outward face planes n.x + d <= 0 (world frame), rounded outward by `margin`:
/// exact inside (the nearest face plane); outside it returns false and leaves the distance to the caller.
bool polyhedron_inside_distance(const std::vector<Eigen::Vector4f>& planes, float margin, const Eigen::Vector3f& x,
                                float& distance, Eigen::Vector3f& outward);
/// Any btConvexShape, collision margin included, by Bullet's GJK (outside) and EPA (inside). Returns +infinity
/// where GJK gives up (a point on the surface, within GJK's tolerance).
float convex_distance(const btConvexShape& shape, const btTransform& world_from_shape, const Eigen::Vector3f& x,
                      Eigen::Vector3f& outward);

}  // namespace voxfmt::bullet
