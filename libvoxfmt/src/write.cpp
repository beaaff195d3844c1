// Writing an asset: validate (structure first, semantic rules beside the write), then write atomically.
#include <fcntl.h>
#include <unistd.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <future>
#include <limits>
#include <new>
#include <optional>
#include <system_error>
#include <thread>

#include "h5.h"
#include "load.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/io.h"

namespace voxfmt {

namespace {

// Value bricks per chunk of /voxelmap/brick_values: 64 KB of codes, a unit deflate compresses well.
constexpr uint64_t kBricksPerChunk = 64;

template <class T, size_t K>
const T* flat(const std::vector<std::array<T, K>>& rows) {
  return rows.empty() ? nullptr : rows.front().data();
}

bool write_root_attributes(h5::Writer& w, const Asset& a) {
  const hid_t root = w.file();
  // The oldest version whose rules the file follows (spec §7): 2.1 for interpolated estimates.
  const bool settled = a.voxelmap.estimates == Voxelmap::Estimates::Settled;
  const uint32_t version[2] = {kFormatVersion.major, settled ? kFormatVersion.minor : 1u};
  return w.string_attribute(root, "format", "voxfmt") &&
         w.numeric_attribute<uint32_t>(root, "format_version", {2}, version) &&
         w.string_attribute(root, "units", "m") && w.string_attribute(root, "frame", "right-handed") &&
         w.string_attribute(root, "up_axis", a.up_axis) &&
         w.numeric_attribute<double>(root, "bounds_min", {3}, a.bounds_min.data()) &&
         w.numeric_attribute<double>(root, "bounds_max", {3}, a.bounds_max.data());
}

bool write_voxelmap(h5::Writer& w, const Voxelmap& vm, const WriteOptions& opt) {
  auto vg = w.create_group(w.file(), "voxelmap");
  if (!vg) return false;
  const auto bd = vm.brick_dims();
  const auto ld = vm.lattice_dims();
  const uint32_t brick_edge = Voxelmap::kBrickEdge;
  const uint64_t edge = std::max(1u, opt.chunk_edge);
  return w.numeric_attribute<double>(vg->get(), "origin", {3}, vm.origin.data()) &&
         w.numeric_attribute<double>(vg->get(), "voxel_size", {}, &vm.voxel_size) &&
         w.numeric_attribute<uint32_t>(vg->get(), "dims", {3}, vm.dims.data()) &&
         w.string_attribute(vg->get(), "index_order", "zyx") &&
         w.numeric_attribute<double>(vg->get(), "distance_band", {}, &vm.distance_band) &&
         (!vm.margin || w.numeric_attribute<uint32_t>(vg->get(), "margin", {}, &*vm.margin)) &&
         (!vm.shell_thickness || w.numeric_attribute<double>(vg->get(), "shell_thickness", {}, &*vm.shell_thickness)) &&
         w.numeric_attribute<uint32_t>(vg->get(), "brick_edge", {}, &brick_edge) &&
         w.numeric_attribute<double>(vg->get(), "distance_quantum", {}, &vm.distance_quantum) &&
         w.numeric_attribute<double>(vg->get(), "estimate_quantum", {}, &vm.estimate_quantum) &&
         w.numeric_attribute<double>(vg->get(), "lattice_error", {2}, vm.lattice_error.data()) &&
         w.dataset<int32_t>(vg->get(), "bricks", {bd[2], bd[1], bd[0]}, vm.bricks.data(), opt.deflate_level,
                            {edge, edge, edge}) &&
         w.dataset<int16_t>(vg->get(), "brick_values", {vm.value_brick_count(), Voxelmap::kBrickVoxels},
                            vm.brick_values.data(), opt.deflate_level, {kBricksPerChunk, Voxelmap::kBrickVoxels}) &&
         w.dataset<float>(vg->get(), "lattice", {ld[2], ld[1], ld[0]}, vm.lattice.data(), opt.deflate_level,
                          {edge, edge, edge});
}

bool write_point_shell(h5::Writer& w, const PointShell& ps) {
  auto pg = w.create_group(w.file(), "pointshell");
  if (!pg) return false;
  const uint64_t n = ps.points.size();
  return w.dataset<double>(pg->get(), "points", {n, 3}, flat(ps.points)) &&
         w.dataset<float>(pg->get(), "normals", {n, 3}, flat(ps.normals)) &&
         w.dataset<double>(pg->get(), "sphere_centers", {n, 3}, flat(ps.sphere_centers)) &&
         w.dataset<double>(pg->get(), "sphere_radii", {n}, ps.sphere_radii.data()) &&
         w.dataset<uint32_t>(pg->get(), "child_begin", {n}, ps.child_begin.data()) &&
         w.dataset<uint32_t>(pg->get(), "child_count", {n}, ps.child_count.data()) &&
         w.dataset<uint32_t>(pg->get(), "level_offsets", {ps.level_offsets.size()}, ps.level_offsets.data()) &&
         (!ps.point_spacing || w.numeric_attribute<double>(pg->get(), "point_spacing", {}, &*ps.point_spacing)) &&
         (!ps.branching || w.numeric_attribute<double>(pg->get(), "branching", {}, &*ps.branching));
}

bool write_mass_properties(h5::Writer& w, const MassProperties& mass) {
  auto mg = w.create_group(w.file(), "mass_properties");
  if (!mg) return false;
  return w.numeric_attribute<double>(mg->get(), "volume", {}, &mass.volume) &&
         w.numeric_attribute<double>(mg->get(), "center_of_mass", {3}, mass.center_of_mass.data()) &&
         w.numeric_attribute<double>(mg->get(), "inertia", {3, 3}, mass.inertia.data());
}

bool write_provenance(h5::Writer& w, const Provenance& p) {
  nlohmann::json deps = nlohmann::json::object();
  for (const auto& [name, version_string] : p.dependency_versions) deps[name] = version_string;
  nlohmann::json warnings = nlohmann::json::array();
  for (const BuildWarning& bw : p.build_warnings) warnings.push_back({{"code", bw.code}, {"message", bw.message}});
  auto prov = w.create_group(w.file(), "provenance");
  if (!prov) return false;
  return w.string_attribute(prov->get(), "generator", p.generator) &&
         w.string_attribute(prov->get(), "generator_version", p.generator_version) &&
         w.string_attribute(prov->get(), "source_file", p.source_file) &&
         w.string_attribute(prov->get(), "source_sha256", p.source_sha256) &&
         w.string_attribute(prov->get(), "build_parameters", p.build_parameters_json) &&
         w.string_attribute(prov->get(), "dependency_versions",
                            deps.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace)) &&
         w.string_attribute(prov->get(), "build_warnings",
                            warnings.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace)) &&
         (p.created_utc.empty() || w.string_attribute(prov->get(), "created_utc", p.created_utc));
}

