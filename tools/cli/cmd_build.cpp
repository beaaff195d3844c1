// `voxfmt build MESH -o OUT`: bake one mesh into an asset (voxfmt::bake::bake_to_file), with progress.
#include <unistd.h>

#include <chrono>
#include <iomanip>
#include <iostream>

#include "bake_options.h"
#include "commands.h"
#include "voxfmt/bake/bake.h"

namespace voxfmt::cli {

namespace {

struct Options {
  std::string mesh;
  std::string output;
  bake::Settings bake;
  bool json = false;
  bool quiet = false;
};

int run(const Options& o) {
  const bool show_progress = !o.quiet && !o.json && isatty(STDERR_FILENO);
  const auto start = std::chrono::steady_clock::now();
  auto progress = [&](std::string_view stage, double fraction) {
    if (!show_progress) return;
    const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::cerr << "\r\033[K" << std::setw(3) << int(fraction * 100 + 0.5) << "% " << stage << "  (" << std::fixed
              << std::setprecision(1) << t << " s)" << std::flush;
  };
  const Result<bake::Summary> summary = bake::bake_to_file(o.mesh, o.output, o.bake, progress);
  if (show_progress) std::cerr << "\r\033[K" << std::flush;
  if (!summary) {
    if (o.json) std::cout << bake::error_json(o.mesh, summary.error()) << "\n";
    return report_error("build", summary.error());
  }
  const bake::Summary& s = summary.value();
  if (o.json) {
    std::cout << bake::to_json(s) << "\n";
  } else if (!o.quiet) {
    for (const BuildWarning& w : s.warnings)
      std::cerr << "warning: " << w.code << ": " << terminal_safe(w.message) << "\n";
    std::cout << terminal_safe(o.output) << ": " << s.dims[0] << "x" << s.dims[1] << "x" << s.dims[2] << " voxels of "
              << s.voxel_size << " m, " << s.points << " points in " << s.points_per_level.size() << " levels, "
              << s.file_size_bytes / 1024 << " KiB, " << std::fixed << std::setprecision(2) << s.total_s << " s\n";
  }
  return kExitOk;
}

}  // namespace

void add_build_command(CLI::App& app, int& exit_code) {
  auto o = std::make_shared<Options>();
  CLI::App* cmd = app.add_subcommand("build", "Bake a mesh (any format assimp reads) into a voxfmt asset");
  cmd->add_option("mesh", o->mesh, "Input mesh file (OBJ, PLY, STL, OFF, glTF/GLB, FBX, DAE, ...)")->required();
  cmd->add_option("-o,--output", o->output,
                  "Output asset file (.vox.h5); validated against the spec in memory, then written atomically")
      ->check(output_path())
      ->required();
  add_bake_options(*cmd, o->bake);
  cmd->add_option_function<uint64_t>(
         "--max-memory", [o](uint64_t mib) { o->bake.voxelmap.max_memory_bytes = mib << 20; },
         "MiB the voxelmap, and the point shell, may each need at its peak; a bake that would need more is refused "
         "up front with OUT_OF_MEMORY and the estimate (default: 3/4 of this machine's memory)")
      ->transform(whole_number())
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 40));
  cmd->add_flag("--json", o->json, "Print a JSON summary (timings, peak memory, sizes, warnings) on stdout");
  cmd->add_flag("-q,--quiet", o->quiet, "No progress, warnings or summary");
  cmd->footer(
      "\nExamples:\n"
      "  voxfmt build bunny.off -o bunny.vox.h5                         # defaults: 128 voxels, 10,000 points\n"
      "  voxfmt build part.stl -o part.vox.h5 --unit-scale 0.001 --voxel-size 5e-5   # a mesh in mm, 50 um voxels\n"
      "  voxfmt build bunny.off -o bunny.vox.h5 --resolution 306 --points 35000 --json   # the seed's settings\n");
  cmd->callback([o, &exit_code] { exit_code = run(*o); });
}

}  // namespace voxfmt::cli
