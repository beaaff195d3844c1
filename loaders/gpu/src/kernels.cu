// The batched contact query on a CUDA device: a block of core::kBlockLanes threads per environment, walking its
// tree level by level (core/block_walk.h) — the very code the CPU tests run on an emulated block, where it gives the
// runtime's contacts in the runtime's order. The grid holds as many blocks as the device keeps resident; each takes
// environments in turn. Compiled with --fmad=false, so that the device's float arithmetic is the CPU's (no fused
// multiply-adds): the same lookups, the same points.
#include <cuda_runtime.h>

#include "device.h"

namespace voxfmt::gpu::device {

namespace {

// A thread block as the block walk's Block: a phase on every thread, then a barrier.
struct CudaBlock {
  template <class Phase>
  __device__ void each(Phase&& phase) const {
    phase(int(threadIdx.x));
    __syncthreads();
  }
};

#if VOXFMT_BLOCK_MIN_BLOCKS > 0  // a register cap (device.h)
#define VOXFMT_ENVIRONMENT_BOUNDS __launch_bounds__(core::kBlockLanes, VOXFMT_BLOCK_MIN_BLOCKS)
#else
#define VOXFMT_ENVIRONMENT_BOUNDS __launch_bounds__(core::kBlockLanes)
#endif

__global__ void VOXFMT_ENVIRONMENT_BOUNDS
    environments(core::BatchInputs<float> in, core::BatchOutputs out, core::OpenRange* frontiers, uint32_t capacity) {
  // Raw storage: BlockState's members have default initialisers, which __shared__ variables may not run.
  __shared__ __align__(16) unsigned char storage[sizeof(core::BlockState)];
  core::BlockState& state = *reinterpret_cast<core::BlockState*>(storage);
  const core::Frontier frontier{frontiers + size_t(blockIdx.x) * 2 * capacity, capacity};
  for (size_t e = blockIdx.x; e < in.environments; e += gridDim.x)
    core::run_environment_block(CudaBlock{}, state, in, out, e, frontier);
}

// What went wrong, with CUDA's last error cleared: the process may go on (without a device, or on another one).
std::string failure(cudaError_t status) {
  cudaGetLastError();
  return std::string(cudaGetErrorName(status)) + ": " + cudaGetErrorString(status);
}

}  // namespace

std::string unavailable_reason() {
  int devices = 0;
  const cudaError_t status = cudaGetDeviceCount(&devices);
  if (status != cudaSuccess) return failure(status);
  return devices > 0 ? std::string() : std::string("no CUDA device");
}

std::string device_name() {
  int device = 0;
  cudaDeviceProp properties{};
  if (cudaGetDevice(&device) != cudaSuccess || cudaGetDeviceProperties(&properties, device) != cudaSuccess) {
    cudaGetLastError();
    return std::string();
  }
  return properties.name;
}

int device_of(const void* pointer, std::string& error) {
  cudaPointerAttributes attributes{};
  const cudaError_t status = cudaPointerGetAttributes(&attributes, pointer);
  if (status != cudaSuccess) {
    error = failure(status);
    return -1;
  }
  if (attributes.type == cudaMemoryTypeUnregistered || attributes.device < 0) {
    error = "not memory CUDA knows of (an ordinary host address)";
    return -1;
  }
  return attributes.device;
}

int current_device(std::string& error) {
  int device = -1;
  const cudaError_t status = cudaGetDevice(&device);
  if (status != cudaSuccess) {
    error = failure(status);
    return -1;
  }
  return device;
}

std::string make_current(int device) {
  const cudaError_t status = cudaSetDevice(device);
  return status == cudaSuccess ? std::string() : failure(status);
}

std::string synchronize_stream(uintptr_t stream) {
  const cudaError_t status = cudaStreamSynchronize(reinterpret_cast<cudaStream_t>(stream));
  return status == cudaSuccess ? std::string() : failure(status);
}

void* copy_to_device(const void* host, size_t bytes, std::string& error) {
  void* device = nullptr;
  cudaError_t status = cudaMalloc(&device, bytes > 0 ? bytes : 1);
  if (status == cudaSuccess && bytes > 0) status = cudaMemcpy(device, host, bytes, cudaMemcpyHostToDevice);
  if (status != cudaSuccess) {
    error = failure(status);
    if (device) cudaFree(device);
    return nullptr;
  }
  return device;
}

void release(void* device_pointer) {
  if (device_pointer) cudaFree(device_pointer);
}

unsigned resident_blocks(std::string& error) {
  int device = 0, processors = 0, per_processor = 0;
  cudaError_t status = cudaGetDevice(&device);
  if (status == cudaSuccess) status = cudaDeviceGetAttribute(&processors, cudaDevAttrMultiProcessorCount, device);
  if (status == cudaSuccess)
    status = cudaOccupancyMaxActiveBlocksPerMultiprocessor(&per_processor, environments, core::kBlockLanes, 0);
  if (status != cudaSuccess) {
    error = failure(status);
    return 0;
  }
  return unsigned(processors) * unsigned(per_processor > 0 ? per_processor : 1);
}

std::string keep_in_pool(size_t bytes) {
  int device = 0;
  cudaMemPool_t pool = nullptr;
  uint64_t threshold = 0;
  cudaError_t status = cudaGetDevice(&device);
  if (status == cudaSuccess) status = cudaDeviceGetDefaultMemPool(&pool, device);
  if (status == cudaSuccess) status = cudaMemPoolGetAttribute(pool, cudaMemPoolAttrReleaseThreshold, &threshold);
  if (status == cudaSuccess && threshold < bytes) {
    threshold = bytes;
    status = cudaMemPoolSetAttribute(pool, cudaMemPoolAttrReleaseThreshold, &threshold);
  }
  return status == cudaSuccess ? std::string() : failure(status);
}

std::string launch(const core::BatchInputs<float>& in, const core::BatchOutputs& out, unsigned resident,
                   uint32_t capacity, void* stream) {
  if (in.environments == 0) return std::string();
  const cudaStream_t s = static_cast<cudaStream_t>(stream);
  const unsigned blocks = unsigned(in.environments < resident ? in.environments : resident);
  // Each block's frontier, from the stream's memory pool: stream ordered (capturable in a graph) and, unlike memory
  // held by the scene, never shared by two launches on two streams.
  void* frontiers = nullptr;
  cudaError_t status = cudaMallocAsync(&frontiers, size_t(blocks) * 2 * capacity * sizeof(core::OpenRange), s);
  if (status != cudaSuccess) return failure(status);
  environments<<<blocks, core::kBlockLanes, 0, s>>>(in, out, static_cast<core::OpenRange*>(frontiers), capacity);
  status = cudaGetLastError();
  const cudaError_t freed = cudaFreeAsync(frontiers, s);
  if (status == cudaSuccess) status = freed;
  return status == cudaSuccess ? std::string() : failure(status);
}

}  // namespace voxfmt::gpu::device
