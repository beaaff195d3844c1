// One environment of a batched contact query, as host/device code: a pair of assets at a pair of poses, queried
// in the direction the runtime's Auto picks, reduced to what a learning loop needs (contact count, deepest
// penetration, the penalty wrench on A) and, on request, the contacts in a buffer the caller sized, with the
// number that did not fit always counted. env_contacts walks one environment depth first on one thread; the CUDA
// kernel walks one on a block's lanes (block_walk.h), with the same examination of each node and the same
// contact values, in the runtime's order.
#pragma once

#include "walk.h"

namespace voxfmt::runtime::core {

/// One asset as the batch reads it (host or device memory).
struct Body {
  Field field;
  bool has_field = false;
  Shell shell;
  bool has_shell = false;
  double origin[3] = {0, 0, 0};  ///< the field's voxel (0, 0, 0), asset frame
  double voxel_size = 1;
  double bounding_radius = 0;            ///< as CollisionObject::bounding_radius
  double center_of_mass[3] = {0, 0, 0};  ///< asset frame
};

/// Where one environment's contacts go: caller-sized arrays (structure of arrays, as NumPy and PyTorch hold
/// them), `capacity` contacts at most; null arrays are skipped.
struct ContactArrays {
  float* points = nullptr;         ///< capacity x 3: world, on the surface of the object whose point it is
  float* normals = nullptr;        ///< capacity x 3: unit; where A must move to separate from B
  float* depths = nullptr;         ///< capacity: metres; negative for proximity points
  int32_t* point_index = nullptr;  ///< capacity
  uint8_t* point_of_b = nullptr;   ///< capacity: 1 for B's points in A's field
  uint32_t capacity = 0;
};

struct EnvResult {
  uint32_t count = 0;           ///< contacts found (written or not)
  uint32_t overflow = 0;        ///< contacts that did not fit the caller's buffer
  float max_depth = 0;          ///< metres, 0 without a penetrating contact
  float force[3] = {0, 0, 0};   ///< newtons on A: sum of stiffness * depth * normal over penetrating contacts
  float torque[3] = {0, 0, 0};  ///< newton-metres on A about A's centre of mass (world)
  int32_t error = 0;            ///< nonzero: a tree deeper than the walk takes (the loader refuses those)
};

VOXFMT_HD void apply_pose(const RigidPose& p, const float x[3], double out[3]) {
  for (int r = 0; r < 3; ++r)
    out[r] = p.R[3 * r] * (p.scale * double(x[0])) + p.R[3 * r + 1] * (p.scale * double(x[1])) +
             p.R[3 * r + 2] * (p.scale * double(x[2])) + p.t[r];
}

/// The direction QueryDirection::Auto resolves to (auto_direction): true for B's points in A's field. Ties of size,
/// point count and position go to A's points (the runtime breaks them by address).
VOXFMT_HD bool b_points_in_a(const Body& a, const RigidPose& pa, const Body& b, const RigidPose& pb) {
  return auto_direction(a.has_shell && b.has_field, b.has_shell && a.has_field, a.bounding_radius * pa.scale,
                        b.bounding_radius * pb.scale, a.shell.count, b.shell.count, pa.t, pb.t) > 0;
}

/// A contact's normal from the partner field's gradient `g` at the point (grid frame), rotated by the field's pose
/// (NormalSource::DistanceGradient): false, with nothing written, where the field is flat there.
VOXFMT_HD bool gradient_normal(const Vec3& g, const RigidPose& field_pose, double normal[3]) {
  if (!(g.x * g.x + g.y * g.y + g.z * g.z > 0.0f)) return false;
  const double gd[3] = {double(g.x), double(g.y), double(g.z)};
  const double length = sqrt_d(gd[0] * gd[0] + gd[1] * gd[1] + gd[2] * gd[2]);
  const double unit[3] = {gd[0] / length, gd[1] / length, gd[2] / length};
  for (int r = 0; r < 3; ++r)
    normal[r] = field_pose.R[3 * r] * unit[0] + field_pose.R[3 * r + 1] * unit[1] + field_pose.R[3 * r + 2] * unit[2];
  return true;
}

/// A contact's normal from the point's own (NormalSource::PointShell), rotated by the shell's pose.
VOXFMT_HD void point_normal(const Shell& shell, const RigidPose& shell_pose, uint32_t node, double normal[3]) {
  const Vec3& n = shell.normals[node];
  for (int r = 0; r < 3; ++r)
    normal[r] = shell_pose.R[3 * r] * n.x + shell_pose.R[3 * r + 1] * n.y + shell_pose.R[3 * r + 2] * n.z;
  const double length = sqrt_d(normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]);
  for (int r = 0; r < 3; ++r) normal[r] = length > 0 ? normal[r] / length : 0.0;
}

