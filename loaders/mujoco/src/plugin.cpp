// voxfmt.sdf.asset: a MuJoCo SDF plugin whose distance and gradient come from a voxfmt asset's voxelmap, so a
// part baked once collides in MuJoCo as in Bullet. MJCF:
//   <extension><plugin plugin="voxfmt.sdf.asset"><instance name="part">
//     <config key="file" value="/abs/part.vox.h5"/></instance></plugin></extension>
//   <asset><mesh name="part"><plugin instance="part"/></mesh></asset>
//   <geom type="sdf" mesh="part"><plugin instance="part"/></geom>
// MuJoCo's compile-time callbacks see only the numbers sdf_attribute makes, so the file is loaded there (once
// per file: AssetCache) and its handle is the instance's one number; init finds the same entry by the config's
// path and reports a failed load, the one place a plugin may refuse a model.
#include <mujoco/mujoco.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <functional>
#include <mutex>
#include <new>
#include <random>
#include <string>
#include <unordered_map>
#include <vector>

#include <unistd.h>

#include "asset_cache.h"

namespace {

using voxfmt::mujoco::AssetCache;
using voxfmt::mujoco::AssetField;
using voxfmt::mujoco::CachedAsset;

constexpr const char* kPluginName = "voxfmt.sdf.asset";
constexpr const char* kAttributes[] = {"file"};
constexpr int kAttributeCount = 1;

// A failed load still needs a shape for MuJoCo's compile to reach init, where the failure is reported: a small
// sphere at the origin.
constexpr double kPlaceholderRadius = 0.01;

// MuJoCo makes the geom's mesh by marching cubes over the box sdf_aabb gives, 300 cells across the sum of its
// half-sizes, and takes the geom's bounding box and sphere from that mesh. Cells finer than the voxels add
// triangles (compile time, memory) and no detail the field has, so the box is grown until a cell is a voxel;
// never less than two voxels around the object, so the surface closes inside it. Env VOXFMT_MUJOCO_MESH_CELL
// (metres) asks for another cell size (0: the object's box plus two voxels, MuJoCo's finest mesh).
double aabb_margin(const AssetField& field) {
  double box[6];
  field.aabb(0.0, box);
  const double total = box[3] + box[4] + box[5], h = field.voxel_size();
  static const double cell = [] {
    const char* text = std::getenv("VOXFMT_MUJOCO_MESH_CELL");
    return text ? std::atof(text) : -1.0;
  }();
  const double target = cell >= 0 ? cell : h;
  return std::max(2.0 * h, (150.0 * target - total) / 3.0);
}

// Marching cubes cuts the corners and tips of a surface by up to a cell, and the geom's box and bounding sphere
// come from its mesh: too small, they would let MuJoCo's broad phase skip a pair whose tips touch. So the mesh
// is made of the surface grown by half a cell (the distance less that), which holds the object; the collision
// field is the exact one.
double mesh_offset(const AssetField& field) {
  double box[6];
  field.aabb(aabb_margin(field), box);
  return 0.5 * 2.0 * (box[3] + box[4] + box[5]) / 300.0;
}

// What an instance keeps per mjData is its field, and evaluate must find it from (d, instance) alone. MuJoCo
// keeps d->plugin_data for that, but some copies of an mjData copy that word as bytes (the Python bindings'
// pickle: mj_makeData, whose init runs here, then the saved buffer over it): a pointer there was another
// process's address, or a second owner of the original's and freed twice. So the word is only a hint, a handle
// (this process's nonce, a slot) checked against the slot's owner; the registry, keyed by (mjData, instance), is
// the truth. A handle that is not the mjData's own is looked up by key and mended; destroy frees by key.
struct Slot {  // atomics: a copied handle may name a slot another thread is giving to a new mjData
  std::atomic<const mjData*> d{nullptr};
  std::atomic<int> instance{-1};
  std::atomic<const AssetField*> field{nullptr};
};

class Registry {
 public:
  static Registry& get() {
    static Registry* registry = new Registry;  // never destroyed: mjData may outlive static destructors
    return *registry;
  }

