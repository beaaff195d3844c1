// Running a piece of work in a forked child process, for parsers of untrusted files whose libraries can crash
// or hang on damaged input (HDF5's decoders, assimp's importers). The child streams its result back through a
// pipe; a child that dies, hangs or sends something malformed is a failure the caller reports, not a crash of
// the caller. Internal to voxfmt's libraries (POSIX only): not a stable API.
#pragma once

#if !defined(_WIN32)
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <new>
#include <optional>
#include <string>
#include <type_traits>
#include <vector>

// Sanitizer runtimes (when linked) call a death callback on a report; a fuzzer registers one that saves the input
// as a crash. Weak: absent from ordinary builds.
extern "C" void __sanitizer_set_death_callback(void (*callback)(void)) __attribute__((weak));

namespace voxfmt::detail {

// ------------------------------------------------------------------ a minimal wire format (child -> parent)
// Streamed through the pipe: arrays go straight from the child's vectors into the parent's, with no copy of
// the whole asset on either side (a 300^3 grid is ~150 MB).

class WireWriter {
 public:
  explicit WireWriter(int fd) : fd_(fd) {}
  template <class T>
  void pod(const T& value) {
    static_assert(std::is_trivially_copyable_v<T>);
    put(&value, sizeof(T));
  }
  void text(const std::string& s) {
    pod(uint64_t(s.size()));
    put(s.data(), s.size());
  }
  template <class T>
  void array(const std::vector<T>& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    pod(uint64_t(v.size()));
    put(v.data(), v.size() * sizeof(T));
  }
  template <class T>
  void maybe(const std::optional<T>& v) {
    pod(uint8_t(v.has_value()));
    if (v) pod(*v);
  }
  /// A sequence of structures, each written by `each(item)`.
  template <class T, class Each>
  void list(const std::vector<T>& v, Each&& each) {
    pod(uint64_t(v.size()));
    for (const T& item : v) each(item);
  }
  void text_map(const std::map<std::string, std::string>& m) {
    pod(uint64_t(m.size()));
    for (const auto& [key, value] : m) {
      text(key);
      text(value);
    }
  }
  bool flush() {
    if (ok_ && !buffer_.empty()) ok_ = write_all(buffer_.data(), buffer_.size());
    buffer_.clear();
    return ok_;
  }

 private:
  void put(const void* data, size_t size) {
    if (size >= kDirect) {
      flush();
      if (ok_) ok_ = write_all(static_cast<const char*>(data), size);
      return;
    }
    buffer_.append(static_cast<const char*>(data), size);
    if (buffer_.size() >= kDirect) flush();
  }
  bool write_all(const char* p, size_t size) {
    while (size > 0) {
      ssize_t n = ::write(fd_, p, size);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) return false;
      p += n;
      size -= size_t(n);
    }
    return true;
  }
  static constexpr size_t kDirect = 1 << 16;
  int fd_;
  std::string buffer_;
  bool ok_ = true;
};

/// When the parent gives up on a child: after `total_s` seconds in all (0: never), or after `idle_s` seconds
/// without progress (0: never), progress being bytes arriving or the child bumping `*progress` (a counter in
/// memory shared with it). Idle time is the child's own CPU time (Linux: /proc), so a child that a loaded machine
/// (or a sanitizer) starves is not taken for one that hangs: a parse looping in HDF5 burns CPU without progress.
/// A child that neither progresses nor runs (blocked) is stopped after kBlockedFactor times `idle_s` of wall
/// time. A parse whose work is bounded by what the file declares needs no total limit: one that stops making
/// progress has hung, whatever the file's size and the machine's load.
/// `asleep_s` (0: off) stops sooner a child that sleeps (state S: waiting on a lock or a pipe, not starved and not
/// in disk I/O) without CPU or progress for that long: a parse of a local file never waits like that, but a child
/// forked while another thread held a lock it needs does (clang 14's ASan allocator has no fork handler).
/// `max_added_bytes` (0: off) stops a child whose resident memory grows by more than that beyond what it shared
/// with the parent at the fork (Linux: /proc): a parser that believes a header announcing 2e9 vertices allocates
/// about 1 GB a second. (RLIMIT_AS cannot do this: a sanitizer reserves terabytes of address space up front.)
struct Watchdog {
  double total_s = 0;
  double idle_s = 0;
  const std::atomic<uint64_t>* progress = nullptr;
  double asleep_s = 0;
  double max_added_bytes = 0;
  static constexpr double kBlockedFactor = 12;
};

