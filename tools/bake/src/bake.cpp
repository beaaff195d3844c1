// The whole bake: import -> repair -> voxelmap -> point shell -> tree -> mass -> asset with provenance; the
// public entry points (bake_mesh, bake_to_file) and the one serialisation of a bake's summary.
#include <CGAL/version.h>
#include <assimp/version.h>
#include <oneapi/tbb/global_control.h>
#include <oneapi/tbb/task_group.h>
#include <oneapi/tbb/version.h>
#include <openssl/evp.h>
#include <nlohmann/json.hpp>

#include <sys/resource.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <ctime>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <thread>
#include <type_traits>

#include "stages.h"
#include "vec3_math.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/utf8.h"
#include "voxfmt/io.h"
#include "voxfmt/version.h"
#include "winding_number.h"

namespace voxfmt::bake {

namespace {

// Of the largest triangles (up to 64), the share with the winding number's inside right behind them (>= 1/2 a
// millionth of the surface's size behind the centre, by the exact sum): near 1 for closed parts however thin,
// near 0 for an open sheet, which closes around nothing.
double share_with_inside_behind(const TriangleMesh& mesh) {
  std::vector<std::pair<double, size_t>> by_area(mesh.triangles.size());
  for (size_t f = 0; f < mesh.triangles.size(); ++f) {
    const auto& t = mesh.triangles[f];
    by_area[f] = {-length(cross(mesh.vertices[t[1]] - mesh.vertices[t[0]], mesh.vertices[t[2]] - mesh.vertices[t[0]])),
                  f};
  }
  const size_t n = std::min<size_t>(64, by_area.size());
  std::partial_sort(by_area.begin(), by_area.begin() + ptrdiff_t(n), by_area.end());
  const auto [lo, hi] = bounding_box(mesh);
  const double step = 1e-6 * length(hi - lo);
  const WindingNumber winding(mesh);
  size_t inside = 0;
  for (size_t m = 0; m < n; ++m) {
    const auto& t = mesh.triangles[by_area[m].second];
    const Vec3 &a = mesh.vertices[t[0]], &b = mesh.vertices[t[1]], &c = mesh.vertices[t[2]];
    const Vec3 behind = (a + b + c) * (1.0 / 3) - normalized(cross(b - a, c - a)) * step;
    inside += winding.evaluate(behind, std::numeric_limits<double>::infinity()) >= 0.5;
  }
  return n ? double(inside) / double(n) : 0.0;
}

uint64_t peak_memory_bytes() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return uint64_t(usage.ru_maxrss) * 1024;  // Linux reports KiB
}

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Runs `work`, turning the stages' exceptions into the one error model at the library's edge.
template <class T, class Work>
Result<T> guarded(const std::string& mesh_path, Work&& work) {
  try {
    return work();
  } catch (const BakeError& e) {  // every message names the input, whichever stage threw
    const std::string message = e.what();
    return Error{e.code(), message.rfind(mesh_path, 0) == 0 ? message : mesh_path + ": " + message, mesh_path};
  } catch (const std::bad_alloc&) {
    return Error{IssueCode::OutOfMemory, mesh_path + ": out of memory (try a coarser resolution or voxel size)",
                 mesh_path};
  } catch (const std::system_error& e) {
    // No thread to be had (EAGAIN under an address-space or process limit) is memory, not a bug.
    if (e.code() == std::errc::resource_unavailable_try_again || e.code() == std::errc::not_enough_memory)
      return Error{IssueCode::OutOfMemory, mesh_path + ": out of memory starting a thread (" + e.what() + ")",
                   mesh_path};
    return Error{IssueCode::Internal, mesh_path + ": " + e.what(), mesh_path};
  } catch (const std::exception& e) {  // library failures (CGAL preconditions, TBB) still get a clean error
    // TBB reports a worker it could not start as a runtime_error naming pthread_create.
    if (std::string_view(e.what()).find("pthread_create") != std::string_view::npos)
      return Error{IssueCode::OutOfMemory, mesh_path + ": out of memory starting a thread (" + e.what() + ")",
                   mesh_path};
    return Error{IssueCode::Internal, mesh_path + ": " + e.what(), mesh_path};
  } catch (...) {  // a progress callback's own exception of any type
    return Error{IssueCode::Internal, mesh_path + ": stopped by an exception that is not a std::exception", mesh_path};
  }
}

// Times a bake's stages (kBakeStages) and tells the progress callback as each stage of the whole bake starts.
// Stages that run side by side set their own times (distinct slots: no race); timings() lists them in the
// list's order, whatever order they ran in.
class StageTimes {
 public:
  explicit StageTimes(const ProgressCallback& progress) : progress_(progress) {}

