// What the CUDA side of the batch offers the host side (scene.cpp): plain types only, so that the host code needs
// no CUDA headers and the CUDA code no Eigen. Implemented in kernels.cu.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include "core/batch.h"

namespace voxfmt::gpu::device {

namespace core = runtime::core;

/// Empty if a CUDA device can be used, else why not (no driver, no device, ...).
std::string unavailable_reason();
/// The name of the current CUDA device ("NVIDIA H100 80GB HBM3"), or empty.
std::string device_name();

/// Copies `bytes` from host memory to new device memory; nullptr (and `error`) on failure.
void* copy_to_device(const void* host, size_t bytes, std::string& error);
void release(void* device_pointer);

/// Runs every environment of `in` into `out` (device pointers) on `stream`, asynchronously: one CUDA thread per
/// environment (core::run_environment). Empty, or the launch's error.
std::string launch(const core::BatchInputs<float>& in, const core::BatchOutputs& out, void* stream);

}  // namespace voxfmt::gpu::device
