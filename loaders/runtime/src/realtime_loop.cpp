#include "voxfmt/runtime/realtime_loop.h"

namespace voxfmt::runtime {

void RealtimeLoop::start(uint64_t max_cycles) {
  stop();
  stop_ = false;
  cycles_ = 0;
  overruns_ = 0;
  thread_ = std::thread([this, max_cycles] { run(max_cycles); });
}

void RealtimeLoop::stop() {
  stop_ = true;
  join();
}

void RealtimeLoop::join() {
  if (thread_.joinable()) thread_.join();
}

void RealtimeLoop::run(uint64_t max_cycles) {
  using Clock = std::chrono::steady_clock;
  const auto period =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / settings_.rate_hz));
  const auto spin =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double, std::micro>(settings_.spin_us));
  const double dt = 1.0 / settings_.rate_hz;
  const auto start = Clock::now();
  uint64_t k = 0;     // index of the deadline the next cycle starts at
  uint64_t last = 0;  // the deadline of the cycle before (a cycle after an overrun covers the skipped ones)
  while (!stop_.load(std::memory_order_relaxed) &&
         (max_cycles == 0 || cycles_.load(std::memory_order_relaxed) < max_cycles)) {
    const auto deadline = start + period * int64_t(k);
    if (Clock::now() < deadline - spin) std::this_thread::sleep_until(deadline - spin);
    while (Clock::now() < deadline) {
    }
    cycle_(double(k) * dt, k == 0 ? dt : double(k - last) * dt);
    last = k;
    cycles_.fetch_add(1, std::memory_order_relaxed);
    // The next deadline still ahead; the ones already passed are overruns.
    const auto end = Clock::now();
    uint64_t next = k + 1;
    if (end > start + period * int64_t(next)) {
      const uint64_t passed = uint64_t((end - start) / period);
      overruns_.fetch_add(1, std::memory_order_relaxed);
      next = passed + 1;
    }
    k = next;
  }
}

}  // namespace voxfmt::runtime
