// The voxelmap's batched lower bounds with SIMD where the CPU has it, chosen at run time so that one binary runs on
// any x86-64: the traversal's cull and open stages spend about half their time here (docs/performance.md). The
// vector kernel computes what core::lower_bound computes, in the same float operations in the same order (no
// fused multiply-adds), so its bounds are the scalar ones bit for bit (tests/runtime/test_query_core.cpp).
#pragma once

#include <cstddef>

#include "../core/field.h"

namespace voxfmt::runtime::core {

enum class SimdKernel { Scalar, Avx2 };

/// The kernel lower_bounds_dispatched runs: AVX2 where the CPU has it, unless the environment variable
/// VOXFMT_SIMD is "off" (for comparisons in one binary), or as use_simd_kernel set it.
SimdKernel simd_kernel();
const char* simd_kernel_name(SimdKernel kernel);
/// Benchmarks: run `kernel` from now on, process-wide (false, nothing changed, where the CPU lacks it).
bool use_simd_kernel(SimdKernel kernel);

/// lower_bound at the n points `u` into `out`, by the kernel simd_kernel() names (the scalar one for a field
/// that is not Field::gather_safe).
void lower_bounds_dispatched(const Field& f, const Vec3* u, size_t n, float* out);

/// The same by the given kernel (tests and benchmarks); false, with nothing written, where the CPU lacks it or
/// the field is not Field::gather_safe.
bool lower_bounds_with(SimdKernel kernel, const Field& f, const Vec3* u, size_t n, float* out);

/// A voxelmap's arrays must hold this many elements past their last one: a vector gather reads 16-bit codes and
/// lattice values as 32-bit words.
constexpr size_t kGatherPadding = 1;

}  // namespace voxfmt::runtime::core
