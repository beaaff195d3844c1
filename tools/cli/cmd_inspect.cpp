// `voxfmt inspect FILE [--json]`: a readable summary of one asset.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "commands.h"
#include "json_report.h"
#include "voxfmt/io.h"

namespace voxfmt::cli {

namespace {

struct Options {
  std::string file;
  bool json = false;
};

struct Summary {
  uint64_t file_size = 0;
  uint64_t memory_bytes = 0;
  size_t stored_distances = 0;
  int layer_min = 0, layer_max = 0;
  std::vector<uint32_t> points_per_level;
};

Summary summarize(const std::string& file, const Asset& a) {
  Summary s;
  std::error_code ec;
  s.file_size = std::filesystem::file_size(file, ec);
  const Voxelmap& vm = a.voxelmap;
  s.stored_distances = vm.stored_count();
  if (!vm.layers.empty()) {
    auto [lo, hi] = std::minmax_element(vm.layers.begin(), vm.layers.end());
    s.layer_min = *lo;
    s.layer_max = *hi;
  }
  const PointShell& ps = a.point_shell;
  s.points_per_level = ps.points_per_level();
  const size_t n = ps.size();
  s.memory_bytes = vm.layers.size() * sizeof(int16_t) + vm.distances.size() * sizeof(float) +
                   n * (2 * sizeof(Vec3) + sizeof(Vec3f) + sizeof(double) + 2 * sizeof(uint32_t)) +
                   ps.level_offsets.size() * sizeof(uint32_t);
  return s;
}

nlohmann::json vec(const Vec3& v) { return nlohmann::json::array({v[0], v[1], v[2]}); }

nlohmann::json to_json(const std::string& file, const Asset& a, const Summary& s, const std::vector<Issue>& warnings) {
  const Voxelmap& vm = a.voxelmap;
  const MassProperties& m = a.mass;
  nlohmann::json inertia = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) inertia.push_back({m.inertia[r * 3], m.inertia[r * 3 + 1], m.inertia[r * 3 + 2]});
  nlohmann::json warning_list = nlohmann::json::array();
  for (const Issue& w : warnings) warning_list.push_back(std::string(code_name(w.code)) + ": " + w.message);
  return {{"file", file},
          {"file_size_bytes", s.file_size},
          {"format_version", {a.version.major, a.version.minor}},
          {"units", "m"},
          {"frame", "right-handed"},
          {"up_axis", a.up_axis},
          {"bounds_min", vec(a.bounds_min)},
          {"bounds_max", vec(a.bounds_max)},
          {"voxelmap",
           {{"dims", {vm.dims[0], vm.dims[1], vm.dims[2]}},
            {"voxel_size", vm.voxel_size},
            {"origin", vec(vm.origin)},
            {"distance_band", vm.distance_band},
            {"stored_distances", s.stored_distances},
            {"layer_min", s.layer_min},
            {"layer_max", s.layer_max},
            {"memory_bytes", vm.layers.size() * sizeof(int16_t) + vm.distances.size() * sizeof(float)}}},
          {"pointshell",
           {{"points", a.point_shell.size()},
            {"levels", a.point_shell.level_count()},
            {"points_per_level", s.points_per_level},
            {"tree_depth", a.point_shell.level_count() ? a.point_shell.level_count() - 1 : 0}}},
          {"memory_bytes", s.memory_bytes},
          {"mass_properties", {{"volume", m.volume}, {"center_of_mass", vec(m.center_of_mass)}, {"inertia", inertia}}},
          {"provenance", provenance_json(a.provenance)},
          {"warnings", warning_list}};
}

std::string human_bytes(uint64_t bytes) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(1);
  if (bytes >= (1ull << 20)) s << double(bytes) / (1 << 20) << " MiB";
  else if (bytes >= 1024) s << double(bytes) / 1024 << " KiB";
  else s << bytes << " B";
  return s.str();
}

std::string v3(const Vec3& v) {
  std::ostringstream s;
  s << std::setprecision(6) << "(" << v[0] << ", " << v[1] << ", " << v[2] << ")";
  return s.str();
}

