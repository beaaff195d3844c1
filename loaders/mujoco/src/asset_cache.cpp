#include "asset_cache.h"

#include <sys/stat.h>

#include <filesystem>
#include <new>

namespace voxfmt::mujoco {
namespace {

namespace fs = std::filesystem;

// The canonical path with the file's size, modification and status-change times: a file baked again is loaded
// again, and so is one whose load failed once its permissions or content changed (the status-change time moves
// on any write, chmod or rename, and no user can set it back). A path that does not resolve is keyed as written
// (its entry holds the error; once the file exists it has a new key).
std::string key_of(const std::string& path) {
  std::error_code error;
  const fs::path canonical = fs::canonical(path, error);
  if (error) return "?" + path;
  struct stat status {};
  if (::stat(canonical.c_str(), &status) != 0) return "?" + path;
  return canonical.string() + '\n' + std::to_string(status.st_size) + '\n' + std::to_string(status.st_mtim.tv_sec) +
         '.' + std::to_string(status.st_mtim.tv_nsec) + '\n' + std::to_string(status.st_ctim.tv_sec) + '.' +
         std::to_string(status.st_ctim.tv_nsec);
}

std::unique_ptr<CachedAsset> load_entry(const std::string& path) {
  auto entry = std::make_unique<CachedAsset>();
  entry->path = path;
  if (path.empty()) {
    entry->error = voxfmt::Error(voxfmt::IssueCode::BadOption, "the plugin instance has no config key 'file'");
    return entry;
  }
  try {
    auto field = AssetField::load(path);
    if (!field) {
      entry->error = field.error();
      return entry;
    }
    entry->field = std::move(field.value());
  } catch (const std::bad_alloc&) {  // the field is built here, in the caller's process, beyond the read's budget
    entry->error = voxfmt::Error(voxfmt::IssueCode::OutOfMemory, path + ": not enough memory for the asset's field");
  }
  return entry;
}

}  // namespace

AssetCache& AssetCache::instance() {
  static AssetCache cache;  // never destroyed before MuJoCo's models: the process ends with it
  return cache;
}

int AssetCache::acquire(const std::string& path, bool loaded_if_gone) {
  const std::string key = key_of(path);
  std::lock_guard<std::mutex> lock(mutex_);
  if (loaded_if_gone && key[0] == '?') {
    const auto loaded = last_loaded_.find(path);
    if (loaded != last_loaded_.end()) return loaded->second;
  }
  const auto found = handles_.find(key);
  if (found != handles_.end()) {
    if (found->second >= 0 && found->second < kCapacity - 1) last_loaded_[path] = found->second;
    return found->second;
  }
  // Full: no file is read (each naming is told so, without a read under the lock).
  if (count_.load(std::memory_order_relaxed) >= kCapacity - 1) return add(nullptr);
  std::unique_ptr<CachedAsset> entry = load_entry(path);
  int handle;
  if (!entry->field) {  // no slot: a failure is kept apart, under a negative handle, for as long as the key holds
    failures_.push_back(std::move(entry));
    handle = -int(failures_.size());
  } else {
    handle = add(std::move(entry));
    if (handle == kCapacity - 1) return handle;  // full: not remembered, so every naming is told so
    last_loaded_[path] = handle;
  }
  handles_.emplace(key, handle);
  return handle;
}

int AssetCache::add(std::unique_ptr<CachedAsset> entry) {
  const int n = count_.load(std::memory_order_relaxed);
  if (n < kCapacity - 1) {
    entries_[n].store(entry.release(), std::memory_order_release);
    count_.store(n + 1, std::memory_order_release);
    return n;
  }
  // The last slot says why no more files are loaded.
  if (!overflow_) {
    overflow_ = std::make_unique<CachedAsset>();
    overflow_->error =
        voxfmt::Error(voxfmt::IssueCode::OutOfMemory, "the plugin holds " + std::to_string(kCapacity - 1) +
                                                          " asset files already, the most one process may load");
    entries_[kCapacity - 1].store(overflow_.get(), std::memory_order_release);
  }
  return kCapacity - 1;
}

const CachedAsset* AssetCache::get(double handle) const {
  if (handle < 0) {  // a failure (rare: under the lock)
    std::lock_guard<std::mutex> lock(mutex_);
    const double index = -handle - 1;
    if (!(index < double(failures_.size())) || index != double(int(index))) return nullptr;
    return failures_[size_t(index)].get();
  }
  if (!(handle >= 0 && handle < kCapacity) || handle != double(int(handle))) return nullptr;  // also NaN
  return entries_[int(handle)].load(std::memory_order_acquire);
}

}  // namespace voxfmt::mujoco
