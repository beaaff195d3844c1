// Internal: one pass that reads a file and collects structural findings.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/issues.h"

namespace voxfmt::detail {

/// Reads every object of `path` it can, appending findings to `issues`. Returns the asset only when no
/// error-severity finding was made while reading (value rules are validate_asset's job).
std::optional<Asset> load_asset(const std::string& path, std::vector<Issue>& issues);
/// Reads only the root header (format name, version) and the provenance group.
std::optional<Provenance> load_provenance(const std::string& path, std::vector<Issue>& issues);

}  // namespace voxfmt::detail
