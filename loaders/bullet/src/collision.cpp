#include "voxfmt/bullet/collision.h"

#include <BulletCollision/BroadphaseCollision/btCollisionAlgorithm.h>
#include <BulletCollision/CollisionDispatch/btCollisionCreateFunc.h>
#include <BulletCollision/CollisionDispatch/btCollisionObjectWrapper.h>
#include <BulletCollision/CollisionDispatch/btManifoldResult.h>
#include <BulletCollision/CollisionShapes/btBoxShape.h>
#include <BulletCollision/CollisionShapes/btCapsuleShape.h>
#include <BulletCollision/CollisionShapes/btConcaveShape.h>
#include <BulletCollision/CollisionShapes/btConvexPolyhedron.h>
#include <BulletCollision/CollisionShapes/btCylinderShape.h>
#include <BulletCollision/CollisionShapes/btHeightfieldTerrainShape.h>
#include <BulletCollision/CollisionShapes/btMultiSphereShape.h>
#include <BulletCollision/CollisionShapes/btPolyhedralConvexShape.h>
#include <BulletCollision/CollisionShapes/btSphereShape.h>
#include <BulletCollision/CollisionShapes/btStaticPlaneShape.h>
#include <BulletCollision/CollisionShapes/btTriangleCallback.h>
#include <BulletCollision/NarrowPhaseCollision/btPersistentManifold.h>
#include <BulletDynamics/Dynamics/btRigidBody.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <mutex>
#include <new>
#include <string>
#include <unordered_map>

#include "bt_eigen.h"
#include "partner_pairs.h"
#include "static_mesh.h"
#include "traversal/function_query.h"
#include "triangle_set.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/runtime/detail/contact_reduction.h"

namespace voxfmt::bullet {
namespace {

using namespace detail;

struct Shared {
  CollisionSettings settings;
  // On a line of their own: the counters change with every pair test, the settings are read by every one.
  alignas(64) CollisionCounters counters;
  std::atomic<uint64_t> reported_types{0};  // one bit per Bullet shape type already reported as unsupported

  // The step time budget (CollisionSettings::step_time_budget_us): the time the step's pair tests took
  // together, and how many tree levels every shell drops because steps ran over.
  std::atomic<int64_t> step_ns{0};
  std::atomic<uint32_t> levels_dropped{0};
  uint32_t relaxed_steps = 0;

  void begin_step() {
    const double budget = settings.step_time_budget_us;
    const double spent_us = double(step_ns.exchange(0, std::memory_order_relaxed)) * 1e-3;
    uint32_t dropped = levels_dropped.load(std::memory_order_relaxed);
    if (budget <= 0.0) {
      dropped = 0;
    } else if (spent_us > budget) {  // over: one level coarser at once
      dropped = std::min<uint32_t>(dropped + 1, 31);
      relaxed_steps = 0;
    } else if (spent_us < 0.5 * budget && dropped > 0) {  // well under for a while: one level finer
      if (++relaxed_steps >= kRelaxedSteps) {
        --dropped;
        relaxed_steps = 0;
      }
    } else {
      relaxed_steps = 0;
    }
    levels_dropped.store(dropped, std::memory_order_relaxed);
  }
  /// The deepest level a shell of `tree` is tested to under the budget (its leaves less the levels dropped;
  /// QueryOptions::min_points keeps the coarsest levels), or no limit.
  uint32_t level_cap(const runtime::PointTree& tree) const {
    const uint32_t leaf = uint32_t(tree.level_count()) - 1;
    const uint32_t dropped = levels_dropped.load(std::memory_order_relaxed);
    if (dropped == 0) return std::numeric_limits<uint32_t>::max();
    return dropped >= leaf ? 0u : leaf - dropped;
  }
  static constexpr uint32_t kRelaxedSteps = 50;