  /// Runs `work` as `stage`: announced (where the stage reports progress), its wall time recorded.
  template <class Work>
  auto run(BakeStage stage, Work&& work) {
    const BakeStageInfo& info = stage_info(stage);
    if (progress_ && info.progress_start >= 0) progress_(info.name, info.progress_start);
    const auto start = std::chrono::steady_clock::now();
    if constexpr (std::is_void_v<std::invoke_result_t<Work>>) {
      work();
      set(stage, seconds_since(start));
    } else {
      auto result = work();
      set(stage, seconds_since(start));
      return result;
    }
  }
  void set(BakeStage stage, double seconds) {
    seconds_[size_t(stage)] = seconds;
    timed_[size_t(stage)] = true;
  }
  /// Times a stage measured itself (the voxelmap's sub-stages), by name.
  void set(const std::vector<StageTiming>& timings) {
    for (const StageTiming& t : timings)
      for (const BakeStageInfo& info : kBakeStages)
        if (t.stage == info.name) set(info.stage, t.seconds);
  }
  /// Progress within `stage` (one reported as progress): `share` of it done, told as that share of the way to the
  /// next reported stage, at most every 0.2 s (a Python callable takes the GIL each time).
  void within(BakeStage stage, double share) {
    const BakeStageInfo& info = stage_info(stage);
    if (!progress_ || info.progress_start < 0) return;
    const auto now = std::chrono::steady_clock::now();
    if (now < next_within_) return;
    next_within_ = now + std::chrono::milliseconds(200);
    double next = 1.0;
    for (const BakeStageInfo& other : kBakeStages)
      if (other.progress_start > info.progress_start) next = std::min(next, other.progress_start);
    progress_(info.name, info.progress_start + share * (next - info.progress_start));
  }

  std::vector<StageTiming> timings() const {
    std::vector<StageTiming> out;
    for (const BakeStageInfo& info : kBakeStages)
      if (timed_[size_t(info.stage)]) out.push_back({info.name, seconds_[size_t(info.stage)]});
    return out;
  }