  // The handle of (d, instance)'s slot, now holding `field`; 0 if out of memory or slots.
  uintptr_t add(const mjData* d, int instance, const AssetField* field) {
    try {
      const std::lock_guard<std::mutex> lock(mutex_);
      const Key key{d, instance};
      auto found = slots_.find(key);  // one left by an mjData MuJoCo freed without destroy (a failed init)
      uint32_t index;
      if (found != slots_.end()) {
        index = found->second;
      } else {
        const bool reused = !free_.empty();
        if (reused) {
          index = free_.back();
        } else {
          if (used_ == uint32_t(kChunks) << kChunkBits) return 0;
          index = used_;
          if (!chunks_[index >> kChunkBits].load(std::memory_order_relaxed))
            chunks_[index >> kChunkBits].store(new Slot[size_t(1) << kChunkBits], std::memory_order_release);
        }
        slots_.emplace(key, index);  // may throw: nothing is taken yet
        if (reused)
          free_.pop_back();
        else
          ++used_;
      }
      Slot& slot = *at(index);
      slot.field.store(field, std::memory_order_relaxed);
      slot.instance.store(instance, std::memory_order_relaxed);
      slot.d.store(d, std::memory_order_release);
      return handle(index);
    } catch (const std::bad_alloc&) {
      return 0;
    }
  }

  void remove(const mjData* d, int instance) {
    const std::lock_guard<std::mutex> lock(mutex_);
    const auto found = slots_.find(Key{d, instance});
    if (found == slots_.end()) return;
    Slot& slot = *at(found->second);
    slot.d.store(nullptr, std::memory_order_relaxed);
    slot.instance.store(-1, std::memory_order_relaxed);
    slot.field.store(nullptr, std::memory_order_relaxed);
    try {
      free_.push_back(found->second);
    } catch (const std::bad_alloc&) {  // the slot is lost, not reused
    }
    slots_.erase(found);
  }

  // The field of (d, instance), or null if its init never ran in this process.
  const AssetField* field(const mjData* d, int instance) {
    uintptr_t* word = const_cast<uintptr_t*>(&d->plugin_data[instance]);
    if (const Slot* slot = resolve(__atomic_load_n(word, __ATOMIC_RELAXED)))
      if (slot->d.load(std::memory_order_acquire) == d && slot->instance.load(std::memory_order_relaxed) == instance)
        return slot->field.load(std::memory_order_relaxed);
    uint32_t index;
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      const auto found = slots_.find(Key{d, instance});
      if (found == slots_.end()) return nullptr;
      index = found->second;
    }
    // Mended once: threads of a pool that get here together store the same word.
    __atomic_store_n(word, handle(index), __ATOMIC_RELAXED);
    return at(index)->field.load(std::memory_order_relaxed);
  }

 private:
  struct Key {
    const mjData* d;
    int instance;
    bool operator==(const Key& o) const { return d == o.d && instance == o.instance; }
  };
  struct KeyHash {
    size_t operator()(const Key& k) const {
      return std::hash<const void*>()(k.d) ^ (std::hash<int>()(k.instance) * 0x9E3779B97F4A7C15ull);
    }
  };
  // Slots in chunks that never move or go, so a handle is read without the lock.
  static constexpr int kChunkBits = 10;
  static constexpr uint32_t kChunks = 4096;  // 4M instances alive at once

  Registry() {
    // Another process's handles (a pickle) carry another nonce; a clash only costs a slot check that fails.
    uint64_t seed = uint64_t(std::chrono::steady_clock::now().time_since_epoch().count()) ^ (uint64_t(getpid()) << 32) ^
                    reinterpret_cast<uintptr_t>(this);
    try {
      seed ^= std::random_device()();
    } catch (...) {  // the clock and pid serve
    }
    seed *= 0x9E3779B97F4A7C15ull;
    nonce_ = uint32_t(seed >> 32) | 1u;
  }
  uintptr_t handle(uint32_t index) const { return (uintptr_t(nonce_) << 32) | index; }
  Slot* at(uint32_t index) const {
    return chunks_[index >> kChunkBits].load(std::memory_order_acquire) + (index & ((1u << kChunkBits) - 1));
  }
  const Slot* resolve(uintptr_t handle) const {
    if (uint32_t(uint64_t(handle) >> 32) != nonce_) return nullptr;
    const uint32_t index = uint32_t(handle);
    if (index >= uint32_t(kChunks) << kChunkBits) return nullptr;
    const Slot* chunk = chunks_[index >> kChunkBits].load(std::memory_order_acquire);
    return chunk ? chunk + (index & ((1u << kChunkBits) - 1)) : nullptr;
  }

  uint32_t nonce_ = 1;
  std::atomic<Slot*> chunks_[kChunks] = {};
  std::mutex mutex_;  // the rest
  uint32_t used_ = 0;
  std::vector<uint32_t> free_;
  std::unordered_map<Key, uint32_t, KeyHash> slots_;
};