/// CPU seconds (user + system) a child process has used so far; negative where it cannot be read. `state`, when
/// given, gets the process's state letter from /proc (R running, S sleeping, D disk wait, ...; 0 if unknown);
/// `resident_bytes` its resident memory (0 if unknown).
inline double child_cpu_seconds(pid_t pid, char* state = nullptr, double* resident_bytes = nullptr) {
  if (state) *state = 0;
  if (resident_bytes) *resident_bytes = 0;
  char path[64];
  std::snprintf(path, sizeof path, "/proc/%d/stat", int(pid));
  std::FILE* f = std::fopen(path, "r");
  if (!f) return -1;
  char line[1024];
  const size_t n = std::fread(line, 1, sizeof line - 1, f);
  std::fclose(f);
  line[n] = 0;
  // Fields after the command name (which may hold spaces and parentheses): state is field 3, utime 14, stime 15,
  // rss 24 (pages).
  const char* p = std::strrchr(line, ')');
  if (!p) return -1;
  unsigned long long utime = 0, stime = 0, pages = 0;
  char letter = 0;
  const int read =
      std::sscanf(p + 1, " %c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %llu %llu %*d %*d %*d %*d %*d %*d %*u %*u %llu",
                  &letter, &utime, &stime, &pages);
  if (read < 3) return -1;
  if (state) *state = letter;
  if (resident_bytes && read == 4) *resident_bytes = double(pages) * double(::sysconf(_SC_PAGESIZE));
  const long ticks = ::sysconf(_SC_CLK_TCK);
  return ticks > 0 ? double(utime + stime) / double(ticks) : -1;
}

// Bounds-checked and watchdog-bound: the bytes come from our own child, but a child that a hostile file
// corrupted before it finished could send anything, or nothing.
class WireReader {
 public:
  using Clock = std::chrono::steady_clock;
  WireReader(int fd, const Watchdog& watchdog, pid_t child = 0)
      : fd_(fd), watchdog_(watchdog), child_(child), start_(Clock::now()) {
    seen_ = watchdog.progress ? watchdog.progress->load() : 0;
    if (watchdog.max_added_bytes > 0 && child > 0) {
      child_cpu();
      shared_at_fork_ = resident_;  // just forked: the pages it shares with the parent
    }
    progressed();
  }
  bool ok() const { return ok_; }
  bool timed_out() const { return timed_out_; }
  /// Timed out because the child slept without progress for the watchdog's `asleep_s`.
  bool asleep() const { return asleep_; }
  /// Stopped because the child's memory grew beyond the watchdog's `max_added_bytes`.
  bool over_memory() const { return over_memory_; }
  template <class T>
  void pod(T& value) {
    get(&value, sizeof(T));
  }
  void text(std::string& s) {
    uint64_t n = 0;
    pod(n);
    if (!ok_ || n > kMaxElements) {
      ok_ = false;
      return;
    }
    s.resize(size_t(n));
    get(s.data(), size_t(n));
  }
  template <class T>
  void array(std::vector<T>& v) {
    uint64_t n = 0;
    pod(n);
    if (!ok_ || n > kMaxElements) {
      ok_ = false;
      return;
    }
    v.resize(size_t(n));
    get(v.data(), size_t(n) * sizeof(T));
  }
  template <class T>
  void maybe(std::optional<T>& v) {
    uint8_t present = 0;
    pod(present);
    if (present) {
      T value{};
      pod(value);
      v = value;
    } else {
      v.reset();
    }
  }
  /// Grows one item at a time: a damaged count ends at the pipe's end, not in one huge allocation.
  template <class T, class Each>
  void list(std::vector<T>& v, Each&& each) {
    uint64_t n = 0;
    pod(n);
    for (uint64_t i = 0; ok_ && i < n; ++i) each(v.emplace_back());
  }
  void text_map(std::map<std::string, std::string>& m) {
    uint64_t n = 0;
    pod(n);
    for (uint64_t i = 0; ok_ && i < n; ++i) {
      std::string key;
      text(key);
      text(m[key]);
    }
  }