 private:
  static constexpr size_t kCount = std::size(kBakeStages);
  const ProgressCallback& progress_;
  std::array<double, kCount> seconds_{};
  std::array<bool, kCount> timed_{};
  std::chrono::steady_clock::time_point next_within_{};
};

bool encloses_volume(const MassProperties& mass, const TriangleMesh& mesh) {
  const auto [lo, hi] = bounding_box(mesh);
  const double diagonal = length(hi - lo);
  // A flat, closed sheet's volume is rounding, some 1e-16 of area x diagonal. A billionth of the bounding box alone
  // took parts far apart (a 1 m cube and a 1 mm one 1 km away) for a sheet: whichever of the two is smaller.
  return mass.volume > 1e-9 * diagonal * std::min(diagonal * diagonal, surface_area(mesh));
}

// How the bake takes the surface's inside, decided from the repair's report before any voxel exists.
struct InsidePlan {
  bool winding = false;          ///< inside = winding number >= 1/2: open, misoriented or self-intersecting
  double shell_thickness = 0;    ///< > 0: a shell of this thickness (asked for, or chosen after the voxelmap)
  bool closed_but_flat = false;  ///< a closed, double-sided sheet: baked as a shell once the grid exists
  MassProperties mass;           ///< a closed, oriented surface's, by the divergence theorem
};

// A closed, oriented surface encloses what the divergence theorem integrates; otherwise inside is where the
// winding number is >= 1/2, and the mass properties are integrated over that inside, on the voxelmap.
InsidePlan plan_inside(const TriangleMesh& mesh, const RepairReport& r, double shell_thickness) {
  InsidePlan plan;
  plan.winding = !r.closed || !r.consistently_oriented || r.self_intersecting_pairs > 0;
  plan.shell_thickness = shell_thickness;
  if (!plan.winding && shell_thickness == 0) {
    plan.mass = compute_mass_properties(mesh);
    plan.closed_but_flat = !encloses_volume(plan.mass, mesh);
  }
  return plan;
}

struct Geometry {
  Voxelmap voxelmap;
  PointShell shell;
  VoxelmapReport voxelmap_report;
};

// The point shell's peak, before it starts: about 420 bytes a point (candidates, the Poisson-disk grid, the tree;
// measured with the bunny at 0.2, 1 and 2 M points), and for a shell the search that drops its swallowed points
// (about 250 bytes a triangle at its build: drop_points_inside_shell). Beside the voxelmap's own check, so that
// `--points` or `--point-spacing` too is refused up front rather than killed halfway.
void check_point_shell_memory(const TriangleMesh& mesh, const Settings& options, double shell_thickness) {
  constexpr double kBytesPerPoint = 420, kBytesPerShellTriangle = 250;
  const double target = point_shell_target(mesh, options.point_shell);
  // Past 50 million points sampling refuses the spacing itself (BAD_OPTION), with its own message.
  if (!(target <= 50e6)) return;
  // A shell's two sheets each get a spacing's count (a point count is shared between them: sample_shell).
  const double points = shell_thickness > 0 && options.point_shell.point_spacing > 0 ? 2 * target : target;
  const double bytes =
      points * kBytesPerPoint + (shell_thickness > 0 ? double(mesh.triangles.size()) * kBytesPerShellTriangle : 0.0);
  const double limit = memory_limit_bytes(options.voxelmap.max_memory_bytes);
  if (bytes <= limit) return;
  char text[300];
  std::snprintf(text, sizeof text,
                "the point shell (%.0f points) would need about %.1f MiB, more than the %.1f MiB allowed "
                "(--max-memory, max_memory_mib in Python; default 3/4 of this machine's memory): use fewer points "
                "or a wider point spacing",
                points, bytes / 1048576.0, limit / 1048576.0);
  throw BakeError(IssueCode::OutOfMemory, text);
}

// A shell's points lie on its two sheets: half as many on each, less those the shell swallows (more than a quarter
// voxel inside it, so that each point's nearest voxel stores a distance, spec section 4).
PointShell sample_shell(const TriangleMesh& mesh, const Settings& options, double thickness,
                        const std::atomic<bool>* abandon = nullptr) {
  PointShellSettings settings = options.point_shell;
  if (thickness > 0 && settings.point_spacing == 0) settings.points = std::max<uint32_t>(1, settings.points / 2);
  PointShell sampled = sample_point_shell(mesh, settings, abandon);
  if (thickness > 0) {
    offset_to_shell_sheets(sampled, thickness / 2);
    drop_points_inside_shell(sampled, mesh, thickness / 2, 0.25 * planned_voxel_size(mesh, options.voxelmap));
  }
  return sampled;
}

// The voxelmap and the point shell are independent: the (mostly serial) sampling and tree building run beside the
// voxelmap's parallel work, each stage timed by its own wall time.
Geometry build_geometry(const TriangleMesh& mesh, const Settings& options, const InsidePlan& plan, StageTimes& times) {
  check_point_shell_memory(mesh, options, plan.shell_thickness);
  Geometry g;
  VoxelmapSettings voxelmap_options = options.voxelmap;
  voxelmap_options.winding_number_sign = plan.winding;
  // A bake in which no voxel is more than half a voxel inside stops after its band: it becomes a shell.
  g.voxelmap_report.stop_if_shallow = plan.shell_thickness == 0;
  tbb::task_group tasks;
  std::exception_ptr shell_error;
  std::atomic<bool> abandon{false}, shell_done{false};
  tasks.run([&] {
    try {
      g.shell =
          times.run(BakeStage::PointShell, [&] { return sample_shell(mesh, options, plan.shell_thickness, &abandon); });
      times.run(BakeStage::SphereTree, [&] { build_sphere_tree(g.shell, options.point_shell.branching); });
    } catch (...) {
      shell_error = std::current_exception();
    }
    shell_done = true;
  });
  std::vector<StageTiming> voxelmap_stages;
  double share = 0;
  auto tell = [&](double done) {
    share = done;
    times.within(BakeStage::VoxelmapAndPointShell, share);
  };
  try {
    g.voxelmap = times.run(BakeStage::Voxelmap, [&] {
      return build_voxelmap(mesh, voxelmap_options, &voxelmap_stages, &g.voxelmap_report, tell);
    });
    // A point shell of millions of points can outlast the voxelmap (14 s for a million): told on while it runs, so
    // that a caller may stop it. A worker runs it, unless there is none (--threads 1): then it runs in wait().
    if (tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism) > 1)
      while (!shell_done) {
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
        tell(share);
      }
  } catch (...) {
    abandon = true;
    tasks.wait();
    throw;
  }
  tasks.wait();
  if (shell_error) std::rethrow_exception(shell_error);
  times.set(voxelmap_stages);
  return g;
}

