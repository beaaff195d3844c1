// Reading untrusted files in a child process. HDF5 1.10 trusts the bytes of a file: damaged object headers,
// attribute messages or global-heap collections make it read out of bounds (SIGSEGV) or loop forever, deep
// inside its decoders, where no check of ours can intervene. So the parse runs in a forked child that sends
// back what it read (findings and data) through a pipe (voxfmt/detail/isolated_call.h); a child that dies or
// hangs becomes a READ_FAILED finding instead of taking the caller down.
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>

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

// What a read sends back: its findings and, unless it failed, the value.
template <class Value>
struct ReadOutcome {
  std::vector<Issue> issues;
  std::optional<Value> value;
};

// Reads `path` with `read` in a child process (through `visit`, a visitor of Value for either wire). Returns the
// value (with the child's findings appended to `issues`), or nothing with a READ_FAILED finding when the child
// died, hung or sent something malformed.
template <class Value, class ReadInProcess, class Visit>
std::optional<Value> read_isolated(const std::string& path, std::vector<Issue>& issues, ReadInProcess&& read,
                                   Visit&& visit) {
  if (!read_isolation()) return read(path, issues);
  // One isolated read at a time in this process: a child forked while another of our threads is inside HDF5
  // would wait forever for HDF5's lock, which that thread holds in the parent only.
  static std::mutex one_at_a_time;
  std::lock_guard<std::mutex> lock(one_at_a_time);
  // Generous for a real read (seconds per 100 MB), short enough that a looping parse ends.
  std::error_code ec;
  const auto file_size = std::filesystem::file_size(path, ec);
  const double limit_s = 5.0 + (ec ? 0.0 : double(file_size) / 20e6);
  ReadOutcome<Value> read_back;
  const ChildOutcome outcome = run_isolated(
      limit_s, read_back,
      [&] {
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
  auto refuse = [&](const std::string& why) {
    issues.push_back(Issue{IssueCode::ReadFailed, Severity::Error, "/", why});
    return std::nullopt;
  };
  switch (outcome.kind) {
    case ChildOutcome::Finished:
      issues.insert(issues.end(), read_back.issues.begin(), read_back.issues.end());
      return std::move(read_back.value);
    case ChildOutcome::CannotStart:
      return refuse("cannot start the isolated read: " + outcome.detail);
    case ChildOutcome::Died:
      return refuse("the file is damaged: HDF5 died of signal " + std::to_string(outcome.signal) + " (" +
                    strsignal(outcome.signal) + ") reading it (read in isolation: nothing else was affected)");
    case ChildOutcome::TimedOut:
      return refuse("the file is damaged: HDF5 did not finish reading it within " + std::to_string(int(limit_s)) +
                    " s (read in isolation, stopped)");
    case ChildOutcome::OutOfMemory:
      return refuse("not enough memory to read the asset");
    case ChildOutcome::Malformed:
      break;
  }
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