  // Static triangle meshes indexed once each (CollisionSettings::static_mesh_index), shared by every pair that
  // meets them. A pair keeps its mesh's index and looks here only when it has none, or its generation is old.
  std::mutex meshes_mutex;
  std::unordered_map<const btCollisionShape*, std::shared_ptr<const StaticMeshIndex>> meshes;
  std::atomic<uint64_t> mesh_generation{1};  ///< moves on whenever an index is forgotten

  std::shared_ptr<const StaticMeshIndex> mesh_index(const btConcaveShape& shape) {
    const MeshSignature signature = MeshSignature::of(shape);
    std::lock_guard<std::mutex> lock(meshes_mutex);
    std::shared_ptr<const StaticMeshIndex>& index = meshes[&shape];
    if (!index || !(index->signature() == signature)) {  // new, or another mesh at a freed shape's address
      index = StaticMeshIndex::build(shape);
      ++counters.static_mesh_builds;
    }
    return index;
  }
  void forget_mesh(const btCollisionShape& shape) {
    std::lock_guard<std::mutex> lock(meshes_mutex);
    meshes.erase(&shape);
    mesh_generation.fetch_add(1, std::memory_order_relaxed);
  }

  // A pair the algorithm cannot handle produces no contacts: say so once per shape type, never silently.
  void report_unsupported(const btCollisionShape* shape) {
    ++counters.unsupported_pairs;
    const int type = shape->getShapeType();
    const uint64_t bit = uint64_t(1) << (unsigned(type) % 64);
    if (reported_types.fetch_or(bit) & bit) return;
    const std::string message = std::string("voxfmt: a VPS shape against ") + shape->getName() +
                                " (Bullet shape type " + std::to_string(type) +
                                ") is not supported: such pairs produce no contacts";
    if (settings.on_unsupported_pair)
      settings.on_unsupported_pair(message);
    else
      std::fprintf(stderr, "%s\n", message.c_str());
  }
};

/// What a pair keeps between its tests: the traversal fronts (CollisionSettings::coherent) and its static mesh's
/// index (CollisionSettings::static_mesh_index).
struct PairState {
  runtime::QueryState query;
  std::shared_ptr<const StaticMeshIndex> mesh;
  uint64_t mesh_generation = 0;
  VertexCache vertices;
  TriangleSet triangles;  ///< a terrain's (or unindexed mesh's) triangles gathered at the last test, built
  bool indexed = false;   ///< whether the front was made against a static mesh's index (or gathered triangles)
  void reset() {
    query.reset();
    vertices.valid = false;
    triangles.clear();
  }
};

/// Contacts of a VPS shape (A) with any supported partner (B), reduced and fed to a persistent manifold
/// created as (A, B): normals are "on B" and points on B's surface, whatever order Bullet calls us in.
class VpsCollisionAlgorithm : public btCollisionAlgorithm {
 public:
  VpsCollisionAlgorithm(const btCollisionAlgorithmConstructionInfo& ci, const btCollisionObjectWrapper* body0,
                        const btCollisionObjectWrapper* body1, bool swapped, Shared& shared)
      : btCollisionAlgorithm(ci), manifold_(ci.m_manifold), swapped_(swapped), shared_(&shared) {
    const btCollisionObjectWrapper* a = swapped_ ? body1 : body0;
    const btCollisionObjectWrapper* b = swapped_ ? body0 : body1;
    if (!manifold_ && m_dispatcher->needsCollision(a->getCollisionObject(), b->getCollisionObject())) {
      manifold_ = m_dispatcher->getNewManifold(a->getCollisionObject(), b->getCollisionObject());
      owns_manifold_ = true;
    }
  }

  ~VpsCollisionAlgorithm() override {
    if (owns_manifold_ && manifold_) m_dispatcher->releaseManifold(manifold_);
    for (btPersistentManifold* m : extra_)
      if (m) m_dispatcher->releaseManifold(m);
  }

