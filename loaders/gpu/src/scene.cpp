// The host side of the CUDA batch: what goes up to the device (each asset's arrays once, the bodies and pair
// tables), and the launch. No CUDA header here (device.h is plain C++).
#include "voxfmt/gpu/batch.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "device.h"
#include "traversal/eigen.h"

namespace voxfmt::gpu {

namespace core = runtime::core;

struct Scene::Device {
  std::vector<void*> allocations;
  core::Body* bodies = nullptr;
  uint32_t* pair_a = nullptr;
  uint32_t* pair_b = nullptr;
  unsigned resident_blocks = 0;
  uint32_t frontier_capacity = 1;  ///< core::frontier_capacity of the scene's shells
  int ordinal = -1;                ///< the CUDA device the scene was uploaded to (current at upload)
  ~Device() {
    for (void* p : allocations) device::release(p);
  }
  // Uploads `bytes` and keeps the allocation; nullptr on failure.
  template <class T>
  T* upload(const T* host, size_t count, std::string& error) {
    void* p = device::copy_to_device(host, count * sizeof(T), error);
    if (p) allocations.push_back(p);
    return static_cast<T*>(p);
  }

  // Uploads `asset`'s arrays, pointing `body` at them, and widens the frontier for its tree; the bytes taken.
  size_t upload_body(const runtime::CollisionObject& asset, core::Body& body, std::string& error) {
    size_t bytes = 0;
    if (body.has_field) {
      const runtime::SparseVoxelmap& map = asset.voxelmap();
      const size_t bricks = map.brick_count();
      // Value bricks with an apron: a sample's eight corners in one brick wherever the neighbours are stored.
      const std::vector<int16_t> apron = core::apron_codes(body.field, map.value_brick_count());
      size_t lattice = 1;
      for (int a = 0; a < 3; ++a) lattice *= size_t(body.field.lattice_dims[a]);
      body.field.bricks = upload(body.field.bricks, bricks, error);
      body.field = core::with_apron(body.field, upload(apron.data(), apron.size(), error));
      body.field.lattice = upload(body.field.lattice, lattice, error);
      bytes += bricks * sizeof(int32_t) + apron.size() * sizeof(int16_t) + lattice * sizeof(uint16_t);
    }
    if (body.has_shell) {
      const core::Shell* shell = &body.shell;
      frontier_capacity = std::max(frontier_capacity, core::frontier_capacity(&shell, 1));
      const size_t n = body.shell.count;
      body.shell.nodes = upload(body.shell.nodes, n, error);
      body.shell.points = upload(body.shell.points, n, error);
      body.shell.normals = upload(body.shell.normals, n, error);
      bytes += n * (sizeof(core::Node) + 2 * sizeof(core::Vec3));
    }
    return bytes;
  }
};

bool available(std::string* why) {
  const std::string reason = device::unavailable_reason();
  if (why) *why = reason;
  return reason.empty();
}

std::string device_name() { return device::device_name(); }

int device_of(const void* pointer, std::string* why) {
  std::string error;
  const int device = device::device_of(pointer, error);
  if (why) *why = error;
  return device;
}

int current_device(std::string* why) {
  std::string error;
  const int device = device::current_device(error);
  if (why) *why = error;
  return device;
}

bool make_current(int device, std::string* why) {
  const std::string error = device::make_current(device);
  if (why) *why = error;
  return error.empty();
}

bool synchronize_stream(uintptr_t stream, std::string* why) {
  const std::string error = device::synchronize_stream(stream);
  if (why) *why = error;
  return error.empty();
}

Result<std::shared_ptr<Scene>> Scene::upload(const std::vector<std::shared_ptr<const runtime::CollisionObject>>& assets,
                                             const std::vector<Pair>& pairs) {
  std::string why;
  if (!available(&why)) return Error{IssueCode::Internal, "no CUDA device for the batch: " + why};
  if (assets.empty() || pairs.empty()) return Error{IssueCode::BadOption, "a scene needs assets and pairs"};
  std::vector<uint32_t> pair_a, pair_b;
  for (const Pair& p : pairs) {
    if (p[0] >= assets.size() || p[1] >= assets.size())
      return Error{IssueCode::BadOption, "a pair names an asset the scene does not have"};
    pair_a.push_back(p[0]);
    pair_b.push_back(p[1]);
  }
  std::shared_ptr<Scene> scene(new Scene);
  scene->device_ = std::make_unique<Device>();
  scene->pairs_ = pairs.size();
  Device& d = *scene->device_;
  d.ordinal = current_device(&why);
  if (d.ordinal < 0) return Error{IssueCode::Internal, "no current CUDA device for the batch: " + why};
  std::vector<core::Body> bodies;
  std::string error;
  for (const auto& asset : assets) {
    if (!asset) return Error{IssueCode::BadOption, "a scene's asset is null"};
    core::Body body = core::body_of(*asset);  // host pointers, replaced by device ones
    const size_t bytes = d.upload_body(*asset, body, error);
    if (!error.empty()) return Error{IssueCode::OutOfMemory, "cannot upload an asset to the device: " + error};
    bodies.push_back(body);
    scene->asset_bytes_.push_back(bytes);
  }
  d.bodies = d.upload(bodies.data(), bodies.size(), error);
  d.pair_a = d.upload(pair_a.data(), pair_a.size(), error);
  d.pair_b = d.upload(pair_b.data(), pair_b.size(), error);
  if (!error.empty()) return Error{IssueCode::OutOfMemory, "cannot upload the scene's tables: " + error};
  d.resident_blocks = device::resident_blocks(error);
  if (d.resident_blocks == 0) return Error{IssueCode::Internal, "cannot size the batch's grid: " + error};
  error = device::keep_in_pool(scene->frontier_bytes());
  if (!error.empty()) return Error{IssueCode::Internal, "cannot configure the device's memory pool: " + error};
  return scene;
}

Scene::~Scene() = default;

size_t Scene::frontier_bytes() const {
  return size_t(device_->resident_blocks) * 2 * device_->frontier_capacity * sizeof(core::OpenRange);
}

size_t Scene::device_bytes() const {
  size_t total = 0;
  for (size_t b : asset_bytes_) total += b;
  return total;
}

Status Scene::contacts(const Environments& in, const Outputs& out, void* stream) const {
  // Judged as the CPU batch judges them (runtime::BatchScene): a NaN proximity culled every root on the device.
  if (!(std::isfinite(in.proximity) && in.proximity >= 0))
    return Error{IssueCode::BadOption, "batch: proximity must be finite and >= 0"};
  if (!(std::isfinite(in.stiffness) && in.stiffness >= 0))
    return Error{IssueCode::BadOption, "batch: stiffness must be finite and >= 0"};
  if (in.tie != runtime::DirectionTie::APoints)
    return Error{IssueCode::BadOption, "the device batch gives ties to A's points (addresses are the host's)"};
  if (in.count == 0) return Status::success();  // nothing to launch (empty arrays may have null pointers)
  // Launched on another device, the kernel would read the scene's arrays through pointers of its own device.
  std::string why;
  if (const int current = current_device(&why); current != device_->ordinal)
    return Error{IssueCode::BadOption, "the scene lives on CUDA device " + std::to_string(device_->ordinal) +
                                           ", the current one is " +
                                           (current < 0 ? "none (" + why + ")" : std::to_string(current)) +
                                           ": make it current (cudaSetDevice) before contacts()"};
  if (!out.count) return Error{IssueCode::BadOption, "the batch needs a `count` output"};
  if (in.poses_a_f64 || in.poses_b_f64)
    return Error{IssueCode::BadOption, "the device batch takes float32 poses (poses_a, poses_b)"};
  if (!in.poses_a || !in.poses_b) return Error{IssueCode::BadOption, "the batch needs poses_a and poses_b"};
  if (in.interpolation != runtime::Interpolation::Trilinear)
    return Error{IssueCode::BadOption, "the device batch reads distances trilinearly only (tricubic: the CPU batch)"};
  core::BatchInputs<float> inputs;
  inputs.bodies = device_->bodies;
  inputs.pair_a = device_->pair_a;
  inputs.pair_b = device_->pair_b;
  inputs.pair_count = uint32_t(pairs_);
  inputs.pair_index = in.pair;
  inputs.poses_a = in.poses_a;
  inputs.poses_b = in.poses_b;
  inputs.environments = in.count;
  inputs.proximity = in.proximity;
  inputs.stiffness = in.stiffness;
  core::BatchOutputs outputs;
  outputs.count = out.count;
  outputs.max_depth = out.max_depth;
  outputs.force = out.force;
  outputs.torque = out.torque;
  outputs.overflow = out.overflow;
  outputs.error = out.error;
  outputs.contacts = {out.points, out.normals, out.depths, out.point_index, out.point_of_b, out.max_contacts};
  const std::string failure =
      device::launch(inputs, outputs, device_->resident_blocks, device_->frontier_capacity, stream);
  if (!failure.empty())  // the frontier's memory is taken per launch: the device's memory can run out there
    return Error{failure.find("out of memory") != std::string::npos ? IssueCode::OutOfMemory : IssueCode::Internal,
                 "the batch's kernel did not start: " + failure};
  return Status::success();
}

}  // namespace voxfmt::gpu