bool write_contents(h5::Writer& w, const Asset& a, const WriteOptions& opt) {
  return write_root_attributes(w, a) && write_voxelmap(w, a.voxelmap, opt) && write_point_shell(w, a.point_shell) &&
         write_mass_properties(w, a.mass) && write_provenance(w, a.provenance);
}

template <class V>
uint64_t bytes_of(const V& values) {
  return uint64_t(values.size()) * sizeof(typename V::value_type);
}

// The bytes write_contents hands HDF5 in datasets (attributes are negligible).
uint64_t dataset_bytes(const Asset& a) {
  const PointShell& ps = a.point_shell;
  return a.voxelmap.memory_bytes() + bytes_of(ps.points) + bytes_of(ps.normals) + bytes_of(ps.sphere_centers) +
         bytes_of(ps.sphere_radii) + bytes_of(ps.child_begin) + bytes_of(ps.child_count) + bytes_of(ps.level_offsets);
}

// WriteOptions::progress: the datasets' bytes compressed and, with the full check, the value bricks checked (their
// shares of a write, measured on CGAL's bunny at 1024 and 2048: 3/5 and 2/5). Reports run on the thread that made
// it; a report's exception is kept, stops the check, and is thrown again from rethrow_if_stopped once the file is
// closed (it may surface first as a failed dataset: the chunks are compressed by workers that catch everything).
class WriteProgress final : public h5::WriteTicker {
 public:
  WriteProgress(const WriteOptions& options, const Asset& asset)
      : callback_(options.progress),
        interval_(std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(
            std::isfinite(options.progress_interval_s) ? std::clamp(options.progress_interval_s, 0.0, 3600.0) : 0.2))),
        bytes_total_(std::max<uint64_t>(1, dataset_bytes(asset))),
        bricks_total_(options.validation == ValidationLevel::Full ? asset.voxelmap.value_brick_count() : 0) {}

  void add(uint64_t bytes) override {
    bytes_done_.fetch_add(bytes, std::memory_order_relaxed);
    report(false);
  }
  detail::CheckProgress* check() { return &check_; }

  void report(bool now) {
    if (!callback_ || std::this_thread::get_id() != caller_ || stopped_) return;
    const auto t = std::chrono::steady_clock::now();
    if (!now && t < next_) return;
    next_ = t + interval_;
    try {
      callback_(share_done());
    } catch (...) {
      stopped_ = std::current_exception();
      check_.stop = true;
      throw;
    }
  }
  void rethrow_if_stopped() const {
    if (stopped_) std::rethrow_exception(stopped_);
  }

 private:
  static constexpr double kCheckShare = 0.4;
  double share_done() const {
    const double written = std::min(1.0, double(bytes_done_.load(std::memory_order_relaxed)) / double(bytes_total_));
    if (bricks_total_ == 0) return written;
    const double checked =
        std::min(1.0, double(check_.bricks_checked.load(std::memory_order_relaxed)) / double(bricks_total_));
    return (1 - kCheckShare) * written + kCheckShare * checked;
  }
  const std::function<void(double)>& callback_;
  const std::chrono::steady_clock::duration interval_;
  const uint64_t bytes_total_, bricks_total_;
  const std::thread::id caller_ = std::this_thread::get_id();
  std::atomic<uint64_t> bytes_done_{0};
  detail::CheckProgress check_;
  std::chrono::steady_clock::time_point next_{};  // the caller's alone, as is stopped_
  std::exception_ptr stopped_;
};

