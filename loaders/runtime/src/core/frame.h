// Where a query happens: one object's shell mapped into the other's voxel grid, from the two rigid poses. Host and
// device (VOXFMT_HD) compute it alike, in double precision, the sums in the order the runtime has always used
// (left to right, as Eigen's double products), so both look up the same grid coordinates.
#pragma once

#include "hd.h"

namespace voxfmt::runtime::core {

/// A rigid body-to-world placement with uniform scale: world = R (scale x) + t, R row-major.
struct RigidPose {
  double R[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  double t[3] = {0, 0, 0};
  double scale = 1;
};

/// Why a 4x4 matrix is not a rigid placement (spec of the Python API's poses: BAD_POSE), 0 if it is one.
enum PoseProblem : int32_t {
  kPoseRigid = 0,
  kPoseNotFinite = 2,
  kPoseLastRow = 3,
  kPoseNotOrthonormal = 4,
  kPoseReflection = 5
};

/// How far a rotation may be from orthonormal, |R^T R - I| entry by entry: a float32 rotation (quaternion converted,
/// or composed down a kinematic chain) is some 1e-6 off, a scale or shear far more.
inline constexpr double kRigidTolerance = 1e-5;

/// Reads a row-major 4x4 matrix (float or double) as a rigid pose, as the Python API's pose check does: finite,
/// last row 0 0 0 1, |R^T R - I| <= kRigidTolerance entry by entry, determinant +1.
template <class T>
VOXFMT_HD int32_t pose_from_matrix(const T* m, RigidPose& pose) {
  for (int i = 0; i < 16; ++i)
    if (!(double(m[i]) - double(m[i]) == 0.0)) return kPoseNotFinite;
  if (double(m[12]) != 0.0 || double(m[13]) != 0.0 || double(m[14]) != 0.0 || double(m[15]) != 1.0) return kPoseLastRow;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) pose.R[3 * r + c] = double(m[4 * r + c]);
    pose.t[r] = double(m[4 * r + 3]);
  }
  pose.scale = 1;
  const double* R = pose.R;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      const double dot = R[a] * R[b] + R[3 + a] * R[3 + b] + R[6 + a] * R[6 + b] - (a == b ? 1.0 : 0.0);
      if (dot > kRigidTolerance || dot < -kRigidTolerance) return kPoseNotOrthonormal;
    }
  const double det =
      R[0] * (R[4] * R[8] - R[5] * R[7]) - R[1] * (R[3] * R[8] - R[5] * R[6]) + R[2] * (R[3] * R[7] - R[4] * R[6]);
  return det < 0 ? kPoseReflection : kPoseRigid;
}

/// QueryDirection::Auto's rule, for the runtime and the batch alike: +1 for B's points in A's field, -1 for A's
/// points in B's, 0 for a tie of size, point count and position (runtime::resolve_direction breaks it by the objects'
/// addresses for single queries, gives it to A's points for the batches, CPU and GPU). The smaller object's points
/// sample the contact region of the larger one densely; for similar sizes (within 10 %) the choice must not depend on
/// the order the pair comes in (a physics engine hands it either way): fewer points, then the lower position decide.
/// `ra`, `rb`: bounding radii, scaled.
VOXFMT_HD int auto_direction(bool a_points_in_b, bool b_points_in_a, double ra, double rb, uint64_t points_a,
                             uint64_t points_b, const double ta[3], const double tb[3]) {
  if (!a_points_in_b) return 1;
  if (!b_points_in_a) return -1;
  if (rb < 0.9 * ra) return 1;
  if (ra < 0.9 * rb) return -1;
  if (points_a != points_b) return points_b < points_a ? 1 : -1;
  for (int axis = 0; axis < 3; ++axis)
    if (ta[axis] != tb[axis]) return tb[axis] < ta[axis] ? 1 : -1;
  return 0;
}

/// `pose` acting on coordinates relative to `anchor` (a point of its asset frame, PointTree::anchor): x ->
/// pose(anchor + x), its translation pose(anchor) in double. A zero anchor leaves the pose as it is, bit for bit.
VOXFMT_HD RigidPose anchored(const RigidPose& p, const double anchor[3]) {
  RigidPose q = p;
  for (int r = 0; r < 3; ++r)
    q.t[r] = p.R[3 * r] * (p.scale * anchor[0]) + p.R[3 * r + 1] * (p.scale * anchor[1]) +
             p.R[3 * r + 2] * (p.scale * anchor[2]) + p.t[r];
  return q;
}

/// The shell's frame in the target's grid: u = to_grid(x) for x in the shell's asset frame, lengths times
/// radius_scale; a distance d (grid units) is d * metres_per_unit metres.
struct Frame {
  Affine to_grid;
  float radius_scale = 1;
  float proximity = 0;  ///< the query's proximity in grid units
  double metres_per_unit = 1;
};

/// The frame of `shell` (placed by `shell_pose`) in the grid of a field placed by `field_pose`, whose voxel
/// (0, 0, 0) is at `origin` (its asset frame) and whose voxels are `voxel_size` wide.
VOXFMT_HD Frame frame_of(const RigidPose& shell_pose, const RigidPose& field_pose, const double origin[3],
                         double voxel_size, double proximity_m) {
  Frame f;
  const double to_voxels = 1.0 / (field_pose.scale * voxel_size);
  // A = to_voxels * field R^T; M = (A * shell R) * shell scale; m = A (t_shell - t_field) - origin / voxel_size.
  double A[9];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) A[3 * r + c] = to_voxels * field_pose.R[3 * c + r];
  const double d[3] = {shell_pose.t[0] - field_pose.t[0], shell_pose.t[1] - field_pose.t[1],
                       shell_pose.t[2] - field_pose.t[2]};
  float* M = f.to_grid.M;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c)
      M[3 * r + c] =
          float((A[3 * r] * shell_pose.R[c] + A[3 * r + 1] * shell_pose.R[3 + c] + A[3 * r + 2] * shell_pose.R[6 + c]) *
                shell_pose.scale);
  }
  f.to_grid.m = make_vec3(float(A[0] * d[0] + A[1] * d[1] + A[2] * d[2] - origin[0] / voxel_size),
                          float(A[3] * d[0] + A[4] * d[1] + A[5] * d[2] - origin[1] / voxel_size),
                          float(A[6] * d[0] + A[7] * d[1] + A[8] * d[2] - origin[2] / voxel_size));
  f.metres_per_unit = field_pose.scale * voxel_size;
  f.proximity = float(proximity_m / f.metres_per_unit);
  f.radius_scale = float(shell_pose.scale * to_voxels);
  return f;
}

}  // namespace voxfmt::runtime::core
