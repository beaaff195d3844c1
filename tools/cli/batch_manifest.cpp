#include "batch_manifest.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <stdexcept>

#include "report.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/json_path.h"
#include "voxfmt/result.h"

namespace voxfmt::cli {

namespace fs = std::filesystem;

namespace {

[[noreturn]] void fail(const std::string& path, const std::string& what) {
  throw std::runtime_error(path + ": " + what + ": " + std::strerror(errno));
}

void write_all(int fd, const std::string& data, const std::string& path) {
  size_t done = 0;
  while (done < data.size()) {
    const ssize_t n = ::write(fd, data.data() + done, data.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) fail(path, "cannot write");
    done += size_t(n);
  }
}

}  // namespace

std::string json_line(const nlohmann::json& value) {
  return value.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

namespace {
// A manifest reached through a link is its target: compaction replaces the file, which must not turn a shared
// link into a private copy (the same rule as every output's, voxfmt/detail/atomic_file.h).
std::string manifest_target(const std::string& given) {
  const Result<std::string> target = output_target(given);
  if (!target) throw std::runtime_error(target.error().message);
  return target.value();
}

// The records of the manifest at `path`, latest per output. Only a regular file (a FIFO would block the read
// forever), and only a manifest: compaction rewrites the file, so a file given by mistake (notes, a mesh, any
// JSON of another tool) is refused, never overwritten. `check_only` stops at the first record: it is a manifest.
std::map<std::string, nlohmann::json> read_records(const std::string& path, bool check_only = false) {
  if (const std::string kind = not_a_regular_file(path); !kind.empty())
    throw std::runtime_error(path + ": " + kind + ": not a manifest");
  std::map<std::string, nlohmann::json> last;
  std::map<std::string, std::string> folders;  // resolved once each
  std::ifstream in(path);
  std::string line;
  size_t foreign = 0;
  bool too_long = false;
  while (report::read_manifest_line(in, line, too_long)) {  // a record over 1 MiB is dropped, as a torn one is
    foreign += too_long;  // and counts as not ours: a file of nothing else is refused, never overwritten
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    const nlohmann::json record = nlohmann::json::parse(line, nullptr, false);
    if (record.is_discarded() || !record.is_object() || !record.contains("output") || !record["output"].is_string()) {
      // A line torn by a crash is an object cut short; anything else is not ours.
      foreign += !(record.is_discarded() && line.find_first_not_of(" \t") == line.find('{'));
      continue;
    }
    nlohmann::json located = record;
    report::locate_output(located, path);
    const std::string key = report::manifest_output_key(path_of(located, "output"), &folders);
    last[key] = std::move(located);  // (the key first: an assignment's right side is evaluated before its left)
    if (check_only) break;
  }
  if (last.empty() && foreign > 0)
    throw std::runtime_error(path + ": holds no batch record but " + std::to_string(foreign) +
                             " other line(s): not a manifest, not overwritten (choose another --manifest)");
  for (auto it = last.begin(); it != last.end();)  // an asset `batch --prune` removed has no record to keep
    it = text_field(it->second, "status") == "removed" ? last.erase(it) : std::next(it);
  return last;
}
}  // namespace

Manifest::Manifest(const std::string& given) : path_(manifest_target(given)) {
  const std::string& path = path_;
  read_records(path, /*check_only=*/true);  // refused before its lock file is created beside it
  const std::string lock = path + ".lock";
  lock_fd_ = ::open(lock.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (lock_fd_ < 0) fail(lock, "cannot create lock file");
  if (::flock(lock_fd_, LOCK_EX | LOCK_NB) != 0) {
    const bool busy = errno == EWOULDBLOCK;
    ::close(lock_fd_);
    lock_fd_ = -1;
    if (busy)
      throw std::runtime_error(path + ": another voxfmt batch is writing this manifest (" + lock + " is locked)");
    fail(lock, "cannot lock");
  }
  last_ = read_records(path);  // again, under the lock: what another run appended before it ended

  // Compaction, atomically: the old manifest stays until the new one is complete. Temporaries of killed runs
  // are removed by the batch's clean-up of *.partial-* files.
  std::string text;
  for (const auto& [output, record] : last_) text += json_line(record) + "\n";
  const Status compacted = write_file_atomically(path, text);
  if (!compacted) throw std::runtime_error(compacted.error().message);

  fd_ = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
  if (fd_ < 0) fail(path, "cannot open for appending");
}

Manifest::~Manifest() {
  if (fd_ >= 0) ::close(fd_);
  if (lock_fd_ >= 0) ::close(lock_fd_);  // releases the flock
}

std::string text_field(const nlohmann::json& record, const char* key) {
  const auto it = record.find(key);
  return it != record.end() && it->is_string() ? it->get<std::string>() : std::string();
}
int64_t integer_field(const nlohmann::json& record, const char* key) {
  const auto it = record.find(key);
  return it != record.end() && it->is_number_integer() ? it->get<int64_t>() : -1;
}

bool same_parameters(const nlohmann::json& stored, const nlohmann::json& wanted) {
  if (stored.is_string()) {  // provenance keeps the JSON text
    const nlohmann::json parsed = nlohmann::json::parse(stored.get<std::string>(), nullptr, false);
    return !parsed.is_discarded() && parsed == wanted;
  }
  return stored == wanted;
}

bool transient_failure(const std::string& code) {
  const std::optional<IssueCode> known = code_from_name(code);
  if (!known) return true;  // written by a newer version, or by hand: try again
  switch (*known) {
    case IssueCode::Timeout:
    case IssueCode::Crashed:
    case IssueCode::OutOfMemory:
    case IssueCode::Internal:
    case IssueCode::WriteFailed:
    case IssueCode::InputNotFound:
      return true;
    default:
      return false;
  }
}

FileStamp stamp(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return {};
  return {true, uint64_t(st.st_size), int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec};
}

size_t remove_stale_partials(const std::vector<std::string>& outputs) {
  // remove_dead_temporaries' rule (dead_temporary_of), one listing per folder instead of one per output, beside a
  // link's target (where a write lands): another batch's or build's live temporary on this machine is kept.
  std::map<fs::path, std::map<std::string, std::string>> by_dir;  // folder: a temporary's stem -> the output's name
  for (const std::string& output : outputs) {
    const Result<std::string> target = output_target(output);
    const fs::path path = target ? fs::path(target.value()) : fs::path(output);
    const std::string name = path.filename().string();
    by_dir[path.parent_path()].emplace(temporary_stem(name), name);
  }
  size_t removed = 0;
  for (const auto& [dir, names] : by_dir) {
    std::error_code ec;
    for (fs::directory_iterator it(dir.empty() ? "." : dir, ec), end; !ec && it != end; it.increment(ec)) {
      const std::string name = it->path().filename().string();
      const size_t mark = name.rfind(kPartialMarker);
      if (mark == std::string::npos) continue;
      const auto target = names.find(name.substr(0, mark));
      if (target == names.end() || !dead_temporary_of(*it, target->second)) continue;
      std::error_code remove_error;
      removed += fs::remove(it->path(), remove_error);
    }
  }
  return removed;
}

const nlohmann::json* Manifest::last(const std::string& output) const {
  auto it = last_.find(key_of(output));
  return it == last_.end() ? nullptr : &it->second;
}

void Manifest::append(const nlohmann::json& given) {
  nlohmann::json record = given;
  report::stamp_output_from_manifest(record, path_);
  // One write() per line: O_APPEND puts it at the end as a whole; fdatasync makes it survive a crash.
  write_all(fd_, json_line(record) + "\n", path_);
  if (::fdatasync(fd_) != 0) fail(path_, "cannot flush");
  if (record.contains("output") && record["output"].is_string()) last_[key_of(path_of(record, "output"))] = record;
}

}  // namespace voxfmt::cli
