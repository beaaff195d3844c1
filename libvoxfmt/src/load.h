// Internal: one pass that reads a file and collects structural findings.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "voxfmt/asset.h"
#include "voxfmt/issues.h"

namespace voxfmt::detail {

/// Reads every object of `path` it can, appending findings to `issues`. Returns the asset only when no
/// error-severity finding was made while reading (value rules are validate_asset's job). Runs the parse in a
/// child process unless read isolation is off (isolated_read.cpp says why).
std::optional<Asset> load_asset(const std::string& path, std::vector<Issue>& issues);
/// Reads only the root header (format name, version) and the provenance group; isolated like load_asset.
std::optional<Provenance> load_provenance(const std::string& path, std::vector<Issue>& issues);

/// The same, in this process.
std::optional<Asset> load_asset_in_process(const std::string& path, std::vector<Issue>& issues);
std::optional<Provenance> load_provenance_in_process(const std::string& path, std::vector<Issue>& issues);

}  // namespace voxfmt::detail