// MuJoCo's descent asks for the distance at a point, then the gradient there, then the distance again (and for an
// SDF pair alternates between the two geoms): the gradient is computed with the distance and both are kept, per
// thread, for the last few points, so each point costs one lookup. Per thread, not per mjData: with a thread pool
// MuJoCo runs one mjData's collision pairs on several threads at once. A kept point matches only its own mjData,
// instance and field (fields live as long as the process), so one kept past its mjData's end is never mistaken for
// another's.
struct Evaluation {
  const mjData* d = nullptr;
  int instance = -1;
  const AssetField* field = nullptr;
  double point[3] = {NAN, NAN, NAN};
  double distance = 0;
  Eigen::Vector3f direction = Eigen::Vector3f::Zero();  // normalised only if the gradient is asked for
};
constexpr int kKeptEvaluations = 4;  // the last two points of each geom of a pair
thread_local Evaluation t_recent[kKeptEvaluations];
thread_local int t_next = 0;

// Profiling (voxfmt_mujoco_profile): the calls MuJoCo makes, the lookups they cost, and the points looked up,
// so the lookups alone can be replayed and timed apart from MuJoCo's search. Off by default: one predictable
// branch per lookup.
struct Record {
  const AssetField* field;
  double point[3];
  int kind;  // what asked first: sdf_distance (0) or sdf_gradient (1, which also normalises)
};
struct Profile {
  std::mutex mutex;
  uint64_t calls[2] = {0, 0};  // sdf_distance, sdf_gradient
  uint64_t collisions = 0;     // mjc_SDF calls (reset is called once at the start of each)
  uint64_t lookups = 0;
  std::vector<Record> records;  // the first kMaxRecords lookups
};
constexpr size_t kMaxRecords = size_t(1) << 21;
std::atomic<bool> g_profiling{false};
Profile g_profile;

// An mjData whose init never ran in this process (plugin_data copied into one MuJoCo did not make) has no
// field: it is far from everything, said once, rather than a crash.
Evaluation g_nowhere{nullptr, -1, nullptr, {NAN, NAN, NAN}, mjMAXVAL, Eigen::Vector3f::Zero()};
std::atomic<bool> g_said_nowhere{false};

const Evaluation& evaluate(const mjData* d, int instance, const double point[3], int kind) {
  const AssetField* field = Registry::get().field(d, instance);
  if (!field) {
    if (!g_said_nowhere.exchange(true))
      mju_warning("%s: an mjData this process did not make has no field: its geoms collide with nothing", kPluginName);
    return g_nowhere;
  }
  const bool profiling = g_profiling.load(std::memory_order_relaxed);
  if (profiling) {
    const std::lock_guard<std::mutex> lock(g_profile.mutex);
    ++g_profile.calls[kind];
  }
  for (const Evaluation& e : t_recent)
    if (e.point[0] == point[0] && e.point[1] == point[1] && e.point[2] == point[2] && e.d == d &&
        e.instance == instance && e.field == field)
      return e;
  if (profiling) {
    const std::lock_guard<std::mutex> lock(g_profile.mutex);
    ++g_profile.lookups;
    try {
      if (g_profile.records.size() < kMaxRecords)
        g_profile.records.push_back({field, {point[0], point[1], point[2]}, kind});
    } catch (const std::bad_alloc&) {  // the profile keeps fewer points; the lookup goes on
    }
  }
  Evaluation& e = t_recent[t_next];
  t_next = (t_next + 1) % kKeptEvaluations;
  e.d = d, e.instance = instance, e.field = field;
  for (int a = 0; a < 3; ++a) e.point[a] = point[a];
  e.distance = field->evaluate_raw(point, e.direction);
  return e;
}

const AssetField* field_of(const mjtNum* attributes) {
  const CachedAsset* entry = AssetCache::instance().get(attributes[0]);
  return entry ? entry->field.get() : nullptr;
}

int nstate(const mjModel*, int) { return 0; }

