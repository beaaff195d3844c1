// The Bullet algorithm on several threads (run under ThreadSanitizer by scripts/run-tsan.sh): a pile of VPS
// spheres sharing one CollisionObject, with Bullet spheres, a box floor, plane walls and a static VPS voxelmap
// of the same object, stepped with the narrow phase on 2 and 4 threads (ParallelCollisionDispatcher) and
// with Bullet's btCollisionDispatcherMt in a btDiscreteDynamicsWorldMt.
#include <gtest/gtest.h>

#include <BulletCollision/CollisionDispatch/btCollisionDispatcherMt.h>
#include <BulletDynamics/ConstraintSolver/btSequentialImpulseConstraintSolverMt.h>
#include <BulletDynamics/Dynamics/btDiscreteDynamicsWorldMt.h>
#include <btBulletDynamicsCommon.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>
#include <utility>
#include <vector>

#include "analytic_sphere.h"
#include "voxfmt/bullet/collision.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"

namespace voxfmt::bullet {
namespace {

constexpr double kRadius = 0.1, kVoxel = 0.01, kWall = 0.33;
constexpr int kSteps = 250;
constexpr btScalar kStep = btScalar(1.0 / 500);

std::shared_ptr<const runtime::CollisionObject> sphere() {
  static const auto object = [] {
    auto loaded = runtime::CollisionObject::from_asset(test::make_sphere_asset({{0, 0, 0}, kRadius, kVoxel, 600, 4}));
    if (!loaded) throw std::runtime_error(loaded.error().describe());
    return loaded.value();
  }();
  return object;
}

// Pair tests Bullet hands to the VPS algorithm, and the threads they ran on, seen by the near callback.
struct PairLog {
  std::mutex mutex;
  uint64_t vps_pairs = 0;
  std::set<std::thread::id> threads;
};
PairLog* g_log = nullptr;

void logging_near_callback(btBroadphasePair& pair, btCollisionDispatcher& dispatcher, const btDispatcherInfo& info) {
  const auto* a = static_cast<const btCollisionObject*>(pair.m_pProxy0->m_clientObject);
  const auto* b = static_cast<const btCollisionObject*>(pair.m_pProxy1->m_clientObject);
  if ((a->getCollisionShape()->getShapeType() == VpsShape::kShapeType ||
       b->getCollisionShape()->getShapeType() == VpsShape::kShapeType) &&
      dispatcher.needsCollision(a, b)) {
    std::lock_guard<std::mutex> lock(g_log->mutex);
    ++g_log->vps_pairs;
    g_log->threads.insert(std::this_thread::get_id());
  }
  btCollisionDispatcher::defaultNearCallback(pair, dispatcher, info);
}

enum class Dispatch { Sequential, Parallel, BulletMt };

// Every body's pose, bit for bit, and the pairs in contact: what must not depend on the number of threads.
struct State {
  std::vector<btScalar> poses;
  std::set<std::pair<int, int>> touching;
  bool operator==(const State& other) const { return poses == other.poses && touching == other.touching; }
};

/// The pile: 27 dynamic bodies (24 VPS spheres sharing one object, 3 Bullet spheres) in a 0.66 m box whose
/// floor is a box with a static VPS voxelmap of the same sphere half sunk in its middle.
class Pile {
 public:
  Pile(Dispatch dispatch, int threads) : scheduler_(threads) {
    btDefaultCollisionConstructionInfo info;
    prepare_construction_info(info);
    configuration_ = std::make_unique<btDefaultCollisionConfiguration>(info);
    if (dispatch == Dispatch::BulletMt) {
      btSetTaskScheduler(&scheduler_);  // before the Mt classes, which size their per-thread arrays by it
      dispatcher_ = std::make_unique<btCollisionDispatcherMt>(configuration_.get(), 1);
      solver_pool_ = std::make_unique<btConstraintSolverPoolMt>(threads);
      solver_ = std::make_unique<btSequentialImpulseConstraintSolverMt>();
      broadphase_ = std::make_unique<btDbvtBroadphase>();
      world_ = std::make_unique<btDiscreteDynamicsWorldMt>(dispatcher_.get(), broadphase_.get(), solver_pool_.get(),
                                                           solver_.get(), configuration_.get());
    } else {
      if (dispatch == Dispatch::Parallel)
        dispatcher_ = std::make_unique<ParallelCollisionDispatcher>(configuration_.get(), scheduler_);
      else
        dispatcher_ = std::make_unique<btCollisionDispatcher>(configuration_.get());
      solver_ = std::make_unique<btSequentialImpulseConstraintSolver>();
      broadphase_ = std::make_unique<btDbvtBroadphase>();
      world_ = std::make_unique<btDiscreteDynamicsWorld>(dispatcher_.get(), broadphase_.get(), solver_.get(),
                                                         configuration_.get());
    }
    dispatcher_->setNearCallback(logging_near_callback);
    registration_ = register_vps_collision(*dispatcher_);
    world_->setGravity(btVector3(0, btScalar(-9.81), 0));

    add(std::make_shared<btBoxShape>(btVector3(btScalar(kWall), btScalar(0.05), btScalar(kWall))), 0,
        btVector3(0, btScalar(-0.05), 0));
    for (int side = 0; side < 4; ++side) {
      const btVector3 inward = side < 2 ? btVector3(side == 0 ? 1 : -1, 0, 0) : btVector3(0, 0, side == 2 ? 1 : -1);
      add(std::make_shared<btStaticPlaneShape>(inward, btScalar(-kWall)), 0, btVector3(0, 0, 0));
    }
    add(std::make_shared<VpsVoxelmapShape>(sphere()), 0, btVector3(0, btScalar(-0.05), 0));
    first_dynamic_ = int(bodies_.size());
    // 3 x 3 columns of 3, each sphere 2 mm into the one below (the bottom ones into the floor or the bump) and
    // a little off the column's axis: everything touches from the first step, and the columns topple.
    for (int k = 0; k < 27; ++k) {
      const int column = k % 9, layer = k / 9;
      const double base = column == 4 ? 0.05 : 0.0;
      const btVector3 at(btScalar(0.21 * (column % 3 - 1) + 0.01 * std::sin(1.7 * k)),
                         btScalar(base + kRadius - 0.002 + (2 * kRadius - 0.002) * layer),
                         btScalar(0.21 * (column / 3 - 1) + 0.01 * std::cos(2.3 * k)));
      std::shared_ptr<btCollisionShape> shape;
      if (column == (4 + 3 * layer) % 9)  // one Bullet sphere per layer
        shape = std::make_shared<btSphereShape>(btScalar(kRadius));
      else
        shape = std::make_shared<VpsMixedShape>(sphere());
      add(std::move(shape), 1, at);
    }
  }