  void processCollision(const btCollisionObjectWrapper* body0, const btCollisionObjectWrapper* body1,
                        const btDispatcherInfo& info, btManifoldResult* result) override {
    const btCollisionObjectWrapper* a_wrap = swapped_ ? body1 : body0;
    const btCollisionObjectWrapper* b_wrap = swapped_ ? body0 : body1;
    if (!manifold_) {  // a pair the dispatcher would not collide (two static bodies) asked by contactTest: made now
      manifold_ = m_dispatcher->getNewManifold(a_wrap->getCollisionObject(), b_wrap->getCollisionObject());
      owns_manifold_ = true;
    }
    const auto* a_shape = static_cast<const VpsShape*>(a_wrap->getCollisionShape());
    const runtime::Pose pose_a = a_shape->asset_pose(a_wrap->getWorldTransform());
    const CollisionSettings& settings = shared_->settings;
    const runtime::QueryOptions options = query_options(*a_shape, a_wrap, b_wrap, info, *result);
    const bool budgeted = settings.step_time_budget_us > 0.0;
    const auto start = budgeted ? std::chrono::steady_clock::now() : std::chrono::steady_clock::time_point{};
    thread_local runtime::ContactSet contacts;
    thread_local runtime::QueryScratch scratch;
    contacts.clear();
    if (!state_) state_ = std::make_unique<PairState>();
    if (!settings.coherent) state_->reset();
    const bool cut = collide(*a_shape, a_wrap->getWorldTransform(), pose_a, b_wrap, options, contacts, scratch,
                             settings.coherent ? &state_->query : nullptr);
    if (budgeted)
      shared_->step_ns.fetch_add(
          std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count(),
          std::memory_order_relaxed);
    if (settings.on_contacts)
      settings.on_contacts(a_wrap->getCollisionObject(), b_wrap->getCollisionObject(), contacts);
    result->setPersistentManifold(manifold_);
    CollisionCounters& counters = shared_->counters;  // atomic: pairs may run on several threads at once
    ++counters.pair_tests;
    counters.raw_contacts += contacts.contacts.size();
    counters.points_tested += contacts.stats.points_tested;
    counters.nodes_visited += contacts.stats.nodes_visited;
    if (cut) ++counters.budget_cuts;
    const size_t regions = owns_manifold_ ? std::clamp<size_t>(settings.contact_regions, 1, kMaxRegions) : 1;
    if (regions == 1) {
      add_to_manifold(contacts.contacts, manifold_, made_threshold_[0], *result);
      if (owns_manifold_) result->refreshContactPoints();
      return;
    }
    add_by_region(contacts.contacts, *a_shape, pose_a, regions, a_wrap, b_wrap, *result);
  }

 private:
  // The pair's query: the settings', with the largest proximity any of its parts asks for (the settings, Bullet's
  // closest-point threshold, either shape's, and the speculative distance of this step).
  runtime::QueryOptions query_options(const VpsShape& a_shape, const btCollisionObjectWrapper* a_wrap,
                                      const btCollisionObjectWrapper* b_wrap, const btDispatcherInfo& info,
                                      const btManifoldResult& result) const {
    const CollisionSettings& settings = shared_->settings;
    runtime::QueryOptions options = settings.query;
    options.proximity =
        std::max({options.proximity, double(result.m_closestPointDistanceThreshold), a_shape.proximity()});
    if (b_wrap->getCollisionShape()->getShapeType() == VpsShape::kShapeType)
      options.proximity =
          std::max(options.proximity, static_cast<const VpsShape*>(b_wrap->getCollisionShape())->proximity());
    if (settings.speculative_contacts)
      options.proximity = std::max(options.proximity, speculative_distance(a_wrap, b_wrap, info.m_timeStep));
    return options;
  }