// No voxel more than half a voxel inside (layer >= 1): an open sheet that closes around nothing, or parts thinner
// than a voxel; the fractional voxels along it are not a volume the voxelmap can represent.
// A closed surface too: one thinner than a voxel (a needle at a coarse grid) left no inside at all, unsaid.
// The band's count says so (a scan of every voxel's layer took 3 s at 2048^3, on one thread).
bool encloses_nothing(const InsidePlan& plan, const Geometry& g) {
  return plan.shell_thickness == 0 &&
         (plan.closed_but_flat || g.voxelmap_report.stopped || g.voxelmap_report.deep_centres == 0);
}

// Why a surface that encloses nothing is baked as a shell two voxels thick, and what to do about it: thin parts
// (an inside behind the surface, all of it within half a voxel) or a sheet (no inside at all).
BuildWarning shell_mode_warning(const TriangleMesh& mesh, const InsidePlan& plan, const Geometry& g) {
  const double thickness = 2 * g.voxelmap.voxel_size;
  const uint64_t inside = g.voxelmap_report.inside_centres;
  char text[480];
  // A closed surface that is not flat has an inside behind it everywhere.
  const bool closed_solid = !plan.winding && !plan.closed_but_flat;
  if (inside > 0 || closed_solid || (plan.winding && share_with_inside_behind(mesh) >= 0.5)) {
    char centres[96] = "no voxel centre lies inside it";
    if (inside > 0)
      std::snprintf(centres, sizeof centres, "%llu voxel centres lie inside it, none more than half a voxel deep",
                    static_cast<unsigned long long>(inside));
    std::snprintf(text, sizeof text,
                  "the surface's parts are thinner than a voxel (%s): its inside vanishes at this resolution. "
                  "Baked as a shell %.6g m (2 voxels) thick; pass --shell-thickness with the parts' real "
                  "thickness, or use voxels smaller than them (--voxel-size, --resolution)",
                  centres, thickness);
  } else {
    std::snprintf(text, sizeof text,
                  "the surface encloses no volume at this resolution (an open or flat sheet): baked as a shell "
                  "%.6g m (2 voxels) thick; --shell-thickness sets another thickness",
                  thickness);
  }
  return {"SHELL_MODE", text};
}

// A grid of a few voxels across keeps the object's place but not its shape: every contact is then as coarse as a
// voxel, which a resolution typed short (--resolution 1) gives without a word. Fewer than 8 is said.
std::optional<BuildWarning> coarse_grid_warning(const TriangleMesh& mesh, double voxel_size) {
  constexpr double kFewestVoxels = 8;
  const auto [lo, hi] = bounding_box(mesh);
  const double longest = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]}), voxels = longest / voxel_size;
  if (!(voxels < kFewestVoxels)) return std::nullopt;
  char text[320];
  std::snprintf(text, sizeof text,
                "the object spans %.3g %s of %.6g m along its longest side: its shape is lost and its contacts "
                "are only as exact as a voxel; use --resolution %g or more (the default is 128), or a --voxel-size "
                "of at most %.3g m",
                voxels, voxels == 1 ? "voxel" : "voxels", voxel_size, kFewestVoxels, longest / kFewestVoxels);
  return BuildWarning{"COARSE_GRID", text};
}

// The voxelmap, point shell and tree again, as a shell of `thickness` (one after the other: the bake is nearly
// done, and a shell's voxelmap is quick).
void rebuild_as_shell(const TriangleMesh& mesh, const Settings& options, const InsidePlan& plan, Geometry& g,
                      StageTimes& times) {
  const double thickness = plan.shell_thickness;
  check_point_shell_memory(mesh, options, thickness);  // a spacing's points twice now: one set on each sheet
  VoxelmapSettings voxelmap_options = options.voxelmap;
  voxelmap_options.winding_number_sign = plan.winding;
  voxelmap_options.shell_thickness = thickness;
  std::vector<StageTiming> voxelmap_stages;
  g.voxelmap = times.run(BakeStage::Voxelmap, [&] { return build_voxelmap(mesh, voxelmap_options, &voxelmap_stages); });
  times.set(voxelmap_stages);
  g.shell = times.run(BakeStage::PointShell, [&] { return sample_shell(mesh, options, thickness); });
  times.run(BakeStage::SphereTree, [&] { build_sphere_tree(g.shell, options.point_shell.branching); });
}

