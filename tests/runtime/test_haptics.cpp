// Haptic rendering on exact spheres and a wall made in code (no bake): forces against the closed form, the
// continuity bound along a sliding path, the time budget by counters, rest without oscillation growth, and a
// device jumping through a thin wall.
#include <gtest/gtest.h>

#include <pthread.h>
#include <sched.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <iostream>
#include <thread>

#include "analytic_sphere.h"
#include "voxfmt/runtime/haptics.h"

namespace voxfmt::runtime {
namespace {

constexpr double kToolRadius = 0.05, kObjectRadius = 0.1, kVoxel = 0.005;

std::shared_ptr<const CollisionObject> load(const Asset& asset) {
  auto loaded = CollisionObject::from_asset(asset);
  if (!loaded) throw std::runtime_error(loaded.error().describe());
  return loaded.value();
}

std::shared_ptr<const CollisionObject> tool() {
  static const auto object = load(test::make_sphere_asset({{0, 0, 0}, kToolRadius, kVoxel, 4000, 4}));
  return object;
}

std::shared_ptr<const CollisionObject> big_sphere() {
  static const auto object = load(test::make_sphere_asset({{0, 0, 0}, kObjectRadius, kVoxel, 2000, 4}));
  return object;
}

// A wall |x| <= kVoxel (two voxels thick) across the whole grid of a sphere asset: the sphere's voxelmap
// rewritten with the slab's exact distances.
std::shared_ptr<const CollisionObject> thin_wall() {
  static const auto object = [] {
    Asset a = test::make_sphere_asset({{0, 0, 0}, kObjectRadius, kVoxel, 2000, 4});
    a.voxelmap = make_voxelmap(a.voxelmap, [](const Vec3& p) { return std::abs(p[0]) - kVoxel; });
    return load(a);
  }();
  return object;
}

Pose at(double x, double y = 0, double z = 0, const Eigen::Matrix3d& rotation = Eigen::Matrix3d::Identity()) {
  Pose pose;
  pose.rotation = rotation;
  pose.translation = {x, y, z};
  return pose;
}

TEST(Haptics, ForceOfAKnownPenetrationMatchesTheClosedForm) {
  // The tool sphere 3 mm into the big one along +x: every tool point inside pushes with k * (R - |p|) along
  // its inward normal; the sum points along +x (the tool out of the big sphere).
  HapticParameters parameters;
  const double overlap = 0.003, x = kObjectRadius + kToolRadius - overlap;
  HapticRenderer renderer(tool(), at(x), parameters);
  renderer.add_object(big_sphere(), at(0));
  const Wrench w = renderer.contact_wrench_at(at(x));
  Eigen::Vector3d expected = Eigen::Vector3d::Zero();
  const PointTree& tree = tool()->point_tree();
  for (size_t i = 0; i < tree.size(); ++i) {
    const Eigen::Vector3d p = tree.asset_point(i) + Eigen::Vector3d(x, 0, 0);
    const double depth = kObjectRadius - p.norm();
    if (depth > 0) expected += parameters.contact_stiffness * depth * tree.normals[i].cast<double>();
  }
  ASSERT_GT(expected.norm(), 0.0);
  EXPECT_GT(w.force.x(), 0.0);
  EXPECT_LT(std::hypot(w.force.y(), w.force.z()), 0.02 * w.force.norm()) << w.force.transpose();
  EXPECT_NEAR(w.force.norm(), expected.norm(), 0.05 * expected.norm())
      << w.force.transpose() << " vs " << expected.transpose();
  // Contacts through the centres of spheres exert no torque about the tool's centre.
  EXPECT_LT(w.torque.norm(), 0.02 * w.force.norm() * kToolRadius);
}

TEST(Haptics, ForceIsContinuousAlongASlidingPath) {
  // The tool slides around the big sphere's surface 2 mm deep while turning. Per cycle, a tool point moves at
  // most d (translation + rotation times the tool's radius); its depth, interpolated trilinearly from samples of
  // a 1-Lipschitz distance, changes by at most sqrt(3) d, and its normal turns by the rotation angle a. So
  // |F1 - F0| <= k * (N sqrt(3) d + a * sum(depth)) with N the points in contact in either cycle.
  HapticParameters parameters;
  HapticRenderer renderer(tool(), at(0), parameters);
  renderer.add_object(big_sphere(), at(0));
  const double radius = kObjectRadius + kToolRadius - 0.002;
  Wrench previous;
  size_t previous_contacts = 0;
  double previous_depth_sum = 0, worst_ratio = 0;
  Pose previous_pose;
  for (int step = 0; step <= 400; ++step) {
    const double angle = 0.3 * step / 400.0, turn = 0.5 * step / 400.0;
    const Pose pose = at(radius * std::cos(angle), radius * std::sin(angle), 0.0,
                         Eigen::AngleAxisd(turn, Eigen::Vector3d(0.3, 0.4, 0.866).normalized()).toRotationMatrix());
    const Wrench w = renderer.contact_wrench_at(pose);
    double depth_sum = 0;
    for (const Contact& c : renderer.contacts()) depth_sum += c.depth;
    if (step > 0) {
      const double rotation = rotation_vector(pose.rotation * previous_pose.rotation.transpose()).norm();
      const double d = (pose.translation - previous_pose.translation).norm() + rotation * kToolRadius;
      const double n = double(std::max(previous_contacts, renderer.contacts().size()));
      const double bound =
          parameters.contact_stiffness * (n * std::sqrt(3.0) * d + rotation * std::max(depth_sum, previous_depth_sum));
      const double jump = (w.force - previous.force).norm();
      EXPECT_LE(jump, bound) << "step " << step;
      worst_ratio = std::max(worst_ratio, jump / bound);
    }
    EXPECT_GT(renderer.contacts().size(), 10u) << "step " << step;
    previous = w;
    previous_contacts = renderer.contacts().size();
    previous_depth_sum = depth_sum;
    previous_pose = pose;
  }
  RecordProperty("worst_jump_over_bound", std::to_string(worst_ratio));
}

TEST(Haptics, TimeBudgetIsHonouredByWholeLevels) {
  const PointTree& tree = tool()->point_tree();
  const Pose pose = at(kObjectRadius + kToolRadius - 0.003);
  {  // No budget: the leaves are reached.
    HapticRenderer renderer(tool(), pose);
    renderer.add_object(big_sphere(), at(0));
    const HapticCycle& cycle = renderer.step(pose, 1e-3);
    EXPECT_EQ(cycle.levels_completed, tree.level_count() - 1);
    EXPECT_FALSE(cycle.time_budget_hit);
  }
  // A budget nothing fits in. The first cycle, at the leaf level, runs the whole tree (coherent queries run to
  // the end) and, over budget, moves the cap one level up; every later cycle runs out of time, the cap moves up
  // one level per cycle, never above the level a cycle completed, and no cycle tests a point below the cap.
  HapticParameters parameters;
  parameters.time_budget_us = 1e-3;
  HapticRenderer renderer(tool(), pose, parameters);
  renderer.add_object(big_sphere(), at(0));
  const uint32_t leaf = uint32_t(tree.level_count() - 1);
  {
    const HapticCycle cycle = renderer.step(pose, 1e-3);
    EXPECT_FALSE(cycle.time_budget_hit);
    EXPECT_EQ(cycle.levels_completed, leaf);
    EXPECT_GT(cycle.query_cpu_us, parameters.time_budget_us);
    EXPECT_EQ(renderer.level_cap(), leaf - 1);
  }
  uint32_t cap = leaf - 1;
  for (int i = 1; i < 8; ++i) {
    const HapticCycle cycle = renderer.step(pose, 1e-3);
    EXPECT_TRUE(cycle.time_budget_hit || cap == 0) << "cycle " << i;
    EXPECT_LE(cycle.levels_completed, cap);
    EXPECT_LE(cycle.points_tested, tree.points_up_to_level(std::min(cap + 1, leaf)));
    EXPECT_EQ(renderer.level_cap(), std::max(cycle.levels_completed, cap > 0 ? cap - 1 : 0u)) << "cycle " << i;
    cap = std::min(renderer.level_cap(), leaf);
  }
  EXPECT_LT(cap, leaf);
}

TEST(Haptics, CoupledToolComesToRestWithoutOscillationGrowth) {
  // The device held 4 mm inside the big sphere; the tool starts 2 mm outside and is pulled in by the coupling.
  const Pose start = at(kObjectRadius + kToolRadius + 0.002);
  const Pose device = at(kObjectRadius + kToolRadius - 0.004);
  HapticRenderer renderer(tool(), start);
  renderer.add_object(big_sphere(), at(0));
  std::vector<double> energy, speed;
  double max_penetration = 0;
  for (int i = 0; i < 3000; ++i) {
    const HapticCycle& cycle = renderer.step(device, 1e-3);
    energy.push_back(renderer.energy());
    speed.push_back(renderer.tool_velocity().norm());
    if (i > 200) max_penetration = std::max(max_penetration, cycle.max_penetration);
  }
  // No oscillation growth: once the device stands still the energy never rises above what it was (the implicit
  // step dissipates; the point-shell normals are not exactly the penalty potential's gradient, which leaves
  // relative wobbles below 1e-5 at rest), and it ends well below its value early in the contact.
  double highest = energy[0];
  for (size_t i = 1; i < energy.size(); ++i) {
    EXPECT_LE(energy[i], highest * (1 + 1e-4)) << "cycle " << i;
    highest = std::max(highest, energy[i]);
  }
  EXPECT_LT(energy.back(), energy[50]);
  EXPECT_LT(speed.back(), 1e-4);
  const double early = *std::max_element(speed.begin() + 100, speed.begin() + 600);
  const double late = *std::max_element(speed.begin() + 2000, speed.end());
  EXPECT_LT(late, 0.1 * early + 1e-6);
  // At rest the coupling (4 mm stretch at most) is balanced by contacts less than a voxel deep.
  EXPECT_GT(renderer.contacts().size(), 0u);
  EXPECT_LT(max_penetration, kVoxel);
  EXPECT_GT(renderer.tool_pose().translation.x(), kObjectRadius + kToolRadius - kVoxel);
}

// With the device held at `device`, 2 s (at least 200 steps) of `dt`: the energy never rises from one step to the
// next, and the tool ends on the device, at rest.
void expect_settles_on(HapticRenderer& renderer, const Pose& device, double dt) {
  renderer.step(device, dt);
  double previous = renderer.energy();
  const int steps = std::max(200, int(2.0 / dt));
  for (int i = 0; i < steps; ++i) {
    renderer.step(device, dt);
    ASSERT_LE(renderer.energy(), previous * (1 + 1e-9) + 1e-12) << "dt " << dt << ", step " << i;
    previous = renderer.energy();
  }
  EXPECT_LT((renderer.tool_pose().translation - device.translation).norm(), 1e-4) << dt;
  EXPECT_LT(rotation_vector(renderer.tool_pose().rotation * device.rotation.transpose()).norm(), 1e-3) << dt;
  EXPECT_LT(renderer.tool_velocity().norm(), 1e-3) << dt;
}

TEST(Haptics, ASaturatedCouplingIsStableAtAnyTimeStep) {
  // The device 5 cm away and turned 2 rad: the coupling asks 50 N and 4 N m, saturated at 30 N and 1.5 N m.
  // Integrated explicitly, a saturated spring once swung the tool past the device and back for good (energy
  // from 1.25 J to 58 J at 50 ms steps). It is a softer implicit spring now: at every step size the energy (the
  // saturated spring's own potential) never rises from one step to the next, and the tool settles on the device.
  const Eigen::Matrix3d turned = Eigen::AngleAxisd(2.0, Eigen::Vector3d(0, 0, 1)).toRotationMatrix();
  for (const double dt : {1e-4, 1e-3, 0.03, 0.05, 0.2, 1.0}) {
    HapticRenderer renderer(tool(), at(0.05));
    expect_settles_on(renderer, at(0, 0, 0, turned), dt);
  }
}

TEST(Haptics, ACouplingSaturatedByAMovingDeviceAndItsDamperStaysBoundedAndSettles) {
  // The device swings round a 10 cm circle at 6 m/s, turning, then stops: the spring is stretched and the damper
  // asks 5 N s/m x 6 m/s, both past their 30 N. The tool follows within a bound at every step size; once the
  // device is still its energy never rises and it settles on the device, at 1 ms steps as at 0.2 s.
  for (const double dt : {1e-3, 0.03, 0.2}) {
    HapticRenderer renderer(tool(), at(0.1));
    const double omega = 60.0;  // rad/s
    auto device_at = [&](double t) {
      return at(0.1 * std::cos(omega * t), 0.1 * std::sin(omega * t), 0,
                Eigen::AngleAxisd(omega * t, Eigen::Vector3d(0, 0, 1)).toRotationMatrix());
    };
    const int moving = std::max(10, int(0.5 / dt));
    bool saturated = false;
    for (int i = 1; i <= moving; ++i) {
      const HapticCycle& cycle = renderer.step(device_at(i * dt), dt);
      saturated |= cycle.device_wrench.force.norm() > 0.99 * HapticParameters{}.max_force;
      ASSERT_LT((renderer.tool_pose().translation - device_at(i * dt).translation).norm(), 1.0)
          << "dt " << dt << ", step " << i;
      ASSERT_TRUE(std::isfinite(renderer.energy()));
    }
    EXPECT_TRUE(saturated) << dt;
    expect_settles_on(renderer, device_at(moving * dt), dt);
  }
}

TEST(Haptics, NoForceLimitMeansNoCoupling) {
  // max_force and max_torque of 0: the device feels nothing and the tool is not pulled (not even by the implicit
  // step's stiffness, which a limit of 0 once left in).
  HapticParameters parameters;
  parameters.max_force = parameters.max_torque = 0;
  HapticRenderer renderer(tool(), at(0.05), parameters);
  for (int i = 0; i < 100; ++i) {
    const HapticCycle& cycle =
        renderer.step(at(0, 0, 0, Eigen::AngleAxisd(1.0, Eigen::Vector3d::UnitX()).matrix()), 1e-3);
    ASSERT_EQ(cycle.device_wrench.force.norm(), 0.0);
    ASSERT_EQ(cycle.device_wrench.torque.norm(), 0.0);
  }
  EXPECT_EQ(renderer.tool_pose().translation.x(), 0.05);
  EXPECT_EQ(renderer.tool_velocity().norm(), 0.0);
}

TEST(Haptics, DeviceJumpingThroughAThinWallLeavesTheToolOnTheNearSide) {
  // The wall is two voxels (10 mm) thick at x = 0. The device jumps from x = -60 mm (tool 10 mm in front of
  // the wall) to x = +80 mm in one cycle and stays there: the coupling pulls the tool at full force, the
  // contacts hold it. Per-point stiffness for this coarse tool (4,000 points on a 5 cm sphere, 1/8 of the bunny's
  // density): 30 N are held by ~25 points 1/3 voxel deep.
  HapticParameters parameters;
  parameters.contact_stiffness = 2000.0;
  HapticRenderer renderer(tool(), at(-0.06), parameters);
  renderer.add_object(thin_wall(), at(0));
  double furthest = -1;
  for (int i = 0; i < 2000; ++i) {
    renderer.step(at(0.08), 1e-3);
    furthest = std::max(furthest, renderer.tool_pose().translation.x() + kToolRadius);
  }
  EXPECT_LT(furthest, 0.0) << "the tool's front passed the wall's centre plane";
  EXPECT_GT(renderer.contacts().size(), 0u);
  EXPECT_LT(renderer.tool_pose().translation.x() + kToolRadius, -0.5 * kVoxel) << "at rest, half a voxel in";
}

TEST(Haptics, ANonFiniteSampleIsRejectedAndNeverPoisonsTheTool) {
  // One NaN device pose or time step once made every later output NaN, for good.
  const double x = kObjectRadius + kToolRadius - 0.002;
  HapticRenderer renderer(tool(), at(x));
  renderer.add_object(big_sphere(), at(0));
  const Wrench first = renderer.step(at(x), 1e-3).device_wrench;
  Pose bad = at(x);
  bad.translation.y() = NAN;
  EXPECT_TRUE(renderer.step(bad, 1e-3).input_rejected);
  for (const double dt : {double(NAN), double(INFINITY), 0.0, -1e-3}) {
    const HapticCycle& cycle = renderer.step(at(x), dt);
    EXPECT_TRUE(cycle.input_rejected) << dt;
    EXPECT_TRUE(cycle.device_wrench.force.allFinite()) << dt;
  }
  for (int i = 0; i < 100; ++i) {
    const HapticCycle& cycle = renderer.step(at(x), 1e-3);
    ASSERT_FALSE(cycle.input_rejected);
    ASSERT_TRUE(cycle.device_wrench.force.allFinite() && cycle.contact_wrench.force.allFinite()) << i;
  }
  EXPECT_TRUE(first.force.allFinite());
  // Parameters that are not finite or negative are refused where the renderer is made.
  for (double HapticParameters::*field : {&HapticParameters::contact_stiffness, &HapticParameters::coupling_stiffness,
                                          &HapticParameters::max_force, &HapticParameters::tool_mass}) {
    for (const double value : {-1.0, double(NAN), double(INFINITY)}) {
      HapticParameters parameters;
      parameters.*field = value;
      EXPECT_THROW(HapticRenderer(tool(), at(x), parameters), std::invalid_argument) << value;
    }
  }
  Pose nowhere = at(x);
  nowhere.translation.x() = INFINITY;
  EXPECT_THROW(HapticRenderer(tool(), nowhere), std::invalid_argument);
  for (const double proximity : {-1e-3, double(NAN)}) {  // dropped contacts, or every contact
    HapticParameters parameters;
    parameters.query.proximity = proximity;
    EXPECT_THROW(HapticRenderer(tool(), at(x), parameters), std::invalid_argument) << proximity;
  }
}

TEST(Haptics, AStepTheNumbersCannotHoldIsRejectedWhole) {
  // A finite but absurd time step overflowed the implicit solve: the tool became NaN for good.
  const double x = kObjectRadius + kToolRadius - 0.002;
  for (const double dt : {1e160, 5e-324}) {
    HapticRenderer renderer(tool(), at(x));
    renderer.add_object(big_sphere(), at(0));
    const Wrench before = renderer.step(at(x), 1e-3).device_wrench;
    const Pose tool_before = renderer.tool_pose();
    const HapticCycle& odd = renderer.step(at(x + 0.01), dt);
    EXPECT_TRUE(odd.input_rejected) << dt;
    EXPECT_TRUE(odd.device_wrench.force.isApprox(before.force) || odd.device_wrench.force == before.force) << dt;
    EXPECT_TRUE(renderer.tool_pose().translation == tool_before.translation) << dt;
    for (int i = 0; i < 20; ++i) {
      const HapticCycle& cycle = renderer.step(at(x), 1e-3);
      ASSERT_FALSE(cycle.input_rejected) << dt;
      ASSERT_TRUE(cycle.device_wrench.force.allFinite() && renderer.tool_pose().translation.allFinite()) << dt;
    }
  }
  // A device far away pulls with the saturated force, not with none (its distance squared overflowed).
  HapticParameters parameters;
  HapticRenderer renderer(tool(), at(x), parameters);
  const HapticCycle& far = renderer.step(at(1e160), 1e-3);
  EXPECT_FALSE(far.input_rejected);
  EXPECT_NEAR(far.device_wrench.force.x(), -parameters.max_force, 1e-9 * parameters.max_force);
}

TEST(Haptics, AnObjectPoseThatIsNotFiniteIsRefusedAndNeverPoisonsTheContacts) {
  // A NaN pose once became the anchor of the pair's coherent front: no contact for the next 1023 cycles.
  const double x = kObjectRadius + kToolRadius - 0.002;
  HapticRenderer renderer(tool(), at(x));
  Pose bad = at(0);
  bad.translation.x() = NAN;
  EXPECT_THROW(renderer.add_object(big_sphere(), bad), std::invalid_argument);
  const size_t id = renderer.add_object(big_sphere(), at(0));
  EXPECT_THROW(renderer.set_object_pose(id, bad), std::invalid_argument);
  EXPECT_GT(renderer.step(at(x), 1e-3).contacts, 0u);
  // The tool itself at a NaN pose (contact_wrench_at takes any pose): no contact, and the next pose finds them.
  Pose nowhere = at(x);
  nowhere.translation.y() = NAN;
  EXPECT_EQ(renderer.contact_wrench_at(nowhere).force.norm(), 0.0);
  const Wrench after = renderer.contact_wrench_at(at(x));
  EXPECT_GT(renderer.contacts().size(), 0u);
  EXPECT_GT(after.force.x(), 0.0);
}

TEST(RealtimeLoop, RunsTheCyclesAndHandsOffTheLatestValue) {
  LatestValue<Wrench> latest;
  int calls = 0;
  double last_time = -1;
  RealtimeLoop loop({2000.0, 80.0}, [&](double time, double dt) {
    ++calls;
    EXPECT_GT(time, last_time);
    EXPECT_GE(dt, 0.5e-3 - 1e-12);
    last_time = time;
    Wrench w;
    w.force.x() = calls;
    latest.publish(w);
  });
  ASSERT_TRUE(loop.start(200));
  loop.join();
  EXPECT_EQ(calls, 200);
  EXPECT_EQ(loop.stats().cycles, 200u);
  bool fresh = false;
  EXPECT_EQ(latest.latest(&fresh).force.x(), 200.0);
  EXPECT_TRUE(fresh);
  latest.latest(&fresh);
  EXPECT_FALSE(fresh);
}

TEST(RealtimeLoop, BadSettingsAreRefusedAndTheCycleMayStopItsOwnLoop) {
  // A rate of 0 or NaN once ran a busy loop with NaN steps; 2 GHz divided by a period of 0; a negative spin
  // held stop() for seconds.
  int calls = 0;
  // A period beyond the clock's range (1e-11 Hz) overflowed it and spun millions of cycles.
  for (const LoopSettings settings :
       {LoopSettings{0.0, 80.0}, LoopSettings{double(NAN), 80.0}, LoopSettings{2e9, 0.0}, LoopSettings{1e-11, 0.0},
        LoopSettings{1000.0, -1e7}, LoopSettings{1000.0, double(NAN)}}) {
    RealtimeLoop loop(settings, [&](double, double) { ++calls; });
    const Status started = loop.start(10);
    ASSERT_FALSE(started);
    EXPECT_EQ(started.error().code, IssueCode::BadOption);
  }
  EXPECT_EQ(calls, 0);
  RealtimeLoop* self = nullptr;
  bool restart_refused = false;
  RealtimeLoop loop({2000.0, 80.0}, [&](double, double) {
    if (++calls == 3) {
      restart_refused = !self->start();  // a thread assigned over itself: terminate
      self->stop();                      // once std::system_error (a thread joining itself): terminate
    }
  });
  self = &loop;
  ASSERT_TRUE(loop.start());
  loop.join();
  EXPECT_EQ(calls, 3);
  EXPECT_TRUE(restart_refused);
  // A spin longer than the period (20 kHz, 80 us) is a busy wait, not an error.
  RealtimeLoop busy({20000.0, 80.0}, [&](double, double) { ++calls; });
  ASSERT_TRUE(busy.start(20));
  busy.join();
  EXPECT_EQ(busy.stats().cycles, 20u);
}

TEST(RealtimeLoop, StopReturnsWithinASliceOfASlowPeriodAndRunsNoMoreCycles) {
  // stop() waited out the period (10 s at 0.1 Hz), then ran one more cycle.
  std::atomic<int> calls{0};
  RealtimeLoop loop({0.1, 0.0}, [&](double, double) { ++calls; });
  ASSERT_TRUE(loop.start());
  while (calls.load() == 0) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  const auto asked = std::chrono::steady_clock::now();
  loop.stop();
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - asked).count(), 2.0);
  EXPECT_EQ(calls.load(), 1);
}

