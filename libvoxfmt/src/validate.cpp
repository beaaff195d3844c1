#include "voxfmt/io.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <memory>
#include <new>
#include <optional>
#include <sstream>

#include "load.h"
#include "voxfmt/detail/cores.h"
#include "voxfmt/detail/estimate_transform.h"
#include "voxfmt/detail/utf8.h"

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

/// The voxelmap's scalar attributes; false where its dims leave nothing else to check.
bool check_voxelmap_attributes(const Voxelmap& vm, const FormatVersion& version, Checker& c) {
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
          "distance band " + fmt(vm.distance_band) + " voxels is outside [1, " + fmt(kMaxDistanceBand) + "]");
  // Thicker, and a shell's lattice values would pass what a runtime's single-precision voxel units hold (spec §3.2).
  if (vm.shell_thickness && std::isfinite(*vm.shell_thickness) && std::isfinite(vm.voxel_size) &&
      *vm.shell_thickness > kMaxDistanceBand * vm.voxel_size)
    c.add(IssueCode::ValueOutOfRange, g + "/@shell_thickness",
          "shell thickness " + fmt(*vm.shell_thickness) + " m is more than " + fmt(kMaxDistanceBand) + " voxels");
  if (!detail::grid_size_allowed(vm.dims, version)) {
    c.add(IssueCode::ValueOutOfRange, g + "/@dims", "dims must be >= 1 each with " + detail::grid_size_limit(version));
    return false;
  }
  return true;
}

/// 2.x: the quanta must let every band distance and every estimate near the band be coded in 15 bits; the
/// lattice's stated error.
void check_quanta(const Voxelmap& vm, Checker& c) {
  const std::string g = "/voxelmap";
  const double band_m = vm.distance_band * vm.voxel_size;
  auto quantum = [&](double q, const char* name) {
    const std::string path = g + "/@" + name;
    if (!std::isfinite(q))
      c.add(IssueCode::NonFiniteValue, path, std::string(name) + " is not finite");
    else if (!(q > 0) || q * Voxelmap::kMaxSteps < band_m * (1 - 1e-9))
      c.add(IssueCode::ValueOutOfRange, path,
            std::string(name) + " " + fmt(q) + " m must be > 0 and code the band's " + fmt(band_m) + " m in " +
                std::to_string(Voxelmap::kMaxSteps) + " steps");
  };
  quantum(vm.distance_quantum, "distance_quantum");
  quantum(vm.estimate_quantum, "estimate_quantum");
  if (!std::isfinite(vm.lattice_error[0]) || !std::isfinite(vm.lattice_error[1]))
    c.add(IssueCode::NonFiniteValue, g + "/@lattice_error", "lattice error is not finite");
  else if (!(vm.lattice_error[0] >= 0 && vm.lattice_error[0] <= kMaxDistanceBand && vm.lattice_error[1] >= 0 &&
             vm.lattice_error[1] <= 1))
    c.add(IssueCode::ValueOutOfRange, g + "/@lattice_error",
          "lattice error must have [0] in [0, " + fmt(kMaxDistanceBand) +
              "] voxels (more lifts the lattice's ceiling past what a runtime holds) and [1] in [0, 1] (a fraction "
              "of the distance)");
}

/// The arrays' shapes, the brick table's entries and its rows of brick_values; false where what it found leaves
/// nothing else to check.
bool check_brick_table(const Voxelmap& vm, Checker& c) {
  const std::string g = "/voxelmap";
  if (vm.bricks.size() != vm.brick_count()) {
    c.add(IssueCode::WrongShape, g + "/bricks",
          "holds " + std::to_string(vm.bricks.size()) + " bricks, dims say " + std::to_string(vm.brick_count()));
    return false;
  }
  if (vm.brick_values.size() % Voxelmap::kBrickVoxels != 0) {
    c.add(IssueCode::WrongShape, g + "/brick_values", "is not [n, 512]");
    return false;
  }
  if (vm.lattice.size() != vm.lattice_count()) {
    c.add(IssueCode::WrongShape, g + "/lattice",
          "holds " + std::to_string(vm.lattice.size()) + " points, dims say " + std::to_string(vm.lattice_count()));
    return false;
  }
  const int64_t value_bricks = int64_t(vm.value_brick_count());
  for (size_t b = 0; b < vm.bricks.size(); ++b) {
    const int32_t entry = vm.bricks[b];
    if (entry == Voxelmap::kCoarseOutside || entry == Voxelmap::kCoarseInside || (entry >= 0 && entry < value_bricks))
      continue;
    c.add(IssueCode::ValueOutOfRange, g + "/bricks",
          "brick " + std::to_string(b) + " holds " + std::to_string(entry) + ": neither a value brick below " +
              std::to_string(value_bricks) + " nor -1 (coarse, outside) or -2 (coarse, inside)");
    return false;
  }
  // Each row of brick_values is one brick's (spec §3.2): a row's estimates belong to its brick's place.
  std::vector<uint8_t> uses(size_t(value_bricks), 0);
  for (size_t b = 0; b < vm.bricks.size(); ++b) {
    const int32_t entry = vm.bricks[b];
    if (entry < 0) continue;
    if (uses[size_t(entry)]++ == 0) continue;
    c.add(IssueCode::ValueOutOfRange, g + "/bricks",
          "bricks share row " + std::to_string(entry) + " of brick_values (each row is one brick's)");
    return false;
  }
  const auto unused = std::find(uses.begin(), uses.end(), uint8_t(0));
  if (unused != uses.end())
    c.add(IssueCode::ValueOutOfRange, g + "/brick_values",
          "row " + std::to_string(unused - uses.begin()) + " belongs to no brick (each row is one brick's)");
  return true;
}

