// The CUDA batch without voxfmt's libraries, for a GPU machine that has only CUDA and Python (scripts/gpu-check.sh):
// one asset's arrays, exported where voxfmt is built (voxfmt._voxfmt._export_core) and uploaded by CuPy, become a
// core::Body here, and loaders/gpu/src/kernels.cu runs the batch over them — the same kernel voxfmt links.
#include <cuda_runtime.h>

#include <cstring>
#include <string>
#include <vector>

#include "../../loaders/gpu/src/device.h"

namespace core = voxfmt::runtime::core;

extern "C" {

/// The lanes of the kernel's blocks (-DVOXFMT_BLOCK_LANES).
int voxfmt_gpu_check_lanes() { return core::kBlockLanes; }

/// The blocks a multiprocessor should hold that the kernel was built for (-DVOXFMT_BLOCK_MIN_BLOCKS; 0: no cap).
int voxfmt_gpu_check_min_blocks() { return VOXFMT_BLOCK_MIN_BLOCKS; }

/// Runs `envs` environments of one asset against itself (pair (0, 0)). Arrays: device pointers (the contact
/// outputs, `max_contacts` rows per environment, may be null when it is 0); the numbers (field_floats 18,
/// field_dims 9, body_doubles 8, as _export_core gives them): host. `codes` are the value bricks with their apron
/// (as _export_core gives them and gpu::Scene uploads them) when `apron`, else the runtime's plain 8^3 bricks. With
/// `kernel_ms` (host), the kernel's time by CUDA events around the launch, waited for. Returns 0, or -1 with the reason
/// in `error_text`.
int voxfmt_gpu_check_run(const int32_t* bricks, const int16_t* codes, int apron, const uint16_t* lattice,
                         const float* field_floats, const int32_t* field_dims, const void* nodes, const float* points,
                         const float* normals, const double* body_doubles, uint32_t count, uint32_t levels,
                         const float* poses_a, const float* poses_b, size_t envs, double proximity, double stiffness,
                         int32_t* out_count, float* max_depth, float* force, float* torque, int32_t* overflow,
                         int32_t* error, uint32_t max_contacts, float* contact_points, float* contact_normals,
                         float* contact_depths, int32_t* point_index, uint8_t* point_of_b, float* kernel_ms,
                         uintptr_t stream, char* error_text, size_t error_size) {
  static core::Body* device_body = nullptr;
  static uint32_t* device_pair = nullptr;
  core::Body b;
  b.has_field = b.has_shell = true;
  b.field.bricks = bricks;
  b.field.lattice = lattice;
  b.field.codes = codes;
  if (apron) b.field = core::with_apron(b.field, codes);
  for (int a = 0; a < 3; ++a) {
    b.field.dims[a] = field_dims[a];
    b.field.brick_dims[a] = field_dims[3 + a];
    b.field.lattice_dims[a] = field_dims[6 + a];
  }
  const float* f = field_floats;
  b.field.decode_step[0] = f[0];
  b.field.decode_step[1] = f[1];
  b.field.stored_slack = f[2];
  b.field.estimate_slack = f[3];
  b.field.estimate_offset = f[4];
  b.field.estimate_shrink = f[5];
  b.field.band_edge = f[6];
  b.field.lattice_step = f[7];
  b.field.cover_max = core::make_vec3(f[8], f[9], f[10]);
  b.field.object_min = core::make_vec3(f[11], f[12], f[13]);
  b.field.object_max = core::make_vec3(f[14], f[15], f[16]);
  b.field.value_estimate_slack = f[17];
  b.shell.nodes = static_cast<const core::Node*>(nodes);
  b.shell.points = reinterpret_cast<const core::Vec3*>(points);
  b.shell.normals = reinterpret_cast<const core::Vec3*>(normals);
  b.shell.count = count;
  b.shell.levels = levels;
  for (int a = 0; a < 3; ++a) {
    b.origin[a] = body_doubles[a];
    b.center_of_mass[a] = body_doubles[4 + a];
  }
  b.voxel_size = body_doubles[3];
  b.bounding_radius = body_doubles[7];
  std::string failure;
  // The body and the pair table go up once per process and are refreshed in place when the asset changes (one at a
  // time), as a scene uploads them once: a copy every call would add a synchronous transfer to each round trip.
  // The asset is known by its arrays' addresses and its numbers (a Body's padding would make a byte compare of it
  // unreliable).
  std::string asset;
  const auto add = [&asset](const void* bytes, size_t size) { asset.append(static_cast<const char*>(bytes), size); };
  for (const void* array : {static_cast<const void*>(bricks), static_cast<const void*>(codes),
                            static_cast<const void*>(lattice), nodes, static_cast<const void*>(points),
                            static_cast<const void*>(normals)})
    add(&array, sizeof array);
  add(&apron, sizeof apron), add(&count, sizeof count), add(&levels, sizeof levels);
  add(field_floats, 18 * sizeof(float)), add(field_dims, 9 * sizeof(int32_t)), add(body_doubles, 8 * sizeof(double));
  static std::string uploaded;
  if (!device_body) {
    device_body = static_cast<core::Body*>(voxfmt::gpu::device::copy_to_device(&b, sizeof b, failure));
    const uint32_t zero = 0;
    device_pair = static_cast<uint32_t*>(voxfmt::gpu::device::copy_to_device(&zero, sizeof zero, failure));
    uploaded = asset;
  } else if (asset != uploaded) {
    if (cudaMemcpy(device_body, &b, sizeof b, cudaMemcpyHostToDevice) == cudaSuccess)
      uploaded = asset;
    else
      failure = "cannot update the body";
  }
  if (failure.empty()) {
    core::BatchInputs<float> in;
    in.bodies = device_body;
    in.pair_a = in.pair_b = device_pair;
    in.pair_count = 1;
    in.poses_a = poses_a;
    in.poses_b = poses_b;
    in.environments = envs;
    in.proximity = proximity;
    in.stiffness = stiffness;
    core::BatchOutputs out;
    out.count = out_count;
    out.max_depth = max_depth;
    out.force = force;
    out.torque = torque;
    out.overflow = overflow;
    out.error = error;
    out.contacts = {contact_points, contact_normals, contact_depths, point_index, point_of_b, max_contacts};
    // The frontier's size from the tree (read back once per tree) and the grid's from the device.
    static const void* sized_for = nullptr;
    static uint32_t capacity = 1;
    static unsigned resident = 0;
    if (nodes != sized_for) {
      std::vector<core::Node> host(count);
      if (cudaMemcpy(host.data(), nodes, count * sizeof(core::Node), cudaMemcpyDeviceToHost) != cudaSuccess)
        failure = "cannot read the tree back";
      core::Shell shell = b.shell;
      shell.nodes = host.data();
      const core::Shell* shells[] = {&shell};
      capacity = core::frontier_capacity(shells, 1);
      sized_for = nodes;
    }
    if (resident == 0 && failure.empty()) resident = voxfmt::gpu::device::resident_blocks(failure);
    static cudaEvent_t begin = nullptr, end = nullptr;
    if (kernel_ms && !begin && (cudaEventCreate(&begin) != cudaSuccess || cudaEventCreate(&end) != cudaSuccess))
      failure = "cannot create the timing events";
    const cudaStream_t s = reinterpret_cast<cudaStream_t>(stream);
    if (failure.empty() && kernel_ms) cudaEventRecord(begin, s);
    if (failure.empty()) failure = voxfmt::gpu::device::launch(in, out, resident, capacity, s);
    if (failure.empty() && kernel_ms) {
      cudaEventRecord(end, s);
      if (cudaEventSynchronize(end) != cudaSuccess || cudaEventElapsedTime(kernel_ms, begin, end) != cudaSuccess)
        failure = "cannot time the kernel";
    }
  }
  if (failure.empty()) return 0;
  std::strncpy(error_text, failure.c_str(), error_size - 1);
  error_text[error_size - 1] = 0;
  return -1;
}

}  // extern "C"
