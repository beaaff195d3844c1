// Every asset the plugin has loaded in this process, once per file: MuJoCo's compile-time callbacks see only
// numbers, so an asset is named by its handle here (an index), and every geom naming the same file shares it.
#pragma once

#include <atomic>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "asset_field.h"

namespace voxfmt::mujoco {

/// One file's outcome: the field, or why there is none.
struct CachedAsset {
  std::shared_ptr<const AssetField> field;  ///< null if the load failed
  voxfmt::Error error;                      ///< the reason, if it failed
  std::string path;                         ///< as the model named it
};

class AssetCache {
 public:
  static constexpr int kCapacity = 4096;
  static AssetCache& instance();

  /// The handle of `path`'s entry, loading the file the first time it is named (again if it changed on disk:
  /// the key is the canonical path with the file's size, modification and status-change times; the earlier version
  /// stays loaded, as a model compiled against it may still use it). A failed load is an entry too, so the failure can
  /// be reported where MuJoCo lets a plugin report one (init), and compile and init judge a file alike; it has a
  /// negative handle and takes none of the kCapacity places (a mended file has a new key and loads). Thread-safe.
  ///
  /// `kLoadedIfGone`: where `path` no longer resolves (deleted, moved, or relative to another working directory),
  /// the version last loaded under that name, if any (what a model compiled against it uses).
  static constexpr bool kLoadedIfGone = true;
  int acquire(const std::string& path, bool loaded_if_gone = false);
  /// The entry of a handle, or null for a handle this cache never gave. Lock-free for loaded files.
  const CachedAsset* get(double handle) const;
  /// Files loaded so far (each version of a file baked again while the process runs counts).
  int size() const { return count_.load(std::memory_order_acquire); }

 private:
  int add(std::unique_ptr<CachedAsset> entry);  // under mutex_

  mutable std::mutex mutex_;
  std::unordered_map<std::string, int> handles_;        ///< key -> handle
  std::unordered_map<std::string, int> last_loaded_;    ///< path as named -> its latest loaded handle
  std::vector<std::unique_ptr<CachedAsset>> failures_;  ///< handle -1 - i: the i-th failed key
  std::atomic<const CachedAsset*> entries_[kCapacity] = {};
  std::atomic<int> count_{0};
  std::unique_ptr<CachedAsset> overflow_;  ///< what every path gets once the cache is full
};

}  // namespace voxfmt::mujoco
