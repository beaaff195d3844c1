// How every subcommand turns an error code into its exit status: one table.
#include <iostream>

#include "commands.h"
#include "json_report.h"

namespace voxfmt::cli {

namespace {
// Exit 2: the command could not do its work for reasons outside the data (a bad argument, a missing file,
// a file that cannot be written, memory or a budget too small for it). Every other code means the input itself
// is bad: exit 1.
constexpr IssueCode kUsageOrIo[] = {IssueCode::BadOption, IssueCode::FileNotFound, IssueCode::WriteFailed,
                                    IssueCode::OutOfMemory};
}  // namespace

int exit_status(IssueCode code) {
  for (IssueCode usage : kUsageOrIo)
    if (code == usage) return kExitUsageOrIo;
  return kExitInvalid;
}

int report_error(const char* command, const Error& error) {
  std::cerr << "voxfmt " << command << ": error: " << terminal_safe(error.describe()) << "\n";
  return exit_status(error.code);
}

int report_error(const char* command, const Error& error, bool json, const std::string& input) {
  if (json)
    std::cout << to_text(nlohmann::json{{"status", "error"},
                                        {"input", input},
                                        {"code", code_name(error.code)},
                                        {"message", error.message}})
              << "\n";
  return report_error(command, error);
}

}  // namespace voxfmt::cli
