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

#include <x86intrin.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>

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

// The box MuJoCo's marching cubes samples (300 cells across the sum of its half-sizes): the object's bounds
// with room for two cells or two voxels, so the surface closes inside it.
double aabb_margin(const AssetField& field) {
  double box[6];
  field.aabb(0.0, box);
  return std::max(2.0 * field.voxel_size(), 4.0 / 300.0 * (box[3] + box[4] + box[5]));
}

// Profiling (voxfmt_mujoco_profile): how many lookups MuJoCo's search makes and the time they take, to tell the
// lookups' share of a step from the search's own. Off by default: one predictable branch per call.
std::atomic<bool> g_profiling{false};
std::atomic<uint64_t> g_calls[2];   // distance, gradient
std::atomic<uint64_t> g_cycles[2];  // time-stamp counter cycles inside them

struct Profile {
  explicit Profile(int kind) : kind_(kind), start_(g_profiling.load(std::memory_order_relaxed) ? __rdtsc() : 0) {}
  ~Profile() {
    if (!start_) return;
    g_calls[kind_].fetch_add(1, std::memory_order_relaxed);
    g_cycles[kind_].fetch_add(__rdtsc() - start_, std::memory_order_relaxed);
  }
  int kind_;
  uint64_t start_;
};

const AssetField* field_of(const mjData* d, int instance) {
  return reinterpret_cast<const AssetField*>(d->plugin_data[instance]);
}

const AssetField* field_of(const mjtNum* attributes) {
  const CachedAsset* entry = AssetCache::instance().get(attributes[0]);
  return entry ? entry->field.get() : nullptr;
}

int nstate(const mjModel*, int) { return 0; }

int init(const mjModel* m, mjData* d, int instance) {
  const char* file = mj_getPluginConfig(m, instance, "file");
  const CachedAsset* entry = AssetCache::instance().get(AssetCache::instance().acquire(file ? file : ""));
  if (!entry || !entry->field) {
    const std::string reason = entry ? entry->error.describe() : std::string("INTERNAL: no cache entry");
    mju_warning("%s: cannot use '%s': %s", kPluginName, file ? file : "", reason.c_str());
    return -1;
  }
  // Cache entries live as long as the process, so the instance keeps a plain pointer: nothing to copy or free.
  d->plugin_data[instance] = reinterpret_cast<uintptr_t>(entry->field.get());
  return 0;
}

// mjc_SDF calls reset and compute on every SDF collision (counters for visualisation); there is nothing to do.
void reset(const mjModel*, mjtNum*, void*, int) {}
void compute(const mjModel*, mjData*, int, int) {}

mjtNum sdf_distance(const mjtNum point[3], const mjData* d, int instance) {
  const Profile profile(0);
  return field_of(d, instance)->distance(point);
}

void sdf_gradient(mjtNum gradient[3], const mjtNum point[3], const mjData* d, int instance) {
  const Profile profile(1);
  field_of(d, instance)->distance_and_gradient(point, gradient);
}

mjtNum sdf_staticdistance(const mjtNum point[3], const mjtNum* attributes) {
  if (const AssetField* field = field_of(attributes)) return field->distance(point);
  return std::sqrt(point[0] * point[0] + point[1] * point[1] + point[2] * point[2]) - kPlaceholderRadius;
}

void sdf_attribute(mjtNum attributes[], const char* name[], const char* value[]) {
  const char* file = "";
  for (int i = 0; i < kAttributeCount; ++i)
    if (name[i] && std::strcmp(name[i], "file") == 0 && value[i]) file = value[i];
  attributes[0] = AssetCache::instance().acquire(file);
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
  mjpPlugin plugin;
  mjp_defaultPlugin(&plugin);
  plugin.name = kPluginName;
  plugin.capabilityflags = mjPLUGIN_SDF;
  plugin.nattribute = kAttributeCount;
  plugin.attributes = kAttributes;
  plugin.nstate = nstate;
  plugin.init = init;
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

/// Distances (n) and unit gradients (n x 3, may be null) of the asset at `path` at `points` (n x 3, asset frame,
/// metres), through the plugin's cache. Returns 0, or -1 with the voxfmt error's "CODE: message" in `error`.
__attribute__((visibility("default"))) int voxfmt_mujoco_evaluate(const char* path, int n, const double* points,
                                                                  double* distances, double* gradients, char* error,
                                                                  int error_size) {
  const CachedAsset* entry = AssetCache::instance().get(AssetCache::instance().acquire(path ? path : ""));
  if (!entry || !entry->field) {
    const std::string reason = entry ? entry->error.describe() : std::string("INTERNAL: no cache entry");
    if (error && error_size > 0) std::snprintf(error, size_t(error_size), "%s", reason.c_str());
    return -1;
  }
  for (int i = 0; i < n; ++i)
    distances[i] = gradients ? entry->field->distance_and_gradient(points + 3 * i, gradients + 3 * i)
                             : entry->field->distance(points + 3 * i);
  return 0;
}

/// Profiling of the lookups MuJoCo makes: `enable` 1 starts (from zero), 0 stops; `out` (may be null) gets the
/// calls of sdf_distance and sdf_gradient since the start and the nanoseconds spent in each (the time-stamp
/// counter, scaled by the wall clock of the interval).
__attribute__((visibility("default"))) void voxfmt_mujoco_profile(int enable, double out[4]) {
  using Clock = std::chrono::steady_clock;
  static Clock::time_point wall_start;
  static uint64_t tsc_start = 0;
  if (out) {
    const double ns_per_cycle =
        std::chrono::duration<double, std::nano>(Clock::now() - wall_start).count() / double(__rdtsc() - tsc_start);
    for (int k = 0; k < 2; ++k) {
      out[k] = double(g_calls[k].load());
      out[2 + k] = double(g_cycles[k].load()) * ns_per_cycle;
    }
  }
  if (enable) {
    for (int k = 0; k < 2; ++k) g_calls[k] = g_cycles[k] = 0;
    wall_start = Clock::now();
    tsc_start = __rdtsc();
  }
  g_profiling.store(enable != 0);
}

}  // extern "C"
