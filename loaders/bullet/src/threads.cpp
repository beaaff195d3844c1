#include "voxfmt/bullet/world.h"

#include <BulletCollision/BroadphaseCollision/btDispatcher.h>
#include <BulletCollision/BroadphaseCollision/btOverlappingPairCache.h>
#include <BulletCollision/NarrowPhaseCollision/btPersistentManifold.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <mutex>
#include <system_error>
#include <thread>
#include <utility>

namespace voxfmt::bullet {
namespace {

// True on a thread that runs a ThreadPoolScheduler's task: a parallelFor from inside it runs inline (the
// pool is busy with the outer loop).
thread_local bool t_in_task = false;

// The pair this thread processes for a ParallelCollisionDispatcher: manifold changes are tagged with it.
struct CurrentPair {
  const ParallelCollisionDispatcher* dispatcher = nullptr;
  int pair = 0;
};
thread_local CurrentPair t_current;

}  // namespace

bool bullet_is_thread_safe() {
  // Without BT_THREADSAFE, btParallelFor runs the body itself and never asks the scheduler.
  struct Probe : btITaskScheduler {
    bool asked = false;
    Probe() : btITaskScheduler("voxfmt probe") {}
    int getMaxNumThreads() const override { return 1; }
    int getNumThreads() const override { return 1; }
    void setNumThreads(int) override {}
    void parallelFor(int begin, int end, int, const btIParallelForBody& body) override {
      asked = true;
      body.forLoop(begin, end);
    }
    btScalar parallelSum(int begin, int end, int, const btIParallelSumBody& body) override {
      asked = true;
      return body.sumLoop(begin, end);
    }
  };
  struct Nothing : btIParallelForBody {
    void forLoop(int, int) const override {}
  };
  btITaskScheduler* previous = btGetTaskScheduler();
  Probe probe;
  btSetTaskScheduler(&probe);
  btParallelFor(0, 2, 1, Nothing());
  btSetTaskScheduler(previous);
  return probe.asked;
}

// Workers sleep on `wake` between loops; a loop is published under the mutex (so the workers see its fields),
// its chunks are claimed through `next`, and the caller waits on `finished` until every worker has left it.
// `loops` is held by the loop in progress and by a resize, so workers are never stopped mid-loop.
struct ThreadPoolScheduler::Pool {
  std::mutex loops;  // one loop (or resize) at a time, whoever calls
  std::mutex mutex;
  std::condition_variable wake, finished;
  std::vector<std::thread> workers;
  std::atomic<int> threads{1};  // workers + 1, readable while a resize runs
  bool stop = false;
  uint64_t generation = 0;  // loops published so far
  int running = 0;          // workers not yet done with the current loop
  const btIParallelForBody* for_body = nullptr;
  const btIParallelSumBody* sum_body = nullptr;
  int64_t end = 0, grain = 1;
  std::atomic<int64_t> next{0};
  btScalar sum = 0;
  std::exception_ptr failure;  // the first exception a body threw in this loop
  int pending = 0;             // a size asked for from inside a task: applied when the loop ends

  // A worker that cannot be started (a process at its thread limit) is not an error, as for voxfmt::run_workers:
  // the pool runs with those started (getNumThreads says how many) and the calling thread.
  void start(int count) {
    std::lock_guard<std::mutex> lock(mutex);
    try {
      for (int k = 0; k < count; ++k) workers.emplace_back([this, seen = generation] { worker(seen); });
    } catch (const std::system_error&) {
    }
    threads.store(int(workers.size()) + 1);
  }

  void join() {
    {
      std::lock_guard<std::mutex> lock(mutex);
      stop = true;
    }
    wake.notify_all();
    for (std::thread& worker : workers) worker.join();
    workers.clear();
    stop = false;
    threads.store(1);
  }

  // Under `loops`.
  void resize(int count) {
    if (count == threads.load()) return;
    join();
    start(count - 1);
  }