// The first error-severity finding as an INVALID_ASSET error naming the rule it breaks.
std::optional<Error> first_error(const std::string& path, const std::vector<Issue>& issues) {
  for (const Issue& issue : issues)
    if (issue.severity == Severity::Error)
      return Error{IssueCode::InvalidAsset,
                   path + ": refusing to write an asset that breaks spec rule " + code_name(issue.code) + " at " +
                       issue.path + ": " + issue.message,
                   path, issue.path};
  return std::nullopt;
}

}  // namespace

std::string hdf5_library_version() {
  unsigned major = 0, minor = 0, release = 0;
  H5get_libversion(&major, &minor, &release);
  return std::to_string(major) + "." + std::to_string(minor) + "." + std::to_string(release);
}

namespace {
// Writes `bytes` to `file` (a new temporary); errors name the target `path` and the system's reason.
Status write_bytes(const std::string& file, const std::vector<char>& bytes, const std::string& path) {
  const int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
  if (fd < 0) return Error{IssueCode::WriteFailed, path + ": cannot create file: " + std::strerror(errno), path};
  const char* p = bytes.data();
  size_t left = bytes.size();
  while (left > 0) {
    const ssize_t n = ::write(fd, p, left);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const std::string why = n < 0 ? std::strerror(errno) : "nothing written";
      ::close(fd);
      return Error{IssueCode::WriteFailed,
                   path + ": cannot write (" + why + ") after " + std::to_string(bytes.size() - left) + " of " +
                       std::to_string(bytes.size()) + " bytes",
                   path};
    }
    p += n;
    left -= size_t(n);
  }
  if (::close(fd) != 0)
    return Error{IssueCode::WriteFailed, path + ": cannot finish file: " + std::strerror(errno), path};
  return Status::success();
}

