#include "voxfmt/bullet/world.h"

#include <BulletCollision/BroadphaseCollision/btDispatcher.h>
#include <BulletCollision/BroadphaseCollision/btOverlappingPairCache.h>
#include <BulletCollision/NarrowPhaseCollision/btPersistentManifold.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <system_error>
#include <thread>

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
struct ThreadPoolScheduler::Pool {
  std::mutex loops;  // one loop at a time, whoever calls
  std::mutex mutex;
  std::condition_variable wake, finished;
  std::vector<std::thread> workers;
  bool stop = false;
  uint64_t generation = 0;  // loops published so far
  int running = 0;          // workers not yet done with the current loop
  const btIParallelForBody* for_body = nullptr;
  const btIParallelSumBody* sum_body = nullptr;
  int64_t end = 0, grain = 1;
  std::atomic<int64_t> next{0};
  btScalar sum = 0;

  // A worker that cannot be started (a process at its thread limit) is not an error, as for voxfmt::run_workers:
  // the pool runs with those started (getNumThreads says how many) and the calling thread.
  void start(int count) {
    std::lock_guard<std::mutex> lock(mutex);
    try {
      for (int k = 0; k < count; ++k) workers.emplace_back([this, seen = generation] { worker(seen); });
    } catch (const std::system_error&) {
    }
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
  }

  void work() {
    t_in_task = true;
    btScalar partial = 0;
    for (;;) {
      const int64_t begin = next.fetch_add(grain, std::memory_order_relaxed);
      if (begin >= end) break;
      const int stop_at = int(std::min(end, begin + grain));
      if (for_body)
        for_body->forLoop(int(begin), stop_at);
      else
        partial += sum_body->sumLoop(int(begin), stop_at);
    }
    t_in_task = false;
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
      running = int(workers.size());
      ++generation;
    }
    wake.notify_all();
    work();
    std::unique_lock<std::mutex> lock(mutex);
    finished.wait(lock, [&] { return running == 0; });
    return sum;
  }
};

ThreadPoolScheduler::ThreadPoolScheduler(int threads)
    : btITaskScheduler("voxfmt::bullet::ThreadPoolScheduler"), pool_(std::make_unique<Pool>()) {
  setNumThreads(threads);
}

ThreadPoolScheduler::~ThreadPoolScheduler() { pool_->join(); }

int ThreadPoolScheduler::getNumThreads() const { return int(pool_->workers.size()) + 1; }

void ThreadPoolScheduler::setNumThreads(int threads) {
  threads = std::clamp(threads, 1, getMaxNumThreads());
  if (threads == getNumThreads()) return;
  pool_->join();
  pool_->start(threads - 1);
}

void ThreadPoolScheduler::parallelFor(int begin, int end, int grain, const btIParallelForBody& body) {
  grain = std::max(grain, 1);
  if (begin >= end) return;
  if (t_in_task || pool_->workers.empty() || end - begin <= grain) {
    body.forLoop(begin, end);
    return;
  }
  pool_->run(begin, end, grain, &body, nullptr);
}

btScalar ThreadPoolScheduler::parallelSum(int begin, int end, int grain, const btIParallelSumBody& body) {
  grain = std::max(grain, 1);
  if (begin >= end) return 0;
  if (t_in_task || pool_->workers.empty() || end - begin <= grain) return body.sumLoop(begin, end);
  return pool_->run(begin, end, grain, nullptr, &body);
}

namespace {

class PairLoop : public btIParallelForBody {
 public:
  PairLoop(ParallelCollisionDispatcher& dispatcher, btBroadphasePair* pairs, const btDispatcherInfo& info)
      : dispatcher_(dispatcher), pairs_(pairs), info_(info), near_(dispatcher.getNearCallback()) {}
  void forLoop(int begin, int end) const override {
    for (int i = begin; i < end; ++i) {
      t_current = {&dispatcher_, i};
      near_(pairs_[i], dispatcher_, info_);
    }
    t_current = {};
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
  scheduler_.parallelFor(0, count, grain_, PairLoop(*this, pairs->getOverlappingPairArrayPtr(), info));
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