  void work() {
    // Cleared however the body leaves: a thread left marked would run every later loop alone.
    struct InTask {
      InTask() { t_in_task = true; }
      ~InTask() { t_in_task = false; }
    } in_task;
    btScalar partial = 0;
    try {
      for (;;) {
        const int64_t begin = next.fetch_add(grain, std::memory_order_relaxed);
        if (begin >= end) break;
        const int stop_at = int(std::min(end, begin + grain));
        if (for_body)
          for_body->forLoop(int(begin), stop_at);
        else
          partial += sum_body->sumLoop(int(begin), stop_at);
      }
    } catch (...) {
      // The other threads take no more chunks; the caller rethrows once every thread has left the body.
      next.store(end, std::memory_order_relaxed);
      std::lock_guard<std::mutex> lock(mutex);
      if (!failure) failure = std::current_exception();
      return;
    }
    if (sum_body) {
      std::lock_guard<std::mutex> lock(mutex);
      sum += partial;
    }
  }

  void worker(uint64_t seen) {
    std::unique_lock<std::mutex> lock(mutex);
    for (;;) {
      wake.wait(lock, [&] { return stop || generation != seen; });
      if (stop) return;
      seen = generation;
      lock.unlock();
      work();
      lock.lock();
      if (--running == 0) finished.notify_one();
    }
  }

  btScalar run(int begin, int stop_at, int chunk, const btIParallelForBody* for_loop,
               const btIParallelSumBody* sum_loop) {
    std::lock_guard<std::mutex> one_loop(loops);
    {
      std::lock_guard<std::mutex> lock(mutex);
      for_body = for_loop;
      sum_body = sum_loop;
      end = stop_at;
      grain = chunk;
      next.store(begin, std::memory_order_relaxed);
      sum = 0;
      failure = nullptr;
      running = int(workers.size());
      ++generation;
    }
    wake.notify_all();
    work();
    std::exception_ptr thrown;
    btScalar total;
    int resize_to;
    {
      std::unique_lock<std::mutex> lock(mutex);
      finished.wait(lock, [&] { return running == 0; });
      thrown = std::exchange(failure, nullptr);
      total = sum;
      resize_to = std::exchange(pending, 0);
    }
    if (resize_to) resize(resize_to);
    if (thrown) std::rethrow_exception(thrown);
    return total;
  }
};

ThreadPoolScheduler::ThreadPoolScheduler(int threads)
    : btITaskScheduler("voxfmt::bullet::ThreadPoolScheduler"), pool_(std::make_unique<Pool>()) {
  setNumThreads(threads);
}

ThreadPoolScheduler::~ThreadPoolScheduler() {
  std::lock_guard<std::mutex> one_loop(pool_->loops);
  pool_->join();
}

int ThreadPoolScheduler::getNumThreads() const { return pool_->threads.load(); }

void ThreadPoolScheduler::setNumThreads(int threads) {
  threads = std::clamp(threads, 1, getMaxNumThreads());
  if (t_in_task) {
    // From a loop body: the loop holds `loops` and may run on the very workers a resize would join.
    std::lock_guard<std::mutex> lock(pool_->mutex);
    pool_->pending = threads;
    return;
  }
  // Waits for a loop that another thread runs.
  std::lock_guard<std::mutex> one_loop(pool_->loops);
  pool_->resize(threads);
}

void ThreadPoolScheduler::parallelFor(int begin, int end, int grain, const btIParallelForBody& body) {
  grain = std::max(grain, 1);
  if (begin >= end) return;
  if (t_in_task || pool_->threads.load() == 1 || end - begin <= grain) {
    body.forLoop(begin, end);
    return;
  }
  pool_->run(begin, end, grain, &body, nullptr);
}

btScalar ThreadPoolScheduler::parallelSum(int begin, int end, int grain, const btIParallelSumBody& body) {
  grain = std::max(grain, 1);
  if (begin >= end) return 0;
  if (t_in_task || pool_->threads.load() == 1 || end - begin <= grain) return body.sumLoop(begin, end);
  return pool_->run(begin, end, grain, nullptr, &body);
}

namespace {

class PairLoop : public btIParallelForBody {
 public:
  PairLoop(ParallelCollisionDispatcher& dispatcher, btBroadphasePair* pairs, const btDispatcherInfo& info)
      : dispatcher_(dispatcher), pairs_(pairs), info_(info), near_(dispatcher.getNearCallback()) {}
  void forLoop(int begin, int end) const override {
    // Cleared however a near callback leaves: a thread left tagged would queue its later manifold changes.
    struct Untag {
      ~Untag() { t_current = {}; }
    } untag;
    for (int i = begin; i < end; ++i) {
      t_current = {&dispatcher_, i};
      near_(pairs_[i], dispatcher_, info_);
    }
  }