MassProperties mass_properties(const std::string& mesh_path, const TriangleMesh& mesh, const InsidePlan& plan,
                               const Voxelmap& voxelmap) {
  auto check_volume = [&](const MassProperties& mass, const char* what) {
    if (!encloses_volume(mass, mesh))
      throw BakeError(IssueCode::ZeroVolume, mesh_path + ": the surface encloses no volume (" + what + ")");
  };
  if (plan.shell_thickness > 0) {
    const MassProperties mass = shell_mass_properties(mesh, plan.shell_thickness);
    check_volume(mass, "a surface of zero area, or a shell too thin for the part's size: --shell-thickness");
    return mass;
  }
  if (!plan.winding) return plan.mass;
  MassProperties mass = voxelmap_mass_properties(voxelmap);
  check_volume(mass, "an open sheet");
  // The inside closes the surface, so it lies within the surface's bounds; the voxels' partial fractions can put
  // the centre a fraction of a voxel past a flat side.
  const auto [lo, hi] = bounding_box(mesh);
  for (int a = 0; a < 3; ++a) mass.center_of_mass[a] = std::clamp(mass.center_of_mass[a], lo[a], hi[a]);
  return mass;
}

Provenance provenance_of(const std::string& mesh_path, const Settings& options,
                         const std::vector<BuildWarning>& warnings) {
  Provenance p;
  p.generator = "voxfmt build";
  p.generator_version = VOXFMT_VERSION_STRING;
  // The format stores text as UTF-8 (spec §1); a file name may hold any bytes, and is then kept escaped (\xNN).
  p.source_file = utf8_escaped(std::filesystem::path(mesh_path).filename().string());
  Result<std::string> sha = sha256_file(mesh_path);
  if (!sha) throw BakeError(sha.error().code, sha.error().message);
  p.source_sha256 = sha.value();
  p.build_parameters_json = build_parameters_json(options);
  p.dependency_versions = dependency_versions();
  for (const BuildWarning& w : warnings) p.build_warnings.push_back({w.code, utf8_escaped(w.message)});
  p.created_utc = utc_now();
  return p;
}

Asset assemble(const std::string& mesh_path, const TriangleMesh& mesh, const Settings& options, const InsidePlan& plan,
               Geometry geometry, const std::vector<BuildWarning>& warnings) {
  Asset asset;
  asset.mass = mass_properties(mesh_path, mesh, plan, geometry.voxelmap);
  asset.up_axis = options.up_axis;
  const auto [lo, hi] = bounding_box(mesh);
  asset.bounds_min = lo;
  asset.bounds_max = hi;
  for (int a = 0; a < 3 && plan.shell_thickness > 0; ++a) {  // a shell's surface is its sheets, around the mesh
    asset.bounds_min[a] -= plan.shell_thickness / 2;
    asset.bounds_max[a] += plan.shell_thickness / 2;
  }
  asset.voxelmap = std::move(geometry.voxelmap);
  asset.point_shell = std::move(geometry.shell);
  // A point or two on a crumpled surface have a nominal spacing beyond the object's scale: the spec's limit instead.
  if (asset.point_shell.point_spacing)
    asset.point_shell.point_spacing =
        std::min(*asset.point_shell.point_spacing,
                 max_point_spacing(asset.bounds_min, asset.bounds_max, asset.voxelmap.voxel_size));
  asset.provenance = provenance_of(mesh_path, options, warnings);
  return asset;
}

Summary summarize(const std::string& mesh_path, const Asset& asset, const BuildReport& report) {
  Summary s;
  s.input = mesh_path;
  s.source_sha256 = asset.provenance.source_sha256;
  s.input_vertices = report.input_vertices;
  s.input_triangles = report.input_triangles;
  s.closed = report.repair.closed;
  s.timings = report.timings;
  const Voxelmap& vm = asset.voxelmap;
  s.dims = vm.dims;
  s.voxel_size = vm.voxel_size;
  s.stored_distances = vm.stored_count();
  s.points = asset.point_shell.size();
  s.points_per_level = asset.point_shell.points_per_level();
  s.volume = asset.mass.volume;
  s.warnings = report.repair.warnings;
  return s;
}

}  // namespace