// The field of the file named `path` through the cache (loading it the first time), or null with why in `reason`
// ("CODE: message"). No exception may cross MuJoCo's C frames (unwinding through them crashes): every failure,
// memory included, comes back as a reason.
const AssetField* field_named(const char* path, bool loaded_if_gone, std::string& reason) {
  try {
    const CachedAsset* entry =
        AssetCache::instance().get(AssetCache::instance().acquire(path ? path : "", loaded_if_gone));
    if (entry && entry->field) return entry->field.get();  // cache entries live as long as the process
    reason = entry ? entry->error.describe() : std::string("INTERNAL: no cache entry");
  } catch (const std::bad_alloc&) {
    reason = "OUT_OF_MEMORY: not enough memory for the asset's field";
  } catch (const std::exception& e) {
    reason = std::string("INTERNAL: ") + e.what();
  } catch (...) {
    reason = "INTERNAL: unknown failure";
  }
  return nullptr;
}

// An mjData made from a compiled model (MjData, mj_copyModel, mj_copyData) reaches init; the file it names may be
// gone by then (a temporary folder cleaned up, a relative name after a change of working directory that no longer
// resolves): the version this process last loaded under that name serves, as it serves a compile then.
int init(const mjModel* m, mjData* d, int instance) {
  const char* file = mj_getPluginConfig(m, instance, "file");
  std::string reason;
  if (const AssetField* field = field_named(file, AssetCache::kLoadedIfGone, reason)) {
    if ((d->plugin_data[instance] = Registry::get().add(d, instance, field))) return 0;
    reason = "OUT_OF_MEMORY: not enough memory for the plugin's instance";
  }
  mju_warning("%s: cannot use '%s': %s", kPluginName, file ? file : "", reason.c_str());
  return -1;
}

// mj_copyData keeps the destination's own plugin_data (made by its init): nothing to copy. By key, not by the
// word, which may be a copy of another mjData's.
void destroy(mjData* d, int instance) {
  Registry::get().remove(d, instance);
  d->plugin_data[instance] = 0;
}

// mjc_SDF calls reset and compute on every SDF collision (counters for visualisation); there is nothing to do.
void reset(const mjModel*, mjtNum*, void*, int) {
  if (g_profiling.load(std::memory_order_relaxed)) {
    const std::lock_guard<std::mutex> lock(g_profile.mutex);
    ++g_profile.collisions;
  }
}
void compute(const mjModel*, mjData*, int, int) {}

mjtNum sdf_distance(const mjtNum point[3], const mjData* d, int instance) {
  return evaluate(d, instance, point, 0).distance;
}

void sdf_gradient(mjtNum gradient[3], const mjtNum point[3], const mjData* d, int instance) {
  const Evaluation& e = evaluate(d, instance, point, 1);
  if (e.field)
    e.field->unit_gradient(e.direction, point, gradient);
  else
    gradient[0] = gradient[1] = gradient[2] = 0;
}

mjtNum sdf_staticdistance(const mjtNum point[3], const mjtNum* attributes) {
  if (const AssetField* field = field_of(attributes)) {
    Eigen::Vector3f direction;
    return field->evaluate_raw(point, direction) - mesh_offset(*field);  // a few flops next to the lookup
  }
  return std::sqrt(point[0] * point[0] + point[1] * point[1] + point[2] * point[2]) - kPlaceholderRadius;
}

void sdf_attribute(mjtNum attributes[], const char* name[], const char* value[]) {
  const char* file = "";
  for (int i = 0; i < kAttributeCount; ++i)
    if (name[i] && std::strcmp(name[i], "file") == 0 && value[i]) file = value[i];
  try {
    attributes[0] = AssetCache::instance().acquire(file, AssetCache::kLoadedIfGone);
  } catch (...) {  // the placeholder shape; init says why
    attributes[0] = NAN;
  }
}

void sdf_aabb(mjtNum aabb[6], const mjtNum* attributes) {
  if (const AssetField* field = field_of(attributes)) {
    field->aabb(aabb_margin(*field), aabb);
    return;
  }
  for (int a = 0; a < 3; ++a) {
    aabb[a] = 0;
    aabb[3 + a] = 2 * kPlaceholderRadius;
  }
}

