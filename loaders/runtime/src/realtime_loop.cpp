#include "voxfmt/runtime/haptics.h"

#include <algorithm>
#include <cmath>
#include <string>

#ifdef __linux__
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#endif

namespace voxfmt::runtime {

Status RealtimeLoop::start(uint64_t max_cycles) {
  if (on_loop_thread())
    return Error{IssueCode::BadOption,
                 "RealtimeLoop: start() from the loop's own cycle (stop it, then start it "
                 "from another thread)"};
  stop();
  // A rate of 0 or NaN ran a busy loop of NaN time steps; over a GHz the period rounded to 0 and divided by it;
  // below ~1e-10 Hz the period overflowed the clock's nanoseconds.
  constexpr double kMinRateHz = 1e-3, kMaxRateHz = 1e6;
  if (!(settings_.rate_hz >= kMinRateHz && settings_.rate_hz <= kMaxRateHz))
    return Error{IssueCode::BadOption,
                 "RealtimeLoop: rate_hz must be in [0.001, 1e6], not " + std::to_string(settings_.rate_hz)};
  if (!(settings_.spin_us >= 0.0 && std::isfinite(settings_.spin_us)))
    return Error{IssueCode::BadOption,
                 "RealtimeLoop: spin_us must be finite and >= 0, not " + std::to_string(settings_.spin_us)};
  stop_ = false;
  cycles_ = 0;
  overruns_ = 0;
  realtime_priority_ = false;
  memory_locked_ = false;
  cpu_ = -1;
  thread_ = std::thread([this, max_cycles] { run(max_cycles); });
  return Status::success();
}

void RealtimeLoop::stop() {
  stop_ = true;
  join();
}

void RealtimeLoop::join() {
  // From the loop's own thread a join would wait for itself (std::system_error, then terminate).
  if (!on_loop_thread() && thread_.joinable()) thread_.join();
}

bool RealtimeLoop::on_loop_thread() const { return loop_thread_.load() == std::this_thread::get_id(); }

namespace {

// Each request is tried on its own; a refusal (no permission, no such CPU) is reported, never fatal.
void apply_realtime_settings(const LoopSettings& settings, std::atomic<bool>& priority, std::atomic<bool>& locked,
                             std::atomic<int>& cpu) {
#ifdef __linux__
  if (settings.lock_memory) locked = mlockall(MCL_CURRENT | MCL_FUTURE) == 0;
  if (settings.cpu >= 0 && settings.cpu < CPU_SETSIZE) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(settings.cpu, &set);
    if (pthread_setaffinity_np(pthread_self(), sizeof set, &set) == 0) cpu = settings.cpu;
  }
  if (settings.realtime_priority) {
    sched_param param{};
    param.sched_priority =
        std::clamp(settings.priority, sched_get_priority_min(SCHED_FIFO), sched_get_priority_max(SCHED_FIFO));
    priority = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param) == 0;
  }
#else
  (void)settings, (void)priority, (void)locked, (void)cpu;
#endif
}

}  // namespace

void RealtimeLoop::run(uint64_t max_cycles) {
  using Clock = std::chrono::steady_clock;
  loop_thread_ = std::this_thread::get_id();
  apply_realtime_settings(settings_, realtime_priority_, memory_locked_, cpu_);
  const auto period =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / settings_.rate_hz));
  // A spin longer than the period is a busy wait.
  const auto spin = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double, std::micro>(std::min(settings_.spin_us, 1e6 / settings_.rate_hz)));
  const double dt = 1.0 / settings_.rate_hz;
  const auto start = Clock::now();
  uint64_t k = 0;     // index of the deadline the next cycle starts at
  uint64_t last = 0;  // the deadline of the cycle before (a cycle after an overrun covers the skipped ones)
  while (!stop_.load(std::memory_order_relaxed) &&
         (max_cycles == 0 || cycles_.load(std::memory_order_relaxed) < max_cycles)) {
    const auto deadline = start + period * int64_t(k);
    // Asleep in slices, so that stop() returns within one (not a whole period) and no cycle runs after it.
    constexpr auto kSlice = std::chrono::milliseconds(20);
    for (auto now = Clock::now(); now < deadline - spin && !stop_.load(std::memory_order_relaxed); now = Clock::now())
      std::this_thread::sleep_until(std::min(deadline - spin, now + kSlice));
    while (Clock::now() < deadline && !stop_.load(std::memory_order_relaxed)) {
    }
    if (stop_.load(std::memory_order_relaxed)) break;
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
  loop_thread_ = std::thread::id();  // ids are reused once a thread is gone
}

}  // namespace voxfmt::runtime