Bounds bounding_box(const TriangleMesh& mesh) {
  Bounds b{mesh.vertices.front(), mesh.vertices.front()};
  for (const Vec3& v : mesh.vertices)
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = std::min(b.lo[a], v[a]);
      b.hi[a] = std::max(b.hi[a], v[a]);
    }
  return b;
}

double surface_area(const TriangleMesh& mesh) {
  double area = 0;
  for (const auto& t : mesh.triangles)
    area += 0.5 * length(cross(mesh.vertices[t[1]] - mesh.vertices[t[0]], mesh.vertices[t[2]] - mesh.vertices[t[0]]));
  return area;
}

Result<std::string> sha256_file(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec))  // a folder reads as empty, a pipe never ends
    return Error{IssueCode::InputNotFound, path + ": not a regular file, nothing to hash", path};
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error{IssueCode::InputNotFound, path + ": cannot open for hashing", path};
  std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(), EVP_MD_CTX_free);
  EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr);
  std::vector<char> buffer(1 << 16);
  while (in) {
    in.read(buffer.data(), std::streamsize(buffer.size()));
    if (in.gcount() > 0) EVP_DigestUpdate(ctx.get(), buffer.data(), size_t(in.gcount()));
  }
  if (in.bad()) return Error{IssueCode::ReadFailed, path + ": a read failed while hashing", path};
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int length = 0;
  EVP_DigestFinal_ex(ctx.get(), digest, &length);
  return lowercase_hex(std::string_view(reinterpret_cast<const char*>(digest), length));
}

bool asset_is_current(const std::string& asset, const std::string& mesh, const Settings& settings) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(asset, ec)) return false;
  const Result<Provenance> provenance = read_provenance(asset);
  if (!provenance) return false;
  const Result<std::string> sha = sha256_file(mesh);
  if (!sha || sha.value() != provenance.value().source_sha256) return false;
  if (provenance.value().generator_version != VOXFMT_VERSION_STRING) return false;  // an older bake: baked anew
  const nlohmann::json stored = nlohmann::json::parse(provenance.value().build_parameters_json, nullptr, false);
  if (stored.is_discarded() || stored != nlohmann::json::parse(build_parameters_json(settings))) return false;
  ReadOptions quick;  // and it still reads: a file damaged past its provenance is baked again
  quick.level = ValidationLevel::Quick;
  quick.max_memory_bytes = std::numeric_limits<uint64_t>::max() / 2;  // this bake's own asset, however large
  for (const Issue& issue : validate_file(asset, quick))
    if (issue.severity == Severity::Error) return false;
  return true;
}

std::map<std::string, std::string> dependency_versions() {
  return {{"voxfmt", VOXFMT_VERSION_STRING},
          {"assimp", std::to_string(aiGetVersionMajor()) + "." + std::to_string(aiGetVersionMinor()) + "." +
                         std::to_string(aiGetVersionRevision())},
          {"cgal", CGAL_VERSION_STR},
          {"tbb", std::to_string(TBB_VERSION_MAJOR) + "." + std::to_string(TBB_VERSION_MINOR)},
          {"hdf5", hdf5_library_version()}};
}

