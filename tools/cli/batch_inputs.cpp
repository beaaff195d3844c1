#include "batch_inputs.h"

#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>

#include "voxfmt/bake/bake.h"
#include "voxfmt/detail/atomic_file.h"

namespace voxfmt::cli {

namespace fs = std::filesystem;

namespace {

bool is_list_file(const std::string& argument) {
  std::string ext = fs::path(argument).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext == ".txt" || ext == ".lst" || ext == ".list";
}

// A path as an error message shows it: a 10 MB line of a list file is not repeated whole.
std::string shown(const std::string& path) {
  constexpr size_t kLongest = 240;
  return path.size() <= kLongest ? path : path.substr(0, kLongest) + "... (" + std::to_string(path.size()) + " bytes)";
}

// A mesh named explicitly must be a regular file: opening a FIFO to hash it would wait forever, before any child
// or --timeout exists. (Folder scans skip anything else already.)
void require_regular(const fs::path& path, const std::string& where) {
  if (const std::string kind = not_a_regular_file(path.string()); !kind.empty()) throw UsageError(where + ": " + kind);
}

// Whether a list file's entries are relative to its folder: not for a pipe or another special file, nor for a
// descriptor's name (/dev/stdin, /dev/fd/N, /proc/PID/fd/N) even when redirected from a file. Their entries are
// relative to the working directory, where `find` printed them.
bool has_own_folder(const std::string& file) {
  std::error_code ec;
  if (!fs::is_regular_file(file, ec)) return false;
  const fs::path path = fs::path(file).lexically_normal();
  const fs::path parent = path.parent_path();
  return path != "/dev/stdin" && parent != "/dev/fd" &&
         !(parent.filename() == "fd" && parent.parent_path().parent_path() == "/proc");
}

class Collector {
 public:
  explicit Collector(const std::string& output_dir, std::vector<std::string>* skipped) : skipped_(skipped) {
    std::error_code ec;
    output_dir_ = fs::weakly_canonical(output_dir, ec);
  }

  void argument(const std::string& argument) {
    if (!argument.empty() && argument[0] == '@') return list(argument.substr(1));
    std::error_code ec;
    if (fs::is_directory(argument, ec)) return directory(argument);
    if (!fs::exists(argument, ec))
      throw UsageError(shown(argument) + ": no such file or directory", IssueCode::FileNotFound);
    if (is_list_file(argument)) return list(argument);
    require_regular(argument, shown(argument));
    add(argument, fs::path(argument).filename().generic_string());
  }

  std::vector<BatchItem> finish() {
    std::vector<BatchItem> items;
    for (auto& [key, item] : by_key_) items.push_back(std::move(item));
    return items;  // std::map: sorted by key
  }

 private:
  void add(const fs::path& input, const std::string& key) {
    std::error_code ec;
    const fs::path identity = fs::weakly_canonical(input, ec);
    auto [it, inserted] = by_key_.try_emplace(key);
    if (!inserted) {
      if (fs::weakly_canonical(it->second.input, ec) == identity) return;  // the same file reached twice
      throw UsageError("two inputs would write the same asset '" + key + ".vox.h5': " + it->second.input + " and " +
                       input.string() + " (pass their common parent directory, or list them in a list file)");
    }
    it->second.input = input.string();
    it->second.key = key;
    it->second.input_bytes = fs::file_size(input, ec);
    if (ec) it->second.input_bytes = 0;
  }

  void directory(const fs::path& root) {
    std::error_code ec;
    fs::recursive_directory_iterator it(root, fs::directory_options::skip_permission_denied, ec), end;
    if (ec) throw UsageError(root.string() + ": cannot read directory: " + ec.message());
    for (; it != end; it.increment(ec)) {
      if (ec) throw UsageError(root.string() + ": cannot read directory: " + ec.message());
      const fs::path& path = it->path();
      const std::string name = path.filename().string();
      const bool is_dir = it->is_directory(ec);
      if (name.empty() || name[0] == '.' || (is_dir && fs::weakly_canonical(path, ec) == output_dir_)) {
        if (is_dir) it.disable_recursion_pending();  // hidden folders and our own output are not inputs
        continue;
      }
      if (is_dir || !it->is_regular_file(ec) || !bake::is_mesh_file_name(name)) {
        note_skipped(*it, is_dir, name);
        continue;
      }
      add(path, path.lexically_relative(root).generic_string());
    }
  }

