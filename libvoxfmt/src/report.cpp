#include "voxfmt/detail/report.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <filesystem>
#include <tuple>

namespace voxfmt {

namespace {

nlohmann::json vec(const Vec3& v) { return nlohmann::json::array({v[0], v[1], v[2]}); }

nlohmann::json provenance_json(const Provenance& p) {
  nlohmann::json warnings = nlohmann::json::array();
  for (const BuildWarning& w : p.build_warnings) warnings.push_back({{"code", w.code}, {"message", w.message}});
  nlohmann::json params = nlohmann::json::parse(p.build_parameters_json, nullptr, false);
  if (params.is_discarded()) params = p.build_parameters_json;
  nlohmann::json out = {{"generator", p.generator},     {"generator_version", p.generator_version},
                        {"source_file", p.source_file}, {"source_sha256", p.source_sha256},
                        {"build_parameters", params},   {"dependency_versions", p.dependency_versions},
                        {"build_warnings", warnings}};
  if (!p.created_utc.empty()) out["created_utc"] = p.created_utc;
  return out;
}

}  // namespace

AssetSummary summarize_asset(const std::string& file, const Asset& a) {
  AssetSummary s;
  std::error_code ec;
  const auto size = std::filesystem::file_size(file, ec);
  s.file_size = ec ? 0 : size;
  const Voxelmap& vm = a.voxelmap;
  s.stored_distances = vm.stored_count();
  std::tie(s.layer_min, s.layer_max) = vm.layer_range();
  s.value_bricks = vm.value_brick_count();
  s.coarse_bricks = vm.brick_count() - std::min(vm.brick_count(), s.value_bricks);
  const PointShell& ps = a.point_shell;
  s.points_per_level = ps.points_per_level();
  const size_t n = ps.size();
  s.memory_bytes = vm.memory_bytes() + n * (2 * sizeof(Vec3) + sizeof(Vec3f) + sizeof(double) + 2 * sizeof(uint32_t)) +
                   ps.level_offsets.size() * sizeof(uint32_t);
  return s;
}

std::string inspect_json(const std::string& file, const Asset& a, const AssetSummary& s,
                         const std::vector<Issue>& warnings) {
  const Voxelmap& vm = a.voxelmap;
  const MassProperties& m = a.mass;
  nlohmann::json inertia = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) inertia.push_back({m.inertia[r * 3], m.inertia[r * 3 + 1], m.inertia[r * 3 + 2]});
  nlohmann::json warning_list = nlohmann::json::array();
  for (const Issue& w : warnings) warning_list.push_back(std::string(code_name(w.code)) + ": " + w.message);
  const nlohmann::json out = {
      {"file", file},
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
        {"estimates", vm.estimates == Voxelmap::Estimates::Settled ? "settled" : "interpolated"},
        {"layer_min", s.layer_min},
        {"layer_max", s.layer_max},
        {"bricks", vm.brick_count()},
        {"value_bricks", s.value_bricks},
        {"coarse_bricks", s.coarse_bricks},
        {"lattice_error", {vm.lattice_error[0], vm.lattice_error[1]}},
        {"memory_bytes", vm.memory_bytes()}}},
      {"pointshell",
       {{"points", a.point_shell.size()},
        {"levels", a.point_shell.level_count()},
        {"points_per_level", s.points_per_level},
        {"tree_depth", a.point_shell.level_count() ? a.point_shell.level_count() - 1 : 0}}},
      {"memory_bytes", s.memory_bytes},
      {"mass_properties", {{"volume", m.volume}, {"center_of_mass", vec(m.center_of_mass)}, {"inertia", inertia}}},
      {"provenance", provenance_json(a.provenance)},
      {"warnings", warning_list}};
  // Invalid UTF-8 (a file name) becomes U+FFFD instead of throwing.
  return out.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

}  // namespace voxfmt
