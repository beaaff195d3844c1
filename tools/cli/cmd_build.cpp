// `voxfmt build MESH -o OUT`: bake one mesh into an asset.
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iomanip>
#include <iostream>

#include "bake.h"
#include "commands.h"
#include "json_report.h"
#include "voxfmt/io.h"

namespace voxfmt::cli {

namespace {

struct Options {
  std::string mesh;
  std::string output;
  bake::BuildOptions build;
  int deflate = 4;
  bool json = false;
  bool quiet = false;
};

uint64_t peak_memory_bytes() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return uint64_t(usage.ru_maxrss) * 1024;  // Linux reports KiB
}

int run(const Options& o) {
  const bool show_progress = !o.quiet && !o.json && isatty(STDERR_FILENO);
  const auto start = std::chrono::steady_clock::now();
  bake::BuildReport report;
  int bake_stages = 0;  // the bake's own stages; "write" comes after them
  auto progress = [&](int index, int count, const std::string& stage) {
    bake_stages = std::max(bake_stages, count);
    if (!show_progress) return;
    const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::cerr << "\r\033[K[" << index << "/" << count + 1 << "] " << stage << "  (" << std::fixed << std::setprecision(1)
              << t << " s)" << std::flush;
  };
  try {
    Asset asset = bake::build_asset(o.mesh, o.build, report, progress);
    progress(bake_stages + 1, bake_stages, "write");
    const auto write_start = std::chrono::steady_clock::now();
    WriteOptions write_options;
    write_options.deflate_level = o.deflate;
    const Status written = write_asset(o.output, asset, write_options);
    if (!written) throw bake::BakeError("WRITE_FAILED", written.error().message);
    report.timings.push_back({"write", std::chrono::duration<double>(std::chrono::steady_clock::now() - write_start).count()});
    if (show_progress) std::cerr << "\r\033[K";

    const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::error_code ec;
    const uint64_t file_size = std::filesystem::file_size(o.output, ec);
    const PointShell& ps = asset.point_shell;
    if (o.json) {
      nlohmann::json timings = nlohmann::json::object();
      for (const auto& t : report.timings) timings[t.stage] = t.seconds;
      nlohmann::json warnings = nlohmann::json::array();
      for (const auto& w : report.repair.warnings) warnings.push_back({{"code", w.code}, {"message", w.message}});
      const Voxelmap& vm = asset.voxelmap;
      std::cout << to_text(nlohmann::json{{"status", "ok"},
                                  {"input", o.mesh},
                                  {"output", o.output},
                                  {"input_vertices", report.input_vertices},
                                  {"input_triangles", report.input_triangles},
                                  {"closed", report.repair.closed},
                                  {"timings_s", timings},
                                  {"total_s", total},
                                  {"peak_memory_bytes", peak_memory_bytes()},
                                  {"file_size_bytes", file_size},
                                  {"voxelmap", {{"dims", vm.dims}, {"voxel_size", vm.voxel_size}, {"stored_distances", vm.stored_count()}}},
                                  {"pointshell", {{"points", ps.size()}, {"levels", ps.level_count()}, {"points_per_level", ps.points_per_level()}}},
                                  {"volume", asset.mass.volume},
                                  {"warnings", warnings}})
                << "\n";
    } else if (!o.quiet) {
      for (const auto& w : report.repair.warnings) std::cerr << "warning: " << w.code << ": " << w.message << "\n";
      const Voxelmap& vm = asset.voxelmap;
      std::cout << o.output << ": " << vm.dims[0] << "x" << vm.dims[1] << "x" << vm.dims[2] << " voxels of "
                << vm.voxel_size << " m, " << ps.size() << " points in " << ps.level_count() << " levels, "
                << file_size / 1024 << " KiB, " << std::fixed << std::setprecision(2) << total << " s\n";
    }
    return kExitOk;
  } catch (const bake::BakeError& e) {
    if (show_progress) std::cerr << "\r\033[K";
    if (o.json) std::cout << to_text(nlohmann::json{{"status", "error"}, {"input", o.mesh}, {"code", e.code()}, {"message", e.what()}}) << "\n";
    std::cerr << "voxfmt build: error: " << e.code() << ": " << e.what() << "\n";
    return e.code() == "BAD_OPTION" ? kExitUsageOrIo : kExitInvalid;
  } catch (const std::exception& e) {  // library failures (OpenVDB, CGAL, allocation) still get a clean message
    if (show_progress) std::cerr << "\r\033[K";
    if (o.json) std::cout << to_text(nlohmann::json{{"status", "error"}, {"input", o.mesh}, {"code", "INTERNAL"}, {"message", e.what()}}) << "\n";
    std::cerr << "voxfmt build: error: " << o.mesh << ": " << e.what() << "\n";
    return kExitInvalid;
  }
}

}  // namespace

