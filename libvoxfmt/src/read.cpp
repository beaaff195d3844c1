// Reading an asset file into the plain types, collecting structural findings.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <set>

#include "h5.h"
#include "load.h"
#include "voxfmt/io.h"

namespace voxfmt {
namespace detail {

namespace {

Vec3 to_vec3(const std::vector<double>& v) { return {v[0], v[1], v[2]}; }

template <class T, size_t K>
std::vector<std::array<T, K>> to_rows(const std::vector<T>& flat) {
  std::vector<std::array<T, K>> rows(flat.size() / K);
  if (!rows.empty()) std::memcpy(rows.data(), flat.data(), rows.size() * sizeof(std::array<T, K>));
  return rows;
}

void check_vocabulary(h5::Reader& r, const std::optional<std::string>& value, const std::string& path,
                      std::initializer_list<const char*> allowed) {
  if (!value) return;
  for (const char* a : allowed)
    if (*value == a) return;
  std::string list;
  for (const char* a : allowed) list += std::string(list.empty() ? "" : ", ") + "'" + a + "'";
  r.report(IssueCode::BadAttributeValue, path, "value '" + *value + "' is not allowed (expected " + list + ")");
}

void report_unknown(h5::Reader& r, hid_t object, const std::string& path, std::set<std::string> known_members,
                    std::set<std::string> known_attributes, bool is_group) {
  if (is_group)
    for (const std::string& name : r.member_names(object))
      if (!known_members.count(name))
        r.report(IssueCode::UnknownObject, h5::join_path(path, name),
                 "object not defined by this format version; ignored");
  for (const std::string& name : r.attribute_names(object))
    if (!known_attributes.count(name))
      r.report(IssueCode::UnknownObject, path + (path == "/" ? "" : "/") + "@" + name,
               "attribute not defined by this format version; ignored");
}

// Format 2.0 (spec §3): the brick table, the value bricks and the lattice, as they are held in memory.
void read_bricks(h5::Reader& r, hid_t g, const std::string& p, Voxelmap& vm) {
  if (auto v = r.numeric_attribute<uint32_t>(g, p, "brick_edge", {}))
    if ((*v)[0] != Voxelmap::kBrickEdge)
      r.report(IssueCode::BadAttributeValue, p + "/@brick_edge",
               "brick edge " + std::to_string((*v)[0]) + " is not supported (format 2.0 bricks are 8 voxels)");
  if (auto v = r.numeric_attribute<double>(g, p, "distance_quantum", {})) vm.distance_quantum = (*v)[0];
  if (auto v = r.numeric_attribute<double>(g, p, "estimate_quantum", {})) vm.estimate_quantum = (*v)[0];
  if (auto v = r.numeric_attribute<double>(g, p, "lattice_error", {2})) vm.lattice_error = {(*v)[0], (*v)[1]};
  const auto b = vm.brick_dims();
  const auto l = vm.lattice_dims();
  if (auto v = r.dataset<int32_t>(g, p, "bricks", {int64_t(b[2]), int64_t(b[1]), int64_t(b[0])}))
    vm.bricks = std::move(*v);
  if (auto v = r.dataset<int16_t>(g, p, "brick_values", {-1, int64_t(Voxelmap::kBrickVoxels)}))
    vm.brick_values = std::move(*v);
  if (auto v = r.dataset<float>(g, p, "lattice", {int64_t(l[2]), int64_t(l[1]), int64_t(l[0])}))
    vm.lattice = std::move(*v);
}

void read_voxelmap(h5::Reader& r, hid_t g, const FormatVersion& version, ValidationLevel level, bool closed,
                   const DenseReadBudget& budget, Voxelmap& vm, std::vector<Issue>& value_findings) {
  const std::string p = "/voxelmap";
  if (auto v = r.numeric_attribute<double>(g, p, "origin", {3})) vm.origin = to_vec3(*v);
  if (auto v = r.numeric_attribute<double>(g, p, "voxel_size", {})) vm.voxel_size = (*v)[0];
  if (auto v = r.numeric_attribute<double>(g, p, "distance_band", {})) vm.distance_band = (*v)[0];
  if (r.has_attribute(g, "margin"))
    if (auto v = r.numeric_attribute<uint32_t>(g, p, "margin", {})) vm.margin = (*v)[0];
  if (r.has_attribute(g, "shell_thickness"))
    if (auto v = r.numeric_attribute<double>(g, p, "shell_thickness", {})) {
      vm.shell_thickness = (*v)[0];
      // NaN and infinity are NON_FINITE_VALUE, as for every other attribute that must be finite.
      if (!std::isfinite(*vm.shell_thickness))
        r.report(IssueCode::NonFiniteValue, p + "/@shell_thickness", "shell thickness is not finite");
      else if (!(*vm.shell_thickness > 0))
        r.report(IssueCode::ValueOutOfRange, p + "/@shell_thickness", "must be finite and > 0");
    }
  check_vocabulary(r, r.string_attribute(g, p, "index_order"), p + "/@index_order", {"zyx"});
  auto dims = r.numeric_attribute<uint32_t>(g, p, "dims", {3});
  if (!dims) return;
  vm.dims = {(*dims)[0], (*dims)[1], (*dims)[2]};
  if (!grid_size_allowed(vm.dims, version)) {
    r.report(IssueCode::ValueOutOfRange, p + "/@dims",
             "dims [" + std::to_string(vm.dims[0]) + ", " + std::to_string(vm.dims[1]) + ", " +
                 std::to_string(vm.dims[2]) + "] must each be >= 1 with " + grid_size_limit(version));
    return;
  }
  if (version.major == 1) {
    // Layers and distances per voxel: converted to bricks as they are read, a slab of bricks at a time.
    read_dense_voxelmap(r, g, p, version, level, closed, budget, vm, value_findings);
    report_unknown(r, g, p, {"layers", "distances"},
                   {"origin", "voxel_size", "dims", "index_order", "distance_band", "margin", "shell_thickness"}, true);
    return;
  }
  read_bricks(r, g, p, vm);
  vm.estimates = version.minor >= 2 ? Voxelmap::Estimates::Settled : Voxelmap::Estimates::Interpolated;
  report_unknown(r, g, p, {"bricks", "brick_values", "lattice"},
                 {"origin", "voxel_size", "dims", "index_order", "distance_band", "margin", "shell_thickness",
                  "brick_edge", "distance_quantum", "estimate_quantum", "lattice_error"},
                 true);
}

void read_point_shell(h5::Reader& r, hid_t g, PointShell& ps) {
  const std::string p = "/pointshell";
  std::vector<uint64_t> shape;
  auto points = r.dataset<double>(g, p, "points", {-1, 3}, &shape);
  if (r.has_attribute(g, "point_spacing"))
    if (auto v = r.numeric_attribute<double>(g, p, "point_spacing", {})) ps.point_spacing = (*v)[0];
  if (r.has_attribute(g, "branching"))
    if (auto v = r.numeric_attribute<double>(g, p, "branching", {})) ps.branching = (*v)[0];
  if (auto v = r.dataset<uint32_t>(g, p, "level_offsets", {-1})) ps.level_offsets = std::move(*v);
  if (!points) return;
  const int64_t n = int64_t(shape[0]);
  ps.points = to_rows<double, 3>(*points);
  if (auto v = r.dataset<float>(g, p, "normals", {n, 3})) ps.normals = to_rows<float, 3>(*v);
  if (auto v = r.dataset<double>(g, p, "sphere_centers", {n, 3})) ps.sphere_centers = to_rows<double, 3>(*v);
  if (auto v = r.dataset<double>(g, p, "sphere_radii", {n})) ps.sphere_radii = std::move(*v);
  if (auto v = r.dataset<uint32_t>(g, p, "child_begin", {n})) ps.child_begin = std::move(*v);
  if (auto v = r.dataset<uint32_t>(g, p, "child_count", {n})) ps.child_count = std::move(*v);
  report_unknown(r, g, p,
                 {"points", "normals", "sphere_centers", "sphere_radii", "child_begin", "child_count", "level_offsets"},
                 {"point_spacing", "branching"}, true);
}

void read_mass(h5::Reader& r, hid_t g, MassProperties& m) {
  const std::string p = "/mass_properties";
  if (auto v = r.numeric_attribute<double>(g, p, "volume", {})) m.volume = (*v)[0];
  if (auto v = r.numeric_attribute<double>(g, p, "center_of_mass", {3})) m.center_of_mass = to_vec3(*v);
  if (auto v = r.numeric_attribute<double>(g, p, "inertia", {3, 3})) std::copy(v->begin(), v->end(), m.inertia.begin());
  report_unknown(r, g, p, {}, {"volume", "center_of_mass", "inertia"}, true);
}

void read_provenance(h5::Reader& r, hid_t g, Provenance& prov) {
  const std::string p = "/provenance";
  if (auto v = r.string_attribute(g, p, "generator")) prov.generator = *v;
  if (auto v = r.string_attribute(g, p, "generator_version")) prov.generator_version = *v;
  if (auto v = r.string_attribute(g, p, "source_file")) prov.source_file = *v;
  if (auto v = r.string_attribute(g, p, "source_sha256")) prov.source_sha256 = *v;
  if (auto v = r.string_attribute(g, p, "build_parameters")) prov.build_parameters_json = *v;
  if (r.has_attribute(g, "created_utc"))
    if (auto v = r.string_attribute(g, p, "created_utc")) prov.created_utc = *v;
  if (auto v = r.string_attribute(g, p, "dependency_versions")) {
    const nlohmann::json j = nlohmann::json::parse(*v, nullptr, false);
    bool ok = j.is_object();
    if (ok)
      for (const auto& [name, version] : j.items()) {
        if (!version.is_string()) {
          ok = false;
          break;
        }
        prov.dependency_versions[name] = version.get<std::string>();
      }
    if (!ok) r.report(IssueCode::InvalidJson, p + "/@dependency_versions", "is not a JSON object of strings");
  }
  if (auto v = r.string_attribute(g, p, "build_warnings")) {
    const nlohmann::json j = nlohmann::json::parse(*v, nullptr, false);
    bool ok = j.is_array();
    if (ok)
      for (const auto& w : j) {
        if (!w.is_object() || !w.contains("code") || !w.contains("message") || !w["code"].is_string() ||
            !w["message"].is_string()) {
          ok = false;
          break;
        }
        prov.build_warnings.push_back({w["code"].get<std::string>(), w["message"].get<std::string>()});
      }
    if (!ok) r.report(IssueCode::InvalidJson, p + "/@build_warnings", "is not a JSON array of {code, message} objects");
  }
  report_unknown(r, g, p, {},
                 {"generator", "generator_version", "source_file", "source_sha256", "build_parameters",
                  "dependency_versions", "build_warnings", "created_utc"},
                 true);
}

// Checks the root's format name and major version (spec §7); false when the file must not be read further.
bool check_header(h5::Reader& r, FormatVersion& version) {
  const hid_t root = r.file();
  auto format = r.string_attribute(root, "/", "format");
  if (!format) return false;
  if (*format != "voxfmt") {
    r.report(IssueCode::FormatNameMismatch, "/@format", "format is '" + *format + "', expected 'voxfmt'");
    return false;
  }
  auto numbers = r.numeric_attribute<uint32_t>(root, "/", "format_version", {2});
  if (!numbers) return false;
  version = {(*numbers)[0], (*numbers)[1]};
  if (version.major != kFormatVersion.major && version.major != 1) {
    r.report(IssueCode::VersionUnsupported, "/@format_version",
             "format version " + std::to_string(version.major) + "." + std::to_string(version.minor) +
                 " is not supported (this reader knows 1.x and " + std::to_string(kFormatVersion.major) + ".x)");
    return false;
  }
  if (version.major == 1 && version.minor > 1) {
    r.report(IssueCode::VersionNewerMinor, "/@format_version",
             "format version 1." + std::to_string(version.minor) +
                 " is newer than the last 1.x this reader knows (1.1); objects it does not know are ignored");
    return true;
  }
  if (version.major == kFormatVersion.major && version.minor > kFormatVersion.minor)
    r.report(IssueCode::VersionNewerMinor, "/@format_version",
             "format version " + std::to_string(version.major) + "." + std::to_string(version.minor) +
                 " is newer than this reader's " + std::to_string(kFormatVersion.major) + "." +
                 std::to_string(kFormatVersion.minor) + "; objects it does not know are ignored");
  return true;
}

}  // namespace

bool closed_surface(const Provenance& p) {
  for (const BuildWarning& w : p.build_warnings)
    if (w.code == "OPEN_BORDER" || w.code == "NON_MANIFOLD" || w.code == "SELF_INTERSECTIONS") return false;
  return true;
}

namespace {

bool no_errors_since(const std::vector<Issue>& issues, size_t first) {
  for (size_t i = first; i < issues.size(); ++i)
    if (issues[i].severity == Severity::Error) return false;
  return true;
}

}  // namespace

std::optional<Asset> load_asset_in_process(const std::string& path, std::vector<Issue>& issues,
                                           const ReadOptions& options) {
  const size_t first = issues.size();
  h5::Reader r(path, issues);
  r.set_progress(report_read_progress);
  if (!r.open()) return std::nullopt;
  const hid_t root = r.file();
  Asset asset;
  if (!check_header(r, asset.version) || !r.stays_in_file()) return std::nullopt;
  std::error_code size_error;
  const uint64_t file_bytes = std::filesystem::file_size(path, size_error);
  const std::optional<DenseReadBudget> budget = check_read_cost(r, asset.version, size_error ? 0 : file_bytes, options);
  if (!budget) return std::nullopt;
  const ValidationLevel level = options.level;

  check_vocabulary(r, r.string_attribute(root, "/", "units"), "/@units", {"m"});
  check_vocabulary(r, r.string_attribute(root, "/", "frame"), "/@frame", {"right-handed"});
  if (auto v = r.string_attribute(root, "/", "up_axis")) asset.up_axis = *v;
  if (auto v = r.numeric_attribute<double>(root, "/", "bounds_min", {3})) asset.bounds_min = to_vec3(*v);
  if (auto v = r.numeric_attribute<double>(root, "/", "bounds_max", {3})) asset.bounds_max = to_vec3(*v);
  // Provenance first: its warnings say whether a 1.x grid's neighbour rules apply while it is converted.
  if (auto g = r.group(root, "/", "provenance")) read_provenance(r, g->get(), asset.provenance);
  // A 1.x grid's per-voxel rules are checked as it is converted; they are value rules (validate_asset's kind), so
  // they join the findings after the structural verdict below.
  std::vector<Issue> value_findings;
  if (auto g = r.group(root, "/", "voxelmap"))
    read_voxelmap(r, g->get(), asset.version, level, closed_surface(asset.provenance), *budget, asset.voxelmap,
                  value_findings);
  if (auto g = r.group(root, "/", "pointshell")) read_point_shell(r, g->get(), asset.point_shell);
  if (auto g = r.group(root, "/", "mass_properties")) read_mass(r, g->get(), asset.mass);
  report_unknown(r, root, "/", {"voxelmap", "pointshell", "mass_properties", "provenance"},
                 {"format", "format_version", "units", "frame", "up_axis", "bounds_min", "bounds_max"}, true);

  if (!no_errors_since(issues, first)) return std::nullopt;
  issues.insert(issues.end(), value_findings.begin(), value_findings.end());
  return asset;
}

std::optional<Provenance> load_provenance_in_process(const std::string& path, std::vector<Issue>& issues) {
  const size_t first = issues.size();
  h5::Reader r(path, issues);
  r.set_progress(report_read_progress);
  if (!r.open()) return std::nullopt;
  FormatVersion version;
  if (!check_header(r, version) || !r.stays_in_file()) return std::nullopt;
  Provenance provenance;
  if (auto g = r.group(r.file(), "/", "provenance")) read_provenance(r, g->get(), provenance);
  if (!no_errors_since(issues, first)) return std::nullopt;
  return provenance;
}

}  // namespace detail

Result<Asset> read_asset(const std::string& path, std::vector<Issue>* warnings, const ReadOptions& options) {
  std::vector<Issue> issues;
  std::optional<Asset> asset = detail::read_and_check(path, options, issues);
  for (const Issue& issue : issues)
    if (issue.severity == Severity::Error)
      return Error{issue.code, path + ": " + issue.path + ": " + issue.message, path, issue.path};
  if (warnings)
    for (const Issue& issue : issues)
      if (issue.severity == Severity::Warning) warnings->push_back(issue);
  return std::move(*asset);
}

Result<Provenance> read_provenance(const std::string& path) {
  std::vector<Issue> issues;
  try {
    std::optional<Provenance> provenance = detail::load_provenance(path, issues);
    for (const Issue& issue : issues)
      if (issue.severity == Severity::Error)
        return Error{issue.code, path + ": " + issue.path + ": " + issue.message, path, issue.path};
    return std::move(*provenance);
  } catch (const std::bad_alloc&) {
    return Error{IssueCode::OutOfMemory, path + ": not enough memory to read the provenance", path};
  }
}

}  // namespace voxfmt
