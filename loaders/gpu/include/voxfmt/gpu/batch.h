// Batched contact queries on a CUDA device: thousands of environments, each a pair of assets at a pair of poses,
// in one call, with the assets uploaded once and shared by every environment. The device runs the query core the
// CPU runtime runs (the same pruning, the same lookups in the same bricks, level by level as the runtime walks), so
// its contacts are the CPU's, in the CPU's order.
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
#include "voxfmt/runtime/query.h"

namespace voxfmt::gpu {

/// Whether a CUDA device can be used by this process; if not, `why` says what is missing (no driver, no device).
bool available(std::string* why = nullptr);
/// The name of the current CUDA device (e.g. "NVIDIA H100 80GB HBM3"), or empty.
std::string device_name();
/// The CUDA device whose memory `pointer` addresses (device or managed memory, or host memory mapped for CUDA):
/// how arrays that show only their address (`__cuda_array_interface__`) tell their device. -1 and `why` when CUDA
/// cannot say (ordinary host memory, no driver).
int device_of(const void* pointer, std::string* why = nullptr);
/// This thread's current CUDA device, or -1 (`why`) when none can be used.
int current_device(std::string* why = nullptr);
/// Makes `device` this thread's current CUDA device (what uploads and launches use); false and `why` on failure.
bool make_current(int device, std::string* why = nullptr);
/// Waits until the work queued on `stream` (a cudaStream_t as an integer; 0 the legacy default) is done: what a
/// caller reading the outputs on another stream needs first. False and `why` on failure.
bool synchronize_stream(uintptr_t stream, std::string* why = nullptr);

/// E environments and their outputs: the CPU batch's (runtime::BatchScene), as device pointers. The device takes
/// float32 poses only (`poses_a`, `poses_b`; the `_f64` ones must be null).
using Environments = runtime::BatchEnvironments;
using Outputs = runtime::BatchOutputs;

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
  /// Device memory a launch of 0 or more environments takes besides (the walk's frontiers, one per resident block,
  /// as wide as the scene's widest tree level; from the device's default memory pool, which keeps it between
  /// launches). CGAL's bunny at 35,000 points: 4,557 ranges of 20 bytes, twice, a block: 120 MB on an H200, which
  /// keeps 660 blocks (5 a multiprocessor at 96 registers a thread, as Nsight Compute read it there).
  size_t frontier_bytes() const;
  size_t asset_device_bytes(size_t asset) const { return asset_bytes_.at(asset); }
  size_t pair_count() const { return pairs_; }

  /// Queues every environment on `stream` (a cudaStream_t; nullptr = the default stream) and returns at once: a
  /// block of threads per environment, the walk's frontier from the stream's memory pool (stream ordered), nothing
  /// synchronised, so the call can be captured in a CUDA graph and calls on several streams do not share memory.
  /// An error only when the launch itself fails (BAD_OPTION for a missing `count` output, float64 poses, or a
  /// current CUDA device other than the one the scene was uploaded to).
  Status contacts(const Environments& in, const Outputs& out, void* stream = nullptr) const;

 private:
  Scene() = default;
  struct Device;
  std::unique_ptr<Device> device_;
  std::vector<size_t> asset_bytes_;
  size_t pairs_ = 0;
};

}  // namespace voxfmt::gpu
