#include "json_report.h"

namespace voxfmt::cli {

std::string to_text(const nlohmann::json& value) {
  return value.dump(2, ' ', false, nlohmann::json::error_handler_t::replace);
}

nlohmann::json issue_json(const Issue& issue) {
  return {{"code", code_name(issue.code)},
          {"severity", severity_name(issue.severity)},
          {"path", issue.path},
          {"message", issue.message}};
}

nlohmann::json issues_json(const std::vector<Issue>& issues) {
  nlohmann::json out = nlohmann::json::array();
  for (const Issue& issue : issues) out.push_back(issue_json(issue));
  return out;
}

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

}  // namespace voxfmt::cli