  void list(const std::string& file) {
    std::error_code ec;
    if (fs::is_directory(file, ec)) throw UsageError(shown(file) + ": is a folder, not a list file");
    std::ifstream in(file);  // a pipe is fine here: `batch @<(find ...)`
    if (!in) throw UsageError(shown(file) + ": cannot read list file", IssueCode::FileNotFound);
    // `@<(find ...)`, `find ... | voxfmt batch @/dev/stdin`: a pipe's "folder" is /dev/fd, where no entry lies.
    const fs::path base = has_own_folder(file) ? fs::path(file).parent_path() : fs::path();
    std::string line;
    for (size_t number = 1; std::getline(in, line); ++number) {
      const size_t first = line.find_first_not_of(" \t\r");
      if (first == std::string::npos || line[first] == '#') continue;
      const size_t last = line.find_last_not_of(" \t\r");
      const fs::path entry = line.substr(first, last - first + 1);
      const fs::path path = entry.is_absolute() ? entry : base / entry;
      if (fs::is_directory(path, ec)) {
        directory(path);
        continue;
      }
      const std::string where = shown(file) + ":" + std::to_string(number) + ": " + shown(path.string());
      if (!fs::exists(path, ec)) throw UsageError(where + ": no such file or directory", IssueCode::FileNotFound);
      require_regular(path, where);
      const fs::path relative = entry.lexically_normal();
      const bool inside = !entry.is_absolute() && !relative.empty() && *relative.begin() != "..";
      add(path, inside ? relative.generic_string() : entry.filename().generic_string());
    }
  }

  // What a folder scan leaves out that a user may not expect (hidden entries and other files are not noted).
  void note_skipped(const fs::directory_entry& entry, bool is_dir, const std::string& name) {
    if (!skipped_) return;
    std::error_code ec;
    const std::string path = entry.path().string();
    if (is_dir && entry.is_symlink(ec))
      skipped_->push_back(path + ": a link to a folder, not followed");
    else if (is_dir && ::access(entry.path().c_str(), R_OK | X_OK) != 0)
      skipped_->push_back(path + ": a folder that cannot be read");
    else if (!is_dir && entry.is_symlink(ec) && !fs::exists(entry.path(), ec) && bake::is_mesh_file_name(name))
      skipped_->push_back(path + ": a link to nothing");
  }

  fs::path output_dir_;
  std::vector<std::string>* skipped_ = nullptr;
  std::map<std::string, BatchItem> by_key_;
};

// `path` without "." parts and empty ones: "./out/" and "out" name the same outputs in the manifest and the
// messages. ".." stays: after a link to a folder it does not undo the step before it.
fs::path without_dot_parts(const fs::path& path) {
  fs::path out;
  for (const fs::path& part : path)
    if (!part.empty() && part != ".") out /= part;
  return out.empty() ? fs::path(".") : out;
}

}  // namespace

std::vector<BatchItem> collect_inputs(const std::vector<std::string>& inputs, const std::string& output_dir,
                                      std::vector<std::string>* skipped) {
  Collector collector(output_dir, skipped);
  for (const std::string& argument : inputs) collector.argument(argument);
  std::vector<BatchItem> items = collector.finish();
  for (BatchItem& item : items) item.output = without_dot_parts(fs::path(output_dir) / (item.key + ".vox.h5")).string();
  return items;
}

uint64_t shard_hash(const std::string& key) {
  uint64_t hash = 0xcbf29ce484222325ull;  // FNV-1a offset basis and prime (64-bit)
  for (unsigned char c : key) {
    hash ^= c;
    hash *= 0x100000001b3ull;
  }
  return hash;
}

Shard parse_shard(const std::string& text) {
  const size_t slash = text.find('/');
  auto number = [&](const std::string& part, unsigned& out) {
    if (part.empty() || part.size() > 9 || part.find_first_not_of("0123456789") != std::string::npos) return false;
    out = unsigned(std::stoul(part));
    return true;
  };
  Shard shard;
  if (slash == std::string::npos || !number(text.substr(0, slash), shard.index) ||
      !number(text.substr(slash + 1), shard.count) || shard.count == 0 || shard.index >= shard.count)
    throw UsageError("--shard '" + text +
                     "': expected I/N with 0 <= I < N, e.g. 0/4 (Slurm: $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)");
  return shard;
}

}  // namespace voxfmt::cli
