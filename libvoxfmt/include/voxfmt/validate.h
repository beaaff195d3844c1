// Validation of assets against spec/voxfmt-format.md.
#pragma once

#include <string>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/issues.h"

namespace voxfmt {

enum class ValidationLevel {
  Quick,  ///< structure, dtypes, shapes, ranges, tree structure
  Full,   ///< plus semantic rules: layers vs distances, neighbours, normals, spheres, mass properties
};

/// Rules that can be checked on the in-memory asset (ranges, tree structure, JSON, ...).
std::vector<Issue> validate_asset(const Asset& asset, ValidationLevel level = ValidationLevel::Quick);

struct ReadOptions;

/// Opens `path` and reports every finding: structural ones found while reading, then validate_asset's.
/// Never throws; a file that cannot be opened yields FILE_NOT_FOUND or NOT_HDF5, one whose read would exceed
/// the read budget OUT_OF_MEMORY (voxfmt/io.h: ReadOptions).
std::vector<Issue> validate_file(const std::string& path, ValidationLevel level = ValidationLevel::Quick);
std::vector<Issue> validate_file(const std::string& path, const ReadOptions& options);

}  // namespace voxfmt
