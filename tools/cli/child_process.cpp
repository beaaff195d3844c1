#include "child_process.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace voxfmt::cli {

namespace {

constexpr size_t kMaxStderr = 64 * 1024;

// Reads what is available; false at end of file.
bool drain(int fd, std::string& into, size_t keep) {
  char buffer[8192];
  for (;;) {
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n > 0) {
      into.append(buffer, size_t(n));
      if (keep && into.size() > keep) into.erase(0, into.size() - keep);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    return n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK);
  }
}

}  // namespace

std::string self_executable() {
  char path[4096];
  const ssize_t n = ::readlink("/proc/self/exe", path, sizeof path - 1);
  if (n <= 0) throw std::runtime_error("cannot find the voxfmt executable (/proc/self/exe)");
  return std::string(path, size_t(n));
}

ChildPool::~ChildPool() { kill_all(); }

void ChildPool::start(size_t id, const std::vector<std::string>& argv, const ChildLimits& limits) {
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  int out[2], err[2];
  if (::pipe2(out, O_CLOEXEC) != 0) throw std::runtime_error(std::string("pipe: ") + std::strerror(errno));
  if (::pipe2(err, O_CLOEXEC) != 0) {
    ::close(out[0]);
    ::close(out[1]);
    throw std::runtime_error(std::string("pipe: ") + std::strerror(errno));
  }
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid < 0) {
    for (int fd : {out[0], out[1], err[0], err[1]}) ::close(fd);
    throw std::runtime_error(std::string("fork: ") + std::strerror(errno));
  }
  if (pid == 0) {  // child: async-signal-safe calls only
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (::getppid() != parent) ::_exit(127);  // the parent died before prctl took effect
    ::setpgid(0, 0);
    if (limits.max_memory_bytes) {
      const rlimit limit{rlim_t(limits.max_memory_bytes), rlim_t(limits.max_memory_bytes)};
      ::setrlimit(RLIMIT_AS, &limit);
    }
    ::dup2(out[1], STDOUT_FILENO);
    ::dup2(err[1], STDERR_FILENO);
    const int null = ::open("/dev/null", O_RDONLY);
    if (null >= 0) ::dup2(null, STDIN_FILENO);
    ::execv(args[0], args.data());
    ::_exit(127);
  }
  ::close(out[1]);
  ::close(err[1]);
  ::fcntl(out[0], F_SETFL, O_NONBLOCK);
  ::fcntl(err[0], F_SETFL, O_NONBLOCK);
  Child child;
  child.id = id;
  child.pid = pid;
  child.out_fd = out[0];
  child.err_fd = err[0];
  child.start = std::chrono::steady_clock::now();
  child.timeout = limits.timeout_seconds;
  children_.push_back(std::move(child));
}

void ChildPool::wait(int wait_ms) const {
  std::vector<pollfd> fds;
  for (const Child& c : children_) {
    if (c.out_fd >= 0) fds.push_back({c.out_fd, POLLIN, 0});
    if (c.err_fd >= 0) fds.push_back({c.err_fd, POLLIN, 0});
  }
  // Wake up in time for the earliest timeout (in double: a timeout of weeks overflows an int of milliseconds), and
  // soon for a child whose pipes are closed: it is exiting, and its reap should not wait a whole poll (which, with
  // no pipe left to watch, is a sleep: 250 ms added to every bake of a small mesh). Soon is as long as it has been
  // closing (1, 2, 4 ... ms), so one that lingers is not polled a thousand times a second.
  const auto now = std::chrono::steady_clock::now();
  for (const Child& c : children_) {
    if (c.timeout > 0 && !c.timed_out) {
      const double left = c.timeout - std::chrono::duration<double>(now - c.start).count();
      wait_ms = int(std::max(0.0, std::min(double(wait_ms), left * 1000 + 1)));
    }
    if (c.out_fd < 0 && c.err_fd < 0)
      wait_ms = std::min(wait_ms, std::max(1, int(std::chrono::duration<double, std::milli>(now - c.closed).count())));
  }
  if (!fds.empty())
    ::poll(fds.data(), fds.size(), wait_ms);  // EINTR (a signal) just ends the wait early
  else if (wait_ms > 0)
    ::usleep(useconds_t(wait_ms) * 1000);
}

std::vector<ChildResult> ChildPool::poll(int wait_ms) {
  wait(wait_ms);
  std::vector<ChildResult> finished;
  for (size_t i = 0; i < children_.size();) {
    Child& c = children_[i];
    if (c.out_fd >= 0 && !drain(c.out_fd, c.out, 0)) {
      ::close(c.out_fd);
      c.out_fd = -1;
    }
    if (c.err_fd >= 0 && !drain(c.err_fd, c.err, kMaxStderr)) {
      ::close(c.err_fd);
      c.err_fd = -1;
    }
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - c.start).count();
    if (c.timeout > 0 && !c.timed_out && elapsed > c.timeout) {
      ::kill(c.pid, SIGKILL);
      c.timed_out = true;
    }
    int status = 0;
    // Reaped once both pipes are closed (all output read), or right away after a kill (a grandchild could
    // hold the pipes open).
    const bool pipes_done = c.out_fd < 0 && c.err_fd < 0;
    if (pipes_done && c.closed == std::chrono::steady_clock::time_point{}) c.closed = std::chrono::steady_clock::now();
    const pid_t r = (pipes_done || c.timed_out) ? ::waitpid(c.pid, &status, c.timed_out ? 0 : WNOHANG) : 0;
    if (r == c.pid) {
      ChildResult result;
      result.id = c.id;
      result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      result.signal = WIFSIGNALED(status) ? WTERMSIG(status) : 0;
      result.timed_out = c.timed_out;
      result.out = std::move(c.out);
      result.err = std::move(c.err);
      result.seconds = elapsed;
      if (c.out_fd >= 0) ::close(c.out_fd);
      if (c.err_fd >= 0) ::close(c.err_fd);
      finished.push_back(std::move(result));
      children_.erase(children_.begin() + std::ptrdiff_t(i));
      continue;
    }
    ++i;
  }
  return finished;
}

void ChildPool::signal_all(int signal_number) const {
  for (const Child& c : children_)
    if (::kill(-c.pid, signal_number) != 0) ::kill(c.pid, signal_number);  // not yet in its own group
}

void ChildPool::pause_clocks(std::chrono::steady_clock::duration by) {
  for (Child& c : children_) c.start += by;
}

void ChildPool::kill_all() {
  for (Child& c : children_) {
    ::kill(c.pid, SIGKILL);
    int status = 0;
    ::waitpid(c.pid, &status, 0);
    if (c.out_fd >= 0) ::close(c.out_fd);
    if (c.err_fd >= 0) ::close(c.err_fd);
  }
  children_.clear();
}

}  // namespace voxfmt::cli