// HDF5 builds the file in memory (the core driver, no backing store) and we write its bytes to `temp` ourselves.
// HDF5 1.10 does not survive its own disk errors: after a failed write (a full disk, a file-size limit) the file
// cannot be closed, and the library crashes closing it again at exit.
Status write_in_memory_then_to(const std::string& temp, const std::string& path, const Asset& asset,
                               const WriteOptions& options, WriteProgress& progress) {
  std::unique_lock<std::mutex> hdf5(h5::process_mutex());  // until the file is closed (isolated reads fork)
  h5::Handle fapl(H5Pcreate(H5P_FILE_ACCESS), H5Pclose);
  if (!fapl.valid() || H5Pset_fapl_core(fapl.get(), 4 << 20, false) < 0)
    return Error{IssueCode::WriteFailed, path + ": cannot set up HDF5 (" + h5::last_hdf5_reason() + ")", path};
  hid_t file = H5Fcreate(temp.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, fapl.get());
  if (file < 0)
    return Error{IssueCode::WriteFailed, path + ": cannot create file (" + h5::last_hdf5_reason() + ")", path};
  h5::Writer writer(file, &progress);
  bool ok = false;
  std::string reason;
  bool out_of_memory = false;  // the file is built in memory: a failed allocation is OUT_OF_MEMORY, not the disk's
  std::vector<char> image;
  try {
    ok = write_contents(writer, asset, options);
    reason = writer.failure();
    out_of_memory = writer.out_of_memory();
    if (ok && H5Fflush(file, H5F_SCOPE_GLOBAL) < 0) {
      ok = false;
      const h5::Hdf5Failure failure = h5::last_hdf5_failure();
      out_of_memory = failure.out_of_memory;
      reason = "cannot finish file (" + failure.reason + ")";
    }
    const ssize_t size = ok ? H5Fget_file_image(file, nullptr, 0) : -1;
    if (ok && size > 0) {
      image.resize(size_t(size));
      ok = H5Fget_file_image(file, image.data(), image.size()) == size;
    } else {
      ok = false;
    }
    if (!ok && reason.empty()) {
      const h5::Hdf5Failure failure = h5::last_hdf5_failure();
      out_of_memory = failure.out_of_memory;
      reason = "cannot take the file's image (" + failure.reason + ")";
    }
  } catch (const std::bad_alloc&) {
    ok = false;
    out_of_memory = true;
    reason = "out of memory building the file";
  } catch (const std::exception& e) {  // thread failures: still close the file
    ok = false;
    reason = std::string("write failed: ") + e.what();
  } catch (...) {  // a progress report's own exception, thrown again below
    ok = false;
  }
  H5Fclose(file);  // in memory: nothing to fail on
  fapl.reset();
  hdf5.unlock();
  progress.rethrow_if_stopped();
  if (!ok) return Error{out_of_memory ? IssueCode::OutOfMemory : IssueCode::WriteFailed, path + ": " + reason, path};
  return write_bytes(temp, image, path);
}

Status write_checked_asset(const std::string& path, const Asset& asset, const WriteOptions& options) {
  WriteProgress progress(options, asset);
  progress.report(true);
  // Structure first (the writer indexes by it), then the semantic rules beside the write.
  if (auto error = first_error(path, validate_asset(asset, ValidationLevel::Quick))) return *error;
  // Declared after `progress`, so destroyed (the check waited for) before it: the check counts into it.
  std::future<std::optional<Error>> semantic;
  std::optional<Error> semantic_error;
  if (options.validation == ValidationLevel::Full) {
    auto check = [&] {
      return first_error(path, detail::validate_asset(asset, ValidationLevel::Full, progress.check()));
    };
    try {
      semantic = std::async(std::launch::async, check);
    } catch (const std::system_error&) {  // no thread to be had (a process limit): checked here, before the write
      if (std::optional<Error> found = check()) return *found;
    }
  }
  // Whatever happens to the write, the check ends before `asset` may go away (the future's destructor waits).
  auto wait_for_check = [&] {
    if (semantic.valid()) semantic_error = semantic.get();
  };

  h5::silence_hdf5_errors();
  AtomicWrite steps;
  steps.write = [&](const std::string& temp) { return write_in_memory_then_to(temp, path, asset, options, progress); };
  steps.before_commit = [&]() -> Status {
    while (semantic.valid() && semantic.wait_for(std::chrono::milliseconds(20)) != std::future_status::ready)
      progress.report(false);
    wait_for_check();
    if (semantic_error) return *semantic_error;
    return options.before_commit ? options.before_commit() : Status::success();
  };
  Status written = write_file_atomically(path, steps);
  wait_for_check();
  if (semantic_error) return *semantic_error;  // outranks the write failure it may have caused
  return written;
}

}  // namespace

Status write_asset(const std::string& path, const Asset& asset, const WriteOptions& options) {
  try {
    return write_checked_asset(path, asset, options);
  } catch (const std::bad_alloc&) {  // in the rules' checks: the temporary, if any, is gone (write_file_atomically)
    return Error{IssueCode::OutOfMemory, path + ": out of memory writing the asset", path};
  }
}

}  // namespace voxfmt
