// The isolated call's watchdog (voxfmt/detail/isolated_call.h): a child that burns CPU without progress is stopped
// after its idle CPU time; one that makes no progress because it does not run (a starved or sleeping child) is
// not taken for a hung one until it has been blocked for kBlockedFactor times as long; one asleep (on a lock, a pipe)
// is stopped after the watchdog's asleep_s when that is set.
#include <gtest/gtest.h>

#include <chrono>
#include <thread>
#include <vector>

#include "voxfmt/detail/isolated_call.h"

namespace voxfmt::detail {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); }

// One int through the wire.
auto visit_int = [](auto& wire, int& value) { wire.pod(value); };

TEST(Isolation, AChildThatSpinsWithoutProgressIsStoppedAfterItsIdleCpuTime) {
  std::atomic<uint64_t> progress{0};
  int value = 0;
  const auto start = Clock::now();
  const ChildOutcome outcome = run_isolated(
      Watchdog{0, 0.5, &progress}, value,
      [] {
        volatile uint64_t spin = 0;
        for (;;) spin = spin + 1;  // a parse looping in HDF5
        return 0;
      },
      visit_int);
  EXPECT_EQ(outcome.kind, ChildOutcome::TimedOut);
  EXPECT_GE(seconds_since(start), 0.5);
  EXPECT_LT(seconds_since(start), 0.5 * Watchdog::kBlockedFactor);
}

// Touches `megabytes` of fresh memory, 1 MB at a time, then holds it for up to 10 s (a parser believing a header).
int grow_and_hold(size_t megabytes) {
  std::vector<std::vector<char>> blocks;
  for (size_t i = 0; i < megabytes; ++i) blocks.emplace_back(size_t(1) << 20, char(i));
  std::this_thread::sleep_for(std::chrono::seconds(megabytes > 100 ? 10 : 0));
  return int(blocks.size());
}

TEST(Isolation, AChildWhoseMemoryGrowsBeyondItsLimitIsStopped) {
  int value = 0;
  const auto start = Clock::now();
  const ChildOutcome outcome = run_isolated(
      Watchdog{30, 0, nullptr, 0, 64.0 * (1 << 20)}, value, [] { return grow_and_hold(256); }, visit_int);
  EXPECT_EQ(outcome.kind, ChildOutcome::OutOfMemory);
  EXPECT_TRUE(outcome.over_limit);
  EXPECT_LT(seconds_since(start), 9.0);
  // Memory the parent holds at the fork is shared, not the child's: a parent with 128 MB resident starts a child
  // that adds 16 MB under a 64 MB limit.
  std::vector<char> parent(size_t(128) << 20, 1);
  const ChildOutcome small = run_isolated(
      Watchdog{30, 0, nullptr, 0, 64.0 * (1 << 20)}, value, [] { return grow_and_hold(16); }, visit_int);
  EXPECT_EQ(small.kind, ChildOutcome::Finished);
  EXPECT_EQ(value, 16);
  EXPECT_EQ(parent[parent.size() - 1], 1);
}

TEST(Isolation, AChildThatDoesNotRunIsNotTakenForAHungOne) {
  // Sleeping 1.5 s without progress uses no CPU: with an idle limit of 0.5 s of CPU it finishes.
  std::atomic<uint64_t> progress{0};
  int value = 0;
  const ChildOutcome outcome = run_isolated(
      Watchdog{0, 0.5, &progress}, value,
      [] {
        std::this_thread::sleep_for(std::chrono::milliseconds(1500));
        return 42;
      },
      visit_int);
  EXPECT_EQ(outcome.kind, ChildOutcome::Finished);
  EXPECT_EQ(value, 42);
}

TEST(Isolation, AChildBlockedForLongIsStoppedToo) {
  std::atomic<uint64_t> progress{0};
  int value = 0;
  const auto start = Clock::now();
  const ChildOutcome outcome = run_isolated(
      Watchdog{0, 0.2, &progress}, value,
      [] {
        std::this_thread::sleep_for(std::chrono::seconds(60));  // a deadlock
        return 0;
      },
      visit_int);
  EXPECT_EQ(outcome.kind, ChildOutcome::TimedOut);
  EXPECT_GE(seconds_since(start), 0.2 * Watchdog::kBlockedFactor);
  EXPECT_LT(seconds_since(start), 30.0);
}

TEST(Isolation, AChildAsleepWithoutProgressIsStoppedAfterTheAsleepLimit) {
  // A child forked while another thread held a lock sleeps on it forever: with asleep_s it is stopped after that,
  // long before the blocked limit (0.2 s x kBlockedFactor), and said to have slept (the isolated read retries it).
  std::atomic<uint64_t> progress{0};
  int value = 0;
  const auto start = Clock::now();
  const ChildOutcome outcome = run_isolated(
      Watchdog{0, 10.0, &progress, 0.5}, value,
      [] {
        std::this_thread::sleep_for(std::chrono::seconds(60));
        return 0;
      },
      visit_int);
  EXPECT_EQ(outcome.kind, ChildOutcome::TimedOut);
  EXPECT_TRUE(outcome.asleep);
  EXPECT_GE(seconds_since(start), 0.5);
  EXPECT_LT(seconds_since(start), 10.0);
}

TEST(Isolation, AChildAsleepIsStoppedWithOnlyATotalLimitToo) {
  // The import's and the repair's watchdogs have a total limit and asleep_s but no idle limit: a child asleep on a
  // lock inherited at the fork is stopped after asleep_s (and retried by them), not after the total limit.
  int value = 0;
  const auto start = Clock::now();
  const ChildOutcome outcome = run_isolated(
      Watchdog{30.0, 0, nullptr, 0.5}, value,
      [] {
        std::this_thread::sleep_for(std::chrono::seconds(60));
        return 0;
      },
      visit_int);
  EXPECT_EQ(outcome.kind, ChildOutcome::TimedOut);
  EXPECT_TRUE(outcome.asleep);
  EXPECT_GE(seconds_since(start), 0.5);
  EXPECT_LT(seconds_since(start), 10.0);
}

TEST(Isolation, ASpinningChildIsNotSaidToSleep) {
  std::atomic<uint64_t> progress{0};
  int value = 0;
  const ChildOutcome outcome = run_isolated(
      Watchdog{0, 0.5, &progress, 30.0}, value,
      [] {
        volatile uint64_t spin = 0;
        for (;;) spin = spin + 1;
        return 0;
      },
      visit_int);
  EXPECT_EQ(outcome.kind, ChildOutcome::TimedOut);
  EXPECT_FALSE(outcome.asleep);
}

TEST(Isolation, AChildThatSleepsAfterSendingEverythingStillDelivers) {
  // Everything arrived, then the child sleeps instead of exiting: it is stopped and what it sent stands.
  int fds_value = 0;
  const auto start = Clock::now();
  const ChildOutcome outcome = run_isolated(
      Watchdog{0, 10.0, nullptr, 0.5}, fds_value, [] { return 7; },
      [](auto& wire, int& value) {
        wire.pod(value);
        if constexpr (std::is_same_v<std::decay_t<decltype(wire)>, WireWriter>) {
          wire.flush();
          std::this_thread::sleep_for(std::chrono::seconds(60));
        }
      });
  EXPECT_EQ(outcome.kind, ChildOutcome::Finished);
  EXPECT_EQ(fds_value, 7);
  EXPECT_LT(seconds_since(start), 10.0);
}

}  // namespace
}  // namespace voxfmt::detail
