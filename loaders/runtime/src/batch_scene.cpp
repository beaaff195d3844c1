// BatchScene: every environment of a batch through the runtime's own query on worker threads, reduced to what a
// learning loop needs. The poses are judged as the GPU judges them (core::pose_from_matrix), so a bad one is the
// same error code on either.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <new>
#include <string>
#include <vector>

#include "core/batch.h"
#include "voxfmt/detail/cores.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {

namespace {

// A 4x4 row-major matrix as a rigid pose, or why it is none (core::PoseProblem, 2..5).
template <class T>
int32_t read_pose(const T* m, Pose& pose) {
  core::RigidPose rigid;
  const int32_t problem = core::pose_from_matrix(m, rigid);
  if (problem != core::kPoseRigid) return problem;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) pose.rotation(r, c) = rigid.R[3 * r + c];
    pose.translation[r] = rigid.t[r];
  }
  pose.scale = 1.0;
  return 0;
}

int32_t read_poses(const BatchEnvironments& in, size_t e, Pose& pa, Pose& pb) {
  if (in.poses_a) {
    if (const int32_t problem = read_pose(in.poses_a + 16 * e, pa)) return problem;
    return read_pose(in.poses_b + 16 * e, pb);
  }
  if (const int32_t problem = read_pose(in.poses_a_f64 + 16 * e, pa)) return problem;
  return read_pose(in.poses_b_f64 + 16 * e, pb);
}

// Environment e's outputs from its contacts (A's centre of mass in the world is the torque's reference).
void write_environment(const ContactSet& set, const Eigen::Vector3d& reference, const BatchEnvironments& in,
                       const BatchOutputs& out, size_t e) {
  const size_t found = set.contacts.size();
  const size_t kept = std::min<size_t>(found, out.max_contacts);
  out.count[e] = int32_t(found);
  if (out.overflow) out.overflow[e] = int32_t(found - kept);
  float deepest = 0;
  for (const Contact& c : set.contacts)
    if (c.depth > 0) deepest = std::max(deepest, float(c.depth));
  if (out.max_depth) out.max_depth[e] = deepest;
  const Wrench w = penalty_wrench(set, reference, in.stiffness);
  for (int k = 0; k < 3; ++k) {
    if (out.force) out.force[3 * e + k] = float(w.force[k]);
    if (out.torque) out.torque[3 * e + k] = float(w.torque[k]);
  }
  const size_t first = e * size_t(out.max_contacts);
  for (size_t i = 0; i < kept; ++i) {
    const Contact& c = set.contacts[i];
    for (int k = 0; k < 3; ++k) {
      if (out.points) out.points[3 * (first + i) + k] = float(c.point[k]);
      if (out.normals) out.normals[3 * (first + i) + k] = float(c.normal[k]);
    }
    if (out.depths) out.depths[first + i] = float(c.depth);
    if (out.point_index) out.point_index[first + i] = int32_t(c.point_index);
    if (out.point_of_b) out.point_of_b[first + i] = uint8_t(c.point_of_b);
  }
}

// An environment with no result: nothing found, its error code set.
void write_error(const BatchOutputs& out, size_t e, int32_t code) {
  out.count[e] = 0;
  if (out.overflow) out.overflow[e] = 0;
  if (out.max_depth) out.max_depth[e] = 0;
  for (int k = 0; k < 3; ++k) {
    if (out.force) out.force[3 * e + k] = 0;
    if (out.torque) out.torque[3 * e + k] = 0;
  }
  if (out.error) out.error[e] = code;
}

Status check_batch(const BatchEnvironments& in, const BatchOutputs& out) {
  auto bad = [](const std::string& what) { return Error{IssueCode::BadOption, "batch: " + what}; };
  if (!out.count) return bad("the count output is required");
  if (!(std::isfinite(in.stiffness) && in.stiffness >= 0)) return bad("stiffness must be finite and >= 0");
  if (in.interpolation != Interpolation::Trilinear && in.interpolation != Interpolation::Tricubic)
    return bad("interpolation must be Trilinear or Tricubic");
  return Status::success();
}

// Environments are taken in chunks, in turn: they differ in cost (touching or apart).
constexpr size_t kChunk = 16;

}  // namespace

