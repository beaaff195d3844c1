// Between the runtime's Eigen types and the query core's plain ones (host only).
#pragma once

#include <Eigen/Core>

#include "hd.h"

namespace voxfmt::runtime::core {

inline Vec3 to_core(const Eigen::Vector3f& v) { return make_vec3(v.x(), v.y(), v.z()); }
inline Eigen::Vector3f to_eigen(const Vec3& v) { return Eigen::Vector3f(v.x, v.y, v.z); }

/// u = M x + m as the core's Affine (row-major).
inline Affine to_core(const Eigen::Matrix3f& M, const Eigen::Vector3f& m) {
  Affine a;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) a.M[3 * r + c] = M(r, c);
  a.m = to_core(m);
  return a;
}

}  // namespace voxfmt::runtime::core
