// Conversions between Bullet and Eigen math types (private to the Bullet integration).
#pragma once

#include <LinearMath/btMatrix3x3.h>
#include <LinearMath/btVector3.h>

#include <Eigen/Core>

namespace voxfmt::bullet {

inline btVector3 to_bt_vector(const Eigen::Vector3d& v) {
  return btVector3(btScalar(v.x()), btScalar(v.y()), btScalar(v.z()));
}
inline btMatrix3x3 to_bt_matrix(const Eigen::Matrix3d& m) {
  return btMatrix3x3(btScalar(m(0, 0)), btScalar(m(0, 1)), btScalar(m(0, 2)), btScalar(m(1, 0)), btScalar(m(1, 1)),
                     btScalar(m(1, 2)), btScalar(m(2, 0)), btScalar(m(2, 1)), btScalar(m(2, 2)));
}
inline Eigen::Vector3d to_eigen(const btVector3& v) {
  return Eigen::Vector3d(double(v.x()), double(v.y()), double(v.z()));
}
inline Eigen::Matrix3d to_eigen(const btMatrix3x3& m) {
  Eigen::Matrix3d r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r(i, j) = double(m[i][j]);
  return r;
}

}  // namespace voxfmt::bullet
