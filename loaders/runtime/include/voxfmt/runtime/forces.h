// Classical VPS penalty force and torque from a contact set (McNeely et al.; the DLR seed's haptic rendering).
#pragma once

#include <Eigen/Core>

#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {

struct Wrench {
  Eigen::Vector3d force = Eigen::Vector3d::Zero();   ///< newtons, on object A
  Eigen::Vector3d torque = Eigen::Vector3d::Zero();  ///< newton-metres about `reference`, on object A
};

/// F = sum_i k * depth_i * n_i and T = sum_i (P_i - reference) x F_i over the penetrating contacts
/// (depth > 0) of `contacts`, with stiffness k in N/m. The normals of a ContactSet point where A must move,
/// so the wrench acts on A; B receives the opposite force (and the torque about its own reference point).
inline Wrench penalty_wrench(const ContactSet& contacts, const Eigen::Vector3d& reference, double stiffness) {
  Wrench w;
  for (const Contact& c : contacts.contacts) {
    if (c.depth <= 0.0) continue;
    const Eigen::Vector3d f = stiffness * c.depth * c.normal;
    w.force += f;
    w.torque += (c.point - reference).cross(f);
  }
  return w;
}

}  // namespace voxfmt::runtime
