#include "voxfmt/runtime/haptics.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <limits>
#include <stdexcept>

namespace voxfmt::runtime {

namespace {

using Clock = std::chrono::steady_clock;

// CPU time of the calling thread: the computation's own time, which a preemption or a late wake-up does not add to.
double thread_cpu_us() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return double(t.tv_sec) * 1e6 + double(t.tv_nsec) * 1e-3;
}
using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Vector6d = Eigen::Matrix<double, 6, 1>;

Eigen::Matrix3d exp_rotation(const Eigen::Vector3d& w) {
  const double angle = w.norm();
  if (angle < 1e-12) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

// The factor in [0, 1] that brings v's length down to the limit (1 when it is within it; 0 for no force at all).
double saturation_scale(const Eigen::Vector3d& v, double limit) {
  if (limit <= 0) return 0.0;
  const double n = v.stableNorm();  // a device metres away from the tool: its square would overflow
  return n > limit ? limit / n : 1.0;
}

// The energy of a spring of stiffness k stretched by x whose force is capped at `limit`: quadratic up to the cap,
// then linear (the saturated spring's own potential, which the implicit step never lets rise).
double saturated_spring_energy(double k, double x, double limit) {
  if (k * x <= limit) return 0.5 * k * x * x;
  return limit * x - 0.5 * limit * limit / k;
}

}  // namespace

Eigen::Vector3d rotation_vector(const Eigen::Matrix3d& rotation) {
  const Eigen::AngleAxisd aa(rotation);
  double angle = aa.angle();
  Eigen::Vector3d axis = aa.axis();
  if (angle > M_PI) {
    angle = 2 * M_PI - angle;
    axis = -axis;
  }
  return axis * angle;
}

namespace {
bool finite_pose(const Pose& pose) {
  return pose.rotation.allFinite() && pose.translation.allFinite() && std::isfinite(pose.scale) && pose.scale > 0;
}
}  // namespace

HapticRenderer::HapticRenderer(std::shared_ptr<const CollisionObject> tool, const Pose& start,
                               const HapticParameters& parameters)
    : tool_(std::move(tool)), parameters_(parameters), motion_{start, {}}, level_cap_(parameters.query.max_level) {
  if (!tool_ || !tool_->has_point_shell()) throw std::invalid_argument("HapticRenderer: the tool needs a point shell");
  if (!(parameters_.tool_mass > 0 && std::isfinite(parameters_.tool_mass)))
    throw std::invalid_argument("HapticRenderer: tool_mass must be finite and > 0");
  if (!finite_pose(start)) throw std::invalid_argument("HapticRenderer: the start pose must be finite");
  if (!(parameters_.query.proximity >= 0 && std::isfinite(parameters_.query.proximity)))
    throw std::invalid_argument("HapticRenderer: query.proximity must be finite and >= 0");
  if (parameters_.time_budget_us >= kNoTimeBudgetUs) parameters_.time_budget_us = 0.0;  // none, as a query's
  const HapticParameters& p = parameters_;
  // A negative stiffness or limit threw the tool hundreds of metres; NaN made every later output NaN.
  for (const double value :
       {p.contact_stiffness, p.contact_damping, p.coupling_stiffness, p.coupling_damping, p.coupling_angular_stiffness,
        p.coupling_angular_damping, p.max_force, p.max_torque, p.time_budget_us})
    if (!(value >= 0 && std::isfinite(value)))
      throw std::invalid_argument(
          "HapticRenderer: stiffnesses, damping, limits and the time budget must be finite "
          "and >= 0");
  const double volume = tool_->volume() > 0 ? tool_->volume() : 1.0;
  const double s = start.scale;
  // Unit-density inertia scales with length^5; the mass is fixed, so the density is mass / (s^3 volume).
  inertia_body_ = tool_->inertia_unit_density() * (s * s * parameters_.tool_mass / volume);
  if (!(inertia_body_.determinant() > 0)) {
    // A shell-mode or degenerate asset: a solid sphere of the bounding radius keeps the simulation well-posed.
    const double r = std::max(tool_->bounding_radius() * s, 1e-3);
    inertia_body_ = Eigen::Matrix3d::Identity() * (0.4 * parameters_.tool_mass * r * r);
  }
  contacts_.reserve(1024);
  weights_.reserve(1024);
  scratch_set_.contacts.reserve(1024);
  // Breadth-first order puts children after parents: one backward pass sums the subtrees.
  const PointTree& tree = tool_->point_tree();
  subtree_size_.assign(tree.size(), 1);
  for (size_t n = tree.size(); n-- > 0;)
    for (uint32_t c = tree.nodes[n].first_child; c < tree.nodes[n].first_child + tree.nodes[n].child_count; ++c)
      subtree_size_[n] += subtree_size_[c];
}

size_t HapticRenderer::add_object(std::shared_ptr<const CollisionObject> object, const Pose& pose) {
  if (!object || !object->has_voxelmap()) throw std::invalid_argument("HapticRenderer: an object needs a voxelmap");
  if (!finite_pose(pose)) throw std::invalid_argument("HapticRenderer: an object's pose must be finite");
  objects_.push_back({std::move(object), pose, {}});
  return objects_.size() - 1;
}

void HapticRenderer::set_object_pose(size_t index, const Pose& pose) {
  Object& object = objects_.at(index);
  if (!finite_pose(pose)) throw std::invalid_argument("HapticRenderer: an object's pose must be finite");
  object.pose = pose;
}

double HapticRenderer::kinetic_energy(const Eigen::Matrix3d& rotation) const {
  const Eigen::Matrix3d inertia_world = rotation * inertia_body_ * rotation.transpose();
  return 0.5 * parameters_.tool_mass * motion_.velocity.squaredNorm() +
         0.5 * motion_.angular_velocity.dot(inertia_world * motion_.angular_velocity);
}

void HapticRenderer::gather_contacts(const Pose& tool_pose, double budget_us) {
  // The tool's points in every object's voxelmap; the budget is shared by the queries left.
  const auto start = Clock::now();
  contacts_.clear();
  weights_.clear();
  const PointTree& tree = tool_->point_tree();
  const uint32_t leaf_level = uint32_t(tree.level_count() - 1);
  QueryOptions options = parameters_.query;
  options.direction = QueryDirection::APointsInB;
  options.normal_source = NormalSource::PointShell;
  options.cut_level = CutLevel::Points;
  options.refine_cut_contacts = false;  // a cut point stands for its subtree (below): refined, it would count twice
  options.max_level = std::min(options.max_level, level_cap_);
  options.time_budget_us = 0.0;
  // No level cut and no point budget: the queries keep a traversal front per object.
  const bool full_tree = options.max_level >= leaf_level && options.point_budget == std::numeric_limits<size_t>::max();
  if (full_tree) options.max_level = std::numeric_limits<uint32_t>::max();
  cycle_.levels_completed = objects_.empty() ? 0 : std::numeric_limits<uint32_t>::max();
  for (size_t i = 0; i < objects_.size(); ++i) {
    if (budget_us > 0) {
      const double spent = std::chrono::duration<double, std::micro>(Clock::now() - start).count();
      options.time_budget_us = std::max(1e-3, (budget_us - spent) / double(objects_.size() - i));
    }
    scratch_set_.clear();
    if (full_tree) {
      // The whole tree, coherent with this pair's last cycles: a cycle costs what moved. Its time is checked by
      // the caller (a late cycle moves the cap up, and the budgeted traversals take over).
      QueryOptions coherent = options;
      coherent.time_budget_us = 0.0;
      query_contacts(*tool_, tool_pose, *objects_[i].object, objects_[i].pose, coherent, scratch_set_, scratch_,
                     objects_[i].state);
    } else {
      query_contacts(*tool_, tool_pose, *objects_[i].object, objects_[i].pose, options, scratch_set_, scratch_);
    }
    const QueryStats& stats = scratch_set_.stats;
    cycle_.levels_completed = std::min(cycle_.levels_completed, stats.deepest_level);
    cycle_.points_tested += stats.points_tested;
    cycle_.nodes_visited += stats.nodes_visited;
    cycle_.time_budget_hit |= stats.time_budget_hit;
    // A point of the last level tested whose children were not reached stands for its whole subtree.
    const uint32_t cut = stats.deepest_level;
    const uint32_t cut_begin = tree.level_offsets[std::min(cut, leaf_level)];
    const uint32_t cut_end = tree.level_offsets[std::min(cut, leaf_level) + 1];
    for (const Contact& c : scratch_set_.contacts) {
      if (!(c.depth > 0)) continue;
      const bool stands_for_subtree = cut < leaf_level && c.point_index >= cut_begin && c.point_index < cut_end;
      contacts_.push_back(c);
      weights_.push_back(stands_for_subtree ? double(subtree_size_[c.point_index]) : 1.0);
    }
  }
}

Wrench HapticRenderer::contact_wrench_at(const Pose& tool_pose) {
  cycle_ = HapticCycle{};
  gather_contacts(tool_pose, 0.0);
  const Eigen::Vector3d com = tool_pose.apply(tool_->center_of_mass());
  Wrench w;
  for (size_t i = 0; i < contacts_.size(); ++i) {
    const Contact& c = contacts_[i];
    const Eigen::Vector3d f = parameters_.contact_stiffness * weights_[i] * c.depth * c.normal;
    w.force += f;
    w.torque += (c.point - com).cross(f);
  }
  return w;
}

// The contacts' wrench about the centre of mass `com`, the stiffness of its linearisation and its energy.
struct HapticRenderer::ContactTerms {
  Matrix6d stiffness = Matrix6d::Zero();
  Vector6d wrench = Vector6d::Zero();
  double energy = 0.0;
};

// The spring and damper from the tool to the device's pose of it. A saturated coupling is the same spring and
// damper scaled down (its secant: the scale times their force is the saturated force at this stretch and
// velocity), so the implicit step treats it as a softer linear spring and stays stable however large the step.
struct HapticRenderer::Coupling {
  Eigen::Vector3d force, torque;
  double force_scale = 1.0, torque_scale = 1.0;  ///< in [0, 1]; below 1 where saturated
  double energy = 0.0;
};

const HapticCycle& HapticRenderer::step(const Pose& device_pose, double dt) {
  if (!(dt > 0 && std::isfinite(dt))) {  // no time to integrate: the last outputs stand
    cycle_.input_rejected = true;
    return cycle_;
  }
  // A pose that is not finite is replaced by the last finite one (before the first: the start, where the tool is).
  const bool pose_ok = finite_pose(device_pose);
  const Pose device = pose_ok ? device_pose : motion_.have_last_device ? motion_.last_device_pose : motion_.pose;
  const HapticCycle previous = cycle_;
  cycle_ = HapticCycle{};
  cycle_.input_rejected = !pose_ok;
  const Eigen::Vector3d com_asset = tool_->center_of_mass();
  const Eigen::Vector3d com = motion_.pose.apply(com_asset);
  const auto start = Clock::now();
  const double cpu_start = thread_cpu_us();
  gather_contacts(motion_.pose, parameters_.time_budget_us);
  cycle_.query_us = std::chrono::duration<double, std::micro>(Clock::now() - start).count();
  cycle_.query_cpu_us = thread_cpu_us() - cpu_start;
  adapt_level_cap();
  const ContactTerms contact = contact_terms(com);
  const ToolState before = motion_;
  const Coupling coupling = couple(device, dt, com_asset, com);
  motion_.energy = kinetic_energy(motion_.pose.rotation) + contact.energy + coupling.energy;
  integrate(contact, coupling, dt, com_asset, com);
  // A step the numbers cannot hold (a time step of 1e160 s, a device at 1e300 m) is rejected whole: one bad sample
  // never poisons the tool.
  if (!(motion_.velocity.allFinite() && motion_.angular_velocity.allFinite() && finite_pose(motion_.pose) &&
        cycle_.device_wrench.force.allFinite() && cycle_.device_wrench.torque.allFinite())) {
    motion_ = before;
    cycle_ = previous;
    cycle_.input_rejected = true;
  }
  return cycle_;
}

void HapticRenderer::adapt_level_cap() {
  const HapticParameters& p = parameters_;
  if (p.time_budget_us <= 0) return;
  // The cap follows the queries' own (CPU) time, not the wall clock: a cycle delayed by the kernel or another
  // process is cut where its budget ran out, but does not move the cap. Over budget: one level shallower (or the
  // level completed, if deeper). Back one level deeper after 100 cycles in less than half the budget.
  const PointTree& tree = tool_->point_tree();
  const uint32_t leaf_level = uint32_t(tree.level_count() - 1);
  const uint32_t effective = std::min(level_cap_, leaf_level);
  if (cycle_.query_cpu_us > p.time_budget_us && effective > 0) {
    // A budgeted traversal that ran out keeps the level it completed; a full-tree (coherent) one runs to the end.
    level_cap_ = cycle_.time_budget_hit ? std::max(cycle_.levels_completed, effective - 1) : effective - 1;
    relaxed_cycles_ = 0;
  } else if (cycle_.query_cpu_us < 0.5 * p.time_budget_us && effective < leaf_level) {
    if (++relaxed_cycles_ >= 100) {
      level_cap_ = effective + 1 >= leaf_level ? p.query.max_level : effective + 1;
      relaxed_cycles_ = 0;
    }
  } else {
    relaxed_cycles_ = 0;
  }
}

HapticRenderer::ContactTerms HapticRenderer::contact_terms(const Eigen::Vector3d& com) {
  const HapticParameters& p = parameters_;
  ContactTerms t;
  for (size_t i = 0; i < contacts_.size(); ++i) {
    const Contact& c = contacts_[i];
    const double weight = weights_[i];
    Vector6d j;  // generalized direction of the point's normal: [n, r x n]
    j.head<3>() = c.normal;
    j.tail<3>() = (c.point - com).cross(c.normal);
    t.wrench += (p.contact_stiffness * weight * c.depth) * j;
    t.stiffness += weight * j * j.transpose();
    t.energy += 0.5 * p.contact_stiffness * weight * c.depth * c.depth;
    cycle_.max_penetration = std::max(cycle_.max_penetration, c.depth);
  }
  cycle_.contacts = contacts_.size();
  cycle_.contact_wrench.force = t.wrench.head<3>();
  cycle_.contact_wrench.torque = t.wrench.tail<3>();
  return t;
}

HapticRenderer::Coupling HapticRenderer::couple(const Pose& device_pose, double dt, const Eigen::Vector3d& com_asset,
                                                const Eigen::Vector3d& com) {
  const HapticParameters& p = parameters_;
  const Eigen::Vector3d device_com = device_pose.apply(com_asset);
  Eigen::Vector3d device_velocity = Eigen::Vector3d::Zero(), device_angular_velocity = Eigen::Vector3d::Zero();
  if (motion_.have_last_device && dt > 0) {
    device_velocity = (device_com - motion_.last_device_pose.apply(com_asset)) / dt;
    device_angular_velocity =
        rotation_vector(device_pose.rotation * motion_.last_device_pose.rotation.transpose()) / dt;
  }
  motion_.last_device_pose = device_pose;
  motion_.have_last_device = true;
  const Eigen::Vector3d stretch = device_com - com;
  const Eigen::Vector3d twist = rotation_vector(device_pose.rotation * motion_.pose.rotation.transpose());
  Coupling c;
  c.energy = saturated_spring_energy(p.coupling_stiffness, stretch.stableNorm(), p.max_force) +
             saturated_spring_energy(p.coupling_angular_stiffness, twist.stableNorm(), p.max_torque);
  const Eigen::Vector3d force =
      p.coupling_stiffness * stretch + p.coupling_damping * (device_velocity - motion_.velocity);
  const Eigen::Vector3d torque = p.coupling_angular_stiffness * twist +
                                 p.coupling_angular_damping * (device_angular_velocity - motion_.angular_velocity);
  c.force_scale = saturation_scale(force, p.max_force);
  c.torque_scale = saturation_scale(torque, p.max_torque);
  c.force = c.force_scale * force;
  c.torque = c.torque_scale * torque;
  cycle_.device_wrench.force = -c.force;
  cycle_.device_wrench.torque = -c.torque;
  return c;
}

// Implicit Euler: (M + dt D + dt^2 K) v' = M v + dt (F(x, v) + D v), with K and D the linearised stiffness and
// damping of the coupling (scaled where saturated) and the contacts. Unconditionally stable for these linear
// springs. Then the pose moves about the centre of mass.
void HapticRenderer::integrate(const ContactTerms& contact, const Coupling& coupling, double dt,
                               const Eigen::Vector3d& com_asset, const Eigen::Vector3d& com) {
  const HapticParameters& p = parameters_;
  const Eigen::Matrix3d rot = motion_.pose.rotation;
  Matrix6d mass = Matrix6d::Zero();
  mass.topLeftCorner<3, 3>() = Eigen::Matrix3d::Identity() * p.tool_mass;
  mass.bottomRightCorner<3, 3>() = rot * inertia_body_ * rot.transpose();
  Matrix6d damping = p.contact_damping * contact.stiffness;
  Matrix6d stiffness = p.contact_stiffness * contact.stiffness;
  damping.topLeftCorner<3, 3>() += Eigen::Matrix3d::Identity() * (coupling.force_scale * p.coupling_damping);
  stiffness.topLeftCorner<3, 3>() += Eigen::Matrix3d::Identity() * (coupling.force_scale * p.coupling_stiffness);
  damping.bottomRightCorner<3, 3>() +=
      Eigen::Matrix3d::Identity() * (coupling.torque_scale * p.coupling_angular_damping);
  stiffness.bottomRightCorner<3, 3>() +=
      Eigen::Matrix3d::Identity() * (coupling.torque_scale * p.coupling_angular_stiffness);
  Vector6d velocity;
  velocity << motion_.velocity, motion_.angular_velocity;
  Vector6d force = contact.wrench;
  force.head<3>() += coupling.force;
  force.tail<3>() += coupling.torque;
  // The contact damping is not in `force`, only in the implicit matrix: add its explicit part back so the
  // linearisation is consistent (F_damp(v') = -D_contact v').
  const Vector6d rhs = mass * velocity + dt * (force + (damping - p.contact_damping * contact.stiffness) * velocity);
  const Matrix6d system = mass + dt * damping + dt * dt * stiffness;
  const Vector6d next = system.ldlt().solve(rhs);
  motion_.velocity = next.head<3>();
  motion_.angular_velocity = next.tail<3>();
  const Eigen::Vector3d next_com = com + dt * motion_.velocity;
  motion_.pose.rotation = exp_rotation(dt * motion_.angular_velocity) * rot;
  motion_.pose.translation = next_com - motion_.pose.rotation * (motion_.pose.scale * com_asset);
}

}  // namespace voxfmt::runtime