/// No lattice value beyond the grid's diagonal with the lattice's error.
void check_lattice_ceiling(const Voxelmap& vm, Checker& c) {
  const std::string g = "/voxelmap";
  // No voxel is farther from the surface than the grid's diagonal (the surface lies inside the grid), so no
  // lattice value may exceed (1 + e1) times it plus e0 (spec §3.3); a huge one would overflow a runtime's sums.
  const double h = vm.voxel_size;
  const double diagonal =
      h * std::sqrt(double(vm.dims[0] - 1) * (vm.dims[0] - 1) + double(vm.dims[1] - 1) * (vm.dims[1] - 1) +
                    double(vm.dims[2] - 1) * (vm.dims[2] - 1));
  const double ceiling =
      (1 + vm.lattice_error[1]) * (diagonal + vm.shell_thickness.value_or(0.0)) + (vm.lattice_error[0] + 1) * h;
  for (size_t n = 0; n < vm.lattice.size(); ++n) {
    const float v = vm.lattice[n];
    if (std::isfinite(v) && v >= 0 && !(double(v) > ceiling)) continue;
    c.add(std::isfinite(v) ? IssueCode::ValueOutOfRange : IssueCode::NonFiniteValue, g + "/lattice",
          "lattice point " + std::to_string(n) + " holds " + fmt(v) + " m (a distance must be finite, >= 0 and at " +
              "most " + fmt(ceiling) + " m, the grid's diagonal with the lattice's error)");
    break;
  }
}

