#include "voxfmt/validate.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <new>
#include <optional>
#include <sstream>

#include "load.h"

namespace voxfmt {

namespace {

class Checker {
 public:
  explicit Checker(std::vector<Issue>& issues) : issues_(issues) {}
  void add(IssueCode code, const std::string& path, const std::string& message) {
    issues_.push_back(Issue{code, severity_of(code), path, message});
  }
  template <class Range>
  void finite(const Range& values, const std::string& path) {
    size_t index = 0;
    for (const auto& v : values) {
      if (!std::isfinite(double(v))) {
        add(IssueCode::NonFiniteValue, path, "element " + std::to_string(index) + " is not finite");
        return;
      }
      ++index;
    }
  }
  void finite3(const std::vector<Vec3>& values, const std::string& path) {
    for (size_t n = 0; n < values.size(); ++n)
      for (double v : values[n])
        if (!std::isfinite(v)) {
          add(IssueCode::NonFiniteValue, path, "row " + std::to_string(n) + " is not finite");
          return;
        }
  }

 private:
  std::vector<Issue>& issues_;
};

// Bounds of what a valid file may claim (spec §3; voxel sizes in asset.h): beyond them the numbers mean nothing
// physical and overflow the checks that use them.
constexpr double kMaxDistanceBand = 32767;

std::string fmt(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

void check_voxelmap(const Voxelmap& vm, Checker& c) {
  const std::string g = "/voxelmap";
  c.finite(vm.origin, g + "/@origin");
  if (!std::isfinite(vm.voxel_size))
    c.add(IssueCode::NonFiniteValue, g + "/@voxel_size", "voxel size is not finite");
  else if (!(vm.voxel_size >= kMinVoxelSize && vm.voxel_size <= kMaxVoxelSize))
    c.add(IssueCode::ValueOutOfRange, g + "/@voxel_size",
          "voxel size " + fmt(vm.voxel_size) + " m is outside the format's range [" + fmt(kMinVoxelSize) + ", " +
              fmt(kMaxVoxelSize) + "] m");
  if (!std::isfinite(vm.distance_band))
    c.add(IssueCode::NonFiniteValue, g + "/@distance_band", "distance band is not finite");
  else if (!(vm.distance_band >= 1 && vm.distance_band <= kMaxDistanceBand))
    c.add(IssueCode::ValueOutOfRange, g + "/@distance_band",
          "distance band " + fmt(vm.distance_band) + " voxels is outside [1, " + fmt(kMaxDistanceBand) +
              "] (layers are 16-bit)");
  uint64_t count = 1;
  for (uint32_t d : vm.dims) count *= d;
  if (vm.dims[0] == 0 || vm.dims[1] == 0 || vm.dims[2] == 0 || count > 0x7fffffffull) {
    c.add(IssueCode::ValueOutOfRange, g + "/@dims", "dims must be >= 1 each with at most 2^31-1 voxels in all");
    return;
  }
  if (vm.layers.size() != count)
    c.add(IssueCode::WrongShape, g + "/layers",
          "holds " + std::to_string(vm.layers.size()) + " voxels, dims say " + std::to_string(count));
  if (vm.distances.size() != count)
    c.add(IssueCode::WrongShape, g + "/distances",
          "holds " + std::to_string(vm.distances.size()) + " voxels, dims say " + std::to_string(count));
  for (size_t v = 0; v < vm.distances.size(); ++v)
    if (std::isinf(vm.distances[v])) {
      c.add(IssueCode::NonFiniteValue, g + "/distances",
            "voxel " + std::to_string(v) + " holds an infinite distance (use NaN for 'not stored')");
      break;
    }
}

void check_tree(const PointShell& ps, Checker& c) {
  const std::string g = "/pointshell";
  const size_t n = ps.points.size();
  const auto& lo = ps.level_offsets;
  bool offsets_ok = lo.size() >= 2 && lo[0] == 0 && lo[1] == 1 && lo.back() == n;
  for (size_t l = 1; offsets_ok && l < lo.size(); ++l) offsets_ok = lo[l] > lo[l - 1];
  if (!offsets_ok) {
    c.add(IssueCode::LevelOffsetsInvalid, g + "/level_offsets",
          "must start 0, 1, increase strictly and end at N = " + std::to_string(n));
    return;
  }
  // Level by level, the children ranges must tile the next level in node order.
  for (size_t l = 0; l + 1 < lo.size(); ++l) {
    const uint64_t next_begin = lo[l + 1];
    const uint64_t next_end = l + 2 < lo.size() ? lo[l + 2] : next_begin;
    uint64_t expected = next_begin;
    for (uint64_t node = lo[l]; node < lo[l + 1]; ++node) {
      const uint64_t begin = ps.child_begin[node], count = ps.child_count[node];
      if (count == 0) {
        if (begin > n) {
          c.add(IssueCode::ChildRangeInvalid, g + "/child_begin",
                "leaf node " + std::to_string(node) + " has child_begin " + std::to_string(begin) + " > N");
          return;
        }
        continue;
      }
      if (begin < next_begin || begin + count > next_end) {
        c.add(IssueCode::ChildRangeInvalid, g + "/child_begin",
              "node " + std::to_string(node) + " (level " + std::to_string(l) + ") has children [" +
                  std::to_string(begin) + ", " + std::to_string(begin + count) + ") outside the next level [" +
                  std::to_string(next_begin) + ", " + std::to_string(next_end) + ")");
        return;
      }
      if (begin != expected) {
        c.add(IssueCode::TreeNotBreadthFirst, g + "/child_begin",
              "node " + std::to_string(node) + " has first child " + std::to_string(begin) +
                  ", breadth-first order needs " + std::to_string(expected));
        return;
      }
      expected += count;
    }
    if (expected != next_end) {
      c.add(IssueCode::TreeNotBreadthFirst, g + "/child_count",
            "nodes of level " + std::to_string(l) + " have " + std::to_string(expected - next_begin) +
                " children, level " + std::to_string(l + 1) + " has " + std::to_string(next_end - next_begin) +
                " nodes");
      return;
    }
  }
}

void check_point_shell(const PointShell& ps, Checker& c) {
  const std::string g = "/pointshell";
  const size_t n = ps.points.size();
  if (n == 0) {
    c.add(IssueCode::WrongShape, g + "/points", "the point shell has no points");
    return;
  }
  auto same_size = [&](size_t size, const char* name) {
    if (size == n) return true;
    c.add(IssueCode::WrongShape, g + "/" + name,
          "has " + std::to_string(size) + " rows, points has " + std::to_string(n));
    return false;
  };
  bool sizes_ok = same_size(ps.normals.size(), "normals") & same_size(ps.sphere_centers.size(), "sphere_centers") &
                  same_size(ps.sphere_radii.size(), "sphere_radii") & same_size(ps.child_begin.size(), "child_begin") &
                  same_size(ps.child_count.size(), "child_count");
  c.finite3(ps.points, g + "/points");
  c.finite3(ps.sphere_centers, g + "/sphere_centers");
  c.finite(ps.sphere_radii, g + "/sphere_radii");
  for (size_t i = 0; i < ps.sphere_radii.size(); ++i)
    if (ps.sphere_radii[i] < 0) {
      c.add(IssueCode::ValueOutOfRange, g + "/sphere_radii", "radius of node " + std::to_string(i) + " is negative");
      break;
    }
  for (size_t i = 0; i < ps.normals.size(); ++i) {
    const Vec3f& v = ps.normals[i];
    double len = std::sqrt(double(v[0]) * v[0] + double(v[1]) * v[1] + double(v[2]) * v[2]);
    if (!(std::abs(len - 1.0) <= 1e-3)) {
      c.add(IssueCode::NormalNotUnit, g + "/normals", "normal " + std::to_string(i) + " has length " + fmt(len));
      break;
    }
  }
  if (ps.branching && !(std::isfinite(*ps.branching) && *ps.branching >= 2))
    c.add(IssueCode::ValueOutOfRange, g + "/@branching", "branching must be finite and >= 2");
  if (ps.point_spacing && !(std::isfinite(*ps.point_spacing) && *ps.point_spacing >= 0))
    c.add(IssueCode::ValueOutOfRange, g + "/@point_spacing", "point spacing must be finite and >= 0");
  if (sizes_ok) check_tree(ps, c);
}

void check_mass(const MassProperties& m, Checker& c) {
  const std::string g = "/mass_properties";
  if (!std::isfinite(m.volume))
    c.add(IssueCode::NonFiniteValue, g + "/@volume", "volume is not finite");
  else if (m.volume <= 0)
    c.add(IssueCode::ValueOutOfRange, g + "/@volume", "volume " + fmt(m.volume) + " is not > 0");
  c.finite(m.center_of_mass, g + "/@center_of_mass");
  c.finite(m.inertia, g + "/@inertia");
  double scale = 0;
  for (double v : m.inertia) scale = std::max(scale, std::abs(v));
  for (int r = 0; r < 3; ++r)
    for (int col = r + 1; col < 3; ++col)
      if (std::abs(m.inertia[r * 3 + col] - m.inertia[col * 3 + r]) > 1e-9 * scale) {
        c.add(IssueCode::ValueOutOfRange, g + "/@inertia", "inertia tensor is not symmetric");
        return;
      }
}

void check_provenance(const Provenance& p, Checker& c) {
  const std::string g = "/provenance";
  const nlohmann::json params = nlohmann::json::parse(p.build_parameters_json, nullptr, false);
  if (params.is_discarded() || !params.is_object())
    c.add(IssueCode::InvalidJson, g + "/@build_parameters", "build_parameters is not a JSON object");
  bool sha_ok = p.source_sha256.empty() || p.source_sha256.size() == 64;
  for (char ch : p.source_sha256) sha_ok = sha_ok && ((ch >= '0' && ch <= '9') || (ch >= 'a' && ch <= 'f'));
  if (!sha_ok)
    c.add(IssueCode::BadSha256, g + "/@source_sha256", "'" + p.source_sha256 + "' is not 64 lowercase hex digits");
}

// ---- full level: semantic rules (spec §3-§5)

bool has_surface_defects(const Provenance& p) {
  for (const BuildWarning& w : p.build_warnings)
    if (w.code == "OPEN_BORDER" || w.code == "NON_MANIFOLD" || w.code == "SELF_INTERSECTIONS") return true;
  return false;
}

std::string voxel_name(const Voxelmap& vm, size_t v) {
  const size_t i = v % vm.dims[0], j = v / vm.dims[0] % vm.dims[1], k = v / (size_t(vm.dims[0]) * vm.dims[1]);
  return "voxel (" + std::to_string(i) + ", " + std::to_string(j) + ", " + std::to_string(k) + ")";
}

void check_voxelmap_semantics(const Voxelmap& vm, bool closed_surface, Checker& c) {
  const std::string g = "/voxelmap";
  const double h = vm.voxel_size;
  const int min_outside = int(std::floor(vm.distance_band + 0.5));
  bool layer_reported = false, band_reported = false, step_reported = false, jump_reported = false;
  const size_t W = vm.dims[0], WH = size_t(vm.dims[0]) * vm.dims[1];
  for (size_t v = 0; v < vm.voxel_count(); ++v) {
    const float d = vm.distances[v];
    const int layer = vm.layers[v];
    if (Voxelmap::is_stored(d)) {
      const double expected = std::clamp(std::floor(-double(d) / h + 0.5), -32767.0, 32767.0);
      if (!layer_reported && layer != int(expected)) {
        c.add(IssueCode::LayerDistanceMismatch, g + "/layers",
              voxel_name(vm, v) + " has layer " + std::to_string(layer) + " but its distance " + fmt(d) + " m gives " +
                  std::to_string(int(expected)));
        layer_reported = true;
      }
    } else if (!band_reported && std::abs(layer) < min_outside) {
      c.add(IssueCode::LayerOutsideBandTooSmall, g + "/layers",
            voxel_name(vm, v) + " has no stored distance but layer " + std::to_string(layer) +
                " (|layer| must be >= " + std::to_string(min_outside) + " outside the band)");
      band_reported = true;
    }
    if (!closed_surface) continue;  // across a closed hole both rules may break (spec §3)
    const size_t i = v % W, j = v / W % vm.dims[1], k = v / WH;
    const size_t neighbours[3] = {i + 1 < W ? v + 1 : v, j + 1 < vm.dims[1] ? v + W : v,
                                  k + 1 < vm.dims[2] ? v + WH : v};
    for (size_t n : neighbours) {
      if (n == v) continue;
      if (!step_reported && std::abs(layer - vm.layers[n]) > 1) {
        c.add(IssueCode::LayerStepTooLarge, g + "/layers",
              voxel_name(vm, v) + " and " + voxel_name(vm, n) + " differ by " +
                  std::to_string(std::abs(layer - vm.layers[n])) + " layers");
        step_reported = true;
      }
      // Exact distances of 6-neighbours differ by at most h; the rule allows the voxel diagonal, so that a
      // producer's near-band approximations pass and only gross errors (wrong sign, garbage) are flagged.
      if (!jump_reported && Voxelmap::is_stored(d) && Voxelmap::is_stored(vm.distances[n]) &&
          std::abs(double(d) - double(vm.distances[n])) > h * std::sqrt(3.0)) {
        c.add(IssueCode::DistanceJump, g + "/distances",
              voxel_name(vm, v) + " and " + voxel_name(vm, n) +
                  " are one voxel apart but their distances differ by more than the voxel diagonal: " +
                  fmt(std::abs(double(d) - double(vm.distances[n])) / h) + " voxels");
        jump_reported = true;
      }
    }
  }
}

// Distance at the voxel nearest to p, if stored there.
std::optional<double> nearest_distance(const Voxelmap& vm, const Vec3& p) {
  size_t index[3];
  for (int a = 0; a < 3; ++a) {
    const double x = std::floor((p[a] - vm.origin[a]) / vm.voxel_size + 0.5);
    if (!(x >= 0 && x < vm.dims[a])) return std::nullopt;
    index[a] = size_t(x);
  }
  const float d = vm.distances[(index[2] * vm.dims[1] + index[1]) * vm.dims[0] + index[0]];
  if (!Voxelmap::is_stored(d)) return std::nullopt;
  return double(d);
}

void check_point_shell_semantics(const Asset& a, Checker& c) {
  const PointShell& ps = a.point_shell;
  const Voxelmap& vm = a.voxelmap;
  // Inward: one voxel along the normal the distance is lower than one voxel against it. Thin features and
  // sharp edges can fool a nearest-voxel lookup, so only a clear majority of outward normals is reported.
  size_t tested = 0, outward = 0;
  for (size_t n = 0; n < ps.size(); ++n) {
    const Vec3& p = ps.points[n];
    const Vec3f& nn = ps.normals[n];
    const double h = vm.voxel_size;
    const auto in = nearest_distance(vm, {p[0] + h * nn[0], p[1] + h * nn[1], p[2] + h * nn[2]});
    const auto out = nearest_distance(vm, {p[0] - h * nn[0], p[1] - h * nn[1], p[2] - h * nn[2]});
    if (!in || !out) continue;
    ++tested;
    outward += *in > *out;
  }
  if (tested > 0 && outward * 10 > tested)
    c.add(IssueCode::NormalNotInward, "/pointshell/normals",
          std::to_string(outward) + " of " + std::to_string(tested) + " normals point out of the voxelmap's inside");
  // Spec §4: every node's sphere encloses its own point and the points of all its descendants. Each point is
  // checked against the spheres of all its ancestors (N x depth work).
  std::vector<uint32_t> parent(ps.size(), UINT32_MAX);
  for (uint32_t n = 0; n < ps.size(); ++n)
    for (uint32_t ch = ps.child_begin[n]; ch < ps.child_begin[n] + ps.child_count[n]; ++ch) parent[ch] = n;
  for (uint32_t p = 0; p < ps.size(); ++p)
    for (uint32_t node = p; node != UINT32_MAX; node = parent[node]) {
      const Vec3 &centre = ps.sphere_centers[node], &q = ps.points[p];
      const double dx = q[0] - centre[0], dy = q[1] - centre[1], dz = q[2] - centre[2];
      if (std::sqrt(dx * dx + dy * dy + dz * dz) > ps.sphere_radii[node] * (1 + 1e-9) + 1e-12) {
        c.add(IssueCode::SphereNotEnclosing, "/pointshell/sphere_radii",
              "the sphere of node " + std::to_string(node) + " does not enclose point " + std::to_string(p) +
                  " of its subtree");
        return;
      }
    }
}

void check_mass_semantics(const Asset& a, Checker& c) {
  const auto& I = a.mass.inertia;
  const double m1 = I[0], m2 = I[0] * I[4] - I[1] * I[3],
               m3 = I[0] * (I[4] * I[8] - I[5] * I[7]) - I[1] * (I[3] * I[8] - I[5] * I[6]) +
                    I[2] * (I[3] * I[7] - I[4] * I[6]);
  if (!(m1 > 0 && m2 > 0 && m3 > 0))
    c.add(IssueCode::InertiaNotPositiveDefinite, "/mass_properties/@inertia",
          "the inertia tensor is not positive definite");
  for (int axis = 0; axis < 3; ++axis)
    if (!(a.mass.center_of_mass[axis] >= a.bounds_min[axis] && a.mass.center_of_mass[axis] <= a.bounds_max[axis])) {
      c.add(IssueCode::CenterOfMassOutsideBounds, "/mass_properties/@center_of_mass",
            "the centre of mass lies outside the bounds on axis " + std::to_string(axis));
      break;
    }
}

}  // namespace

std::vector<Issue> validate_asset(const Asset& asset, ValidationLevel level) {
  std::vector<Issue> issues;
  Checker c(issues);
  c.finite(asset.bounds_min, "/@bounds_min");
  c.finite(asset.bounds_max, "/@bounds_max");
  for (int a = 0; a < 3; ++a)
    if (asset.bounds_min[a] > asset.bounds_max[a]) {
      c.add(IssueCode::ValueOutOfRange, "/@bounds_max", "bounds_max is below bounds_min on axis " + std::to_string(a));
      break;
    }
  static const char* kAxes[] = {"+X", "-X", "+Y", "-Y", "+Z", "-Z"};
  bool axis_ok = false;
  for (const char* a : kAxes) axis_ok = axis_ok || asset.up_axis == a;
  if (!axis_ok)
    c.add(IssueCode::BadAttributeValue, "/@up_axis", "up_axis '" + asset.up_axis + "' is not one of +X -X +Y -Y +Z -Z");
  check_voxelmap(asset.voxelmap, c);
  check_point_shell(asset.point_shell, c);
  check_mass(asset.mass, c);
  check_provenance(asset.provenance, c);
  // Semantic rules need a structurally sound asset (sizes, tree ranges) to index safely.
  if (level == ValidationLevel::Full && !has_errors(issues)) {
    check_voxelmap_semantics(asset.voxelmap, !has_surface_defects(asset.provenance), c);
    check_point_shell_semantics(asset, c);
    check_mass_semantics(asset, c);
  }
  return issues;
}

std::vector<Issue> validate_file(const std::string& path, ValidationLevel level) {
  std::vector<Issue> issues;
  try {
    std::optional<Asset> asset = detail::load_asset(path, issues);
    if (asset) {
      std::vector<Issue> more = validate_asset(*asset, level);
      issues.insert(issues.end(), more.begin(), more.end());
    }
  } catch (const std::bad_alloc&) {
    issues.push_back(Issue{IssueCode::ReadFailed, Severity::Error, "/", "not enough memory to read the asset"});
  }
  return issues;
}

}  // namespace voxfmt