void add_build_command(CLI::App& app, int& exit_code) {
  auto o = std::make_shared<Options>();
  CLI::App* cmd = app.add_subcommand("build", "Bake a mesh (any format assimp reads) into a voxfmt asset");
  cmd->add_option("mesh", o->mesh, "Input mesh file (OBJ, PLY, STL, OFF, glTF/GLB, FBX, DAE, ...)")->required();
  cmd->add_option("-o,--output", o->output, "Output asset file (.vox.h5); written atomically")->required();
  auto* resolution = cmd->add_option("--resolution", o->build.voxelmap.resolution,
                                     "Voxels along the longest bounding-box axis")
                         ->capture_default_str()->check(CLI::Range(1u, 4096u));
  auto* voxel_size = cmd->add_option("--voxel-size", o->build.voxelmap.voxel_size, "Voxel edge in metres (instead of --resolution)")
                         ->check(CLI::PositiveNumber);
  resolution->excludes(voxel_size);
  auto* points = cmd->add_option("--points", o->build.point_shell.points, "Target number of surface points")
                     ->capture_default_str()->check(CLI::Range(1u, 50'000'000u));
  auto* spacing = cmd->add_option("--point-spacing", o->build.point_shell.point_spacing,
                                  "Minimum distance between points in metres (instead of --points)")
                      ->check(CLI::PositiveNumber);
  points->excludes(spacing);
  cmd->add_option("--branching", o->build.point_shell.branching, "Mean children per point-sphere tree node")
      ->capture_default_str()->check(CLI::Range(2.0, 64.0));
  cmd->add_option("--margin", o->build.voxelmap.margin, "Outer voxels around the bounding box on each side")
      ->capture_default_str()->check(CLI::Range(0u, 1024u));
  cmd->add_option("--band", o->build.voxelmap.distance_band, "Half-width in voxels of the band of exact distances")
      ->capture_default_str()->check(CLI::Range(1.0, 64.0));
  cmd->add_option("--unit-scale", o->build.import.unit_scale, "Multiply coordinates by this to get metres (0.001 for mm)")
      ->capture_default_str()->check(CLI::PositiveNumber);
  cmd->add_option("--up-axis", o->build.up_axis, "Up direction recorded in the asset")
      ->capture_default_str()->check(CLI::IsMember({"+X", "-X", "+Y", "-Y", "+Z", "-Z"}));
  cmd->add_flag("!--no-self-intersection-check", o->build.check_self_intersections,
                "Skip the self-intersection check (faster on huge meshes)");
  cmd->add_option("--seed", o->build.point_shell.seed, "Seed of the point sampling (deterministic)")->capture_default_str();
  cmd->add_option("--deflate", o->deflate, "gzip level 0-9 for the voxel grids")->capture_default_str()->check(CLI::Range(0, 9));
  cmd->add_option("--threads", o->build.threads, "Worker threads (0 = all cores)")->capture_default_str();
  cmd->add_flag("--json", o->json, "Print a JSON summary (timings, peak memory, sizes, warnings) on stdout");
  cmd->add_flag("-q,--quiet", o->quiet, "No progress, warnings or summary");
  cmd->callback([o, &exit_code] { exit_code = run(*o); });
}

}  // namespace voxfmt::cli
