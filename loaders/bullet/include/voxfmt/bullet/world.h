// A ready Bullet dynamics world with VPS collision registered, owning everything it creates: the shortest
// way from assets to a simulation (examples, tests, benchmarks).
#pragma once

#include <btBulletDynamicsCommon.h>

#include <memory>
#include <vector>

#include "voxfmt/bullet/collision.h"

namespace voxfmt::bullet {

/// A dispatcher that times its narrow phase (all pairs of one step), in microseconds.
class TimedDispatcher : public btCollisionDispatcher {
 public:
  using btCollisionDispatcher::btCollisionDispatcher;
  void dispatchAllCollisionPairs(btOverlappingPairCache* pairs, const btDispatcherInfo& info,
                                 btDispatcher* dispatcher) override;
  double last_narrow_phase_us() const { return last_us_; }
  /// Told as each narrow phase starts (CollisionSettings::step_time_budget_us).
  void set_vps(VpsCollisionRegistration* vps) { vps_ = vps; }

 private:
  double last_us_ = 0.0;
  VpsCollisionRegistration* vps_ = nullptr;
};

class World {
 public:
  /// `register_vps`: false gives a plain Bullet world (for comparisons) with the same timing dispatcher.
  explicit World(const CollisionSettings& settings = {}, bool register_vps = true);
  ~World();
  World(const World&) = delete;
  World& operator=(const World&) = delete;

  btDiscreteDynamicsWorld& dynamics() { return *world_; }
  TimedDispatcher& dispatcher() { return *dispatcher_; }
  /// Null for a world without VPS.
  VpsCollisionRegistration* vps() { return registration_.get(); }

  /// Adds a body; mass 0 makes it static (a static triangle mesh is indexed here: CollisionSettings::
  /// static_mesh_index). The world keeps the shape alive. Without `inertia`, the shape's calculateLocalInertia
  /// decides.
  btRigidBody* add_body(std::shared_ptr<btCollisionShape> shape, btScalar mass, const btTransform& transform,
                        const btVector3* inertia = nullptr);
  /// One fixed step of `dt` seconds (no sub-stepping: a haptic loop steps at its own rate).
  void step(btScalar dt) { world_->stepSimulation(dt, 0, dt); }

 private:
  std::unique_ptr<btDefaultCollisionConfiguration> configuration_;
  std::unique_ptr<TimedDispatcher> dispatcher_;
  std::unique_ptr<btBroadphaseInterface> broadphase_;
  std::unique_ptr<btSequentialImpulseConstraintSolver> solver_;
  std::unique_ptr<btDiscreteDynamicsWorld> world_;
  std::unique_ptr<VpsCollisionRegistration> registration_;
  std::vector<std::shared_ptr<btCollisionShape>> shapes_;
  std::vector<std::unique_ptr<btMotionState>> motion_states_;
  std::vector<std::unique_ptr<btRigidBody>> bodies_;
};

}  // namespace voxfmt::bullet