std::string build_parameters_json(const Settings& o) {
  // Every option that changes the data; not threads or deflate (same data, other speed or file size).
  nlohmann::json j = {{"unit_scale", o.import.unit_scale},
                      {"resolution", o.voxelmap.resolution},
                      {"voxel_size", o.voxelmap.voxel_size},
                      {"margin", o.voxelmap.margin},
                      {"distance_band", o.voxelmap.distance_band},
                      {"points", o.point_shell.points},
                      {"point_spacing", o.point_shell.point_spacing},
                      {"branching", o.point_shell.branching},
                      {"seed", o.point_shell.seed},
                      {"check_self_intersections", o.check_self_intersections},
                      {"up_axis", o.up_axis}};
  // Only when set, so that manifests written before shell mode existed stay up to date.
  if (o.voxelmap.shell_thickness > 0) j["shell_thickness"] = o.voxelmap.shell_thickness;
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::string utc_now() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof buffer, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

Asset build_asset(const std::string& mesh_path, const Settings& options, BuildReport& report,
                  const ProgressCallback& progress) {
  std::unique_ptr<tbb::global_control> thread_limit;
  if (options.threads > 0)
    thread_limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, options.threads);
  StageTimes times(progress);
  TriangleMesh mesh = times.run(BakeStage::Import, [&] { return import_mesh(mesh_path, options.import); });
  report.input_vertices = mesh.vertices.size();
  report.input_triangles = mesh.triangles.size();
  InsidePlan plan;
  mesh = times.run(BakeStage::Repair, [&] {  // the imported soup is freed as the repaired mesh replaces it
    TriangleMesh repaired =
        repair_mesh(mesh, report.repair, options.check_self_intersections, options.import.time_limit_s);
    plan = plan_inside(repaired, report.repair, options.voxelmap.shell_thickness);
    return repaired;
  });
  Geometry geometry =
      times.run(BakeStage::VoxelmapAndPointShell, [&] { return build_geometry(mesh, options, plan, times); });
  Asset asset = times.run(BakeStage::Assemble, [&] {
    if (encloses_nothing(plan, geometry)) {
      report.repair.warnings.push_back(shell_mode_warning(mesh, plan, geometry));
      plan.shell_thickness = 2 * geometry.voxelmap.voxel_size;
      rebuild_as_shell(mesh, options, plan, geometry, times);
    }
    if (auto coarse = coarse_grid_warning(mesh, geometry.voxelmap.voxel_size))
      report.repair.warnings.push_back(*coarse);
    return assemble(mesh_path, mesh, options, plan, std::move(geometry), report.repair.warnings);
  });
  report.timings = times.timings();
  return asset;
}

Status check_settings(const Settings& s) {
  auto bad = [](const std::string& what) { return Error{IssueCode::BadOption, "bad option: " + what}; };
  auto finite_non_negative = [](double v) { return std::isfinite(v) && v >= 0; };
  if (!finite_non_negative(s.voxelmap.voxel_size)) return bad("voxel_size must be a finite number > 0 (or 0: none)");
  if (s.voxelmap.voxel_size != 0 && !(s.voxelmap.voxel_size >= kMinVoxelSize && s.voxelmap.voxel_size <= kMaxVoxelSize))
    return bad("voxel_size is outside the format's range 1e-09..1e+06 m");
  if (s.voxelmap.voxel_size == 0 && (s.voxelmap.resolution < 1 || s.voxelmap.resolution > 4096))
    return bad("resolution " + std::to_string(s.voxelmap.resolution) + " is outside 1..4096");
  if (!finite_non_negative(s.point_shell.point_spacing))
    return bad("point_spacing must be a finite number > 0 (or 0: none)");
  if (s.point_shell.point_spacing == 0 && (s.point_shell.points < 1 || s.point_shell.points > 50'000'000))
    return bad("points " + std::to_string(s.point_shell.points) + " is outside 1..50000000");
  if (!(s.point_shell.branching >= 2 && s.point_shell.branching <= 64)) return bad("branching must be within 2..64");
  if (s.voxelmap.margin > 1024) return bad("margin " + std::to_string(s.voxelmap.margin) + " is outside 0..1024");
  if (!(s.voxelmap.distance_band >= 1 && s.voxelmap.distance_band <= 64))
    return bad("band must be within 1..64 voxels");
  if (!finite_non_negative(s.voxelmap.shell_thickness))
    return bad("shell_thickness must be a finite number > 0 (or 0: none)");
  if (!(std::isfinite(s.import.unit_scale) && s.import.unit_scale > 0))
    return bad("unit_scale must be a finite number > 0");
  static const char* const kAxes[] = {"+X", "-X", "+Y", "-Y", "+Z", "-Z"};
  if (std::find(std::begin(kAxes), std::end(kAxes), s.up_axis) == std::end(kAxes))
    return bad("up_axis '" + s.up_axis + "' is none of +X, -X, +Y, -Y, +Z, -Z");
  if (s.deflate < 0 || s.deflate > 9) return bad("deflate " + std::to_string(s.deflate) + " is outside 0..9");
  if (s.threads > kMaxThreads)
    return bad("threads " + std::to_string(s.threads) + " is outside 0.." + std::to_string(kMaxThreads));
  if (!finite_non_negative(s.import.time_limit_s))
    return bad("time_limit_s must be a finite number > 0 (or 0: the default)");
  return Status::success();
}