  // Up to the settings' manifold points of `set` into `manifold`.
  void add_to_manifold(const std::vector<runtime::Contact>& set, btPersistentManifold* manifold,
                       btScalar& made_threshold, btManifoldResult& result) const {
    runtime::ReducedContacts chosen = runtime::reduce_contacts(set, shared_->settings.manifold_points);
    // Bullet drops a point whose gap is over the manifold's breaking threshold (a few millimetres, from the shapes'
    // size), and merges points nearer each other than it: a speculative contact of a body approaching fast was
    // lost, and it passed a thin wall. While nothing is within that threshold, the nearest point alone goes in, the
    // threshold raised to its gap for this step (its constraint is the one that stops the body); then the
    // manifold's own threshold again.
    if (made_threshold == 0) made_threshold = manifold->getContactBreakingThreshold();
    size_t nearest = 0;
    for (size_t i = 1; i < chosen.size(); ++i)
      if (set[chosen.index[i]].depth > set[chosen.index[nearest]].depth) nearest = i;
    const double nearest_gap = chosen.size() ? -set[chosen.index[nearest]].depth : 0.0;
    const bool approaching = nearest_gap > double(made_threshold);
    if (approaching) {
      chosen.index[0] = chosen.index[nearest];
      chosen.count = 1;
    }
    manifold->setContactBreakingThreshold(approaching ? btScalar(nearest_gap * 1.001) : made_threshold);
    std::array<btVector3, 4> on_b;
    for (size_t i = 0; i < chosen.size(); ++i) {
      const runtime::Contact& c = set[chosen.index[i]];
      // Bullet: pointOnB + normalOnB * distance = pointOnA, distance < 0 when penetrating.
      on_b[i] = to_bt_vector(c.point_of_b ? c.point : c.point + c.normal * c.depth);
    }
    // Points of earlier steps that none of this step's is near (Bullet matches them within its breaking threshold)
    // are gone: kept, a stale point holds a body where it was (a peg on a hole's rim climbed out).
    const btScalar near2 = manifold->getContactBreakingThreshold() * manifold->getContactBreakingThreshold();
    for (int p = manifold->getNumContacts() - 1; p >= 0; --p) {
      bool matched = false;
      for (size_t i = 0; i < chosen.size() && !matched; ++i)
        matched = (manifold->getContactPoint(p).m_positionWorldOnB - on_b[i]).length2() <= near2;
      if (!matched) manifold->removeContactPoint(p);
    }
    for (size_t i = 0; i < chosen.size(); ++i) {
      const runtime::Contact& c = set[chosen.index[i]];
      result.addContactPoint(to_bt_vector(c.normal), on_b[i], btScalar(-c.depth));
    }
  }

  // Each contact's region: its cell in A's asset frame (cells as wide as A's bounding radius, fixed to A, so a
  // contact keeps its region from step to step), folded onto the manifolds; each region keeps its own points.
  void add_by_region(const std::vector<runtime::Contact>& set, const VpsShape& a_shape, const runtime::Pose& pose_a,
                     size_t regions, const btCollisionObjectWrapper* a_wrap, const btCollisionObjectWrapper* b_wrap,
                     btManifoldResult& result) {
    thread_local std::array<std::vector<runtime::Contact>, kMaxRegions> groups;
    for (auto& g : groups) g.clear();
    const double cell = a_shape.object().bounding_radius() * pose_a.scale;
    for (const runtime::Contact& c : set) {
      const Eigen::Vector3d local = pose_a.rotation.transpose() * (c.point - pose_a.translation) / cell;
      const auto key = [](double x) { return uint64_t(int64_t(std::floor(x))); };
      const uint64_t hash = key(local.x()) * 73856093u ^ key(local.y()) * 19349663u ^ key(local.z()) * 83492791u;
      groups[hash % regions].push_back(c);
    }
    for (size_t k = 0; k < regions; ++k) {
      btPersistentManifold*& manifold = k == 0 ? manifold_ : extra_[k - 1];
      if (!manifold) {
        if (groups[k].empty()) continue;
        manifold = m_dispatcher->getNewManifold(a_wrap->getCollisionObject(), b_wrap->getCollisionObject());
      }
      result.setPersistentManifold(manifold);
      add_to_manifold(groups[k], manifold, made_threshold_[k], result);
      result.refreshContactPoints();
    }
  }