 private:
  // The format allows 2^31 elements per dataset (h5.cpp); anything more is not an asset.
  static constexpr uint64_t kMaxElements = uint64_t(1) << 31;
  // The child's CPU time, read from /proc at most every 100 ms (the wire calls this for every value).
  double child_cpu() {
    const auto now = Clock::now();
    if (now - cpu_polled_ >= std::chrono::milliseconds(100) || cpu_ < 0) {
      cpu_ = child_cpu_seconds(child_, &state_, &resident_);
      cpu_polled_ = now;
    }
    return cpu_;
  }
  void progressed() {
    last_progress_ = Clock::now();
    asleep_since_.reset();
    if (watchdog_.idle_s > 0 && child_ > 0) cpu_at_progress_ = child_cpu();
  }
  // Milliseconds left before the watchdog fires (<= 0: it has).
  long long left_ms() {
    if (watchdog_.progress) {
      const uint64_t count = watchdog_.progress->load();
      if (count != seen_) {
        seen_ = count;
        progressed();
      }
    }
    const auto now = Clock::now();
    long long left = std::numeric_limits<long long>::max();
    auto until = [&](Clock::time_point from, double seconds) {
      seconds = std::min(seconds, 1e9);  // 31 years: any longer limit is none, and its nanoseconds overflowed
      const auto end = from + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
      // Rounded up: the watchdog never fires before its time (a remaining 0.4 ms is 1 ms, not 0).
      left = std::min<long long>(left, std::chrono::ceil<std::chrono::milliseconds>(end - now).count());
    };
    if (watchdog_.total_s > 0) until(start_, watchdog_.total_s);
    if (watchdog_.max_added_bytes > 0 && child_ > 0) {
      child_cpu();  // reads its resident memory too
      if (resident_ - shared_at_fork_ > watchdog_.max_added_bytes) {
        over_memory_ = true;
        return 0;
      }
    }
    if (watchdog_.idle_s > 0) {
      const double cpu = cpu_at_progress_ >= 0 ? child_cpu() : -1;
      if (cpu >= 0) {
        // The child's CPU time since its last progress; blocked (no CPU, no progress) for long, it is stopped too.
        const double idle_cpu = cpu - cpu_at_progress_;
        left = std::min<long long>(left, (long long)((watchdog_.idle_s - idle_cpu) * 1000.0) + 1);
        until(last_progress_, watchdog_.idle_s * Watchdog::kBlockedFactor);
      } else {
        until(last_progress_, watchdog_.idle_s);
      }
    }
    // Asleep since when, without CPU: a CPU tick or a progress starts the count again (with or without an idle
    // limit: the import and the repair have only a total one).
    const double cpu = watchdog_.asleep_s > 0 && child_ > 0 ? child_cpu() : -1;
    if (cpu >= 0) {
      if (state_ != 'S' || cpu != asleep_cpu_) asleep_since_.reset();
      if (state_ == 'S' && !asleep_since_) {
        asleep_since_ = now;
        asleep_cpu_ = cpu;
      }
      if (asleep_since_) {
        const long long before = left;
        until(*asleep_since_, watchdog_.asleep_s);
        if (left <= 0 && before > 0) asleep_ = true;
      }
    }
    return left;
  }
  void get(void* data, size_t size) {
    char* p = static_cast<char*>(data);
    while (ok_ && size > 0) {
      const long long left = left_ms();
      if (left <= 0) {
        ok_ = false;
        timed_out_ = !over_memory_;
        return;
      }
      pollfd pfd{fd_, POLLIN, 0};
      if (::poll(&pfd, 1, int(std::min<long long>(left, 200))) <= 0) continue;
      const ssize_t n = ::read(fd_, p, size);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        ok_ = false;  // the child closed the pipe early (it died, or sent less than it announced)
        return;
      }
      progressed();
      p += n;
      size -= size_t(n);
    }
  }
  int fd_;
  Watchdog watchdog_;
  pid_t child_ = 0;
  Clock::time_point start_, last_progress_;
  double cpu_at_progress_ = -1, cpu_ = -1;
  Clock::time_point cpu_polled_{};
  char state_ = 0;
  double resident_ = 0, shared_at_fork_ = 0;
  bool over_memory_ = false;
  std::optional<Clock::time_point> asleep_since_;
  double asleep_cpu_ = -1;
  bool asleep_ = false;
  uint64_t seen_ = 0;
  bool ok_ = true;
  bool timed_out_ = false;
};

// How an isolated call ended.
struct ChildOutcome {
  enum Kind { Finished, CannotStart, Died, TimedOut, OutOfMemory, Malformed } kind = Finished;
  int signal = 0;           ///< Died: the signal
  std::string detail;       ///< CannotStart: the reason
  bool asleep = false;      ///< TimedOut: the child slept without progress (Watchdog::asleep_s), it did not spin
  bool over_limit = false;  ///< OutOfMemory: the child grew beyond Watchdog::max_added_bytes (else: the parent)
  bool ok() const { return kind == Finished; }
};

/// The child's side of run_isolated: produces the value, sends it through `fd` and exits (none of the parent's
/// exit handlers). It dies plainly on a crash: the caller's crash handlers (a fuzzer's, a sanitizer's) would take
/// it for one of the caller's.
inline constexpr int kChildOutOfMemory = 4;  ///< the child's exit status when an allocation failed in it