void check_voxelmap(const Voxelmap& vm, const FormatVersion& version, Checker& c) {
  if (!check_voxelmap_attributes(vm, version, c)) return;
  // A 1.x file's bricks are this library's conversion (spec §3.4): its quanta and lattice errors are not the
  // file's, and a conversion its other errors stopped leaves none to check.
  if (version.major == 1 && vm.bricks.empty()) return;
  if (version.major != 1) check_quanta(vm, c);
  if (!check_brick_table(vm, c)) return;
  check_lattice_ceiling(vm, c);
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

// Spec §4: no spacing consumers would pad a shape's box with beyond the object's scale (1e300 m validated).
void check_point_spacing_scale(const Asset& a, Checker& c) {
  if (!a.point_shell.point_spacing) return;
  const double limit = max_point_spacing(a.bounds_min, a.bounds_max, a.voxelmap.voxel_size);
  if (*a.point_shell.point_spacing <= limit) return;
  c.add(IssueCode::ValueOutOfRange, "/pointshell/@point_spacing",
        "point spacing " + fmt(*a.point_shell.point_spacing) + " m is more than 16 times the object's diagonal (" +
            fmt(limit) + " m, the limit)");
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

// Spec §1: every stored string is UTF-8. A reader checks the file's bytes; this checks what a writer was given (a
// file name from the file system may hold any bytes).
void check_text(const std::string& text, const std::string& where, Checker& c) {
  if (!is_utf8(text)) c.add(IssueCode::StringNotUtf8, where, not_utf8_message(text));
}

void check_provenance(const Provenance& p, Checker& c) {
  const std::string g = "/provenance";
  for (const auto& [name, text] : {std::pair{"generator", &p.generator},
                                   {"generator_version", &p.generator_version},
                                   {"source_file", &p.source_file},
                                   {"build_parameters", &p.build_parameters_json},
                                   {"created_utc", &p.created_utc}})
    check_text(*text, g + "/@" + name, c);
  for (const auto& [library, version] : p.dependency_versions) {
    check_text(library, g + "/dependency_versions", c);
    check_text(version, g + "/dependency_versions/@" + utf8_escaped(library), c);
  }
  for (const BuildWarning& w : p.build_warnings) {
    check_text(w.code, g + "/build_warnings", c);
    check_text(w.message, g + "/build_warnings", c);
  }
  const nlohmann::json params = nlohmann::json::parse(p.build_parameters_json, nullptr, false);
  if (params.is_discarded() || !params.is_object())
    c.add(IssueCode::InvalidJson, g + "/@build_parameters", "build_parameters is not a JSON object");
  bool sha_ok = p.source_sha256.empty() || p.source_sha256.size() == 64;
  for (char ch : p.source_sha256) sha_ok = sha_ok && ((ch >= '0' && ch <= '9') || (ch >= 'a' && ch <= 'f'));
  if (!sha_ok)
    c.add(IssueCode::BadSha256, g + "/@source_sha256", "'" + p.source_sha256 + "' is not 64 lowercase hex digits");
}

// ---- full level: semantic rules (spec §3-§5)

std::string voxel_name(uint64_t i, uint64_t j, uint64_t k) {
  return "voxel (" + std::to_string(i) + ", " + std::to_string(j) + ", " + std::to_string(k) + ")";
}

// Spec §3 for format 2.x, checked brick by brick: stored distances within the band, estimates by the file's rule
// (settled, or the lattice interpolated), and no voxel on the wrong side: two 6-neighbours of opposite sign must be
// near enough to the surface for it to pass between them (|d1| + |d2| <= h, a voxel without a stored distance being at
// least (band - 1/2) h from it), and stored neighbours no more than the voxel diagonal apart. Value bricks are shared
// among threads; each reports its own first findings, merged in brick order.
class VoxelmapRules {
 public:
  VoxelmapRules(const Voxelmap& vm, bool closed_surface)
      : vm_(vm),
        closed_(closed_surface),
        h_(vm.voxel_size),
        inverse_h_(1.0 / vm.voxel_size),
        band_m_(vm.distance_band * vm.voxel_size),
        edge_m_((vm.distance_band - 0.5) * vm.voxel_size),
        sign_limit_(vm.voxel_size * (1 + 1e-6) + vm.distance_quantum),
        jump_limit_(vm.voxel_size * std::sqrt(3.0)) {
    if (vm.estimates == Voxelmap::Estimates::Settled)
      settled_ = std::make_unique<detail::EstimateTransform>(vm, vm.brick_values);
  }

  // Checks the value bricks among `bricks` (table indices) in order, appending findings to `issues`.
  // With `progress`: counted 64 bricks at a time, and stopped when asked.
  void check(const std::vector<size_t>& bricks, size_t begin, size_t end, std::vector<Issue>& issues,
             detail::CheckProgress* progress) {
    Findings f{issues};
    const auto bd = vm_.brick_dims();
    for (size_t n = begin; n < end && !f.all(); ++n) {
      const size_t b = bricks[n];
      brick(uint32_t(b % bd[0]), uint32_t(b / bd[0] % bd[1]), uint32_t(b / (size_t(bd[0]) * bd[1])), f);
      if (progress && (n - begin) % 64 == 63) {
        progress->bricks_checked.fetch_add(64, std::memory_order_relaxed);
        if (progress->stop.load(std::memory_order_relaxed)) return;
      }
    }
  }

 private:
  static constexpr uint32_t E = Voxelmap::kBrickEdge;
  struct Near {
    double distance;  // signed: stored, or the estimate
    double nearest;   // lower bound of |d|
    bool stored;
  };
  struct Findings {
    std::vector<Issue>& issues;
    bool outside = false, estimate = false, sign = false, jump = false;
    bool all() const { return outside && estimate && sign && jump; }
    void add(IssueCode code, const std::string& message) {
      issues.push_back(Issue{code, severity_of(code), "/voxelmap/brick_values", message});
    }
  };

  Near near_of(uint32_t i, uint32_t j, uint32_t k) const {
    const int32_t entry = vm_.bricks[vm_.brick_index(i / E, j / E, k / E)];
    if (entry < 0) return Near{entry == Voxelmap::kCoarseInside ? -edge_m_ : edge_m_, edge_m_, false};
    const int16_t code =
        vm_.brick_values[size_t(entry) * Voxelmap::kBrickVoxels + Voxelmap::local_index(i % E, j % E, k % E)];
    const double d = vm_.decode(code);
    return Near{d, Voxelmap::code_is_stored(code) ? std::abs(d) : edge_m_, Voxelmap::code_is_stored(code)};
  }

  bool pair_breaks_a_rule(const Near& a, const Near& b) const {
    return ((a.distance < 0) != (b.distance < 0) && a.nearest + b.nearest > sign_limit_) ||
           (a.stored && b.stored && std::abs(a.distance - b.distance) > jump_limit_);
  }

  void report_pair(const uint32_t (&at)[3], const Near& a, const uint32_t (&other)[3], const Near& b,
                   Findings& f) const {
    const std::string names = voxel_name(at[0], at[1], at[2]) + " and " + voxel_name(other[0], other[1], other[2]);
    if (!f.sign && (a.distance < 0) != (b.distance < 0) && a.nearest + b.nearest > sign_limit_) {
      f.add(IssueCode::SignMismatch, names +
                                         " are one voxel apart and on opposite sides of the surface, but too far "
                                         "from it for the surface to pass between them (" +
                                         fmt(a.distance / h_) + " and " + fmt(b.distance / h_) + " voxels)");
      f.sign = true;
    }
    if (!f.jump && a.stored && b.stored && std::abs(a.distance - b.distance) > jump_limit_) {
      f.add(IssueCode::DistanceJump, names +
                                         " are one voxel apart but their distances differ by more than the voxel "
                                         "diagonal: " +
                                         fmt(std::abs(a.distance - b.distance) / h_) + " voxels");
      f.jump = true;
    }
  }

  /// One brick's voxels as the rules read them: each one's Near, and flat copies in voxels for the branch-free pass
  /// (positions past the grid take part in no pair).
  struct BrickVoxels {
    uint32_t first[3], count[3];
    Near near[Voxelmap::kBrickVoxels];
    float value[Voxelmap::kBrickVoxels], nearest[Voxelmap::kBrickVoxels];
    uint8_t stored[Voxelmap::kBrickVoxels], valid[Voxelmap::kBrickVoxels];
  };

  void brick(uint32_t bi, uint32_t bj, uint32_t bk, Findings& f) const {
    BrickVoxels v;
    read_brick(bi, bj, bk, v, f);
    if (!closed_ || (f.sign && f.jump)) return;  // across a closed hole the sign changes away from the surface
    const bool bad = some_inner_pair_breaks_a_rule(v);
    check_faces(v, f);
    if (bad) search_inner_pairs(v, f);
  }

  /// The brick's voxels into `v`, and the rules of single voxels: stored distances within the band, estimates
  /// those the lattice gives.
  void read_brick(uint32_t bi, uint32_t bj, uint32_t bk, BrickVoxels& v, Findings& f) const {
    const int16_t* codes =
        vm_.brick_values.data() + size_t(vm_.bricks[vm_.brick_index(bi, bj, bk)]) * Voxelmap::kBrickVoxels;
    // Interpolated estimates (2.0, 2.1): those this brick's codes must hold, computed as fill_brick_estimates does
    // (it keeps each code's sign and leaves stored codes alone). Settled ones (2.2) are checked below.
    double expected[Voxelmap::kBrickVoxels];
    if (!settled_) brick_estimate_magnitudes(vm_, bi, bj, bk, expected);
    const uint32_t first[3] = {bi * E, bj * E, bk * E};
    for (int a = 0; a < 3; ++a) {
      v.first[a] = first[a];
      v.count[a] = std::min(E, vm_.dims[size_t(a)] - first[a]);
    }
    for (uint32_t n = 0; n < Voxelmap::kBrickVoxels; ++n) {
      const uint32_t li = n % E, lj = n / E % E, lk = n / (E * E);
      const bool valid = li < v.count[0] && lj < v.count[1] && lk < v.count[2];
      const int16_t code = codes[n];
      const bool is_stored = Voxelmap::code_is_stored(code);
      const double d = vm_.decode(code);
      v.near[n] = Near{d, is_stored ? std::abs(d) : edge_m_, is_stored};
      v.valid[n] = valid;
      v.value[n] = valid ? float(d * inverse_h_) : 1.0f;
      v.nearest[n] = valid ? float(v.near[n].nearest * inverse_h_) : 1e9f;
      v.stored[n] = valid && is_stored;
      if (!valid) continue;
      if (is_stored) {
        if (!f.outside && std::abs(d) > band_m_ + 0.5 * vm_.distance_quantum) {
          f.add(IssueCode::DistanceOutsideBand, voxel_name(first[0] + li, first[1] + lj, first[2] + lk) +
                                                    " stores the distance " + fmt(d) + " m, beyond the band of " +
                                                    fmt(band_m_) + " m");
          f.outside = true;
        }
      } else if (!f.estimate &&
                 (code == 0 || (!settled_ && std::abs(std::abs(d) - expected[n]) >
                                                 0.5 * vm_.estimate_quantum * (1 + 1e-6) + 1e-12 * expected[n]))) {
        // The nearest step (spec §3.2): within half a step of the lattice's value, but for the rounding of the
        // interpolation itself.
        f.add(IssueCode::EstimateMismatch,
              voxel_name(first[0] + li, first[1] + lj, first[2] + lk) + " holds the estimate " + fmt(d) + " m, " +
                  (code == 0 ? std::string("and an estimate is never 0")
                             : "the lattice gives " + fmt(code < 0 ? -expected[n] : expected[n]) + " m"));
        f.estimate = true;
      }
    }
    if (settled_ && !f.estimate)
      if (const size_t unsettled = settled_->count_unsettled(int(bi), int(bj), int(bk))) {
        // The least path lengths are unique (steps are positive), so a settled brick holds exactly the producer's.
        f.add(IssueCode::EstimateMismatch,
              "brick (" + std::to_string(bi) + ", " + std::to_string(bj) + ", " + std::to_string(bk) + ") holds " +
                  std::to_string(unsettled) +
                  " estimates that are not the least of their lattice paths and their neighbours' values plus "
                  "their step (spec §3.1)");
        f.estimate = true;
      }
  }

  /// Pairs inside the brick, one axis at a time, branch-free: the common case finds nothing; the brick is searched
  /// pair by pair (search_inner_pairs) only if some pair breaks a rule.
  bool some_inner_pair_breaks_a_rule(const BrickVoxels& b) const {
    const float sign_limit = float(sign_limit_ / h_), jump_limit = float(jump_limit_ / h_);
    const float *value = b.value, *nearest = b.nearest;
    const uint8_t *stored = b.stored, *valid = b.valid;
    int bad = 0;
    auto pairs_along = [&](uint32_t stride, uint32_t ni, uint32_t nj, uint32_t nk) {
      for (uint32_t lk = 0; lk < nk; ++lk)
        for (uint32_t lj = 0; lj < nj; ++lj)
          for (uint32_t li = 0; li < ni; ++li) {
            const uint32_t v = (lk * E + lj) * E + li, n = v + stride;
            const int sides = (value[v] < 0) != (value[n] < 0);
            const int far = nearest[v] + nearest[n] > sign_limit;
            const int jump = stored[v] & stored[n] & (std::abs(value[v] - value[n]) > jump_limit);
            bad |= valid[v] & valid[n] & ((sides & far) | jump);
          }
    };
    pairs_along(1, E - 1, E, E);
    pairs_along(E, E, E - 1, E);
    pairs_along(E * E, E, E, E - 1);
    return bad != 0;
  }

  /// Pairs across the brick's faces through the table: toward a value brick only on the upper faces (that brick's
  /// lower faces would repeat them), toward a coarse one on both.
  void check_faces(const BrickVoxels& b, Findings& f) const {
    for (int axis = 0; axis < 3; ++axis) {
      const int u = axis == 0 ? 1 : 0, w = axis == 2 ? 1 : 2;
      for (uint32_t side = 0; side < 2; ++side) {
        const uint32_t l_axis = side == 0 ? 0 : b.count[axis] - 1;
        const int64_t neighbour_axis = int64_t(b.first[axis] + l_axis) + (side == 0 ? -1 : 1);
        if (neighbour_axis < 0 || neighbour_axis >= int64_t(vm_.dims[size_t(axis)])) continue;
        uint32_t probe[3] = {b.first[0], b.first[1], b.first[2]};
        probe[axis] = uint32_t(neighbour_axis);
        const bool coarse_neighbour = vm_.bricks[vm_.brick_index(probe[0] / E, probe[1] / E, probe[2] / E)] < 0;
        if (side == 0 && !coarse_neighbour) continue;
        for (uint32_t lv = 0; lv < b.count[w]; ++lv)
          for (uint32_t lu = 0; lu < b.count[u]; ++lu) {
            uint32_t l[3];
            l[axis] = l_axis;
            l[u] = lu;
            l[w] = lv;
            uint32_t at[3] = {b.first[0] + l[0], b.first[1] + l[1], b.first[2] + l[2]};
            uint32_t other[3] = {at[0], at[1], at[2]};
            other[axis] = uint32_t(neighbour_axis);
            const Near& near = b.near[Voxelmap::local_index(l[0], l[1], l[2])];
            const Near across = near_of(other[0], other[1], other[2]);
            if (pair_breaks_a_rule(near, across)) report_pair(at, near, other, across, f);
          }
      }
    }
  }

  /// The brick's inner pairs one by one, to report the first that breaks each rule.
  void search_inner_pairs(const BrickVoxels& b, Findings& f) const {
    for (uint32_t lk = 0; lk < b.count[2]; ++lk)
      for (uint32_t lj = 0; lj < b.count[1]; ++lj)
        for (uint32_t li = 0; li < b.count[0]; ++li) {
          const uint32_t l[3] = {li, lj, lk};
          const uint32_t at[3] = {b.first[0] + li, b.first[1] + lj, b.first[2] + lk};
          const Near& a = b.near[Voxelmap::local_index(li, lj, lk)];
          for (int axis = 0; axis < 3; ++axis) {
            if (l[axis] + 1 >= b.count[axis]) continue;
            uint32_t n[3] = {l[0], l[1], l[2]}, other[3] = {at[0], at[1], at[2]};
            ++n[axis];
            ++other[axis];
            const Near& c = b.near[Voxelmap::local_index(n[0], n[1], n[2])];
            if (pair_breaks_a_rule(a, c)) report_pair(at, a, other, c, f);
          }
        }
  }

  const Voxelmap& vm_;
  bool closed_;
  double h_, inverse_h_, band_m_, edge_m_, sign_limit_, jump_limit_;
  std::unique_ptr<detail::EstimateTransform> settled_;  ///< settled estimates' rule (2.2); null: interpolated
};

void check_voxelmap_semantics(const Voxelmap& vm, bool closed_surface, Checker& c, detail::CheckProgress* progress) {
  std::vector<size_t> bricks;
  bricks.reserve(vm.value_brick_count());
  for (size_t b = 0; b < vm.bricks.size(); ++b)
    if (vm.bricks[b] >= 0) bricks.push_back(b);
  // A share of the bricks per thread; each thread's findings are its bricks' in order, so the merged list is too.
  const unsigned threads = std::max(1u, std::min<unsigned>(usable_cores(), unsigned(bricks.size() / 256 + 1)));
  std::vector<std::vector<Issue>> found(threads);
  run_workers(threads, [&](unsigned t) {
    VoxelmapRules(vm, closed_surface)
        .check(bricks, bricks.size() * t / threads, bricks.size() * (t + 1) / threads, found[t], progress);
  });
  std::vector<IssueCode> reported;
  for (const auto& issues : found)
    for (const Issue& issue : issues) {
      if (std::find(reported.begin(), reported.end(), issue.code) != reported.end()) continue;
      reported.push_back(issue.code);
      c.add(issue.code, issue.path, issue.message);
    }
  if (!closed_surface || std::find(reported.begin(), reported.end(), IssueCode::SignMismatch) != reported.end()) return;
  // Neighbouring coarse bricks: the surface cannot pass between two voxels both farther than (band - 1/2) h.
  const double h = vm.voxel_size;
  if (2 * (vm.distance_band - 0.5) * h <= h * (1 + 1e-6)) return;
  const auto b = vm.brick_dims();
  for (uint32_t bk = 0; bk < b[2]; ++bk)
    for (uint32_t bj = 0; bj < b[1]; ++bj)
      for (uint32_t bi = 0; bi < b[0]; ++bi) {
        const int32_t entry = vm.bricks[vm.brick_index(bi, bj, bk)];
        if (entry >= 0) continue;
        const uint32_t next[3][3] = {{bi + 1, bj, bk}, {bi, bj + 1, bk}, {bi, bj, bk + 1}};
        for (const auto& n : next) {
          if (n[0] >= b[0] || n[1] >= b[1] || n[2] >= b[2]) continue;
          const int32_t other = vm.bricks[vm.brick_index(n[0], n[1], n[2])];
          if (other >= 0 || other == entry) continue;
          c.add(IssueCode::SignMismatch, "/voxelmap/bricks",
                "coarse bricks (" + std::to_string(bi) + ", " + std::to_string(bj) + ", " + std::to_string(bk) +
                    ") and (" + std::to_string(n[0]) + ", " + std::to_string(n[1]) + ", " + std::to_string(n[2]) +
                    ") touch but lie on opposite sides of the surface");
          return;
        }
      }
}

// Spec §3.3: a lattice value l lies within [u, (1 + e1) u + e0 h] of the exact unsigned distance u, and u is
// 1-Lipschitz. So where its voxel stores a distance d, u is |d| within half a quantum; and two neighbouring lattice
// points s apart satisfy l_a <= (1 + e1)(l_b + s) + e0 h. Both hold for any valid lattice and need no mesh; a
// doubled or scaled lattice breaks the first, a damaged point the second. (That l is the distance itself, only
// the mesh can tell.) Floats: l may lie one rounding step below u, hence the relative tolerance. A shell's l and d
// are |u - T/2| and u - T/2 with u, the distance to the mesh, rounded: their rounding is relative to u, which is
// up to T/2 larger than they are.
void check_lattice_semantics(const Voxelmap& vm, Checker& c) {
  const double h = vm.voxel_size, e0 = vm.lattice_error[0] * h, e1 = vm.lattice_error[1];
  const double half_quantum = 0.5 * vm.distance_quantum;
  constexpr double kRounding = 1e-6;
  const double shell_rounding = kRounding * 0.5 * vm.shell_thickness.value_or(0.0);
  const auto l = vm.lattice_dims();
  auto voxel_of = [&](uint32_t a, uint32_t b, uint32_t k) -> std::array<uint32_t, 3> {
    return {Voxelmap::lattice_coordinate(a, vm.dims[0]), Voxelmap::lattice_coordinate(b, vm.dims[1]),
            Voxelmap::lattice_coordinate(k, vm.dims[2])};
  };
  auto name = [](uint32_t a, uint32_t b, uint32_t k) {
    return "lattice point (" + std::to_string(a) + ", " + std::to_string(b) + ", " + std::to_string(k) + ")";
  };
  bool stored_reported = false;
  for (uint32_t k = 0; k < l[2]; ++k)
    for (uint32_t b = 0; b < l[1]; ++b)
      for (uint32_t a = 0; a < l[0]; ++a) {
        const double value = vm.lattice[vm.lattice_index(a, b, k)];
        const auto v = voxel_of(a, b, k);
        if (!stored_reported) {
          const VoxelValue at = vm.voxel(v[0], v[1], v[2]);
          const double u = std::abs(at.distance);
          if (at.stored && (value < (u - half_quantum) * (1 - kRounding) - shell_rounding ||
                            value > ((1 + e1) * (u + half_quantum) + e0) * (1 + kRounding) + shell_rounding)) {
            c.add(IssueCode::LatticeMismatch, "/voxelmap/lattice",
                  name(a, b, k) + " holds " + fmt(value) + " m, but its voxel stores the distance " + fmt(at.distance) +
                      " m (the lattice must hold it within [u, (1 + e1) u + e0 h])");
            stored_reported = true;
          }
        }
        const uint32_t next[3][3] = {{a + 1, b, k}, {a, b + 1, k}, {a, b, k + 1}};
        for (int axis = 0; axis < 3; ++axis) {
          const uint32_t* n = next[axis];
          if (n[0] >= l[0] || n[1] >= l[1] || n[2] >= l[2]) continue;
          const auto w = voxel_of(n[0], n[1], n[2]);
          const double s = h * (double(w[size_t(axis)]) - double(v[size_t(axis)]));
          const double other = vm.lattice[vm.lattice_index(n[0], n[1], n[2])];
          const double low = std::min(value, other), high = std::max(value, other);
          if (high <= ((1 + e1) * (low + s) + e0) * (1 + kRounding) + 2 * shell_rounding) continue;
          c.add(IssueCode::LatticeMismatch, "/voxelmap/lattice",
                name(a, b, k) + " and " + name(n[0], n[1], n[2]) + " hold " + fmt(value) + " and " + fmt(other) +
                    " m, " + fmt(s) + " m apart: distances cannot differ that much (spec §3.3)");
          return;
        }
      }
}

// Distance at the voxel nearest to p, if stored there.
std::optional<double> nearest_distance(const Voxelmap& vm, const Vec3& p) {
  uint32_t index[3];
  for (int a = 0; a < 3; ++a) {
    const double x = std::floor((p[a] - vm.origin[a]) / vm.voxel_size + 0.5);
    if (!(x >= 0 && x < vm.dims[a])) return std::nullopt;
    index[a] = uint32_t(x);
  }
  const VoxelValue v = vm.voxel(index[0], index[1], index[2]);
  if (!v.stored) return std::nullopt;
  return v.distance;
}

// The rules on a voxel's stored distance, which a 1.x grid's conversion has already run (legacy_voxelmap.cpp): their
// findings name /voxelmap/distances, once per file.
bool is_voxel_distance_rule(IssueCode code) {
  return code == IssueCode::DistanceJump || code == IssueCode::DistanceOutsideBand;
}

// Spec §4 (2.2): a point on the surface is within sqrt(3)/2 h of its nearest voxel, so with a band of 1.5 voxels or
// more that voxel stores a distance (a shell's sheet points too: those the shell swallows are not on its surface).
void check_points_on_surface(const Asset& a, Checker& c) {
  const Voxelmap& vm = a.voxelmap;
  const bool from_2_2 = a.version.major > 2 || (a.version.major == 2 && a.version.minor >= 2);
  if (!from_2_2 || vm.distance_band < 1.5) return;
  // Coordinates so large that double cannot place a point within a tenth of a voxel (1e11 voxels out, the slack of
  // check_grid_holds_object) leave its nearest voxel unknown: not judged.
  double largest = 0;
  for (int axis = 0; axis < 3; ++axis)
    largest =
        std::max({largest, std::abs(vm.origin[axis]), std::abs(a.bounds_min[axis]), std::abs(a.bounds_max[axis])});
  if (1e-12 * largest > 0.1 * vm.voxel_size) return;
  size_t off = 0, first = 0;
  for (size_t n = 0; n < a.point_shell.size(); ++n)
    if (!nearest_distance(vm, a.point_shell.points[n]) && off++ == 0) first = n;
  if (off > 0)
    c.add(IssueCode::PointOffSurface, "/pointshell/points",
          std::to_string(off) + " of " + std::to_string(a.point_shell.size()) + " points (point " +
              std::to_string(first) + " the first) have no stored distance at their nearest voxel: they do not lie " +
              "on the voxelmap's surface");
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
  check_points_on_surface(a, c);
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

// Spec §3: the grid covers the object. A grid moved or shrunk off its object (an origin shifted, bounds blown up)
// is a consistent file the engines cannot use: MuJoCo meshes nothing, a query finds no contact.
void check_grid_holds_object(const Asset& a, Checker& c) {
  const Voxelmap& vm = a.voxelmap;
  const double h = vm.voxel_size;
  Vec3 lo, hi;
  double slack = 1e-3 * h;  // rounding of the bounds and the origin, far below a voxel
  for (int axis = 0; axis < 3; ++axis) {
    lo[axis] = vm.origin[axis] - 0.5 * h;
    hi[axis] = vm.origin[axis] + (double(vm.dims[axis]) - 0.5) * h;
    slack = std::max(slack, 1e-12 * std::max(std::abs(lo[axis]), std::abs(hi[axis])));
  }
  auto outside = [&](const Vec3& p, int axis) { return !(p[axis] >= lo[axis] - slack && p[axis] <= hi[axis] + slack); };
  for (int axis = 0; axis < 3; ++axis)
    if (outside(a.bounds_min, axis) || outside(a.bounds_max, axis)) {
      c.add(IssueCode::ValueOutOfRange, "/@bounds_min",
            "the bounds [" + fmt(a.bounds_min[axis]) + ", " + fmt(a.bounds_max[axis]) + "] m on axis " +
                std::to_string(axis) + " reach past the voxelmap's grid [" + fmt(lo[axis]) + ", " + fmt(hi[axis]) +
                "] m: the grid must cover the object (spec §3)");
      return;
    }
  const auto& points = a.point_shell.points;
  for (size_t n = 0; n < points.size(); ++n)
    for (int axis = 0; axis < 3; ++axis)
      if (outside(points[n], axis)) {
        c.add(IssueCode::ValueOutOfRange, "/pointshell/points",
              "point " + std::to_string(n) + " lies outside the voxelmap's grid on axis " + std::to_string(axis) +
                  ": the grid must cover the object (spec §3)");
        return;
      }
}

}  // namespace

std::vector<Issue> validate_asset(const Asset& asset, ValidationLevel level) {
  return detail::validate_asset(asset, level, nullptr);
}

std::vector<Issue> detail::validate_asset(const Asset& asset, ValidationLevel level, CheckProgress* progress) {
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
  check_voxelmap(asset.voxelmap, asset.version, c);
  check_point_shell(asset.point_shell, c);
  check_mass(asset.mass, c);
  check_provenance(asset.provenance, c);
  if (!has_errors(issues)) check_grid_holds_object(asset, c);
  if (!has_errors(issues)) check_point_spacing_scale(asset, c);
  // Semantic rules need a structurally sound asset (sizes, tree ranges) to index safely.
  if (level == ValidationLevel::Full && !has_errors(issues)) {
    check_voxelmap_semantics(asset.voxelmap, detail::closed_surface(asset.provenance), c, progress);
    if (progress && progress->stop) return issues;  // the write it checks for is abandoned
    check_lattice_semantics(asset.voxelmap, c);
    check_point_shell_semantics(asset, c);
    check_mass_semantics(asset, c);
  }
  // A 1.x file has no bricks or lattice: they are this reader's conversion of its dense grids (spec §3.4), so a
  // finding about them names the grid it came from.
  if (asset.version.major == 1)
    for (Issue& issue : issues)
      for (const char* converted : {"/voxelmap/bricks", "/voxelmap/brick_values", "/voxelmap/lattice"})
        if (issue.path == converted) {
          issue.path = is_voxel_distance_rule(issue.code) ? "/voxelmap/distances" : "/voxelmap/layers";
          break;
        }
  return issues;
}

namespace detail {

std::optional<Asset> read_and_check(const std::string& path, const ReadOptions& options, std::vector<Issue>& issues) {
  try {
    std::optional<Asset> asset = load_asset(path, issues, options);
    if (asset) {
      // A 1.x grid's voxel rules ran while it was converted, and the brick rules run again on the conversion: a
      // voxel rule is reported once per file (issue-codes.md), at its first finding.
      auto already = [&](IssueCode code) {
        return std::any_of(issues.begin(), issues.end(), [&](const Issue& i) { return i.code == code; });
      };
      for (Issue& issue : validate_asset(*asset, options.level))
        if (!(is_voxel_distance_rule(issue.code) && already(issue.code))) issues.push_back(std::move(issue));
    }
    if (has_errors(issues)) return std::nullopt;
    return asset;
  } catch (const std::bad_alloc&) {
    issues.push_back(Issue{IssueCode::OutOfMemory, Severity::Error, "/", "not enough memory to read the asset"});
    return std::nullopt;
  }
}

}  // namespace detail

std::vector<Issue> validate_file(const std::string& path, const ReadOptions& options) {
  std::vector<Issue> issues;
  detail::read_and_check(path, options, issues);
  return issues;
}

std::vector<Issue> validate_file(const std::string& path, ValidationLevel level) {
  ReadOptions options;
  options.level = level;
  return validate_file(path, options);
}

}  // namespace voxfmt