__attribute__((constructor)) void register_plugin() {
  // The library is linked against one MuJoCo release (its soname carries the version); a header and library
  // that disagree would mean a broken installation.
  if (mj_version() != mjVERSION_HEADER) {
    mju_warning("%s: built for MuJoCo %d, loaded into %d: not registered", kPluginName, mjVERSION_HEADER, mj_version());
    return;
  }
  // A second copy of this library (another path, a copy in mujoco's plugin folder) must not register again:
  // MuJoCo would raise a fatal error from inside dlopen.
  int slot = -1;
  if (mjp_getPlugin(kPluginName, &slot)) return;
  mjpPlugin plugin;
  mjp_defaultPlugin(&plugin);
  plugin.name = kPluginName;
  plugin.capabilityflags = mjPLUGIN_SDF;
  plugin.nattribute = kAttributeCount;
  plugin.attributes = kAttributes;
  plugin.nstate = nstate;
  plugin.init = init;
  plugin.destroy = destroy;
  plugin.reset = reset;
  plugin.compute = compute;
  plugin.sdf_distance = sdf_distance;
  plugin.sdf_gradient = sdf_gradient;
  plugin.sdf_staticdistance = sdf_staticdistance;
  plugin.sdf_attribute = sdf_attribute;
  plugin.sdf_aabb = sdf_aabb;
  mjp_registerPlugin(&plugin);
}

}  // namespace

// A small C interface for Python (voxfmt.mujoco) and the tests: what the plugin was built against, and the
// field it gives MuJoCo, evaluated at points.
extern "C" {

__attribute__((visibility("default"))) int voxfmt_mujoco_built_version() { return mjVERSION_HEADER; }

/// Bytes of the field the plugin holds for the asset at `path` (loading it through the cache), or -1 if it cannot.
__attribute__((visibility("default"))) long long voxfmt_mujoco_field_bytes(const char* path) {
  std::string reason;
  const AssetField* field = field_named(path, false, reason);
  return field ? static_cast<long long>(field->memory_bytes()) : -1;
}

/// Files the plugin has loaded in this process: one per file (and version), however many geoms name it.
__attribute__((visibility("default"))) int voxfmt_mujoco_loaded_files() { return AssetCache::instance().size(); }

/// Distances (n) and unit gradients (n x 3, may be null) of the asset at `path` at `points` (n x 3, asset frame,
/// metres), through the plugin's cache. Returns 0, or -1 with the voxfmt error's "CODE: message" in `error`.
__attribute__((visibility("default"))) int voxfmt_mujoco_evaluate(const char* path, int n, const double* points,
                                                                  double* distances, double* gradients, char* error,
                                                                  int error_size) {
  std::string reason;
  const AssetField* field = field_named(path, false, reason);
  if (!field) {
    if (error && error_size > 0) std::snprintf(error, size_t(error_size), "%s", reason.c_str());
    return -1;
  }
  for (int i = 0; i < n; ++i) distances[i] = field->evaluate(points + 3 * i, gradients ? gradients + 3 * i : nullptr);
  return 0;
}

/// Profiling of the lookups: `enable` 1 starts afresh, 0 stops. `out` (may be null) gets the calls of
/// sdf_distance and sdf_gradient since the start, the lookups they cost (calls not answered by an instance's
/// last evaluations), and the nanoseconds the recorded lookups (the first 2^21) take replayed in a loop without
/// MuJoCo (best of three), scaled to all of them, and the SDF collisions MuJoCo ran (pair tests whose second geom
/// is this plugin's: mjc_SDF calls reset first).
__attribute__((visibility("default"))) void voxfmt_mujoco_profile(int enable, double out[5]) {
  g_profiling.store(false);
  const std::lock_guard<std::mutex> lock(g_profile.mutex);
  if (out) {
    out[0] = double(g_profile.calls[0]);
    out[1] = double(g_profile.calls[1]);
    out[2] = double(g_profile.lookups);
    double best = 0, sink = 0;
    for (int round = 0; round < 3; ++round) {
      const auto start = std::chrono::steady_clock::now();
      for (const Record& r : g_profile.records) {
        Eigen::Vector3f direction;
        sink += r.field->evaluate_raw(r.point, direction);
        if (r.kind == 1) {
          double gradient[3];
          r.field->unit_gradient(direction, r.point, gradient);
          sink += gradient[0];
        }
      }
      const double ns = std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - start).count();
      best = round == 0 ? ns : std::min(best, ns);
    }
    const double scale = g_profile.records.empty() ? 0.0 : double(g_profile.lookups) / double(g_profile.records.size());
    out[3] = best * scale + (sink == 1e300 ? 1 : 0);  // the sum keeps the loop from being optimised away
    out[4] = double(g_profile.collisions);
  }
  g_profile.calls[0] = g_profile.calls[1] = g_profile.lookups = g_profile.collisions = 0;
  g_profile.records.clear();
  try {
    if (enable) g_profile.records.reserve(size_t(1) << 16);
  } catch (const std::bad_alloc&) {  // records grow as they can
  }
  g_profiling.store(enable != 0);
}

}  // extern "C"
