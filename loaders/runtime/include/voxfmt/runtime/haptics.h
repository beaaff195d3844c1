// Haptic rendering with the Voxmap-PointShell query (the DLR seed's use case): a tool (its point shell) against
// a scene of objects (their voxelmaps), coupled to a 6-DoF device through a spring-damper (virtual coupling).
//
// Each cycle: the device pose comes in; the simulated tool, pulled by the coupling and pushed by the VPS contact
// wrench, advances one implicit Euler step; the coupling wrench goes out to the device. The tool is simulated
// rather than following the device so that a device pose inside an object (or beyond a thin wall) never puts the
// tool there: the contacts hold the tool, the coupling spring stretches, and the user feels the spring.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <thread>
#include <vector>

#include "voxfmt/runtime/collision_object.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::runtime {

// ---- A fixed-rate loop for haptic rendering: one thread, absolute deadlines, lock-free hand-off of the latest
// values between it and the rest of the program, overrun counting. No device SDK: a device is an interface.

/// The latest value from one producer thread to one consumer thread, wait-free on both sides (a triple buffer:
/// the producer never waits for the consumer and the consumer always gets a whole value, the newest one).
template <class T>
class LatestValue {
 public:
  /// Producer: makes `value` the latest.
  void publish(const T& value) {
    slots_[back_] = value;
    back_ = middle_.exchange(back_ | kFresh, std::memory_order_acq_rel) & kIndex;
  }
  /// Consumer: the latest value published (a default T before the first); `fresh` tells whether it is new
  /// since the last call.
  const T& latest(bool* fresh = nullptr) {
    const bool is_new = middle_.load(std::memory_order_relaxed) & kFresh;
    if (is_new) front_ = middle_.exchange(front_, std::memory_order_acq_rel) & kIndex;
    if (fresh) *fresh = is_new;
    return slots_[front_];
  }

 private:
  static constexpr uint8_t kIndex = 3, kFresh = 4;
  T slots_[3]{};
  uint8_t back_ = 0, front_ = 2;    // owned by the producer and the consumer
  std::atomic<uint8_t> middle_{1};  // the slot in between, with a "fresh" bit
};

/// A 6-DoF haptic device: reads its pose, displays a wrench. Called from the loop's thread only.
class HapticDevice {
 public:
  virtual ~HapticDevice() = default;
  /// The handle's pose at `time` seconds since the loop started.
  virtual Pose read_pose(double time) = 0;
  /// The wrench to display until the next cycle.
  virtual void write_wrench(const Wrench& wrench) = 0;
};

/// A device that follows a script (a pose for each time) and keeps the last wrench: tests, benchmarks, demos.
class ScriptedDevice : public HapticDevice {
 public:
  explicit ScriptedDevice(std::function<Pose(double)> script) : script_(std::move(script)) {}
  Pose read_pose(double time) override { return script_(time); }
  void write_wrench(const Wrench& wrench) override { last_ = wrench; }
  const Wrench& last_wrench() const { return last_; }

 private:
  std::function<Pose(double)> script_;
  Wrench last_;
};

struct LoopSettings {
  double rate_hz = 1000.0;  ///< 1 kHz default; 5 kHz and more are fine if a cycle fits; 0.001 Hz to 1 MHz
  /// The loop sleeps until this long before a deadline, then spins: the kernel wakes a sleeping thread tens of
  /// microseconds late, a fifth of a 5 kHz period. At least 0; one period or more is a busy wait.
  double spin_us = 80.0;
  /// Where the system permits (Linux; root or CAP_SYS_NICE / CAP_IPC_LOCK, or the matching rlimits): run the
  /// loop's thread under SCHED_FIFO at `priority`, so that ordinary threads never delay a wake-up; lock the
  /// process's memory (mlockall), so that no page fault stalls a cycle; pin the thread to CPU `cpu` (-1: any).
  /// LoopStats says what was granted; a request that is refused leaves the loop running as before.
  bool realtime_priority = false;
  int priority = 80;
  bool lock_memory = false;
  int cpu = -1;
};

struct LoopStats {
  uint64_t cycles = 0;
  uint64_t overruns = 0;           ///< cycles that ended after the next one's deadline (that deadline is then skipped)
  bool realtime_priority = false;  ///< SCHED_FIFO was granted
  bool memory_locked = false;      ///< mlockall succeeded
  int cpu = -1;                    ///< the CPU the thread is pinned to (-1: not pinned)
};

/// Runs `cycle(time, dt)` at a fixed rate on a thread of its own until stop() (or `max_cycles`). Deadlines are
/// absolute (start + k * period), so timing errors do not accumulate; an overrun skips the deadlines it missed
/// rather than running late cycles back to back.
class RealtimeLoop {
 public:
  using Cycle = std::function<void(double time, double dt)>;
  RealtimeLoop(const LoopSettings& settings, Cycle cycle) : settings_(settings), cycle_(std::move(cycle)) {}
  ~RealtimeLoop() { stop(); }
  RealtimeLoop(const RealtimeLoop&) = delete;
  RealtimeLoop& operator=(const RealtimeLoop&) = delete;