  ~Pile() {
    for (auto& body : bodies_) world_->removeRigidBody(body.get());
    if (btGetTaskScheduler() == &scheduler_) btSetTaskScheduler(btGetSequentialTaskScheduler());
  }

  void step() { world_->stepSimulation(kStep, 0, kStep); }

  State state() const {
    State s;
    for (size_t b = first_dynamic_; b < bodies_.size(); ++b) {
      const btTransform& t = bodies_[b]->getWorldTransform();
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) s.poses.push_back(t.getBasis()[r][c]);
      for (int c = 0; c < 3; ++c) s.poses.push_back(t.getOrigin()[c]);
    }
    for (int m = 0; m < dispatcher_->getNumManifolds(); ++m) {
      const btPersistentManifold* manifold = dispatcher_->getManifoldByIndexInternal(m);
      if (manifold->getNumContacts() == 0) continue;
      const int a = index_of(manifold->getBody0()), b = index_of(manifold->getBody1());
      s.touching.insert({std::min(a, b), std::max(a, b)});
    }
    return s;
  }

  /// Lowest centre height and largest distance from the box's axis of the dynamic bodies.
  std::pair<double, double> extent() const {
    double lowest = 1e9, widest = 0;
    for (size_t b = first_dynamic_; b < bodies_.size(); ++b) {
      const btVector3& p = bodies_[b]->getWorldTransform().getOrigin();
      lowest = std::min(lowest, double(p.y()));
      widest = std::max({widest, std::abs(double(p.x())), std::abs(double(p.z()))});
    }
    return {lowest, widest};
  }

  const CollisionCounters& counters() { return registration_->counters(); }
  size_t dynamic_bodies() const { return bodies_.size() - first_dynamic_; }

