// The query core's host/device vocabulary: functions marked VOXFMT_HD compile for the CPU (g++, clang) and, under
// nvcc, for the GPU too, so that the CPU runtime, its tests and the CUDA kernels run one piece of code. Plain
// structs and math only: no Eigen, no exceptions, no allocation.
#pragma once

#include <cstddef>
#include <cstdint>

#include "voxfmt/runtime/core_types.h"  // VOXFMT_HD, Vec3 and the data types

namespace voxfmt::runtime::core {

VOXFMT_HD Vec3 make_vec3(float x, float y, float z) {
  Vec3 v;
  v.x = x;
  v.y = y;
  v.z = z;
  return v;
}
VOXFMT_HD Vec3 operator+(const Vec3& a, const Vec3& b) { return make_vec3(a.x + b.x, a.y + b.y, a.z + b.z); }
VOXFMT_HD Vec3 operator-(const Vec3& a, const Vec3& b) { return make_vec3(a.x - b.x, a.y - b.y, a.z - b.z); }
VOXFMT_HD Vec3 operator*(float s, const Vec3& a) { return make_vec3(s * a.x, s * a.y, s * a.z); }
VOXFMT_HD float dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
// As std::min, std::max and std::clamp decide (ties and signed zeros alike), so results match them bit for bit.
VOXFMT_HD float min_f(float a, float b) { return b < a ? b : a; }
VOXFMT_HD float max_f(float a, float b) { return a < b ? b : a; }
VOXFMT_HD float clamp_f(float v, float lo, float hi) { return v < lo ? lo : (hi < v ? hi : v); }
VOXFMT_HD int min_i(int a, int b) { return b < a ? b : a; }
VOXFMT_HD int max_i(int a, int b) { return a < b ? b : a; }
VOXFMT_HD float sqrt_f(float v) {
#if defined(__CUDA_ARCH__)
  return sqrtf(v);
#else
  return __builtin_sqrtf(v);
#endif
}

VOXFMT_HD float length(const Vec3& a) { return sqrt_f(dot(a, a)); }

VOXFMT_HD double sqrt_d(double v) {
#if defined(__CUDA_ARCH__)
  return sqrt(v);
#else
  return __builtin_sqrt(v);
#endif
}

/// sqrt(|a|^2 + d^2) without overflow: the float sum where it is finite (every ordinary result, unchanged bit for
/// bit), else in double: a point sent 1e18 m away squares beyond float's range, while the root fits.
VOXFMT_HD float hypot_f(const Vec3& a, float d) {
  const float plain = sqrt_f(dot(a, a) + d * d);
  if (plain <= 3.40282347e+38f) return plain;
  const double x = a.x, y = a.y, z = a.z, w = d;
  return float(sqrt_d(x * x + y * y + z * z + w * w));
}

/// A rigid map with uniform scale, u = M x + m (row-major M): a shell's asset frame into a target's grid. The
/// sums run in the order Eigen's float matrix-vector product uses (a + (b + c)), so the runtime's Eigen code and
/// this agree bit for bit (tests/runtime/test_query_core.cpp).
struct Affine {
  float M[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  Vec3 m;
  VOXFMT_HD Vec3 apply(const Vec3& x) const {
    return make_vec3(M[0] * x.x + (M[1] * x.y + M[2] * x.z) + m.x, M[3] * x.x + (M[4] * x.y + M[5] * x.z) + m.y,
                     M[6] * x.x + (M[7] * x.y + M[8] * x.z) + m.z);
  }
};

}  // namespace voxfmt::runtime::core