/// A contact's normal (world, unit, before the direction's sign): gradient_normal of the field's gradient at the
/// point — `sampled` where the caller has it from the point's distance sample, else sampled here — or, where the
/// field is flat or `gradient` is false, point_normal. The runtime's query computes the same, in the same order.
VOXFMT_HD void contact_normal(const Field& field, const Frame& frame, const RigidPose& field_pose, const Shell& shell,
                              const RigidPose& shell_pose, uint32_t node, bool gradient, const Vec3* sampled,
                              double normal[3]) {
  if (gradient) {
    Vec3 g = make_vec3(0, 0, 0);
    if (sampled)
      g = *sampled;
    else
      sample(field, frame.to_grid.apply(shell.points[node]), &g);
    if (gradient_normal(g, field_pose, normal)) return;
  }
  point_normal(shell, shell_pose, node, normal);
}

/// One environment's query, set up: which object's points go into which field, the frame between them, and what
/// a contact's wrench is taken about. Plain values (a CUDA block keeps it in shared memory).
struct EnvQuery {
  const Shell* shell;
  const Field* field;
  RigidPose shell_pose, field_pose;  ///< the shell's anchored (core::anchored): it places the points as stored
  Frame frame;
  bool gradient_normals;
  double sign;  ///< +1: A's points (normals as they are); -1: B's points (A must move the other way)
  double stiffness;
  double reference[3];  ///< A's centre of mass, world
  uint32_t point_of_b;
  bool runs;  ///< false where one side has no shell or the other no field: nothing to find
};

/// A at `pa` against B at `pb` in the direction the runtime's Auto picks (proximity in metres).
VOXFMT_HD EnvQuery env_query(const Body& a, const RigidPose& pa, const Body& b, const RigidPose& pb, double proximity,
                             double stiffness, bool gradient_normals) {
  EnvQuery q;
  for (int r = 0; r < 3; ++r)
    q.reference[r] = pa.R[3 * r] * (pa.scale * a.center_of_mass[0]) +
                     pa.R[3 * r + 1] * (pa.scale * a.center_of_mass[1]) +
                     pa.R[3 * r + 2] * (pa.scale * a.center_of_mass[2]) + pa.t[r];
  const bool b_in_a = b_points_in_a(a, pa, b, pb);
  const Body& shell_body = b_in_a ? b : a;
  const Body& field_body = b_in_a ? a : b;
  q.shell = &shell_body.shell;
  q.field = &field_body.field;
  q.shell_pose = anchored(b_in_a ? pb : pa, shell_body.shell.anchor);  // the points are from the anchor
  q.field_pose = b_in_a ? pa : pb;
  q.runs = shell_body.has_shell && field_body.has_field;
  q.frame = frame_of(q.shell_pose, q.field_pose, field_body.origin, field_body.voxel_size, proximity);
  q.gradient_normals = gradient_normals;
  q.sign = b_in_a ? -1.0 : 1.0;
  q.stiffness = stiffness;
  q.point_of_b = b_in_a ? 1u : 0u;
  return q;
}

/// One contact: where, which way, how deep, and its share of the penalty wrench (zero unless it penetrates).
struct ContactValues {
  double point[3], normal[3], depth, force[3], torque[3];
};

