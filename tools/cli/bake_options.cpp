#include "bake_options.h"

#include "commands.h"

#include <algorithm>
#include <cstdio>

namespace voxfmt::cli {

void add_bake_options(CLI::App& cmd, bake::Settings& b) {
  auto* resolution = cmd.add_option("--resolution", b.voxelmap.resolution, "Voxels along the longest bounding-box axis")
                         ->capture_default_str()
                         ->transform(whole_number())
                         ->check(CLI::Range(1u, 4096u));
  auto* voxel_size =
      cmd.add_option("--voxel-size", b.voxelmap.voxel_size, "Voxel edge in metres (instead of --resolution)")
          ->check(finite_number());
  resolution->excludes(voxel_size);
  auto* points = cmd.add_option("--points", b.point_shell.points, "Target number of surface points")
                     ->capture_default_str()
                     ->transform(whole_number())
                     ->check(CLI::Range(1u, 50'000'000u));
  auto* spacing = cmd.add_option("--point-spacing", b.point_shell.point_spacing,
                                 "Minimum distance between points in metres (instead of --points)")
                      ->check(finite_number());
  points->excludes(spacing);
  cmd.add_option("--branching", b.point_shell.branching, "Mean children per point-sphere tree node")
      ->capture_default_str()
      ->check(finite_number())
      ->check(CLI::Range(2.0, 64.0));
  cmd.add_option("--margin", b.voxelmap.margin, "Outer voxels around the bounding box on each side")
      ->capture_default_str()
      ->transform(whole_number())
      ->check(CLI::Range(0u, 1024u));
  cmd.add_option("--band", b.voxelmap.distance_band,
                 "Half-width in voxels of the band of exact distances (6 for haptic partners pressed deeper: smoother "
                 "forces for ~1.3x the file; docs/haptics.md)")
      ->capture_default_str()
      ->check(finite_number())
      ->check(CLI::Range(1.0, 64.0));
  cmd.add_option("--shell-thickness", b.voxelmap.shell_thickness,
                 "Bake the surface as a solid shell this thick (metres): thin walls, sheets, open scans. Default: "
                 "the surface's inside, or a 2-voxel shell (with a warning) when it encloses nothing")
      ->check(finite_number());
  cmd.add_option("--unit-scale", b.import.unit_scale, "Multiply coordinates by this to get metres (0.001 for mm)")
      ->capture_default_str()
      ->check(finite_number());
  cmd.add_option("--up-axis", b.up_axis, "Up direction recorded in the asset")
      ->capture_default_str()
      ->check(CLI::IsMember({"+X", "-X", "+Y", "-Y", "+Z", "-Z"}));
  cmd.add_flag("!--no-self-intersection-check", b.check_self_intersections,
               "Skip the self-intersection check (faster on huge meshes)");
  cmd.add_option("--seed", b.point_shell.seed, "Seed of the point sampling (deterministic)")
      ->capture_default_str()
      ->transform(whole_number());  // a uint64: "-1" would wrap to 2^64 - 1
  cmd.add_option("--deflate", b.deflate, "gzip level 0-9 for the voxel grids")
      ->capture_default_str()
      ->transform(whole_number())
      ->check(CLI::Range(0, 9));
  cmd.add_option("--threads", b.threads, "Worker threads of a bake (0 = all cores; in batch: cores / --jobs)")
      ->capture_default_str()
      ->transform(whole_number())
      ->check(CLI::Range(0u, kMaxThreads));
}

namespace {
std::string exact(double value) {  // 17 significant digits: parses back to the same double
  char text[40];
  std::snprintf(text, sizeof text, "%.17g", value);
  return text;
}
}  // namespace

std::vector<std::string> bake_option_args(const bake::Settings& b) {
  std::vector<std::string> args;
  if (b.voxelmap.voxel_size > 0)
    args.insert(args.end(), {"--voxel-size", exact(b.voxelmap.voxel_size)});
  else
    args.insert(args.end(), {"--resolution", std::to_string(b.voxelmap.resolution)});
  if (b.point_shell.point_spacing > 0)
    args.insert(args.end(), {"--point-spacing", exact(b.point_shell.point_spacing)});
  else
    args.insert(args.end(), {"--points", std::to_string(b.point_shell.points)});
  args.insert(args.end(), {"--branching", exact(b.point_shell.branching), "--margin", std::to_string(b.voxelmap.margin),
                           "--band", exact(b.voxelmap.distance_band), "--unit-scale", exact(b.import.unit_scale),
                           "--up-axis=" + b.up_axis /* "-X" alone would look like an option */, "--seed",
                           std::to_string(b.point_shell.seed), "--deflate", std::to_string(b.deflate), "--threads",
                           std::to_string(b.threads)});
  if (!b.check_self_intersections) args.push_back("--no-self-intersection-check");
  if (b.voxelmap.max_memory_bytes > 0)
    args.insert(args.end(), {"--max-memory", std::to_string(std::max<uint64_t>(1, b.voxelmap.max_memory_bytes >> 20))});
  if (b.voxelmap.shell_thickness > 0) args.insert(args.end(), {"--shell-thickness", exact(b.voxelmap.shell_thickness)});
  return args;
}

nlohmann::json build_parameters(const bake::Settings& s) {
  return nlohmann::json::parse(bake::build_parameters_json(s));
}

}  // namespace voxfmt::cli
