#include "voxfmt/detail/atomic_file.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>

namespace voxfmt {

namespace {

// fsync by path (the writer has closed its descriptor). A rename is only durable once the data it exposes is
// on disk, and the rename itself once its folder is: without both, a power cut could leave an empty or torn
// file under the final name.
bool sync_path(const std::string& path, bool directory) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | (directory ? O_DIRECTORY : 0));
  if (fd < 0) return false;
  const int error = ::fsync(fd) == 0 ? 0 : errno;
  ::close(fd);
  errno = error;
  return error == 0 || error == EINVAL;  // EINVAL: this file system cannot sync that kind of object
}

std::string parent_directory(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? "." : slash == 0 ? "/" : path.substr(0, slash);
}

Error write_failed(const std::string& path, const std::string& reason) {
  return Error{IssueCode::WriteFailed, path + ": " + reason, path};
}

constexpr const char* kFolder = "a folder";

// What `path` is where it exists but is not a regular file ("a folder", "a pipe", ...); nullptr otherwise.
const char* special_file_kind(const std::string& path) {
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0 || S_ISREG(info.st_mode)) return nullptr;
  return S_ISDIR(info.st_mode)    ? kFolder
         : S_ISFIFO(info.st_mode) ? "a pipe"
         : S_ISSOCK(info.st_mode) ? "a socket"
                                  : "a device";
}

std::string not_regular_message(const char* kind) { return std::string("is ") + kind + ", not a regular file"; }

// The checks of check_output_path on `path`, which output_target resolved from `given`.
Status check_resolved_output(const std::string& given, const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (const char* kind = special_file_kind(path))
    return write_failed(given, not_regular_message(kind) + (kind == kFolder ? "" : ": not replaced"));
  const fs::path folder = fs::path(path).has_parent_path() ? fs::path(path).parent_path() : fs::path(".");
  if (!fs::exists(folder, ec)) return write_failed(given, "folder " + folder.string() + " does not exist");
  if (!fs::is_directory(folder, ec)) return write_failed(given, folder.string() + " is not a folder");
  // A name its folder's file system cannot hold, or whose temporary it cannot: said before a long job, not by the
  // write at its end. The file system answers (its limit may be below 255 bytes, or count characters, not bytes).
  const std::string name = fs::path(path).filename().string();
  const std::string temporary =
      (folder / (temporary_stem(name) + std::string(kPartialMarker) + "4294967295-4294967295")).string();
  for (const std::string& probe : {path, temporary}) {
    struct stat info {};
    if (::stat(probe.c_str(), &info) != 0 && errno == ENAMETOOLONG)
      return write_failed(given, probe == path ? "the file's name (" + std::to_string(name.size()) +
                                                     " bytes) is longer than its folder's file system allows"
                                               : "the file's name (" + std::to_string(name.size()) +
                                                     " bytes) leaves no room on its folder's file system for its "
                                                     "temporary's (choose a shorter name)");
  }
  return Status::success();
}

}  // namespace

std::string not_a_regular_file(const std::string& path) {
  const char* kind = special_file_kind(path);
  return kind ? not_regular_message(kind) : "";
}

// Where writing `given` lands: through symbolic links, link by link as the kernel follows them (the target need
// not exist yet), since the rename would replace the link itself. Only links of this user (or root's) are
// followed: a link planted by another user in a shared folder (/tmp) could otherwise aim a root process's output
// at any file, which the kernel's protected_symlinks forbids for open() but not for a rename.
Result<std::string> output_target(const std::string& given) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::path target = given;
  for (int hops = 0; fs::is_symlink(target, ec); ++hops) {
    struct stat link {};
    if (::lstat(target.c_str(), &link) != 0 || hops == 40) return write_failed(given, "cannot follow the link");
    if (link.st_uid != ::geteuid() && link.st_uid != 0)
      return write_failed(given, target.string() + " is another user's symbolic link: not followed");
    const fs::path next = fs::read_symlink(target, ec);
    if (ec) return write_failed(given, "cannot follow the link: " + ec.message());
    target = next.is_absolute() ? next : target.parent_path() / next;
  }
  return target.string();
}

Status check_output_path(const std::string& given) {
  if (given.empty()) return write_failed(given, "no output path given");
  const Result<std::string> resolved = output_target(given);
  if (!resolved) return resolved.error();
  return check_resolved_output(given, resolved.value());
}

Status check_output_path(const std::string& path, const std::string& input) {
  if (Status usable = check_output_path(path); !usable) return usable;
  std::error_code ec;
  if (std::filesystem::equivalent(path, input, ec))
    return Error{IssueCode::BadOption, path + ": is the input " + input + ": writing it would replace it", path};
  return Status::success();
}

namespace {
bool digits(const std::string& text) {
  return !text.empty() && text.size() <= 9 && text.find_first_not_of("0123456789") == std::string::npos;
}
}  // namespace

bool process_is_gone(const std::string& pid) {
  if (!digits(pid)) return false;
  const long process = std::stol(pid);
  if (process <= 0) return false;
  if (::kill(pid_t(process), 0) != 0) return errno == ESRCH;
  // A zombie answers kill() but writes nothing more: a bake killed with its batch stays one where nothing reaps
  // orphans (a container whose first process does not).
  std::FILE* stat = std::fopen(("/proc/" + pid + "/stat").c_str(), "r");
  if (!stat) return false;
  char line[512] = {};
  const size_t read = std::fread(line, 1, sizeof line - 1, stat);
  std::fclose(stat);
  const char* close = std::strrchr(line, ')');  // the command name may hold spaces and parentheses
  return read > 0 && close && (close[1] == ' ') && (close[2] == 'Z' || close[2] == 'X');
}