void print_text(const std::string& file, const Asset& a, const Summary& s, const std::vector<Issue>& warnings) {
  const Voxelmap& vm = a.voxelmap;
  const PointShell& ps = a.point_shell;
  std::ostream& o = std::cout;
  auto row = [&](const std::string& key) -> std::ostream& { return o << "  " << std::left << std::setw(20) << key; };
  o << file << "\n";
  row("format") << "voxfmt " << a.version.major << "." << a.version.minor << ", metres, right-handed, up " << a.up_axis << "\n";
  row("file size") << human_bytes(s.file_size) << "\n";
  row("memory (loaded)") << human_bytes(s.memory_bytes) << "\n";
  row("bounds") << v3(a.bounds_min) << " .. " << v3(a.bounds_max) << "\n";
  o << "voxelmap\n";
  row("dims") << vm.dims[0] << " x " << vm.dims[1] << " x " << vm.dims[2] << " (" << vm.voxel_count() << " voxels)\n";
  row("voxel size") << vm.voxel_size << " m\n";
  row("origin") << v3(vm.origin) << "\n";
  row("distance band") << "±" << vm.distance_band << " voxels, " << s.stored_distances << " distances stored\n";
  row("layers") << s.layer_min << " .. " << s.layer_max << " (inside > 0)\n";
  o << "point shell\n";
  row("points") << ps.size() << " in " << ps.level_count() << " levels (tree depth "
                << (ps.level_count() ? ps.level_count() - 1 : 0) << ")\n";
  row("points per level");
  for (size_t l = 0; l < s.points_per_level.size(); ++l) o << (l ? ", " : "") << s.points_per_level[l];
  o << "\n";
  if (ps.point_spacing) row("point spacing") << *ps.point_spacing << " m\n";
  o << "mass properties (unit density)\n";
  row("volume") << a.mass.volume << " m^3\n";
  row("centre of mass") << v3(a.mass.center_of_mass) << "\n";
  row("inertia") << "[" << a.mass.inertia[0] << " " << a.mass.inertia[1] << " " << a.mass.inertia[2] << "; "
                 << a.mass.inertia[3] << " " << a.mass.inertia[4] << " " << a.mass.inertia[5] << "; " << a.mass.inertia[6]
                 << " " << a.mass.inertia[7] << " " << a.mass.inertia[8] << "] m^5\n";
  const Provenance& p = a.provenance;
  o << "provenance\n";
  row("generator") << p.generator << " " << p.generator_version << "\n";
  if (!p.source_file.empty()) row("source") << p.source_file << " (sha256 " << p.source_sha256 << ")\n";
  if (!p.created_utc.empty()) row("created") << p.created_utc << "\n";
  row("build parameters") << p.build_parameters_json << "\n";
  row("build warnings") << p.build_warnings.size() << "\n";
  for (const BuildWarning& w : p.build_warnings) o << "    " << w.code << ": " << w.message << "\n";
  for (const Issue& w : warnings) o << "warning: " << code_name(w.code) << " " << w.path << ": " << w.message << "\n";
}

}  // namespace

void add_inspect_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<Options>();
  CLI::App* cmd = app.add_subcommand("inspect", "Print a summary of an asset: grid, point shell, mass, provenance");
  cmd->add_option("file", options->file, "Asset file (.vox.h5)")->required();
  cmd->add_flag("--json", options->json, "Print the summary as JSON on stdout");
  cmd->callback([options, &exit_code] {
    std::vector<Issue> warnings;
    Result<Asset> asset = read_asset(options->file, &warnings);
    if (!asset) {
      std::cerr << "voxfmt inspect: error: " << asset.error().message << "\n";
      exit_code = asset.error().code == IssueCode::FileNotFound ? kExitUsageOrIo : kExitInvalid;
      return;
    }
    const Summary summary = summarize(options->file, asset.value());
    if (options->json)
      std::cout << to_text(to_json(options->file, asset.value(), summary, warnings)) << "\n";
    else
      print_text(options->file, asset.value(), summary, warnings);
    exit_code = kExitOk;
  });
}

}  // namespace voxfmt::cli