template <class Value, class Produce, class Visit>
[[noreturn]] void produce_and_send(int fd, Produce& produce, Visit& visit) {
  for (int signal_number : {SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT}) ::signal(signal_number, SIG_DFL);
  if (__sanitizer_set_death_callback) __sanitizer_set_death_callback(nullptr);  // a report here is the library's
  bool ok = false;
  try {
    Value produced = produce();
    WireWriter w(fd);
    visit(w, produced);
    ok = w.flush();
  } catch (const std::bad_alloc&) {
    _exit(kChildOutOfMemory);
  } catch (...) {
  }
  _exit(ok ? 0 : 3);
}

/// Waits for the child to exit, its status in `status`. When everything arrived (`sent`), a child that then sleeps
/// instead of exiting (a lock, as in Watchdog) is stopped after `watchdog.asleep_s`: returns false then.
inline bool wait_for_child(pid_t child, const Watchdog& watchdog, bool sent, int& status) {
  if (!sent || watchdog.asleep_s <= 0) {
    while (::waitpid(child, &status, 0) < 0 && errno == EINTR) {
    }
    return true;
  }
  const auto start = std::chrono::steady_clock::now();
  for (;;) {
    const pid_t done = ::waitpid(child, &status, WNOHANG);
    if (done == child || (done < 0 && errno != EINTR)) return true;
    char state = 0;
    child_cpu_seconds(child, &state);
    if (state == 'S' &&
        std::chrono::steady_clock::now() - start > std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                                       std::chrono::duration<double>(watchdog.asleep_s))) {
      ::kill(child, SIGKILL);
      while (::waitpid(child, &status, 0) < 0 && errno == EINTR) {
      }
      return false;
    }
    ::usleep(1000);
  }
}

/// Runs `produce()` in a forked child and fills `value` with what it returned, both sides through
/// `visit(wire, value)` (one visitor for WireWriter and WireReader, so they cannot drift apart). The child is
/// stopped when the `watchdog` fires; it dies plainly on a crash (produce_and_send); a failed allocation in it is
/// `OutOfMemory`, another exception `Malformed`.
template <class Value, class Produce, class Visit>
ChildOutcome run_isolated(const Watchdog& watchdog, Value& value, Produce&& produce, Visit&& visit) {
  ChildOutcome outcome;
  int fds[2];
  if (::pipe(fds) != 0)
    return {ChildOutcome::CannotStart, 0, std::string("cannot create a pipe: ") + std::strerror(errno)};
#if defined(F_SETPIPE_SZ)
  // A 1 MiB pipe instead of 64 KiB: a large asset crosses in 16x fewer writes, reads and switches between the two
  // processes (a 1024^3 asset's 91 MiB: 0.2 s -> see docs/performance.md). Refused above the system's limit: kept.
  ::fcntl(fds[1], F_SETPIPE_SZ, 1 << 20);
#endif
  std::fflush(nullptr);
  const pid_t child = ::fork();
  if (child < 0) {
    ::close(fds[0]);
    ::close(fds[1]);
    return {ChildOutcome::CannotStart, 0, std::string("cannot start a child process: ") + std::strerror(errno)};
  }
  if (child == 0) {
    ::close(fds[0]);
    produce_and_send<Value>(fds[1], produce, visit);
  }
  ::close(fds[1]);
  WireReader r(fds[0], watchdog, child);
  bool out_of_memory = false;
  try {
    visit(r, value);
  } catch (const std::bad_alloc&) {
    out_of_memory = true;
  }
  ::close(fds[0]);
  if (!r.ok() || out_of_memory) ::kill(child, SIGKILL);
  int status = 0;
  if (!wait_for_child(child, watchdog, r.ok(), status)) return outcome;  // stopped asleep after sending: it stands
  if (out_of_memory || (WIFEXITED(status) && WEXITSTATUS(status) == kChildOutOfMemory))
    return {ChildOutcome::OutOfMemory, 0, {}};
  if (r.over_memory()) return {ChildOutcome::OutOfMemory, 0, {}, false, true};
  if (r.ok() && WIFEXITED(status) && WEXITSTATUS(status) == 0) return outcome;
  if (WIFSIGNALED(status) && WTERMSIG(status) != SIGKILL) return {ChildOutcome::Died, WTERMSIG(status), {}};
  if (r.timed_out()) return {ChildOutcome::TimedOut, 0, {}, r.asleep()};
  return {ChildOutcome::Malformed, 0, {}};
}

/// The same with only a total time limit.
template <class Value, class Produce, class Visit>
ChildOutcome run_isolated(double time_limit_s, Value& value, Produce&& produce, Visit&& visit) {
  return run_isolated(Watchdog{time_limit_s, 0, nullptr}, value, std::forward<Produce>(produce),
                      std::forward<Visit>(visit));
}

}  // namespace voxfmt::detail
#endif  // !_WIN32
