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

}  // namespace voxfmt::cli
