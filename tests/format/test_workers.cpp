// voxfmt::run_workers: the one fork-join the library, the Python batch queries and the writer's compression share.
#include <gtest/gtest.h>

#include <chrono>
#include <condition_variable>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include "voxfmt/detail/cores.h"

TEST(Workers, EveryShareRunsOnceOnItsOwnThreadSideBySide) {
  for (unsigned workers : {1u, 2u, 3u, 8u}) {
    std::mutex mutex;
    std::condition_variable all_in;
    std::vector<int> runs(workers, 0);
    std::set<std::thread::id> threads;
    unsigned arrived = 0;
    bool side_by_side = true;
    voxfmt::run_workers(workers, [&](unsigned w) {
      std::unique_lock<std::mutex> lock(mutex);
      ++runs[w];
      threads.insert(std::this_thread::get_id());
      ++arrived;
      all_in.notify_all();
      // Every share waits for all the others: only shares that run at the same time all get past this.
      if (!all_in.wait_for(lock, std::chrono::seconds(30), [&] { return arrived == workers; })) side_by_side = false;
    });
    for (unsigned w = 0; w < workers; ++w) EXPECT_EQ(runs[w], 1) << "share " << w << " of " << workers;
    EXPECT_TRUE(side_by_side) << workers << " shares";
    EXPECT_EQ(threads.size(), workers) << "one thread per share";
    EXPECT_TRUE(threads.count(std::this_thread::get_id())) << "the caller runs a share too";
  }
}

TEST(Workers, NoWorkersStillRunsTheCallersShare) {
  int runs = 0;
  voxfmt::run_workers(0, [&](unsigned w) {
    EXPECT_EQ(w, 0u);
    ++runs;
  });
  EXPECT_EQ(runs, 1);
}
