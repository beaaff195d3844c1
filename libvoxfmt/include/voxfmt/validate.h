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

/// Opens `path` and reports every finding: structural ones found while reading, then validate_asset's.
/// Never throws; a file that cannot be opened yields FILE_NOT_FOUND or NOT_HDF5.
std::vector<Issue> validate_file(const std::string& path, ValidationLevel level = ValidationLevel::Quick);

}  // namespace voxfmt