/// The contact of shell point `node` at `distance` (grid units); `gradient`: the field's there, from its distance
/// sample (contact_normal). The runtime's penalty_wrench computes a contact's share in the same order.
VOXFMT_HD void contact_values(const EnvQuery& q, uint32_t node, float distance, const Vec3* gradient,
                              ContactValues& c) {
  const Vec3& x = q.shell->points[node];
  const float xs[3] = {x.x, x.y, x.z};
  apply_pose(q.shell_pose, xs, c.point);
  contact_normal(*q.field, q.frame, q.field_pose, *q.shell, q.shell_pose, node, q.gradient_normals, gradient, c.normal);
  for (int r = 0; r < 3; ++r) c.normal[r] *= q.sign;
  c.depth = -double(distance) * q.frame.metres_per_unit;
  const double k = c.depth > 0 ? q.stiffness * c.depth : 0.0;
  const double f[3] = {k * c.normal[0], k * c.normal[1], k * c.normal[2]};
  const double r[3] = {c.point[0] - q.reference[0], c.point[1] - q.reference[1], c.point[2] - q.reference[2]};
  for (int a = 0; a < 3; ++a) c.force[a] = f[a];
  c.torque[0] = r[1] * f[2] - r[2] * f[1];
  c.torque[1] = r[2] * f[0] - r[0] * f[2];
  c.torque[2] = r[0] * f[1] - r[1] * f[0];
}

/// Contact `i` of `out` (which must have room for it).
VOXFMT_HD void write_contact(const ContactArrays& out, uint32_t i, const ContactValues& c, uint32_t node,
                             uint32_t point_of_b) {
  for (int k = 0; k < 3; ++k) {
    if (out.points) out.points[3 * i + k] = float(c.point[k]);
    if (out.normals) out.normals[3 * i + k] = float(c.normal[k]);
  }
  if (out.depths) out.depths[i] = float(c.depth);
  if (out.point_index) out.point_index[i] = int32_t(node);
  if (out.point_of_b) out.point_of_b[i] = uint8_t(point_of_b);
}

/// Adds a contact to the environment's reductions (in the order contacts are found: the wrench's sums are the
/// runtime's when that order is).
VOXFMT_HD void add_contact(const ContactValues& c, EnvResult& result, double force[3], double torque[3]) {
  if (c.depth > 0) {
    for (int k = 0; k < 3; ++k) {
      force[k] += c.force[k];
      torque[k] += c.torque[k];
    }
    if (float(c.depth) > result.max_depth) result.max_depth = float(c.depth);
  }
}

/// Adds each contact of the depth-first walk to `result` (and `out`, while it has room).
struct ContactSink {
  const EnvQuery& query;
  ContactArrays out;
  EnvResult& result;
  double force[3], torque[3];

  VOXFMT_HD void operator()(uint32_t node, float distance, bool, const Vec3* gradient) {
    ContactValues c;
    contact_values(query, node, distance, gradient, c);
    add_contact(c, result, force, torque);
    if (result.count < out.capacity)
      write_contact(out, result.count, c, node, query.point_of_b);
    else
      ++result.overflow;
    ++result.count;
  }
};

/// The contacts of A at `pa` against B at `pb` (proximity in metres; 0: penetrating points only), reduced into
/// `result`; the first `out.capacity` written to `out`. Normals as contact_normal says (`gradient_normals`).
VOXFMT_HD void env_contacts(const Body& a, const RigidPose& pa, const Body& b, const RigidPose& pb, double proximity,
                            double stiffness, bool gradient_normals, const ContactArrays& out, EnvResult& result) {
  result = EnvResult{};
  const EnvQuery query = env_query(a, pa, b, pb, proximity, stiffness, gradient_normals);
  if (!query.runs) return;
  ContactSink sink{query, out, result, {0, 0, 0}, {0, 0, 0}};
  if (walk(*query.field, *query.shell, query.frame, sink) < 0) result.error = 1;
  for (int k = 0; k < 3; ++k) {
    result.force[k] = float(sink.force[k]);
    result.torque[k] = float(sink.torque[k]);
  }
}

