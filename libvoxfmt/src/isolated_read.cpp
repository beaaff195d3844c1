// Reading untrusted files in a child process. HDF5 1.10 trusts the bytes of a file: damaged object headers,
// attribute messages or global-heap collections make it read out of bounds (SIGSEGV) or loop forever, deep
// inside its decoders, where no check of ours can intervene. So the parse runs in a forked child that sends
// back what it read (findings and data) through a pipe; a child that dies or hangs becomes a READ_FAILED
// finding instead of taking the caller down.
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <new>
#include <type_traits>

#include "load.h"

#if !defined(_WIN32)
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>
#endif

// Sanitizer runtimes (when linked) call a death callback on a report; a fuzzer registers one that saves the input
// as a crash. Weak: absent from ordinary builds.
extern "C" void __sanitizer_set_death_callback(void (*callback)(void)) __attribute__((weak));

namespace voxfmt {

namespace {
bool isolation_from_environment() {
  const char* value = std::getenv("VOXFMT_READ_ISOLATION");
  return !(value && std::strcmp(value, "0") == 0);
}
bool g_isolation = isolation_from_environment();
}  // namespace

void set_read_isolation(bool enabled) { g_isolation = enabled; }
bool read_isolation() { return g_isolation; }

namespace detail {
namespace {

// ------------------------------------------------------------------ a minimal wire format (child -> parent)
// Streamed through the pipe: arrays go straight from the child's vectors into the parent's, with no copy of
// the whole asset on either side (a 300^3 grid is ~150 MB).

#if !defined(_WIN32)
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

// Bounds-checked and deadline-bound: the bytes come from our own child, but a child that a hostile file
// corrupted before it finished could send anything, or nothing.
class WireReader {
 public:
  WireReader(int fd, std::chrono::steady_clock::time_point deadline) : fd_(fd), deadline_(deadline) {}
  bool ok() const { return ok_; }
  bool timed_out() const { return timed_out_; }
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
  void get(void* data, size_t size) {
    char* p = static_cast<char*>(data);
    while (ok_ && size > 0) {
      const auto left =
          std::chrono::duration_cast<std::chrono::milliseconds>(deadline_ - std::chrono::steady_clock::now()).count();
      if (left <= 0) {
        ok_ = false;
        timed_out_ = true;
        return;
      }
      pollfd pfd{fd_, POLLIN, 0};
      if (::poll(&pfd, 1, int(std::min<long long>(left, 1000))) <= 0) continue;
      const ssize_t n = ::read(fd_, p, size);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        ok_ = false;  // the child closed the pipe early (it died, or sent less than it announced)
        return;
      }
      p += n;
      size -= size_t(n);
    }
  }
  int fd_;
  std::chrono::steady_clock::time_point deadline_;
  bool ok_ = true;
  bool timed_out_ = false;
};

// One visitor per structure for both directions (WireWriter with const data, WireReader with data to fill):
// every field is named once, so the two sides cannot drift apart.
template <class Wire, class P>
void visit_provenance(Wire& w, P& p) {
  w.text(p.generator);
  w.text(p.generator_version);
  w.text(p.source_file);
  w.text(p.source_sha256);
  w.text(p.build_parameters_json);
  w.text(p.created_utc);
  w.text_map(p.dependency_versions);
  w.list(p.build_warnings, [&](auto& warning) {
    w.text(warning.code);
    w.text(warning.message);
  });
}

template <class Wire, class A>
void visit_asset(Wire& w, A& a) {
  w.pod(a.version);
  w.text(a.up_axis);
  w.pod(a.bounds_min);
  w.pod(a.bounds_max);
  auto& vm = a.voxelmap;
  w.pod(vm.origin);
  w.pod(vm.voxel_size);
  w.pod(vm.dims);
  w.pod(vm.distance_band);
  w.maybe(vm.margin);
  w.maybe(vm.shell_thickness);
  w.array(vm.layers);
  w.array(vm.distances);
  auto& ps = a.point_shell;
  w.array(ps.points);
  w.array(ps.normals);
  w.array(ps.sphere_centers);
  w.array(ps.sphere_radii);
  w.array(ps.child_begin);
  w.array(ps.child_count);
  w.array(ps.level_offsets);
  w.maybe(ps.point_spacing);
  w.maybe(ps.branching);
  w.pod(a.mass);
  visit_provenance(w, a.provenance);
}

template <class Wire, class Issues>
void visit_issues(Wire& w, Issues& issues) {
  w.list(issues, [&](auto& issue) {
    w.pod(issue.code);
    w.pod(issue.severity);
    w.text(issue.path);
    w.text(issue.message);
  });
}

// ------------------------------------------------------------------ the child process

// Reads `path` with `read` in a child process that streams the result back, both sides through `visit` (a
// visitor of Value for either wire). Returns the value (with the child's findings appended to `issues`), or
// nothing with a READ_FAILED finding when the child died, hung or sent something malformed.
template <class Value, class ReadInProcess, class Visit>
std::optional<Value> read_isolated(const std::string& path, std::vector<Issue>& issues, ReadInProcess&& read,
                                   Visit&& visit) {
  if (!read_isolation()) return read(path, issues);
  // One isolated read at a time in this process: a child forked while another of our threads is inside HDF5
  // would wait forever for HDF5's lock, which that thread holds in the parent only.
  static std::mutex one_at_a_time;
  std::lock_guard<std::mutex> lock(one_at_a_time);
  auto refuse = [&](const std::string& why) {
    issues.push_back(Issue{IssueCode::ReadFailed, Severity::Error, "/", why});
    return std::nullopt;
  };
  // Generous for a real read (seconds per 100 MB), short enough that a looping parse ends.
  std::error_code ec;
  const auto file_size = std::filesystem::file_size(path, ec);
  const double limit_s = 5.0 + (ec ? 0.0 : double(file_size) / 20e6);
  int fds[2];
  if (::pipe(fds) != 0)
    return refuse(std::string("cannot create a pipe for the isolated read: ") + std::strerror(errno));
  std::fflush(nullptr);
  const pid_t child = ::fork();
  if (child < 0) {
    ::close(fds[0]);
    ::close(fds[1]);
    return refuse(std::string("cannot start the isolated read: ") + std::strerror(errno));
  }
  if (child == 0) {
    // Die plainly: the caller's crash handlers (a fuzzer's, a sanitizer's, a crash reporter's) would take the
    // child's crash inside HDF5 for one of the caller's.
    for (int signal_number : {SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT}) ::signal(signal_number, SIG_DFL);
    if (__sanitizer_set_death_callback) __sanitizer_set_death_callback(nullptr);  // a report here is HDF5's
    ::close(fds[0]);
    bool ok = false;
    try {
      std::vector<Issue> found;
      std::optional<Value> value = read(path, found);
      WireWriter w(fds[1]);
      visit_issues(w, found);
      w.pod(uint8_t(value.has_value()));
      if (value) visit(w, *value);
      ok = w.flush();
    } catch (...) {
    }
    _exit(ok ? 0 : 3);  // none of the parent's exit handlers
  }
  ::close(fds[1]);
  WireReader r(fds[0],
               std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                                      std::chrono::duration<double>(limit_s)));
  std::vector<Issue> found;
  std::optional<Value> value;
  bool out_of_memory = false;
  try {
    uint8_t present = 0;
    visit_issues(r, found);
    r.pod(present);
    if (r.ok() && present) {
      value.emplace();
      visit(r, *value);
    }
  } catch (const std::bad_alloc&) {
    out_of_memory = true;
  }
  ::close(fds[0]);
  if (!r.ok() || out_of_memory) ::kill(child, SIGKILL);
  int status = 0;
  while (::waitpid(child, &status, 0) < 0 && errno == EINTR) {
  }
  if (out_of_memory) return refuse("not enough memory to read the asset");
  if (r.ok() && WIFEXITED(status) && WEXITSTATUS(status) == 0) {
    issues.insert(issues.end(), found.begin(), found.end());
    return value;
  }
  if (WIFSIGNALED(status) && WTERMSIG(status) != SIGKILL)
    return refuse("the file is damaged: HDF5 died of signal " + std::to_string(WTERMSIG(status)) + " (" +
                  strsignal(WTERMSIG(status)) + ") reading it (read in isolation: nothing else was affected)");
  if (r.timed_out())
    return refuse("the file is damaged: HDF5 did not finish reading it within " + std::to_string(int(limit_s)) +
                  " s (read in isolation, stopped)");
  return refuse("the isolated read failed (out of memory, or it sent back malformed data)");
}
#endif  // !_WIN32

}  // namespace

std::optional<Asset> load_asset(const std::string& path, std::vector<Issue>& issues) {
#if defined(_WIN32)
  return load_asset_in_process(path, issues);
#else
  return read_isolated<Asset>(path, issues, load_asset_in_process, [](auto& w, auto& a) { visit_asset(w, a); });
#endif
}

std::optional<Provenance> load_provenance(const std::string& path, std::vector<Issue>& issues) {
#if defined(_WIN32)
  return load_provenance_in_process(path, issues);
#else
  return read_isolated<Provenance>(path, issues, load_provenance_in_process,
                                   [](auto& w, auto& p) { visit_provenance(w, p); });
#endif
}

}  // namespace detail
}  // namespace voxfmt