 public:
  /// How far the pair can close in one step: the relative speed of the centres plus each body's spin times the
  /// reach of the shape from the body's centre of mass, times the step (0 outside a dynamics step). Points within it
  /// become speculative contacts, which Bullet's solver lets close only that gap: nothing passes through a thin wall in
  /// one step.
  static double speculative_distance(const btCollisionObjectWrapper* a, const btCollisionObjectWrapper* b,
                                     btScalar time_step) {
    if (!(time_step > 0)) return 0.0;
    double speed = 0.0;
    btVector3 relative(0, 0, 0);
    for (const btCollisionObjectWrapper* wrap : {a, b}) {
      const btRigidBody* body = btRigidBody::upcast(wrap->getCollisionObject());
      if (!body) continue;
      const btVector3 linear = body->getLinearVelocity();
      relative = wrap == a ? linear : relative - linear;
      const double spin = double(body->getAngularVelocity().length());
      if (spin == 0.0) continue;  // static and resting bodies: no bounding sphere needed
      btVector3 centre;
      btScalar radius = 0;
      wrap->getCollisionShape()->getBoundingSphere(centre, radius);
      // From the body's centre of mass: a compound's child turns about the body's, not about its own origin.
      const btVector3 offset = wrap->getWorldTransform() * centre - body->getCenterOfMassPosition();
      speed += spin * double(radius + offset.length());
    }
    speed += double(relative.length());
    return speed * double(time_step);
  }

  btScalar calculateTimeOfImpact(btCollisionObject*, btCollisionObject*, const btDispatcherInfo&,
                                 btManifoldResult*) override {
    return btScalar(1);
  }

  void getAllContactManifolds(btManifoldArray& manifolds) override {
    if (manifold_ && owns_manifold_) manifolds.push_back(manifold_);
    for (btPersistentManifold* m : extra_)
      if (m) manifolds.push_back(m);
  }

 private:
  // Everything a partner kind's handler needs of one pair test.
  struct PartnerTest {
    const VpsCollisionAlgorithm& algorithm;
    const VpsShape& a;
    const btTransform& ta;
    const runtime::Pose& pose_a;
    const btCollisionShape& b;
    const btTransform& tb;
    const runtime::QueryOptions& options;
    runtime::ContactSet& contacts;
    runtime::QueryScratch& scratch;
    runtime::QueryState* state;
    runtime::TraversalFront* front() const { return state ? &state->a_in_b : nullptr; }
    TriangleSet* kept() const { return state ? &algorithm.state_->triangles : nullptr; }
    ConvexPair convex() const { return ConvexPair{a, pose_a, tb, options, contacts, scratch, front()}; }
  };
  using PartnerHandler = void (*)(const PartnerTest&);

