// What the CUDA side of the batch offers the host side (scene.cpp): plain types only, so that the host code needs
// no CUDA headers and the CUDA code no Eigen. Implemented in kernels.cu.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include "core/block_walk.h"

// Blocks a multiprocessor should hold at once: a register cap for the compiler (0 leaves the registers to it). 640
// threads' worth: five blocks of 128 lanes, 96 registers a thread on sm_90 at any block size, where the compiler
// alone takes 128 and holds four blocks of 128 (measured on an H200: docs/gpu.md). Another value only to measure
// one (scripts/gpu-check.sh's CAPS).
#ifndef VOXFMT_BLOCK_MIN_BLOCKS
#define VOXFMT_BLOCK_MIN_BLOCKS (640 / VOXFMT_BLOCK_LANES)
#endif

namespace voxfmt::gpu::device {

namespace core = runtime::core;

/// Empty if a CUDA device can be used, else why not (no driver, no device, ...).
std::string unavailable_reason();
/// The name of the current CUDA device ("NVIDIA H100 80GB HBM3"), or empty.
std::string device_name();

/// The device holding `pointer`, or -1 and `error` (CUDA cannot say, or it is ordinary host memory).
int device_of(const void* pointer, std::string& error);
/// The current device, or -1 and `error`.
int current_device(std::string& error);
/// Makes `device` current; empty, or why not.
std::string make_current(int device);
/// Waits for the work queued on `stream` (a cudaStream_t as an integer, 0 the legacy default); empty, or why not.
std::string synchronize_stream(uintptr_t stream);

/// Copies `bytes` from host memory to new device memory; nullptr (and `error`) on failure.
void* copy_to_device(const void* host, size_t bytes, std::string& error);
void release(void* device_pointer);

/// How many blocks of the batch's kernel the current device keeps resident at once (its grid); 0 and `error` when
/// the device cannot say.
unsigned resident_blocks(std::string& error);

/// Lets the current device's default memory pool keep at least `bytes` between launches (its release threshold,
/// raised, never lowered): the frontier a launch takes from it is then not returned to the driver and mapped again
/// at every synchronisation.
std::string keep_in_pool(size_t bytes);

/// Runs every environment of `in` into `out` (device pointers) on `stream`, asynchronously: a block per
/// environment (core::run_environment_block) on `resident` blocks, whose frontiers hold `capacity` ranges
/// (core::frontier_capacity of the scene's shells). Empty, or the launch's error.
std::string launch(const core::BatchInputs<float>& in, const core::BatchOutputs& out, unsigned resident,
                   uint32_t capacity, void* stream);

}  // namespace voxfmt::gpu::device