Result<BatchScene> BatchScene::create(std::vector<std::shared_ptr<const CollisionObject>> objects,
                                      std::vector<Pair> pairs) {
  auto bad = [](const std::string& what) { return Error{IssueCode::BadOption, "batch scene: " + what}; };
  if (objects.empty()) return bad("it needs at least one object");
  if (pairs.empty()) return bad("it needs at least one pair (a, b)");
  for (size_t n = 0; n < objects.size(); ++n)
    if (!objects[n]) return bad("object " + std::to_string(n) + " is null");
  for (const Pair& p : pairs)
    if (p[0] >= objects.size() || p[1] >= objects.size())
      return bad("pair (" + std::to_string(p[0]) + ", " + std::to_string(p[1]) +
                 ") names an object the scene does not have");
  BatchScene scene;
  scene.objects_ = std::move(objects);
  scene.pairs_ = std::move(pairs);
  return scene;
}

unsigned BatchScene::workers(size_t environments, unsigned threads) {
  const size_t chunks = (environments + kChunk - 1) / kChunk;
  return unsigned(std::max<size_t>(1, std::min<size_t>(threads ? threads : usable_cores(), chunks)));
}

Status BatchScene::each_environment(const BatchEnvironments& in, const QueryOptions& options, unsigned threads,
                                    const std::function<void(const Visit&)>& visit,
                                    const Trajectory* trajectory) const {
  auto bad = [](const std::string& what) { return Error{IssueCode::BadOption, "batch: " + what}; };
  // One kind, both sides: a float pose beside two double ones was read as float with a null poses_b.
  const bool any32 = in.poses_a || in.poses_b, any64 = in.poses_a_f64 || in.poses_b_f64;
  const bool f32 = in.poses_a && in.poses_b && !any64, f64 = in.poses_a_f64 && in.poses_b_f64 && !any32;
  if (in.count > 0 && !f32 && !f64) return bad("poses_a and poses_b: both float or both double, one of the two");
  if (!(std::isfinite(in.proximity) && in.proximity >= 0)) return bad("proximity must be finite and >= 0");
  QueryOptions query = options;
  query.proximity = in.proximity;
  std::atomic<size_t> next{0};
  std::atomic<bool> out_of_memory{false};
  std::vector<std::exception_ptr> raised(trajectory ? 1u : workers(in.count, threads));
  auto work = [&](unsigned worker) {
    try {
      ContactSet set;
      QueryScratch own;
      QueryScratch& scratch = trajectory ? trajectory->scratch : own;
      for (size_t begin = next.fetch_add(kChunk); begin < in.count; begin = next.fetch_add(kChunk))
        for (size_t e = begin; e < std::min(begin + kChunk, in.count); ++e) {
          set.clear();
          const int32_t pair = in.pair ? in.pair[e] : 0;
          Pose pa, pb;
          int32_t error = pair < 0 || size_t(pair) >= pairs_.size() ? core::kEnvPairOutOfRange : 0;
          if (error == 0) error = read_poses(in, e, pa, pb);
          if (error != 0) {
            visit({worker, e, error, set, Eigen::Vector3d::Zero()});
            continue;
          }
          const CollisionObject& a = *objects_[pairs_[size_t(pair)][0]];
          const CollisionObject& b = *objects_[pairs_[size_t(pair)][1]];
          QueryOptions env_query = query;  // by default the GPU's direction, ties included (core::b_points_in_a)
          env_query.direction = resolve_direction(a, pa, b, pb, query.direction, in.tie);
          if (trajectory)
            query_contacts(a, pa, b, pb, env_query, set, scratch, trajectory->state);
          else
            query_contacts(a, pa, b, pb, env_query, set, scratch);
          visit({worker, e, 0, set, pa.apply(a.center_of_mass())});
        }
    } catch (const std::bad_alloc&) {
      out_of_memory = true;
      next = in.count;  // the other workers stop at their next chunk
    } catch (...) {
      raised[worker] = std::current_exception();  // the visitor's: raised again on the caller's thread
      next = in.count;
    }
  };
  run_workers(unsigned(raised.size()), work);
  if (out_of_memory) return Error{IssueCode::OutOfMemory, "batch: out of memory while querying"};
  for (const std::exception_ptr& e : raised)
    if (e) std::rethrow_exception(e);
  return Status::success();
}

Status BatchScene::contacts(const BatchEnvironments& in, const BatchOutputs& out, unsigned threads,
                            const std::function<void(const Visit&)>& after) const {
  if (const Status checked = check_batch(in, out); !checked) return checked;
  QueryOptions options;
  options.direction = QueryDirection::Auto;
  options.normal_source = NormalSource::DistanceGradient;
  options.interpolation = in.interpolation;
  return each_environment(in, options, threads, [&](const Visit& v) {
    if (v.error != 0) {
      write_error(out, v.environment, v.error);
    } else {
      write_environment(v.contacts, v.reference, in, out, v.environment);
      if (out.error) out.error[v.environment] = 0;
    }
    if (after) after(v);
  });
}

}  // namespace voxfmt::runtime