  // One handler per partner kind that has one (Bullet's shape type), filled once. VPS pairs come before the table
  // (both bodies are shells), and convex kinds without a handler of their own after it (GJK and EPA).
  static const std::array<PartnerHandler, MAX_BROADPHASE_COLLISION_TYPES>& partner_handlers() {
    static const std::array<PartnerHandler, MAX_BROADPHASE_COLLISION_TYPES> table = [] {
      std::array<PartnerHandler, MAX_BROADPHASE_COLLISION_TYPES> t{};
      t[STATIC_PLANE_PROXYTYPE] = [](const PartnerTest& p) {
        if (!p.a.uses_points()) return;
        const auto& plane = static_cast<const btStaticPlaneShape&>(p.b);
        const Eigen::Vector3f n = (to_eigen(p.tb.getBasis()) * to_eigen(plane.getPlaneNormal())).cast<float>();
        const float c = float(plane.getPlaneConstant()) + n.dot(to_eigen(p.tb.getOrigin()).cast<float>());
        points_against(
            p.a, p.pose_a, partner_pose(p.tb),
            [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return plane_distance(n, c, x, outward); },
            p.options, p.contacts, p.scratch, p.front());
      };
      t[TRIANGLE_MESH_SHAPE_PROXYTYPE] = t[SCALED_TRIANGLE_MESH_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        const auto& concave = static_cast<const btConcaveShape&>(p.b);
        p.algorithm.front_against(p.algorithm.shared_->settings.static_mesh_index);
        if (!p.algorithm.shared_->settings.static_mesh_index)
          return collide_concave(p.a, p.pose_a, p.ta, concave, p.tb, p.options, p.contacts, p.scratch, p.kept(),
                                 p.front());
        collide_indexed(p.a, p.pose_a, p.ta, p.algorithm.mesh_index(concave), p.tb, p.options, p.contacts, p.scratch,
                        p.front(), p.state ? &p.algorithm.state_->vertices : nullptr);
      };
      t[TERRAIN_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_concave(p.a, p.pose_a, p.ta, static_cast<const btConcaveShape&>(p.b), p.tb, p.options, p.contacts,
                        p.scratch, p.kept(), p.front());
      };
      t[BOX_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_box(p.convex(), static_cast<const btBoxShape&>(p.b));
      };
      t[SPHERE_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_sphere(p.convex(), static_cast<const btSphereShape&>(p.b));
      };
      t[CAPSULE_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_capsule(p.convex(), static_cast<const btCapsuleShape&>(p.b));
      };
      t[CYLINDER_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_cylinder(p.convex(), static_cast<const btCylinderShape&>(p.b));
      };
      t[MULTI_SPHERE_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_multi_sphere(p.convex(), static_cast<const btMultiSphereShape&>(p.b));
      };
      return t;
    }();
    return table;
  }

  /// Returns whether the step time budget cut a shell above its leaves.
  bool collide(const VpsShape& a, const btTransform& ta, const runtime::Pose& pose_a,
               const btCollisionObjectWrapper* b_wrap, runtime::QueryOptions options, runtime::ContactSet& contacts,
               runtime::QueryScratch& scratch, runtime::QueryState* state) const {
    const btCollisionShape& b = *b_wrap->getCollisionShape();
    const btTransform& tb = b_wrap->getWorldTransform();
    bool cut = false;
    limit_to(a, options, cut);
    if (b.getShapeType() == VpsShape::kShapeType) {
      collide_vps(a, pose_a, static_cast<const VpsShape&>(b), tb, options, cut, contacts, scratch, state);
      return cut;
    }
    const PartnerTest test{*this, a, ta, pose_a, b, tb, options, contacts, scratch, state};
    const int type = b.getShapeType();
    if (type >= 0 && type < MAX_BROADPHASE_COLLISION_TYPES && partner_handlers()[size_t(type)])
      partner_handlers()[size_t(type)](test);
    else if (b.isPolyhedral())
      collide_polyhedron(test.convex(), static_cast<const btPolyhedralConvexShape&>(b));
    else if (b.isConvex())
      collide_curved_convex(test.convex(), static_cast<const btConvexShape&>(b));
    else
      shared_->report_unsupported(&b);
    return cut;
  }

  // A shell's limits: the settings' query's, and on top its shape's own or else the step budget's level cap, which
  // always leaves the levels within step_budget_min_points (then `cut`). The tighter limit wins.
  void limit_to(const VpsShape& shell, runtime::QueryOptions& options, bool& cut) const {
    const runtime::QueryOptions& query = shared_->settings.query;
    options.point_budget = std::min(query.point_budget, shell.point_budget());
    options.min_points = query.min_points;
    uint32_t level = shell.max_level();
    if (shell.max_level() == std::numeric_limits<uint32_t>::max() &&
        shell.point_budget() == std::numeric_limits<size_t>::max()) {
      level = shared_->level_cap(shell.object().point_tree());
      if (level != std::numeric_limits<uint32_t>::max()) {
        cut = true;
        options.min_points = std::max(options.min_points, shared_->settings.step_budget_min_points);
      }
    }
    options.max_level = std::min(query.max_level, level);
  }