  /// Starts the thread; it runs `max_cycles` cycles (0 = until stop()). BAD_OPTION (and no thread) for a rate
  /// that is not in [0.001 Hz, 1 MHz], a spin that is negative or not finite, or a call from the loop's own cycle.
  Status start(uint64_t max_cycles = 0);
  /// Asks the thread to stop and joins it, within 20 ms however slow the rate (no cycle starts after it); called
  /// from the cycle itself, it asks only (the loop ends after the cycle, and is joined by stop(), join() or the
  /// destructor from another thread: the loop must outlive its own cycles, never be destroyed from one).
  void stop();
  /// Waits until the thread has run its cycles (from the loop's own cycle: returns at once). One thread at a
  /// time may join, stop or start a loop.
  void join();
  /// Counters so far (exact after join()/stop()).
  LoopStats stats() const {
    return {cycles_.load(), overruns_.load(), realtime_priority_.load(), memory_locked_.load(), cpu_.load()};
  }

 private:
  void run(uint64_t max_cycles);
  bool on_loop_thread() const;
  LoopSettings settings_;
  Cycle cycle_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<uint64_t> cycles_{0}, overruns_{0};
  std::atomic<bool> realtime_priority_{false}, memory_locked_{false};
  std::atomic<int> cpu_{-1};
  std::atomic<std::thread::id> loop_thread_{};  ///< set by the loop's thread itself (thread_ is the caller's)
};

// ---- Haptic rendering.

/// How to choose these: the contact stiffness (per penetrating point) sets how far the tool sinks in — with N
/// points in contact the surface is N times as stiff, and the tool rests where N * k_point * depth balances the
/// coupling force, so keep N * k_point well above `coupling_stiffness`. The coupling stiffness is what the user
/// feels: a device with physical damping b, sampled at period T, renders a spring passively only while
/// K < 2 b / T (Colgate and Schenkel's condition; coupling damping added in the virtual world relaxes it), so
/// 1-3 kN/m suits desktop devices at 1 kHz; at 5 kHz five times as much is passive. The tool's simulation is
/// implicit (backward Euler): the coupling (a saturated one as its secant, a softer linear spring) and the
/// contacts' stiffness linearised at the start of the cycle are in one 6x6 solve, so the coupling is stable for
/// any stiffness and time step (tested to 1 s steps). Contacts that first touch within a cycle enter the next
/// one, so a step large against the contacts' own period can still bounce.
struct HapticParameters {
  double contact_stiffness = 500.0;         ///< N/m per penetrating point (the seed's per-point penalty)
  double contact_damping = 0.05;            ///< N s/m per penetrating point, on its normal velocity
  double coupling_stiffness = 1000.0;       ///< N/m, tool to device
  double coupling_damping = 5.0;            ///< N s/m, on the tool's velocity relative to the device's
  double coupling_angular_stiffness = 2.0;  ///< N m/rad
  double coupling_angular_damping = 0.01;   ///< N m s/rad
  double max_force = 30.0;                  ///< N: the coupling force is saturated here (device and tool)
  double max_torque = 1.5;                  ///< N m
  double tool_mass = 0.2;                   ///< kg; the inertia is the asset's shape scaled to this mass
  /// Microseconds per cycle for all queries together (0 = none); see HapticRenderer for what a cut means.
  double time_budget_us = 0.0;
  /// Query settings (direction is always the tool's points in the objects' voxelmaps; normals are the tool's
  /// point normals, which turn smoothly with the tool, unlike a gradient of interpolated distances that
  /// turns at voxel faces).
  QueryOptions query;
};

/// What one cycle produced.
struct HapticCycle {
  Wrench device_wrench;   ///< on the device (the coupling's pull toward the tool), about the device's tool centre
  Wrench contact_wrench;  ///< on the tool, from every contact, about the tool's centre of mass
  size_t contacts = 0;    ///< penetrating points, all objects
  double max_penetration = 0.0;   ///< m, deepest point of the tool in any object
  uint32_t levels_completed = 0;  ///< smallest deepest-completed tree level over the objects' queries
  size_t points_tested = 0;       ///< all queries
  size_t nodes_visited = 0;
  bool time_budget_hit = false;
  double query_us = 0.0;      ///< wall time of the queries
  double query_cpu_us = 0.0;  ///< CPU time of the queries (what the level cap follows)
  /// The device pose was not finite (the cycle ran with the last finite one), or `dt` was not a finite time
  /// > 0, or the step's result was not finite (a `dt` of 1e160 s, a device at 1e300 m): then the cycle did not
  /// run, the tool is where it was and the outputs are the previous cycle's. One bad sample never poisons the tool.
  bool input_rejected = false;
};

class HapticRenderer {
 public:
  /// `tool` needs a point shell; `start` is the tool's (and the device's) pose at the first cycle. Throws
  /// std::invalid_argument for a tool without a point shell, a start pose that is not finite, a `tool_mass` that
  /// is not > 0, or a stiffness, damping, limit, budget or `query.proximity` that is negative or not finite.
  HapticRenderer(std::shared_ptr<const CollisionObject> tool, const Pose& start,
                 const HapticParameters& parameters = {});