namespace {

// bake_mesh but for its last word ("done"), which bake_to_file says only once the file is written.
Result<Baked> bake_in_memory(const std::string& mesh_path, const Settings& settings, const ProgressCallback& progress) {
  if (const Status checked = check_settings(settings); !checked) {
    Error error = checked.error();
    error.message = mesh_path + ": " + error.message;
    error.file = mesh_path;
    return error;
  }
  return guarded<Baked>(mesh_path, [&] {
    const auto start = std::chrono::steady_clock::now();
    BuildReport report;
    Baked baked;
    baked.asset = build_asset(mesh_path, settings, report, progress);
    baked.summary = summarize(mesh_path, baked.asset, report);
    baked.summary.total_s = seconds_since(start);
    baked.summary.peak_memory_bytes = peak_memory_bytes();
    return baked;
  });
}

}  // namespace

Result<Baked> bake_mesh(const std::string& mesh_path, const Settings& settings, const ProgressCallback& progress) {
  Result<Baked> baked = bake_in_memory(mesh_path, settings, progress);
  if (!baked || !progress) return baked;
  return guarded<Baked>(mesh_path, [&]() -> Result<Baked> {
    progress("done", 1.0);
    return std::move(baked.value());
  });
}

Result<Summary> bake_to_file(const std::string& mesh_path, const std::string& output_path, const Settings& settings,
                             const ProgressCallback& progress) {
  const auto start = std::chrono::steady_clock::now();
  // before a long bake; never onto the mesh itself
  if (Status usable = check_output_path(output_path, mesh_path); !usable) return usable.error();
  Result<Baked> baked = bake_in_memory(mesh_path, settings, progress);
  if (!baked) return baked.error();
  // The callback may throw here too (a caller's cancel): guarded. At "done" the file is in place (it replaced
  // whatever the path held): a throw there is reported and the file stays.
  return guarded<Summary>(mesh_path, [&]() -> Result<Summary> {
    const BakeStageInfo& write = stage_info(BakeStage::Write);
    const auto write_start = std::chrono::steady_clock::now();
    WriteOptions write_options;  // validation: Full, beside the write
    write_options.deflate_level = settings.deflate;
    if (progress)
      write_options.progress = [&](double done) {
        progress(write.name, write.progress_start + (1 - write.progress_start) * done);
      };
    const Status written = write_asset(output_path, baked->asset, write_options);
    if (!written) {
      Error error = written.error();
      if (error.code == IssueCode::InvalidAsset)  // the bake made something the spec forbids: say whose fault
        error.message =
            mesh_path +
            ": the baked asset is invalid, nothing was written (a bake bug: please report it): " + error.message;
      return error;
    }
    Summary summary = std::move(baked->summary);
    summary.timings.push_back({write.name, seconds_since(write_start)});
    summary.output = output_path;
    std::error_code ec;
    summary.file_size_bytes = std::filesystem::file_size(output_path, ec);
    summary.total_s = seconds_since(start);
    summary.peak_memory_bytes = peak_memory_bytes();
    if (progress) progress("done", 1.0);
    return summary;
  });
}

Result<TriangleMesh> read_mesh(const std::string& mesh_path, const ImportSettings& settings) {
  return guarded<TriangleMesh>(mesh_path, [&] { return import_mesh(mesh_path, settings); });
}

std::string to_json(const Summary& s) {
  nlohmann::json timings = nlohmann::json::object();
  for (const StageTiming& t : s.timings) timings[t.stage] = t.seconds;
  nlohmann::json warnings = nlohmann::json::array();
  for (const BuildWarning& w : s.warnings) warnings.push_back({{"code", w.code}, {"message", w.message}});
  const nlohmann::json j = {
      {"status", "ok"},
      {"input", s.input},
      {"output", s.output},
      {"source_sha256", s.source_sha256},
      {"input_vertices", s.input_vertices},
      {"input_triangles", s.input_triangles},
      {"closed", s.closed},
      {"timings_s", timings},
      {"total_s", s.total_s},
      {"peak_memory_bytes", s.peak_memory_bytes},
      {"file_size_bytes", s.file_size_bytes},
      {"voxelmap", {{"dims", s.dims}, {"voxel_size", s.voxel_size}, {"stored_distances", s.stored_distances}}},
      {"pointshell",
       {{"points", s.points}, {"levels", s.points_per_level.size()}, {"points_per_level", s.points_per_level}}},
      {"volume", s.volume},
      {"warnings", warnings}};
  return j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::string error_json(const std::string& input, const Error& error) {
  const nlohmann::json j = {
      {"status", "error"}, {"input", input}, {"code", code_name(error.code)}, {"message", error.message}};
  return j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace);
}

}  // namespace voxfmt::bake