TEST(RealtimeLoop, ReportsTheSchedulingItWasGranted) {
  // SCHED_FIFO and a pinned CPU where the system permits: what the loop reports is what its thread runs with.
  // (Not mlockall: under a sanitizer's reserved shadow memory it would try to lock terabytes.)
  LoopSettings settings{2000.0, 80.0};
  settings.realtime_priority = true;
  settings.cpu = 0;
  int policy = -1, cpu = -1;
  RealtimeLoop loop(settings, [&](double, double) {
    sched_param param{};
    pthread_getschedparam(pthread_self(), &policy, &param);
    cpu = sched_getcpu();
  });
  ASSERT_TRUE(loop.start(20));
  loop.join();
  const LoopStats stats = loop.stats();
  EXPECT_EQ(stats.cycles, 20u);
  EXPECT_EQ(policy == SCHED_FIFO, stats.realtime_priority);
  if (stats.cpu >= 0) {
    EXPECT_EQ(stats.cpu, 0);
    EXPECT_EQ(cpu, 0);
  }
  EXPECT_FALSE(stats.memory_locked);
  std::cout << "[ figures  ] SCHED_FIFO " << (stats.realtime_priority ? "granted" : "refused") << ", CPU "
            << (stats.cpu >= 0 ? "pinned" : "not pinned") << "\n";
}

}  // namespace
}  // namespace voxfmt::runtime