  // Two VPS bodies: the direction the settings ask (Auto: the runtime's choice), each way with its shell's limits.
  void collide_vps(const VpsShape& a, const runtime::Pose& pose_a, const VpsShape& b, const btTransform& tb,
                   runtime::QueryOptions options, bool& cut, runtime::ContactSet& contacts,
                   runtime::QueryScratch& scratch, runtime::QueryState* state) const {
    const runtime::Pose pose_b = b.asset_pose(tb);
    const bool a_in_b = a.uses_points() && b.uses_voxelmap();
    const bool b_in_a = b.uses_points() && a.uses_voxelmap();
    runtime::QueryDirection direction = shared_->settings.query.direction;
    if (direction == runtime::QueryDirection::Auto)
      direction = a_in_b && b_in_a
                      ? runtime::resolve_direction(a.object(), pose_a, b.object(), pose_b, direction)
                      : (a_in_b ? runtime::QueryDirection::APointsInB : runtime::QueryDirection::BPointsInA);
    auto query = [&](runtime::QueryDirection way, const VpsShape& shell) {
      options.direction = way;
      limit_to(shell, options, cut);
      if (state)
        runtime::query_contacts(a.object(), pose_a, b.object(), pose_b, options, contacts, scratch, *state);
      else
        runtime::query_contacts(a.object(), pose_a, b.object(), pose_b, options, contacts, scratch);
    };
    const bool both = direction == runtime::QueryDirection::Both;
    if (a_in_b && (both || direction == runtime::QueryDirection::APointsInB))
      query(runtime::QueryDirection::APointsInB, a);
    if (b_in_a && (both || direction == runtime::QueryDirection::BPointsInA))
      query(runtime::QueryDirection::BPointsInA, b);
  }

  static constexpr size_t kMaxRegions = 4;
  btPersistentManifold* manifold_;
  std::array<btPersistentManifold*, kMaxRegions - 1> extra_{};  ///< the other regions' manifolds, made on first use
  /// Each region's manifold's own breaking threshold, as made (0: not seen yet); raised in a step for its gaps.
  std::array<btScalar, kMaxRegions> made_threshold_{};
  bool owns_manifold_ = false;
  bool swapped_;
  Shared* shared_;
  /// The pair's static mesh index, looked up in the shared cache when the pair has none or it is stale (the mesh
  /// changed, or was forgotten); a new index starts the fronts afresh (their bounds are of the old one).
  const StaticMeshIndex& mesh_index(const btConcaveShape& shape) const {
    PairState& state = *state_;
    const uint64_t generation = shared_->mesh_generation.load(std::memory_order_relaxed);
    if (!state.mesh || state.mesh_generation != generation || !(state.mesh->signature() == MeshSignature::of(shape))) {
      state.mesh = shared_->mesh_index(shape);
      state.mesh_generation = generation;
      state.reset();
    }
    return *state.mesh;
  }

  /// A front made against the index is no front for gathered triangles, nor the other way round:
  /// `static_mesh_index` switched between tests starts it afresh.
  void front_against(bool indexed) const {
    if (!state_ || state_->indexed == indexed) return;
    state_->reset();
    state_->indexed = indexed;
  }

