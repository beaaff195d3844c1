// Child processes for `voxfmt batch`: start, collect output, time out, reap.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <cstddef>
#include <string>
#include <vector>

namespace voxfmt::cli {

struct ChildLimits {
  double timeout_seconds = 0;   ///< 0 = none; on expiry the child gets SIGKILL
  size_t max_memory_bytes = 0;  ///< 0 = none; RLIMIT_AS of the child (allocation fails beyond it)
};

struct ChildResult {
  size_t id = 0;       ///< the caller's id given to start()
  int exit_code = -1;  ///< when it exited normally
  int signal = 0;      ///< when a signal ended it
  bool timed_out = false;
  std::string out, err;  ///< stdout, and the last 64 KiB of stderr
  double seconds = 0;    ///< wall time
};

/// Runs children with their stdout and stderr captured. Each child is in a process group of its own (a
/// terminal's Ctrl-C reaches only the parent, which decides) and gets SIGKILL when the parent dies, even by
/// SIGKILL, so a killed batch leaves no orphan bakes behind.
class ChildPool {
 public:
  ChildPool() = default;
  ~ChildPool();
  ChildPool(const ChildPool&) = delete;
  ChildPool& operator=(const ChildPool&) = delete;

  /// Starts argv[0] with these arguments. Throws std::runtime_error when it cannot fork.
  void start(size_t id, const std::vector<std::string>& argv, const ChildLimits& limits);
  /// Waits up to `wait_ms` for output or exits; returns the children that finished (and were reaped).
  std::vector<ChildResult> poll(int wait_ms);
  size_t running() const { return children_.size(); }
  /// SIGKILLs and reaps every running child.
  void kill_all();
  /// Sends `signal_number` to every running child's process group (SIGSTOP, SIGCONT: Ctrl-Z reaches only the
  /// parent's group).
  void signal_all(int signal_number) const;
  /// Moves every running child's start `by` later: time stopped does not count toward its timeout.
  void pause_clocks(std::chrono::steady_clock::duration by);

 private:
  struct Child {
    size_t id;
    pid_t pid;
    int out_fd, err_fd;
    std::chrono::steady_clock::time_point start;
    double timeout;
    bool timed_out = false;
    std::chrono::steady_clock::time_point closed{};  ///< when both pipes closed (it is exiting)
    std::string out, err;
  };
  /// Sleeps until a child writes, a timeout is due or `wait_ms` have passed (the first part of poll).
  void wait(int wait_ms) const;
  std::vector<Child> children_;
};

/// The path of the running executable (to start `voxfmt build` children of the same build).
std::string self_executable();

}  // namespace voxfmt::cli
