// Reading untrusted files in a child process. HDF5 1.10 trusts the bytes of a file: damaged object headers,
// attribute messages or global-heap collections make it read out of bounds (SIGSEGV) or loop forever, deep
// inside its decoders, where no check of ours can intervene. So the parse runs in a forked child that sends
// back what it read (findings and data) through a pipe (voxfmt/detail/isolated_call.h); a child that dies or
// hangs becomes a READ_FAILED finding instead of taking the caller down.
#include <sys/mman.h>

#include <atomic>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <new>

#include "h5.h"
#include "load.h"
#include "voxfmt/detail/isolated_call.h"

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

// Set in an isolated read's child: the counter its parent watches.
std::atomic<uint64_t>* g_progress = nullptr;
constexpr double kIdleLimitS = 10.0;
// A read of a local file never sleeps this long without progress (see Watchdog::asleep_s).
constexpr double kAsleepLimitS = 5.0;

#if !defined(_WIN32)
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
  w.pod(vm.distance_quantum);
  w.pod(vm.estimate_quantum);
  w.pod(vm.lattice_error);
  w.pod(vm.estimates);
  w.array(vm.bricks);
  w.array(vm.brick_values);
  w.array(vm.lattice);
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

// What a read sends back: its findings and, unless it failed, the value.
template <class Value>
struct ReadOutcome {
  std::vector<Issue> issues;
  std::optional<Value> value;
};

// A counter in memory the parent shares with its children: the child bumps it after each piece it reads
// (h5::Reader's progress hook), the parent's watchdog watches it.
class SharedCounter {
 public:
  SharedCounter()
      : memory_(
            ::mmap(nullptr, sizeof(std::atomic<uint64_t>), PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1, 0)) {
    if (memory_ != MAP_FAILED) counter_ = new (memory_) std::atomic<uint64_t>(0);
  }
  ~SharedCounter() {
    if (memory_ != MAP_FAILED) ::munmap(memory_, sizeof(std::atomic<uint64_t>));
  }
  SharedCounter(const SharedCounter&) = delete;
  SharedCounter& operator=(const SharedCounter&) = delete;
  std::atomic<uint64_t>* get() const { return counter_; }  // null if the memory could not be mapped

 private:
  void* memory_;
  std::atomic<uint64_t>* counter_ = nullptr;
};

// Why a child's read gave no value, as the READ_FAILED (or OUT_OF_MEMORY) finding the caller gets.
Issue failed_read(const ChildOutcome& outcome) {
  auto refuse = [](const std::string& why, IssueCode code = IssueCode::ReadFailed) {
    return Issue{code, Severity::Error, "/", why};
  };
  switch (outcome.kind) {
    case ChildOutcome::CannotStart:
      return refuse("cannot start the isolated read: " + outcome.detail);
    case ChildOutcome::Died:
      return refuse("the file is damaged: HDF5 died of signal " + std::to_string(outcome.signal) + " (" +
                    strsignal(outcome.signal) + ") reading it (read in isolation: nothing else was affected)");
    case ChildOutcome::TimedOut:
      if (outcome.asleep)
        return refuse("the read made no progress: it waited " + std::to_string(int(kAsleepLimitS)) +
                      " s twice without reading (not a regular file? read in isolation, stopped)");
      return refuse("the file is damaged: HDF5 made no progress reading it for " + std::to_string(int(kIdleLimitS)) +
                    " s of its CPU time (read in isolation, stopped)");
    case ChildOutcome::OutOfMemory:
      return refuse("not enough memory to read the asset", IssueCode::OutOfMemory);
    case ChildOutcome::Finished:
    case ChildOutcome::Malformed:
      break;
  }
  return refuse("the isolated read failed (out of memory, or it sent back malformed data)");
}

// Reads `path` with `read` in a child process (through `visit`, a visitor of Value for either wire). Returns the
// value (with the child's findings appended to `issues`), or nothing with a READ_FAILED finding when the child
// died, hung or sent something malformed.
template <class Value, class ReadInProcess, class Visit>
std::optional<Value> read_isolated(const std::string& path, std::vector<Issue>& issues, ReadInProcess&& read,
                                   Visit&& visit) {
  if (!read_isolation()) return read(path, issues);
  // One isolated read at a time in this process, and none while a write is inside HDF5: a child forked while
  // another of our threads is inside HDF5 would wait forever for HDF5's lock, which that thread holds in the parent
  // only (a bake writing on one thread stalled a load on another for the watchdog's 5 s, twice).
  std::lock_guard<std::mutex> lock(h5::process_mutex());
  // The parent stops the child only when neither the shared counter nor the pipe has moved while the child used
  // kIdleLimitS of CPU time (a starved child is not a hung one; see Watchdog). A real read never pauses that long
  // between pieces of at most 2^22 elements, whatever the file's size or the machine's load; a parse that loops in
  // HDF5 stops moving at once. What a file may make us read is bounded by the spec's limits.
  const SharedCounter counter;
  if (!counter.get()) {
    issues.push_back(Issue{IssueCode::ReadFailed, Severity::Error, "/",
                           std::string("cannot start the isolated read: ") + std::strerror(errno)});
    return std::nullopt;
  }
  ReadOutcome<Value> read_back;
  auto attempt = [&] {
    read_back = ReadOutcome<Value>{};
    return run_isolated(
        Watchdog{0, kIdleLimitS, counter.get(), kAsleepLimitS}, read_back,
        [&] {
          g_progress = counter.get();  // in the child
          ReadOutcome<Value> r;
          r.value = read(path, r.issues);
          return r;
        },
        [&](auto& w, auto& r) {
          visit_issues(w, r.issues);
          uint8_t present = r.value.has_value();
          w.pod(present);
          if (!present) return;
          if (!r.value) r.value.emplace();  // the parent's side
          visit(w, *r.value);
        });
  };
  ChildOutcome outcome = attempt();
  // A child asleep on a lock inherited from another thread (the process's other libraries start threads: OpenVDB's
  // log4cplus starts four) says nothing about the file: read it once more. A second sleep is the file's (a FIFO).
  if (outcome.kind == ChildOutcome::TimedOut && outcome.asleep) outcome = attempt();
  if (outcome.kind != ChildOutcome::Finished) {
    issues.push_back(failed_read(outcome));
    return std::nullopt;
  }
  issues.insert(issues.end(), read_back.issues.begin(), read_back.issues.end());
  return std::move(read_back.value);
}
#endif  // !_WIN32

}  // namespace

void report_read_progress() {
  if (g_progress) g_progress->fetch_add(1, std::memory_order_relaxed);
}

std::optional<Asset> load_asset(const std::string& path, std::vector<Issue>& issues, const ReadOptions& options) {
  auto read = [&options](const std::string& p, std::vector<Issue>& found) {
    return load_asset_in_process(p, found, options);
  };
#if defined(_WIN32)
  return read(path, issues);
#else
  return read_isolated<Asset>(path, issues, read, [](auto& w, auto& a) { visit_asset(w, a); });
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
