// Batched contact queries on a CUDA device: thousands of environments, each a pair of assets at a pair of poses,
// in one call, with the assets uploaded once and shared by every environment. The device runs the query core the
// CPU runtime runs (the same pruning, the same lookups in the same bricks), so its contacts are the CPU's.
// Built when a CUDA compiler is found (CMake option VOXFMT_CUDA); `available()` says whether this process can use
// a device at all.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "voxfmt/result.h"
#include "voxfmt/runtime/collision_object.h"

namespace voxfmt::gpu {

/// Whether a CUDA device can be used by this process; if not, `why` says what is missing (no driver, no device).
bool available(std::string* why = nullptr);
/// The name of the current CUDA device (e.g. "NVIDIA H100 80GB HBM3"), or empty.
std::string device_name();

/// E environments: device pointers, row-major.
struct Environments {
  size_t count = 0;
  const float* poses_a = nullptr;  ///< E x 4 x 4 body-to-world matrices of A (rigid: else error 2..5)
  const float* poses_b = nullptr;  ///< E x 4 x 4 of B
  const int32_t* pair = nullptr;   ///< E indices into the scene's pairs, or nullptr: pair 0 for every one
  double proximity = 0.0;          ///< metres: also report points outside but nearer than this (negative depth)
  double stiffness = 1.0;          ///< N/m of the penalty wrench
};

/// Per-environment outputs: device pointers the caller sized (only `count` is required). Contacts: E x
/// `max_contacts` (points and normals E x max_contacts x 3); the contacts that did not fit are counted in
/// `overflow`, never dropped silently.
struct Outputs {
  int32_t* count = nullptr;     ///< E: contacts found
  float* max_depth = nullptr;   ///< E: metres, 0 without penetration
  float* force = nullptr;       ///< E x 3: on A, sum of stiffness * depth * normal over penetrating contacts
  float* torque = nullptr;      ///< E x 3: on A, about A's centre of mass in the world
  int32_t* overflow = nullptr;  ///< E: contacts found beyond max_contacts
  int32_t* error = nullptr;     ///< E: 0, or why the environment has no result (1 tree too deep, 2..5 bad pose,
                                ///< 6 pair out of range)
  uint32_t max_contacts = 0;
  float* points = nullptr;
  float* normals = nullptr;
  float* depths = nullptr;
  int32_t* point_index = nullptr;
  uint8_t* point_of_b = nullptr;
};

/// Assets resident on the current CUDA device and the pairs an environment may hold.
class Scene {
 public:
  using Pair = std::array<uint32_t, 2>;  ///< (A, B): indices into the scene's assets
  /// Uploads `assets` (their bricks, lattice and tree as the runtime holds them) once.
  static Result<std::shared_ptr<Scene>> upload(
      const std::vector<std::shared_ptr<const runtime::CollisionObject>>& assets, const std::vector<Pair>& pairs);
  ~Scene();
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  /// Device memory the assets take, in all and one by one (the pair tables aside).
  size_t device_bytes() const;
  size_t asset_device_bytes(size_t asset) const { return asset_bytes_.at(asset); }
  size_t pair_count() const { return pairs_; }

  /// Queues every environment on `stream` (a cudaStream_t; nullptr = the default stream) and returns at once:
  /// nothing is allocated or synchronised, so the call can be captured in a CUDA graph. An error only when the
  /// launch itself fails (BAD_OPTION for a missing `count` output).
  Status contacts(const Environments& in, const Outputs& out, void* stream = nullptr) const;

 private:
  Scene() = default;
  struct Device;
  std::unique_ptr<Device> device_;
  std::vector<size_t> asset_bytes_;
  size_t pairs_ = 0;
};

}  // namespace voxfmt::gpu