  /// Adds an object (it needs a voxelmap: else std::invalid_argument) at `pose`; returns its index for
  /// set_object_pose (which throws std::out_of_range for an index it did not return). Both throw
  /// std::invalid_argument for a pose that is not finite (or a scale not > 0), and keep the object's last pose.
  size_t add_object(std::shared_ptr<const CollisionObject> object, const Pose& pose);
  void set_object_pose(size_t index, const Pose& pose);
  size_t object_count() const { return objects_.size(); }

  /// One haptic cycle of length `dt` seconds with the device at `device_pose` (see HapticCycle::input_rejected
  /// for a pose or `dt` that is not finite). No allocation after the first few cycles (buffers keep their capacity).
  const HapticCycle& step(const Pose& device_pose, double dt);

  /// The contact wrench on the tool (about its centre of mass) were it at `tool_pose`, from the full trees (no
  /// budget); contacts() holds the contacts after the call. For tests and offline force maps.
  Wrench contact_wrench_at(const Pose& tool_pose);

  /// The simulated tool.
  const Pose& tool_pose() const { return motion_.pose; }
  const Eigen::Vector3d& tool_velocity() const { return motion_.velocity; }
  const Eigen::Vector3d& tool_angular_velocity() const { return motion_.angular_velocity; }
  /// Energy at the start of the last cycle, J: the tool's kinetic energy, the coupling spring's (quadratic up to
  /// max_force / max_torque, linear beyond: the saturated spring's potential) and the contacts' penalty potential
  /// (k depth^2 / 2 per point).
  double energy() const { return motion_.energy; }
  /// Contacts of the last cycle (all objects, world frame, normals pushing the tool out).
  const std::vector<Contact>& contacts() const { return contacts_; }
  /// The tree level the renderer stops at. At the leaf level (no cut) the queries are coherent: each object keeps
  /// the tool's last traversal, so a cycle costs what moved. Every point of the tool is a surface point (the tree's
  /// levels are disjoint subsets of the shell), so a traversal cut at level L reports the points of levels 0..L that
  /// penetrate; each penetrating point of level L whose children were not reached counts with the weight of its
  /// subtree (the points it stands for), so the force keeps its size when the cut moves. With a time budget, a
  /// cycle whose queries take more CPU time than the budget moves the cap one level up (or to the level it
  /// completed, if deeper; full-tree cycles run to the end); it moves one level down after 100 cycles that used
  /// less than half the budget. So the cut changes rarely instead of flickering between levels, and a cycle the
  /// kernel delays (a late wake-up, a preemption) is cut where its wall-clock budget ran out but leaves the cap.
  uint32_t level_cap() const { return level_cap_; }
  const HapticParameters& parameters() const { return parameters_; }

 private:
  struct ContactTerms;
  struct Coupling;
  void gather_contacts(const Pose& tool_pose, double budget_us);
  void adapt_level_cap();
  ContactTerms contact_terms(const Eigen::Vector3d& com);
  Coupling couple(const Pose& device_pose, double dt, const Eigen::Vector3d& com_asset, const Eigen::Vector3d& com);
  void integrate(const ContactTerms& contact, const Coupling& coupling, double dt, const Eigen::Vector3d& com_asset,
                 const Eigen::Vector3d& com);
  double kinetic_energy(const Eigen::Matrix3d& rotation) const;
  struct Object {
    std::shared_ptr<const CollisionObject> object;
    Pose pose;
    QueryState state;  ///< the tool against this object: the last traversal, for the next cycle
  };
  std::shared_ptr<const CollisionObject> tool_;
  HapticParameters parameters_;
  std::vector<Object> objects_;
  Eigen::Matrix3d inertia_body_;  ///< about the centre of mass, asset frame, kg m^2
  /// What a step changes, kept whole so that a step the numbers cannot hold is undone whole.
  struct ToolState {
    Pose pose;
    Pose last_device_pose;
    bool have_last_device = false;
    Eigen::Vector3d velocity = Eigen::Vector3d::Zero();          ///< of the centre of mass
    Eigen::Vector3d angular_velocity = Eigen::Vector3d::Zero();  ///< world frame
    double energy = 0.0;
  };
  ToolState motion_;
  uint32_t level_cap_;
  uint32_t relaxed_cycles_ = 0;
  ContactSet scratch_set_;
  QueryScratch scratch_;
  std::vector<Contact> contacts_;
  std::vector<double> weights_;         ///< per contact: the points it stands for (its subtree at a cut)
  std::vector<uint32_t> subtree_size_;  ///< per tree node: itself and all its descendants
  HapticCycle cycle_;
};

/// Rotation vector (axis * angle, |angle| <= pi) of a rotation matrix.
Eigen::Vector3d rotation_vector(const Eigen::Matrix3d& rotation);

}  // namespace voxfmt::runtime
