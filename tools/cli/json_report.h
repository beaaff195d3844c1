// JSON views of libvoxfmt types shared by the subcommands.
#pragma once

#include <nlohmann/json.hpp>

#include <vector>

#include "voxfmt/result.h"

namespace voxfmt::cli {

/// Serialises for printing; invalid UTF-8 (e.g. from a file name) becomes U+FFFD instead of throwing.
std::string to_text(const nlohmann::json& value);

nlohmann::json issue_json(const Issue& issue);
nlohmann::json issues_json(const std::vector<Issue>& issues);

}  // namespace voxfmt::cli