 private:
  void add(std::shared_ptr<btCollisionShape> shape, btScalar mass, const btVector3& at) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shape->calculateLocalInertia(mass, inertia);
    auto body = std::make_unique<btRigidBody>(mass, nullptr, shape.get(), inertia);
    body->setWorldTransform(btTransform(btQuaternion::getIdentity(), at));
    body->setUserIndex(int(bodies_.size()));
    world_->addRigidBody(body.get());
    bodies_.push_back(std::move(body));
    shapes_.push_back(std::move(shape));
  }
  static int index_of(const btCollisionObject* object) { return object->getUserIndex(); }

  ThreadPoolScheduler scheduler_;
  std::unique_ptr<btDefaultCollisionConfiguration> configuration_;
  std::unique_ptr<btCollisionDispatcher> dispatcher_;
  std::unique_ptr<btBroadphaseInterface> broadphase_;
  std::unique_ptr<btConstraintSolverPoolMt> solver_pool_;
  std::unique_ptr<btConstraintSolver> solver_;
  std::unique_ptr<btDiscreteDynamicsWorld> world_;
  std::unique_ptr<VpsCollisionRegistration> registration_;
  std::vector<std::shared_ptr<btCollisionShape>> shapes_;
  std::vector<std::unique_ptr<btRigidBody>> bodies_;
  int first_dynamic_ = 0;
};

struct Outcome {
  State first, last;
  uint64_t vps_pairs = 0, pair_tests = 0, raw_contacts = 0, points_tested = 0;
  size_t threads_used = 0;
  double lowest = 0, widest = 0;
};

Outcome simulate(Dispatch dispatch, int threads) {
  PairLog log;
  g_log = &log;
  Pile pile(dispatch, threads);
  Outcome run;
  for (int step = 0; step < kSteps; ++step) {
    pile.step();
    if (step == 0) run.first = pile.state();
  }
  run.last = pile.state();
  run.vps_pairs = log.vps_pairs;
  run.threads_used = log.threads.size();
  run.pair_tests = pile.counters().pair_tests;
  run.raw_contacts = pile.counters().raw_contacts;
  run.points_tested = pile.counters().points_tested;
  std::tie(run.lowest, run.widest) = pile.extent();
  g_log = nullptr;
  return run;
}

// The pile settles in the box: nobody falls through the floor (centres above the radius, within half a voxel)
// or through a wall, and the counters add up to the pairs Bullet handed to the algorithm.
void expect_settled_pile(const Outcome& run) {
  EXPECT_GT(run.lowest, kRadius - 0.5 * kVoxel);
  EXPECT_LT(run.widest, kWall - kRadius + 0.5 * kVoxel);
  EXPECT_GT(run.vps_pairs, uint64_t(kSteps) * 24);  // each VPS sphere meets something in every step
  EXPECT_EQ(run.pair_tests, run.vps_pairs);
  EXPECT_GT(run.raw_contacts, 0u);
  EXPECT_GE(run.first.touching.size(), 27u);  // each sphere on the one below it, the floor or the bump
  EXPECT_GE(run.last.touching.size(), 24u);
}

TEST(BulletThreads, PileOnTwoAndFourThreadsIsTheSequentialSimulationBitForBit) {
  const Outcome sequential = simulate(Dispatch::Sequential, 1);
  expect_settled_pile(sequential);
  for (int threads : {2, 4}) {
    SCOPED_TRACE(threads);
    const Outcome parallel = simulate(Dispatch::Parallel, threads);
    expect_settled_pile(parallel);
    // Identical inputs, pair results independent of the thread that computed them, manifolds in the sequential
    // order: the same simulation, not merely a similar one.
    EXPECT_TRUE(parallel.first == sequential.first);
    EXPECT_TRUE(parallel.last == sequential.last);
    EXPECT_EQ(parallel.pair_tests, sequential.pair_tests);
    EXPECT_EQ(parallel.raw_contacts, sequential.raw_contacts);
    EXPECT_EQ(parallel.points_tested, sequential.points_tested);
    // Really on several threads: a worker takes pairs in some step of the 250 (each waits for it to wake).
    EXPECT_GE(parallel.threads_used, 2u);
  }
}