std::string temporary_stem(const std::string& target_name) {
  // The longest suffix: the marker, a pid (at most 10 digits) and "-" and a counter (at most 10).
  constexpr size_t kNameMax = 255, kSuffixMax = kPartialMarker.size() + 10 + 1 + 10, kHashChars = 16;
  if (target_name.size() + kSuffixMax <= kNameMax) return target_name;
  uint64_t hash = 14695981039346656037ull;  // FNV-1a: stable across runs and builds, unlike std::hash
  for (const unsigned char c : target_name) hash = (hash ^ c) * 1099511628211ull;
  size_t keep = kNameMax - kSuffixMax - 1 - kHashChars;
  while (keep > 0 && (static_cast<unsigned char>(target_name[keep]) & 0xC0) == 0x80) --keep;  // whole UTF-8 characters
  char hex[kHashChars + 1];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(hash));
  return target_name.substr(0, keep) + "~" + hex;
}

bool dead_temporary_of(const std::filesystem::directory_entry& entry, const std::string& target_name) {
  const std::string name = entry.path().filename().string();
  const std::string prefix = temporary_stem(target_name) + std::string(kPartialMarker);
  if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) return false;
  // Exactly PID-N, a regular file (not a link, not a folder), of a process that is gone.
  const std::string tail = name.substr(prefix.size());
  const size_t dash = tail.find('-');
  if (dash == std::string::npos || !digits(tail.substr(dash + 1))) return false;
  std::error_code ec;
  return std::filesystem::is_regular_file(entry.symlink_status(ec)) && process_is_gone(tail.substr(0, dash));
}

size_t remove_dead_temporaries(const std::string& given) {
  namespace fs = std::filesystem;
  const Result<std::string> resolved = output_target(given);  // temporaries lie beside a link's target
  if (!resolved) return 0;
  const fs::path target(resolved.value());
  const std::string target_name = target.filename().string();
  size_t removed = 0;
  std::error_code ec;
  const fs::path folder = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    if (!dead_temporary_of(*it, target_name)) continue;
    std::error_code remove_error;
    removed += fs::remove(it->path(), remove_error) ? 1 : 0;
  }
  return removed;
}

Status write_file_atomically(const std::string& given, const AtomicWrite& steps) {
  if (given.empty()) return write_failed(given, "no output path given");
  const Result<std::string> resolved = output_target(given);
  if (!resolved) return resolved.error();
  const std::string& path = resolved.value();
  if (Status usable = check_resolved_output(given, path); !usable) return usable;
  static std::atomic<unsigned> counter{0};
  const size_t slash = path.find_last_of('/');
  const std::string folder = slash == std::string::npos ? "" : path.substr(0, slash + 1);
  const std::string temp = folder + temporary_stem(path.substr(folder.size())) + std::string(kPartialMarker) +
                           std::to_string(::getpid()) + "-" + std::to_string(counter++);
  // A file of this user's that is replaced keeps its permissions, set just before the rename. A private asset stays
  // private during the write too: the temporary is made before any byte is written, for its owner alone (and
  // writable by them, whatever the final mode: a read-only asset is replaced as before). Set-id bits are not
  // carried; another user's file is replaced by one of the umask's mode, as a new file is.
  struct stat replaced {};
  const bool keep_mode =
      ::stat(path.c_str(), &replaced) == 0 && S_ISREG(replaced.st_mode) && replaced.st_uid == ::geteuid();
  const mode_t mode = replaced.st_mode & 0777;
  if (keep_mode) {
    const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, (mode & 0700) | 0600);
    if (fd < 0) return write_failed(path, std::string("cannot create the temporary file: ") + std::strerror(errno));
    ::close(fd);
  }
  // From here the temporary is ours: removed on every way out but the rename, an exception's included.
  struct RemoveUnlessCommitted {
    const std::string& temp;
    bool committed = false;
    ~RemoveUnlessCommitted() {
      if (!committed) std::remove(temp.c_str());
    }
  } guard{temp};
  Status written = steps.write ? steps.write(temp) : Status(write_failed(path, "nothing to write"));
  if (!written) return written;
  if (!sync_path(temp, false))
    return write_failed(path, std::string("cannot flush the temporary file to disk: ") + std::strerror(errno));
  if (steps.before_commit) {
    Status check = steps.before_commit();
    if (!check) return check;
  }
  if (keep_mode && ::chmod(temp.c_str(), mode) != 0)  // past the umask, and what a writer's copy may have set
    return write_failed(path, std::string("cannot keep the replaced file's permissions: ") + std::strerror(errno));
  if (std::rename(temp.c_str(), path.c_str()) != 0)
    return write_failed(path, std::string("cannot rename the temporary file into place: ") + std::strerror(errno));
  guard.committed = true;
  sync_path(parent_directory(path), true);  // best effort: the file is complete either way
  return Status::success();
}

Status write_file_atomically(const std::string& path, std::string_view bytes) {
  AtomicWrite steps;
  steps.write = [&](const std::string& temp) -> Status {
    std::FILE* file = std::fopen(temp.c_str(), "wb");
    if (!file) return write_failed(path, std::string("cannot create: ") + std::strerror(errno));
    const bool wrote = std::fwrite(bytes.data(), 1, bytes.size(), file) == bytes.size();
    const int write_errno = errno;
    const bool closed = std::fclose(file) == 0;
    if (!wrote || !closed)
      return write_failed(path, std::string("cannot write: ") + std::strerror(wrote ? errno : write_errno));
    return Status::success();
  };
  return write_file_atomically(path, steps);
}

}  // namespace voxfmt
