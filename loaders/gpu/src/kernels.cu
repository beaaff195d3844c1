// The batched contact query on a CUDA device: one thread per environment, each running the query core's
// environment (core/batch.h) — the very function the CPU path and its tests run. Compiled with --fmad=false, so
// that the device's float arithmetic is the CPU's (no fused multiply-adds): the same lookups, the same points.
#include <cuda_runtime.h>

#include "device.h"

namespace voxfmt::gpu::device {

namespace {

__global__ void environments(core::BatchInputs<float> in, core::BatchOutputs out) {
  const size_t e = size_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (e < in.environments) core::run_environment(in, out, e);
}

std::string describe(cudaError_t status) {
  return std::string(cudaGetErrorName(status)) + ": " + cudaGetErrorString(status);
}

}  // namespace

std::string unavailable_reason() {
  int devices = 0;
  const cudaError_t status = cudaGetDeviceCount(&devices);
  if (status != cudaSuccess) {
    cudaGetLastError();  // clear it: the process may go on without a device
    return describe(status);
  }
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

void* copy_to_device(const void* host, size_t bytes, std::string& error) {
  void* device = nullptr;
  cudaError_t status = cudaMalloc(&device, bytes > 0 ? bytes : 1);
  if (status == cudaSuccess && bytes > 0) status = cudaMemcpy(device, host, bytes, cudaMemcpyHostToDevice);
  if (status != cudaSuccess) {
    error = describe(status);
    cudaGetLastError();
    if (device) cudaFree(device);
    return nullptr;
  }
  return device;
}

void release(void* device_pointer) {
  if (device_pointer) cudaFree(device_pointer);
}

std::string launch(const core::BatchInputs<float>& in, const core::BatchOutputs& out, void* stream) {
  if (in.environments == 0) return std::string();
  // 128 threads a block: the walk's stack (48 ranges of 16 bytes) lives in each thread's local memory.
  constexpr unsigned kThreads = 128;
  const size_t blocks = (in.environments + kThreads - 1) / kThreads;
  environments<<<unsigned(blocks), kThreads, 0, static_cast<cudaStream_t>(stream)>>>(in, out);
  const cudaError_t status = cudaGetLastError();
  return status == cudaSuccess ? std::string() : describe(status);
}

}  // namespace voxfmt::gpu::device