/// Why an environment has no result (EnvResult::error, the batch's `error` output).
/// kEnvFrontierFull: a level of the block walk opened more nodes than its frontier holds (a scene sizes it so that
/// none does: this is a fault, never an input's).
enum EnvError : int32_t {
  kEnvOk = 0,
  kEnvTreeTooDeep = 1,
  kEnvPairOutOfRange = 6,
  kEnvFrontierFull = 7
};  // 2..5: PoseProblem

/// A batch: the assets, the pairs environments may hold (indices into `bodies`), and per environment its pair
/// (null: pair 0 for all) and the two 4x4 row-major body-to-world matrices.
template <class T>
struct BatchInputs {
  const Body* bodies = nullptr;
  const uint32_t* pair_a = nullptr;  ///< per pair: A's body
  const uint32_t* pair_b = nullptr;  ///< per pair: B's body
  uint32_t pair_count = 0;
  const int32_t* pair_index = nullptr;  ///< per environment, or null
  const T* poses_a = nullptr;           ///< environments x 16
  const T* poses_b = nullptr;
  size_t environments = 0;
  double proximity = 0;
  double stiffness = 1;
  /// Normals from the partner's distance gradient (the runtime's default, QueryOptions::normal_source), else the
  /// points' own.
  bool gradient_normals = true;
};

/// Per-environment outputs (any may be null but count): the reductions, and `contacts` (its arrays sized
/// environments x contacts.capacity, environment e's at e x capacity).
struct BatchOutputs {
  int32_t* count = nullptr;
  float* max_depth = nullptr;
  float* force = nullptr;   ///< environments x 3
  float* torque = nullptr;  ///< environments x 3
  int32_t* overflow = nullptr;
  int32_t* error = nullptr;
  ContactArrays contacts;
};

/// Environment `e`'s part of the contact outputs.
VOXFMT_HD ContactArrays environment_contacts(const BatchOutputs& out, size_t e) {
  ContactArrays at = out.contacts;
  const size_t first = e * size_t(at.capacity);
  if (at.points) at.points += 3 * first;
  if (at.normals) at.normals += 3 * first;
  if (at.depths) at.depths += first;
  if (at.point_index) at.point_index += first;
  if (at.point_of_b) at.point_of_b += first;
  return at;
}

/// Environment `e`'s reductions into the outputs.
VOXFMT_HD void write_result(const BatchOutputs& out, size_t e, const EnvResult& r) {
  out.count[e] = int32_t(r.count);
  if (out.max_depth) out.max_depth[e] = r.max_depth;
  for (int k = 0; k < 3; ++k) {
    if (out.force) out.force[3 * e + k] = r.force[k];
    if (out.torque) out.torque[3 * e + k] = r.torque[k];
  }
  if (out.overflow) out.overflow[e] = int32_t(r.overflow);
  if (out.error) out.error[e] = r.error;
}

/// Environment `e`'s pair and poses (false, with `r.error` set, for a bad pair index or pose).
template <class T>
VOXFMT_HD bool environment_of(const BatchInputs<T>& in, size_t e, int32_t& pair, RigidPose& pa, RigidPose& pb,
                              EnvResult& r) {
  pair = in.pair_index ? in.pair_index[e] : 0;
  if (pair < 0 || uint32_t(pair) >= in.pair_count)
    r.error = kEnvPairOutOfRange;
  else if (const int32_t problem = pose_from_matrix(in.poses_a + 16 * e, pa))
    r.error = problem;
  else if (const int32_t problem_b = pose_from_matrix(in.poses_b + 16 * e, pb))
    r.error = problem_b;
  return r.error == 0;
}

/// Environment `e` of a batch, start to end: the same on a CPU thread and a CUDA thread.
template <class T>
VOXFMT_HD void run_environment(const BatchInputs<T>& in, const BatchOutputs& out, size_t e) {
  EnvResult r;
  int32_t pair = 0;
  RigidPose pa, pb;
  if (environment_of(in, e, pair, pa, pb, r)) {
    env_contacts(in.bodies[in.pair_a[pair]], pa, in.bodies[in.pair_b[pair]], pb, in.proximity, in.stiffness,
                 in.gradient_normals, environment_contacts(out, e), r);
  }
  write_result(out, e, r);
}

}  // namespace voxfmt::runtime::core
