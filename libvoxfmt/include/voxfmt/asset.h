// Plain data types of a voxfmt asset (spec/voxfmt-format.md). No HDF5, CGAL or OpenVDB here: the runtime
// loaders and the bake tools share these types.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "voxfmt/voxelmap.h"

namespace voxfmt {

/// [major, minor] of the file format.
struct FormatVersion {
  uint32_t major = 1;
  uint32_t minor = 0;
  friend bool operator==(const FormatVersion& a, const FormatVersion& b) {
    return a.major == b.major && a.minor == b.minor;
  }
};

/// The format version this library writes and fully understands.
inline constexpr FormatVersion kFormatVersion{2, 2};

/// The voxel sizes a valid file may have (spec §3): beyond them the numbers mean nothing physical.
inline constexpr double kMinVoxelSize = 1e-9, kMaxVoxelSize = 1e6;

/// The largest point spacing a valid file may have (spec §4): 16 times the diagonal of [bounds_min, bounds_max], or 16
/// voxels if more. A writer whose nominal spacing is larger (a point or two on a crumpled surface) writes this.
inline double max_point_spacing(const Vec3& bounds_min, const Vec3& bounds_max, double voxel_size) {
  double diagonal2 = 0;
  for (int axis = 0; axis < 3; ++axis)
    diagonal2 += (bounds_max[axis] - bounds_min[axis]) * (bounds_max[axis] - bounds_min[axis]);
  return 16 * std::max(std::sqrt(diagonal2), voxel_size);
}

/// Point shell organised as a breadth-first point-sphere tree (spec §4). Node n is point n.
struct PointShell {
  std::vector<Vec3> points;
  std::vector<Vec3f> normals;  ///< inward unit normals
  std::vector<Vec3> sphere_centers;
  std::vector<double> sphere_radii;
  std::vector<uint32_t> child_begin;
  std::vector<uint32_t> child_count;
  std::vector<uint32_t> level_offsets;  ///< L+1 entries: level l is [level_offsets[l], level_offsets[l+1])
  std::optional<double> point_spacing;
  std::optional<double> branching;  ///< mean children per node aimed for

  size_t size() const { return points.size(); }
  size_t level_count() const { return level_offsets.empty() ? 0 : level_offsets.size() - 1; }
  /// Number of nodes on each tree level, root first.
  std::vector<uint32_t> points_per_level() const {
    std::vector<uint32_t> sizes;
    for (size_t l = 0; l < level_count(); ++l) sizes.push_back(level_offsets[l + 1] - level_offsets[l]);
    return sizes;
  }
};

/// Unit-density mass properties of the closed surface (spec §5).
struct MassProperties {
  double volume = 0.0;              ///< m^3
  Vec3 center_of_mass{};            ///< m
  std::array<double, 9> inertia{};  ///< row-major 3x3 about the centre of mass, m^5
};

struct BuildWarning {
  std::string code;
  std::string message;
  friend bool operator==(const BuildWarning& a, const BuildWarning& b) {
    return a.code == b.code && a.message == b.message;
  }
};

/// Where the asset came from (spec §6).
struct Provenance {
  std::string generator;
  std::string generator_version;
  std::string source_file;                   ///< file name only
  std::string source_sha256;                 ///< 64 lowercase hex digits, or empty
  std::string build_parameters_json = "{}";  ///< JSON object
  std::map<std::string, std::string> dependency_versions;
  std::vector<BuildWarning> build_warnings;
  std::string created_utc;  ///< ISO 8601; empty = not recorded
};

struct Asset {
  FormatVersion version = kFormatVersion;  ///< version found when read; written files use kFormatVersion
  std::string up_axis = "+Y";
  Vec3 bounds_min{};
  Vec3 bounds_max{};
  Voxelmap voxelmap;
  PointShell point_shell;
  MassProperties mass;
  Provenance provenance;
};

}  // namespace voxfmt