  std::unique_ptr<PairState> state_;  ///< made on first use (a pointer: the algorithm lives in Bullet's pool)
};

// Bullet's pool slots are sized from its own algorithms; ours must not be larger (see prepare_construction_info).
static_assert(sizeof(VpsCollisionAlgorithm) <= 96, "keep the algorithm small: it lives in the dispatcher's pool");

class CreateFunc : public btCollisionAlgorithmCreateFunc {
 public:
  CreateFunc(Shared& shared, bool swapped) : shared_(shared) { m_swapped = swapped; }
  btCollisionAlgorithm* CreateCollisionAlgorithm(btCollisionAlgorithmConstructionInfo& ci,
                                                 const btCollisionObjectWrapper* body0,
                                                 const btCollisionObjectWrapper* body1) override {
    void* memory = ci.m_dispatcher1->allocateCollisionAlgorithm(sizeof(VpsCollisionAlgorithm));
    return new (memory) VpsCollisionAlgorithm(ci, body0, body1, m_swapped, shared_);
  }

 private:
  Shared& shared_;
};

class Registration : public VpsCollisionRegistration {
 public:
  Registration(btCollisionDispatcher& dispatcher, const CollisionSettings& settings)
      : direct_(shared_, false), swapped_(shared_, true) {
    shared_.settings = settings;
    const int vps = VpsShape::kShapeType;
    // Every partner type: convex shapes, planes, static meshes and terrains are handled; the rest report
    // themselves once. Compounds stay with Bullet's compound algorithm, which meets us child by child.
    for (int other = 0; other < MAX_BROADPHASE_COLLISION_TYPES; ++other) {
      if (other == COMPOUND_SHAPE_PROXYTYPE || other == EMPTY_SHAPE_PROXYTYPE || other == INVALID_SHAPE_PROXYTYPE)
        continue;
      // Simulation (contact) and closest-point (contactTest, compounds) tables, both orders.
      dispatcher.registerCollisionCreateFunc(vps, other, &direct_);
      dispatcher.registerClosestPointsCreateFunc(vps, other, &direct_);
      if (other != vps) {
        dispatcher.registerCollisionCreateFunc(other, vps, &swapped_);
        dispatcher.registerClosestPointsCreateFunc(other, vps, &swapped_);
      }
    }
  }
  CollisionSettings& settings() override { return shared_.settings; }
  CollisionCounters& counters() override { return shared_.counters; }
  void begin_step() override { shared_.begin_step(); }
  StaticMeshInfo prepare_static_mesh(const btCollisionShape& shape) override {
    const int type = shape.getShapeType();
    if (type != TRIANGLE_MESH_SHAPE_PROXYTYPE && type != SCALED_TRIANGLE_MESH_SHAPE_PROXYTYPE) return {};
    const std::shared_ptr<const StaticMeshIndex> index = shared_.mesh_index(static_cast<const btConcaveShape&>(shape));
    const StaticMeshIndex::Info& built = index->info();
    StaticMeshInfo info;
    info.triangles = built.triangles;
    info.vertices = built.vertices;
    info.cells = built.cells;
    info.memory_bytes = built.memory_bytes;
    info.build_seconds = built.build_seconds;
    return info;
  }
  void forget_static_mesh(const btCollisionShape& shape) override { shared_.forget_mesh(shape); }

 private:
  Shared shared_;
  CreateFunc direct_;
  CreateFunc swapped_;
};

}  // namespace

runtime::QueryOptions physics_query_defaults() {
  runtime::QueryOptions query;
  query.cut_level = runtime::CutLevel::Points;
  query.refine_cut_contacts = true;
  return query;
}

std::unique_ptr<VpsCollisionRegistration> register_vps_collision(btCollisionDispatcher& dispatcher,
                                                                 const CollisionSettings& settings) {
  return std::make_unique<Registration>(dispatcher, settings);
}

void prepare_construction_info(btDefaultCollisionConstructionInfo& info) {
  info.m_customCollisionAlgorithmMaxElementSize =
      std::max(info.m_customCollisionAlgorithmMaxElementSize, int(sizeof(VpsCollisionAlgorithm)));
}

}  // namespace voxfmt::bullet
