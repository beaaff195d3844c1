#include "batch_manifest.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <stdexcept>

namespace voxfmt::cli {

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

void sync_directory_of(const std::string& path) {
  const std::string dir = std::filesystem::path(path).parent_path().string();
  const int fd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

}  // namespace

std::string json_line(const nlohmann::json& value) {
  return value.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

Manifest::Manifest(const std::string& path) : path_(path) {
  const std::string lock = path + ".lock";
  lock_fd_ = ::open(lock.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (lock_fd_ < 0) fail(lock, "cannot create lock file");
  if (::flock(lock_fd_, LOCK_EX | LOCK_NB) != 0) {
    const bool busy = errno == EWOULDBLOCK;
    ::close(lock_fd_);
    lock_fd_ = -1;
    if (busy) throw std::runtime_error(path + ": another voxfmt batch is writing this manifest (" + lock + " is locked)");
    fail(lock, "cannot lock");
  }

  {
    std::ifstream in(path);
    std::string line;
    while (std::getline(in, line)) {
      const nlohmann::json record = nlohmann::json::parse(line, nullptr, false);
      if (record.is_discarded() || !record.is_object() || !record.contains("output") || !record["output"].is_string())
        continue;  // a line torn by a crash, or not ours
      last_[record["output"].get<std::string>()] = record;
    }
  }

  // Compaction: temporary + fsync + rename, so the old manifest stays until the new one is complete. Stale
  // temporaries of killed runs are harmless and removed by the caller's clean-up of *.partial-* files.
  const std::string temp = path + ".partial-" + std::to_string(::getpid()) + "-manifest";
  const int out = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (out < 0) fail(temp, "cannot create");
  std::string text;
  for (const auto& [output, record] : last_) text += json_line(record) + "\n";
  write_all(out, text, temp);
  if (::fsync(out) != 0) fail(temp, "cannot flush");
  ::close(out);
  if (std::rename(temp.c_str(), path.c_str()) != 0) fail(path, "cannot replace");
  sync_directory_of(path);

  fd_ = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
  if (fd_ < 0) fail(path, "cannot open for appending");
}

Manifest::~Manifest() {
  if (fd_ >= 0) ::close(fd_);
  if (lock_fd_ >= 0) ::close(lock_fd_);  // releases the flock
}

const nlohmann::json* Manifest::last(const std::string& output) const {
  auto it = last_.find(output);
  return it == last_.end() ? nullptr : &it->second;
}

void Manifest::append(const nlohmann::json& record) {
  // One write() per line: O_APPEND puts it at the end as a whole; fdatasync makes it survive a crash.
  write_all(fd_, json_line(record) + "\n", path_);
  if (::fdatasync(fd_) != 0) fail(path_, "cannot flush");
  if (record.contains("output") && record["output"].is_string()) last_[record["output"].get<std::string>()] = record;
}

}  // namespace voxfmt::cli