TEST(BulletThreads, BulletMtWorldWithTaskSchedulerRunsThePile) {
  const bool threaded = bullet_is_thread_safe();
  RecordProperty("bullet_threadsafe", threaded ? "yes" : "no");
  if (!threaded)
    std::cout << "note: this Bullet was built without BT_THREADSAFE: btCollisionDispatcherMt runs its pairs on the "
                 "calling thread whatever the task scheduler\n";
  const Outcome sequential = simulate(Dispatch::Sequential, 1);
  const Outcome mt = simulate(Dispatch::BulletMt, 2);
  expect_settled_pile(mt);
  // The first step's narrow phase sees the same poses whatever order the pairs run in: the same pairs touch.
  // Later steps differ (Bullet's Mt solver, and btCollisionDispatcherMt adds new manifolds thread by thread).
  EXPECT_EQ(mt.first.touching, sequential.first.touching);
  if (!threaded) {
    EXPECT_EQ(mt.threads_used, 1u);  // what "not thread safe" means here: no parallelism at all
  }
}

// ---- The pool itself: resizing from another thread, and loop bodies that throw.

// Ends the process when `seconds` pass before it is destroyed: a hang fails the test instead of blocking ctest.
class Watchdog {
 public:
  Watchdog(const char* what, int seconds)
      : thread_([this, what, seconds] {
          std::unique_lock<std::mutex> lock(mutex_);
          if (!done_cv_.wait_for(lock, std::chrono::seconds(seconds), [this] { return done_; })) {
            std::fprintf(stderr, "hang: %s did not finish in %d s\n", what, seconds);
            std::_Exit(3);
          }
        }) {}
  ~Watchdog() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      done_ = true;
    }
    done_cv_.notify_one();
    thread_.join();
  }

 private:
  std::mutex mutex_;
  std::condition_variable done_cv_;
  bool done_ = false;
  std::thread thread_;
};

// Counts the iterations it runs and the threads that ran them; a chunk takes about `sleep_us`.
struct CountingBody : btIParallelForBody {
  mutable std::atomic<int> iterations{0};
  mutable std::mutex mutex;
  mutable std::set<std::thread::id> threads;
  int sleep_us = 0;
  void forLoop(int begin, int end) const override {
    if (sleep_us) std::this_thread::sleep_for(std::chrono::microseconds(sleep_us));
    iterations += end - begin;
    std::lock_guard<std::mutex> lock(mutex);
    threads.insert(std::this_thread::get_id());
  }
};

TEST(BulletThreads, SetNumThreadsWhileAnotherThreadLoopsWaitsForTheLoop) {
  Watchdog watchdog("setNumThreads during parallelFor", 60);
  ThreadPoolScheduler scheduler(4);
  // Loops run for as long as the resizes do (a fixed count of loops could end, on a loaded machine, before the
  // resizes begin).
  std::atomic<bool> resizing{true};
  std::atomic<int> loops_run{0};
  int wrong = 0;
  std::thread loops([&] {
    while (resizing || loops_run < 10) {
      CountingBody body;
      scheduler.parallelFor(0, 64, 1, body);
      wrong += body.iterations != 64;
      ++loops_run;
    }
  });
  for (int k = 0; k < 200; ++k) scheduler.setNumThreads(1 + k % 4);
  resizing = false;
  loops.join();
  EXPECT_EQ(wrong, 0);
  EXPECT_GE(loops_run, 10);
  scheduler.setNumThreads(3);
  EXPECT_EQ(scheduler.getNumThreads(), 3);
}

TEST(BulletThreads, SetNumThreadsFromALoopBodyTakesEffectAfterTheLoop) {
  Watchdog watchdog("setNumThreads from a loop body", 60);
  ThreadPoolScheduler scheduler(4);
  struct Resize : btIParallelForBody {
    ThreadPoolScheduler& scheduler;
    explicit Resize(ThreadPoolScheduler& s) : scheduler(s) {}
    void forLoop(int begin, int) const override {
      if (begin == 5) scheduler.setNumThreads(2);
    }
  };
  scheduler.parallelFor(0, 32, 1, Resize(scheduler));
  EXPECT_EQ(scheduler.getNumThreads(), 2);
  CountingBody body;
  scheduler.parallelFor(0, 32, 1, body);
  EXPECT_EQ(body.iterations, 32);
}