 private:
  ParallelCollisionDispatcher& dispatcher_;
  btBroadphasePair* pairs_;
  const btDispatcherInfo& info_;
  btNearCallback near_;
};

}  // namespace

ParallelCollisionDispatcher::ParallelCollisionDispatcher(btCollisionConfiguration* configuration,
                                                         btITaskScheduler& scheduler, int grain)
    : btCollisionDispatcher(configuration), scheduler_(scheduler), grain_(std::max(grain, 1)) {}

void ParallelCollisionDispatcher::dispatchAllCollisionPairs(btOverlappingPairCache* pairs, const btDispatcherInfo& info,
                                                            btDispatcher* dispatcher) {
  // The continuous mode's near callback keeps the smallest time of impact in `info`: one thread.
  if (info.m_dispatchFunc != btDispatcherInfo::DISPATCH_DISCRETE) {
    btCollisionDispatcher::dispatchAllCollisionPairs(pairs, info, dispatcher);
    return;
  }
  const int count = pairs->getNumOverlappingPairs();
  if (count == 0) return;
  // Applied also when a near callback throws: the manifolds made so far belong to their algorithms.
  struct Apply {
    ParallelCollisionDispatcher& self;
    ~Apply() { self.apply_changes(); }
  } apply{*this};
  scheduler_.parallelFor(0, count, grain_, PairLoop(*this, pairs->getOverlappingPairArrayPtr(), info));
}

void ParallelCollisionDispatcher::apply_changes() {
  // The list as a sequential dispatcher leaves it (the solver's order follows it): changes in pair order,
  // each pair's in the order they happened.
  std::lock_guard<std::mutex> lock(mutex_);
  std::stable_sort(changes_.begin(), changes_.end(),
                   [](const ManifoldChange& a, const ManifoldChange& b) { return a.pair < b.pair; });
  for (const ManifoldChange& change : changes_) {
    if (change.created) {
      change.manifold->m_index1a = m_manifoldsPtr.size();
      m_manifoldsPtr.push_back(change.manifold);
    } else {
      btCollisionDispatcher::releaseManifold(change.manifold);
    }
  }
  changes_.clear();
}

btPersistentManifold* ParallelCollisionDispatcher::getNewManifold(const btCollisionObject* body0,
                                                                  const btCollisionObject* body1) {
  std::lock_guard<std::mutex> lock(mutex_);
  btPersistentManifold* manifold = btCollisionDispatcher::getNewManifold(body0, body1);
  if (manifold && t_current.dispatcher == this) {
    m_manifoldsPtr.pop_back();  // appended last by the base: it takes its place after the step
    changes_.push_back({t_current.pair, manifold, true});
  }
  return manifold;
}

void ParallelCollisionDispatcher::releaseManifold(btPersistentManifold* manifold) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (t_current.dispatcher == this) {
    changes_.push_back({t_current.pair, manifold, false});
    return;
  }
  btCollisionDispatcher::releaseManifold(manifold);
}

void* ParallelCollisionDispatcher::allocateCollisionAlgorithm(int size) {
  std::lock_guard<std::mutex> lock(mutex_);
  return btCollisionDispatcher::allocateCollisionAlgorithm(size);
}

void ParallelCollisionDispatcher::freeCollisionAlgorithm(void* pointer) {
  std::lock_guard<std::mutex> lock(mutex_);
  btCollisionDispatcher::freeCollisionAlgorithm(pointer);
}

}  // namespace voxfmt::bullet
