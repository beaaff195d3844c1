// A fixed-rate loop for haptic rendering: one thread, absolute deadlines, lock-free hand-off of the latest
// values between it and the rest of the program, overrun counting. No device SDK: a device is an interface.
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <thread>
#include <vector>

#include "voxfmt/runtime/forces.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {

/// The latest value from one producer thread to one consumer thread, wait-free on both sides (a triple buffer:
/// the producer never waits for the consumer and the consumer always gets a whole value, the newest one).
template <class T>
class LatestValue {
 public:
  /// Producer: makes `value` the latest.
  void publish(const T& value) {
    slots_[back_] = value;
    back_ = middle_.exchange(back_ | kFresh, std::memory_order_acq_rel) & kIndex;
  }
  /// Consumer: the latest value published (a default T before the first); `fresh` tells whether it is new
  /// since the last call.
  const T& latest(bool* fresh = nullptr) {
    const bool is_new = middle_.load(std::memory_order_relaxed) & kFresh;
    if (is_new) front_ = middle_.exchange(front_, std::memory_order_acq_rel) & kIndex;
    if (fresh) *fresh = is_new;
    return slots_[front_];
  }

 private:
  static constexpr uint8_t kIndex = 3, kFresh = 4;
  T slots_[3]{};
  uint8_t back_ = 0, front_ = 2;    // owned by the producer and the consumer
  std::atomic<uint8_t> middle_{1};  // the slot in between, with a "fresh" bit
};

/// A 6-DoF haptic device: reads its pose, displays a wrench. Called from the loop's thread only.
class HapticDevice {
 public:
  virtual ~HapticDevice() = default;
  /// The handle's pose at `time` seconds since the loop started.
  virtual Pose read_pose(double time) = 0;
  /// The wrench to display until the next cycle.
  virtual void write_wrench(const Wrench& wrench) = 0;
};

/// A device that follows a script (a pose for each time) and keeps the last wrench: tests, benchmarks, demos.
class ScriptedDevice : public HapticDevice {
 public:
  explicit ScriptedDevice(std::function<Pose(double)> script) : script_(std::move(script)) {}
  Pose read_pose(double time) override { return script_(time); }
  void write_wrench(const Wrench& wrench) override { last_ = wrench; }
  const Wrench& last_wrench() const { return last_; }

 private:
  std::function<Pose(double)> script_;
  Wrench last_;
};

struct LoopSettings {
  double rate_hz = 1000.0;  ///< 1 kHz default; 5 kHz and more are fine if a cycle fits
  /// The loop sleeps until this long before a deadline, then spins: the kernel wakes a sleeping thread tens of
  /// microseconds late, a fifth of a 5 kHz period.
  double spin_us = 80.0;
  /// Where the system permits (Linux; root or CAP_SYS_NICE / CAP_IPC_LOCK, or the matching rlimits): run the
  /// loop's thread under SCHED_FIFO at `priority`, so that ordinary threads never delay a wake-up; lock the
  /// process's memory (mlockall), so that no page fault stalls a cycle; pin the thread to CPU `cpu` (-1: any).
  /// LoopStats says what was granted; a request that is refused leaves the loop running as before.
  bool realtime_priority = false;
  int priority = 80;
  bool lock_memory = false;
  int cpu = -1;
};

struct LoopStats {
  uint64_t cycles = 0;
  uint64_t overruns = 0;           ///< cycles that ended after the next one's deadline (that deadline is then skipped)
  bool realtime_priority = false;  ///< SCHED_FIFO was granted
  bool memory_locked = false;      ///< mlockall succeeded
  int cpu = -1;                    ///< the CPU the thread is pinned to (-1: not pinned)
};

/// Runs `cycle(time, dt)` at a fixed rate on a thread of its own until stop() (or `max_cycles`). Deadlines are
/// absolute (start + k * period), so timing errors do not accumulate; an overrun skips the deadlines it missed
/// rather than running late cycles back to back.
class RealtimeLoop {
 public:
  using Cycle = std::function<void(double time, double dt)>;
  RealtimeLoop(const LoopSettings& settings, Cycle cycle) : settings_(settings), cycle_(std::move(cycle)) {}
  ~RealtimeLoop() { stop(); }
  RealtimeLoop(const RealtimeLoop&) = delete;
  RealtimeLoop& operator=(const RealtimeLoop&) = delete;

  /// Starts the thread; it runs `max_cycles` cycles (0 = until stop()).
  void start(uint64_t max_cycles = 0);
  /// Asks the thread to stop and joins it.
  void stop();
  /// Waits until the thread has run its cycles.
  void join();
  /// Counters so far (exact after join()/stop()).
  LoopStats stats() const {
    return {cycles_.load(), overruns_.load(), realtime_priority_.load(), memory_locked_.load(), cpu_.load()};
  }

 private:
  void run(uint64_t max_cycles);
  LoopSettings settings_;
  Cycle cycle_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<uint64_t> cycles_{0}, overruns_{0};
  std::atomic<bool> realtime_priority_{false}, memory_locked_{false};
  std::atomic<int> cpu_{-1};
};

}  // namespace voxfmt::runtime