// A body that throws on one thread: parallelFor rethrows once no thread is left in the body, and the threads
// are fit for the next loop.
struct ThrowingBody : btIParallelForBody {
  enum class Where { Caller, Worker };
  Where where;
  std::thread::id caller = std::this_thread::get_id();
  mutable std::atomic<int> inside{0}, worker_entries{0};
  mutable std::atomic<bool> thrown{false};
  explicit ThrowingBody(Where w) : where(w) {}
  void forLoop(int, int) const override {
    ++inside;
    const bool on_caller = std::this_thread::get_id() == caller;
    if (!on_caller) ++worker_entries;
    if (on_caller && where == Where::Worker) {
      // Keeps the caller in the loop until a worker has taken a chunk (it throws).
      for (int k = 0; k < 5000 && !thrown; ++k) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    std::this_thread::sleep_for(std::chrono::microseconds(300));
    if (on_caller == (where == Where::Caller) && !thrown.exchange(true)) {
      --inside;
      throw std::runtime_error("body failed");
    }
    --inside;
  }
};

// After a loop whose body threw, the next loop runs whole and on more than one thread (a thread left marked as a
// task would run every later loop alone).
void expect_a_later_loop_spread(ThreadPoolScheduler& scheduler) {
  CountingBody next;
  next.sleep_us = 2000;
  scheduler.parallelFor(0, 40, 1, next);
  EXPECT_EQ(next.iterations, 40);
  EXPECT_GE(next.threads.size(), 2u);
}

TEST(BulletThreads, ABodyThrowingOnTheCallingThreadIsRethrownAfterTheWorkersLeaveIt) {
  Watchdog watchdog("a throwing loop body", 60);
  ThreadPoolScheduler scheduler(4);
  ThrowingBody body(ThrowingBody::Where::Caller);
  EXPECT_THROW(scheduler.parallelFor(0, 400, 1, body), std::runtime_error);
  EXPECT_EQ(body.inside, 0);  // nobody is still in the body when parallelFor leaves
  const int entries = body.worker_entries;
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(body.worker_entries, entries);  // nor enters it after
  expect_a_later_loop_spread(scheduler);    // the calling thread is not left marked as a task
}

TEST(BulletThreads, ABodyThrowingOnAWorkerIsRethrownOnTheCallingThread) {
  Watchdog watchdog("a throwing loop body", 60);
  ThreadPoolScheduler scheduler(3);
  ThrowingBody body(ThrowingBody::Where::Worker);
  EXPECT_THROW(scheduler.parallelFor(0, 400, 1, body), std::runtime_error);
  EXPECT_EQ(body.inside, 0);
  expect_a_later_loop_spread(scheduler);
}

// A near callback that throws (a user's, or bad_alloc in an algorithm): the manifolds made before it are on
// the dispatcher's list, and the thread's later manifolds are not held back for a step.
TEST(BulletThreads, ANearCallbackThrowingLeavesTheDispatcherConsistent) {
  ThreadPoolScheduler scheduler(1);
  btDefaultCollisionConfiguration configuration;
  ParallelCollisionDispatcher dispatcher(&configuration, scheduler);
  btDbvtBroadphase broadphase;
  btCollisionWorld world(&dispatcher, &broadphase, &configuration);
  btBoxShape box(btVector3(1, 1, 1));
  btCollisionObject a, b;
  a.setCollisionShape(&box);
  b.setCollisionShape(&box);
  b.setWorldTransform(btTransform(btQuaternion::getIdentity(), btVector3(btScalar(1.5), 0, 0)));
  world.addCollisionObject(&a);
  world.addCollisionObject(&b);
  static bool throw_next = false;
  dispatcher.setNearCallback([](btBroadphasePair& pair, btCollisionDispatcher& d, const btDispatcherInfo& info) {
    btCollisionDispatcher::defaultNearCallback(pair, d, info);
    if (std::exchange(throw_next, false)) throw std::runtime_error("near callback failed");
  });
  throw_next = true;
  EXPECT_THROW(world.performDiscreteCollisionDetection(), std::runtime_error);
  EXPECT_EQ(dispatcher.getNumManifolds(), 1);  // the pair's manifold, made before the throw
  btPersistentManifold* extra = dispatcher.getNewManifold(&a, &b);
  EXPECT_EQ(dispatcher.getNumManifolds(), 2);  // not queued as if inside the step
  dispatcher.releaseManifold(extra);
  world.performDiscreteCollisionDetection();
  ASSERT_EQ(dispatcher.getNumManifolds(), 1);
  EXPECT_GT(dispatcher.getManifoldByIndexInternal(0)->getNumContacts(), 0);
  world.removeCollisionObject(&b);
  EXPECT_EQ(dispatcher.getNumManifolds(), 0);
  world.removeCollisionObject(&a);
}

}  // namespace
}  // namespace voxfmt::bullet
