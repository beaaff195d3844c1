// `voxfmt export ASSET --nvdb OUT.nvdb`: the asset's distance field for other engines (Warp's volumes, NanoVDB's
// tools), built from the runtime's own field after the read has judged the asset as every consumer does.
#include <chrono>
#include <iomanip>
#include <iostream>

#include "commands.h"
#include "json_report.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/engines/layouts.h"
#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::cli {

namespace {

struct Options {
  std::string file;
  std::string nvdb;
  double width = 0;
  bool uncompressed = false;
  bool json = false;
  ReadOptions read;
};

int run_export(const Options& o) {
  using clock = std::chrono::steady_clock;
  const auto start = clock::now();
  // A typo in the output costs no read of a large asset.
  if (const Status writable = check_output_path(o.nvdb, o.file); !writable)
    return report_error("export", writable.error(), o.json, o.file);
  runtime::LoadOptions load;
  load.load_point_shell = false;
  load.read = o.read;  // every rule of validate --level full, judged once by the read
  auto object = runtime::CollisionObject::load(o.file, load);
  if (!object) return report_error("export", object.error(), o.json, o.file);
  const auto read = clock::now();
  engines::NanoVdbOptions options;
  options.width_voxels = o.width;
  options.compress = !o.uncompressed;
  Result<engines::NanoVdbGrids> grids = engines::nanovdb_grids(*object.value(), options);
  if (!grids) return report_error("export", grids.error(), o.json, o.file);
  remove_dead_temporaries(o.nvdb);  // what an export killed while writing left beside it
  const Status written = write_file_atomically(o.nvdb, grids->file);
  if (!written) return report_error("export", written.error(), o.json, o.file);
  const auto done = clock::now();
  const double read_s = std::chrono::duration<double>(read - start).count();
  const double export_s = std::chrono::duration<double>(done - read).count();
  const engines::NanoVdbGrids& g = grids.value();
  if (o.json) {
    nlohmann::json out = {{"file", o.nvdb},
                          {"kind", "nvdb"},
                          {"grids", {"distance", "coarse"}},
                          {"bytes", g.file.size()},
                          {"uncompressed_bytes", g.uncompressed_bytes},
                          {"compressed", !o.uncompressed},
                          {"level_set_width", g.width},
                          {"distance_leaves", g.distance_leaves},
                          {"distance_active_voxels", g.distance_active_voxels},
                          {"coarse_voxels", g.coarse_voxels},
                          {"timings_s", {{"read", read_s}, {"export", export_s}}}};
    std::cout << to_text(out) << "\n";
    return kExitOk;
  }
  std::cout << terminal_safe(o.nvdb) << ": NanoVDB grids \"distance\" (level set, " << g.distance_leaves
            << " leaves, width " << std::setprecision(4) << g.width << " m) and \"coarse\" (" << g.coarse_voxels
            << " points), " << g.file.size() << " bytes" << (o.uncompressed ? "" : " (ZIP)") << " in " << std::fixed
            << std::setprecision(2) << read_s + export_s << " s\n";
  return kExitOk;
}

}  // namespace

void add_export_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<Options>();
  CLI::App* cmd = app.add_subcommand(
      "export", "Write an asset's distance field for other engines: NanoVDB grids for NVIDIA Warp and NanoVDB tools");
  cmd->add_option("file", options->file, "Asset file (.vox.h5)")->required();
  cmd->add_option("--nvdb", options->nvdb,
                  "Write two float32 NanoVDB grids (metres, the asset's frame): \"distance\", a level set whose "
                  "leaves are the asset's bricks near the surface (its voxels exact within the band), and "
                  "\"coarse\", one unsigned distance every 8 voxels for the far field (its sign is the level set's)")
      ->check(output_path())
      ->required();
  cmd->add_option("--width", options->width,
                  "Half-width of the \"distance\" level set in voxels: values clamp to +-width (default: the band the "
                  "asset stores completely, its distance band - 1/2)")
      ->check(finite_number())
      ->check(CLI::Range(0.5, 32767.0));
  cmd->add_flag("--uncompressed", options->uncompressed,
                "Write the grids uncompressed (default: NanoVDB's ZIP codec, which Warp and nanovdb_print read)");
  cmd->add_flag("--json", options->json, "Print what was written as JSON on stdout");
  add_read_budget_option(cmd, options->read);
  cmd->footer(
      "\nThe asset is read and judged as by `voxfmt validate --level full`: a damaged asset is refused with its code\n"
      "before anything is written. Warp: wp.Volume.load_from_nvdb(open(OUT, 'rb')) loads \"distance\";\n"
      "volume.load_next_grid() loads \"coarse\". Or, without a file: voxfmt.warp.volume(asset).\n\n"
      "Examples:\n"
      "  voxfmt export bunny.vox.h5 --nvdb bunny.nvdb\n"
      "  voxfmt export bunny.vox.h5 --nvdb bunny.nvdb --width 6 --json\n");
  cmd->callback([options, &exit_code] { exit_code = run_export(*options); });
}

}  // namespace voxfmt::cli
