// A ready Bullet dynamics world with VPS collision registered, owning everything it creates: the shortest
// way from assets to a simulation (examples, tests, benchmarks).
//
// And Bullet's narrow phase on several threads.
//
// Bullet's multi-threaded classes (btCollisionDispatcherMt, btDiscreteDynamicsWorldMt, btConstraintSolverPoolMt)
// hand their work to the task scheduler only in a Bullet built with BT_THREADSAFE. Debian's is not: there
// btParallelFor runs on the calling thread whatever scheduler is set, btCreateDefaultTaskScheduler and the
// OpenMP/TBB/PPL schedulers return null, and Bullet's own pool locks are no-ops (bullet_is_thread_safe() tells).
//
// ParallelCollisionDispatcher runs the pairs of a step on a task scheduler's threads with any Bullet build: it
// takes a lock around what Bullet would lock itself (the algorithm and manifold pools, the manifold list) and
// puts the manifolds created or released during a step into the list in the order a sequential dispatcher
// gives, so a simulation comes out the same, to the bit, on any number of threads.
//
//   voxfmt::bullet::ThreadPoolScheduler scheduler(2);
//   btDefaultCollisionConstructionInfo info;
//   voxfmt::bullet::prepare_construction_info(info);
//   btDefaultCollisionConfiguration config(info);
//   voxfmt::bullet::ParallelCollisionDispatcher dispatcher(&config, scheduler);
//   auto vps = voxfmt::bullet::register_vps_collision(dispatcher);
//   btDiscreteDynamicsWorld world(&dispatcher, &broadphase, &solver, &config);
#pragma once

#include <BulletCollision/CollisionDispatch/btCollisionDispatcher.h>
#include <LinearMath/btThreads.h>
#include <btBulletDynamicsCommon.h>

#include <memory>
#include <mutex>
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

// ---- The narrow phase on several threads (see the top of this file).
/// True when the linked Bullet was built with BT_THREADSAFE, i.e. btParallelFor hands work to the task
/// scheduler and btCollisionDispatcherMt runs pairs on its threads. Sets a scheduler for a moment: call it
/// from the main thread while no simulation runs.
bool bullet_is_thread_safe();

/// A btITaskScheduler on a pool of std::threads: the calling thread and threads - 1 workers take chunks of
/// `grain` iterations in turn. Also usable with btSetTaskScheduler for Bullet's Mt classes in a BT_THREADSAFE
/// build (set another scheduler before destroying it). A parallelFor called from inside a task runs on the
/// calling thread.
class ThreadPoolScheduler : public btITaskScheduler {
 public:
  explicit ThreadPoolScheduler(int threads);
  ~ThreadPoolScheduler() override;
  ThreadPoolScheduler(const ThreadPoolScheduler&) = delete;
  ThreadPoolScheduler& operator=(const ThreadPoolScheduler&) = delete;

  int getMaxNumThreads() const override { return int(BT_MAX_THREAD_COUNT); }
  int getNumThreads() const override;
  /// From another thread, waits for the parallelFor in progress; from inside a loop body, takes effect when
  /// that loop ends.
  void setNumThreads(int threads) override;
  /// An exception thrown by a loop body is rethrown here once every thread has left the body (the remaining
  /// chunks are skipped); the first one when several threads throw.
  void parallelFor(int begin, int end, int grain, const btIParallelForBody& body) override;
  btScalar parallelSum(int begin, int end, int grain, const btIParallelSumBody& body) override;

 private:
  struct Pool;
  std::unique_ptr<Pool> pool_;
};

/// A collision dispatcher whose narrow phase runs the overlapping pairs on `scheduler`'s threads, `grain` pairs
/// per task, with any Bullet build (see the top of this file). The pairs are those of the pair cache in its
/// order (btDispatcherInfo::m_deterministicOverlappingPairs is not used); collision algorithms must be thread
/// safe for different pairs, as for btCollisionDispatcherMt (the VPS algorithm and Bullet's own are).
class ParallelCollisionDispatcher : public btCollisionDispatcher {
 public:
  ParallelCollisionDispatcher(btCollisionConfiguration* configuration, btITaskScheduler& scheduler, int grain = 1);

  void dispatchAllCollisionPairs(btOverlappingPairCache* pairs, const btDispatcherInfo& info,
                                 btDispatcher* dispatcher) override;
  btPersistentManifold* getNewManifold(const btCollisionObject* body0, const btCollisionObject* body1) override;
  void releaseManifold(btPersistentManifold* manifold) override;
  void* allocateCollisionAlgorithm(int size) override;
  void freeCollisionAlgorithm(void* pointer) override;

  btITaskScheduler& scheduler() { return scheduler_; }

 private:
  /// A manifold created or released while pair `pair` was processed: applied to the list after the step.
  struct ManifoldChange {
    int pair;
    btPersistentManifold* manifold;
    bool created;
  };

  void apply_changes();

  btITaskScheduler& scheduler_;
  int grain_;
  std::mutex mutex_;  // Bullet's pools and manifold list, and changes_
  std::vector<ManifoldChange> changes_;
};

}  // namespace voxfmt::bullet
