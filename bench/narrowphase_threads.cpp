// narrowphase-threads: the narrow phase of a pile of VPS bunnies sharing one loaded asset, on 1 and 2 threads.
//
// The bunnies (CGAL's bunny00.off at 0.15 m, resolution 128, 10,000 points, baked once into --cache) drop into a
// 0.5 m box (a box floor, plane walls) and pile up, 1 kHz. Each run builds the same world from scratch; only the
// dispatcher differs: voxfmt's ParallelCollisionDispatcher on each thread count (the same simulation to the bit
// on any count, so every run does the same work: checked), and Bullet's btCollisionDispatcherMt with the same
// task scheduler (sequential in a Bullet built without BT_THREADSAFE, like Debian's). Runs alternate between the
// configurations, --repeat times; each configuration's figure is the median of its runs, its speed-up the median
// of its ratios to the first configuration within each round. Timed: the dispatcher's
// dispatchAllCollisionPairs (every pair of a step), and the whole stepSimulation.
#include <BulletCollision/CollisionDispatch/btCollisionDispatcherMt.h>
#include <btBulletDynamicsCommon.h>
#include <unistd.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "common/figures.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/bullet/collision.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/cores.h"

namespace {

namespace fs = std::filesystem;
using namespace voxfmt_bench;  // quantile, mean, fixed, load_average
using Clock = std::chrono::steady_clock;
constexpr btScalar kDt = btScalar(1e-3);
constexpr double kHalfBox = 0.25;

double micros(Clock::duration d) { return std::chrono::duration<double, std::micro>(d).count(); }

/// A dispatcher whose narrow phase (all pairs of a step) is timed.
template <class Base>
class Timed : public Base {
 public:
  using Base::Base;
  void dispatchAllCollisionPairs(btOverlappingPairCache* pairs, const btDispatcherInfo& info,
                                 btDispatcher* dispatcher) override {
    const auto start = Clock::now();
    Base::dispatchAllCollisionPairs(pairs, info, dispatcher);
    step_us.push_back(micros(Clock::now() - start));
  }
  std::vector<double> step_us;
};

enum class Dispatch { Parallel, BulletMt };

struct Config {
  Dispatch dispatch;
  int threads;
  std::string name() const {
    return dispatch == Dispatch::Parallel ? "voxfmt ParallelCollisionDispatcher" : "btCollisionDispatcherMt";
  }
};

struct RunResult {
  double narrow_mean_us = 0, narrow_p50_us = 0, narrow_p90_us = 0, step_mean_us = 0;
  uint64_t pair_tests = 0;
  std::vector<btScalar> final_poses;
};

RunResult run(const std::shared_ptr<const voxfmt::runtime::CollisionObject>& object, const Config& config, int bodies,
              int steps) {
  voxfmt::bullet::ThreadPoolScheduler scheduler(config.threads);
  btDefaultCollisionConstructionInfo info;
  voxfmt::bullet::prepare_construction_info(info);
  btDefaultCollisionConfiguration configuration(info);
  std::unique_ptr<btCollisionDispatcher> dispatcher;
  std::vector<double>* narrow_us = nullptr;
  if (config.dispatch == Dispatch::Parallel) {
    auto timed = std::make_unique<Timed<voxfmt::bullet::ParallelCollisionDispatcher>>(&configuration, scheduler);
    narrow_us = &timed->step_us;
    dispatcher = std::move(timed);
  } else {
    btSetTaskScheduler(&scheduler);  // before the dispatcher, which sizes its per-thread arrays by it
    auto timed = std::make_unique<Timed<btCollisionDispatcherMt>>(&configuration, 1);
    narrow_us = &timed->step_us;
    dispatcher = std::move(timed);
  }
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world(dispatcher.get(), &broadphase, &solver, &configuration);
  world.setGravity(btVector3(0, btScalar(-9.81), 0));
  auto vps = voxfmt::bullet::register_vps_collision(*dispatcher);

  std::vector<std::unique_ptr<btCollisionShape>> statics;
  std::vector<std::unique_ptr<btRigidBody>> all;
  auto add = [&](btCollisionShape* shape, btScalar mass, const btTransform& at) {
    btVector3 inertia(0, 0, 0);
    if (mass > 0) shape->calculateLocalInertia(mass, inertia);
    all.push_back(std::make_unique<btRigidBody>(mass, nullptr, shape, inertia));
    all.back()->setWorldTransform(at);
    world.addRigidBody(all.back().get());
  };
  statics.push_back(std::make_unique<btBoxShape>(btVector3(btScalar(kHalfBox), btScalar(0.05), btScalar(kHalfBox))));
  add(statics.back().get(), 0, btTransform(btQuaternion::getIdentity(), btVector3(0, btScalar(-0.05), 0)));
  for (int side = 0; side < 4; ++side) {
    const btVector3 inward = side < 2 ? btVector3(side == 0 ? 1 : -1, 0, 0) : btVector3(0, 0, side == 2 ? 1 : -1);
    statics.push_back(std::make_unique<btStaticPlaneShape>(inward, btScalar(-kHalfBox)));
    add(statics.back().get(), 0, btTransform::getIdentity());
  }
  // One shape for every bunny: the asset is loaded once and shared.
  voxfmt::bullet::VpsMixedShape bunny(object);
  const size_t first_bunny = all.size();
  for (int k = 0; k < bodies; ++k) {
    const int column = k % 9, layer = k / 9;
    const btVector3 axis(btScalar(std::sin(1.3 * k)), btScalar(std::cos(2.1 * k)), 1);
    const btQuaternion turn(axis.normalized(), btScalar(0.9 * k));
    add(&bunny, 1,
        btTransform(turn, btVector3(btScalar(0.16 * (column % 3 - 1)), btScalar(0.12 + 0.17 * layer),
                                    btScalar(0.16 * (column / 3 - 1)))));
  }

  std::vector<double> step_us;
  for (int s = 0; s < steps; ++s) {
    const auto start = Clock::now();
    world.stepSimulation(kDt, 0, kDt);
    step_us.push_back(micros(Clock::now() - start));
  }
  RunResult result;
  result.narrow_mean_us = mean(*narrow_us);
  result.narrow_p50_us = quantile(*narrow_us, 0.5);
  result.narrow_p90_us = quantile(*narrow_us, 0.9);
  result.step_mean_us = mean(step_us);
  result.pair_tests = vps->counters().pair_tests;
  for (size_t b = first_bunny; b < all.size(); ++b) {
    const btTransform& t = all[b]->getWorldTransform();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) result.final_poses.push_back(t.getBasis()[r][c]);
    for (int c = 0; c < 3; ++c) result.final_poses.push_back(t.getOrigin()[c]);
  }
  for (auto& body : all) world.removeRigidBody(body.get());
  if (btGetTaskScheduler() == &scheduler) btSetTaskScheduler(btGetSequentialTaskScheduler());
  return result;
}

std::string cpu_model() {
  std::ifstream info("/proc/cpuinfo");
  for (std::string line; std::getline(info, line);)
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  return "unknown";
}

std::string json_string(const std::string& text) {
  std::string out = "\"";
  for (char c : text) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out + "\"";
}

}  // namespace

int main(int argc, char** argv) {
  std::string mesh = VOXFMT_SAMPLE_MESHES "/bunny00.off", cache = "out/narrowphase_threads", asset, json_path;
  int bodies = 24, steps = 1000, repeat = 3;
  std::vector<int> thread_counts = {1, 2};
  bool bullet_mt = true;
  CLI::App app{"narrowphase-threads — the narrow phase of a pile of VPS bunnies sharing one asset, on 1 and 2 threads"};
  app.add_option("--mesh", mesh, "mesh of the bodies, baked at 0.15 m, resolution 128, 10,000 points")
      ->capture_default_str();
  app.add_option("--cache", cache, "folder for the baked asset")->capture_default_str();
  app.add_option("--asset", asset, "an asset to use as it is instead of baking --mesh");
  app.add_option("--bodies", bodies, "VPS bodies in the pile")->capture_default_str()->check(CLI::Range(1, 200));
  app.add_option("--steps", steps, "steps at 1 kHz per run")->capture_default_str()->check(CLI::Range(1, 1000000));
  app.add_option("--threads", thread_counts, "thread counts of ParallelCollisionDispatcher")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  app.add_option("--repeat", repeat, "runs per configuration (alternating); the median is reported")
      ->capture_default_str()
      ->check(CLI::Range(1, 100));
  app.add_flag("!--no-bullet-mt", bullet_mt, "skip btCollisionDispatcherMt");
  app.add_option("--json", json_path, "write the results as JSON");
  CLI11_PARSE(app, argc, argv);

  try {
    if (asset.empty()) {
      fs::create_directories(cache);
      asset = cache + "/bunny.vox.h5";
      voxfmt::bake::Settings settings;
      settings.import.unit_scale = 0.15;
      settings.voxelmap.resolution = 128;
      settings.point_shell.points = 10000;
      if (!voxfmt::bake::asset_is_current(asset, mesh, settings)) {  // another --mesh: baked again
        std::cerr << "bake: " << mesh << " -> " << asset << "\n";
        const auto summary = voxfmt::bake::bake_to_file(mesh, asset, settings);
        if (!summary) throw std::runtime_error(summary.error().describe());
      }
    }
    auto loaded = voxfmt::runtime::CollisionObject::load(asset);
    if (!loaded) throw std::runtime_error(loaded.error().describe());
    const auto object = loaded.value();

    const bool threadsafe = voxfmt::bullet::bullet_is_thread_safe();
    std::vector<Config> configs;
    for (int t : thread_counts) configs.push_back({Dispatch::Parallel, t});
    if (bullet_mt)
      configs.push_back({Dispatch::BulletMt, *std::max_element(thread_counts.begin(), thread_counts.end())});

    const std::string load_start = load_average();
    std::vector<std::vector<RunResult>> results(configs.size());
    for (int r = 0; r < repeat; ++r)
      for (size_t c = 0; c < configs.size(); ++c) {
        results[c].push_back(run(object, configs[c], bodies, steps));
        std::cerr << "run " << r + 1 << "/" << repeat << ": " << configs[c].name() << ", " << configs[c].threads
                  << " thread(s): narrow phase " << fixed(results[c].back().narrow_mean_us, 0) << " us/step\n";
      }
    const std::string load_end = load_average();

    // Every ParallelCollisionDispatcher run is the same simulation: same pairs, same final poses to the bit.
    const RunResult& reference = results[0][0];
    bool identical = true;
    for (size_t c = 0; c < configs.size(); ++c)
      if (configs[c].dispatch == Dispatch::Parallel)
        for (const RunResult& result : results[c])
          identical =
              identical && result.final_poses == reference.final_poses && result.pair_tests == reference.pair_tests;

    // Speed-ups are taken within each round of runs (a shared machine's load drifts between rounds), then the
    // median over the rounds.
    struct Row {
      double narrow_mean, narrow_p50, narrow_p90, step_mean, narrow_speedup, step_speedup;
    };
    std::vector<Row> rows;
    for (const auto& runs : results) {
      auto median_of = [&](auto&& value) {
        std::vector<double> v;
        for (size_t r = 0; r < runs.size(); ++r) v.push_back(value(runs[r], results[0][r]));
        return quantile(v, 0.5);
      };
      rows.push_back({median_of([](const RunResult& run, const RunResult&) { return run.narrow_mean_us; }),
                      median_of([](const RunResult& run, const RunResult&) { return run.narrow_p50_us; }),
                      median_of([](const RunResult& run, const RunResult&) { return run.narrow_p90_us; }),
                      median_of([](const RunResult& run, const RunResult&) { return run.step_mean_us; }),
                      median_of([](const RunResult& run, const RunResult& base) {
                        return base.narrow_mean_us / run.narrow_mean_us;
                      }),
                      median_of([](const RunResult& run, const RunResult& base) {
                        return base.step_mean_us / run.step_mean_us;
                      })});
    }

    std::cout << "narrowphase-threads: " << bodies << " VPS bodies sharing one asset (" << asset << ", "
              << object->point_tree().size() << " points), " << steps << " steps at 1 kHz, median of " << repeat
              << " runs\n"
              << "Bullet " << btGetVersion() << ": "
              << (threadsafe ? "built with BT_THREADSAFE"
                             : "built without BT_THREADSAFE (btCollisionDispatcherMt runs on the calling thread)")
              << "\nmachine: " << cpu_model() << ", " << voxfmt::usable_cores() << " usable cores, load average "
              << load_start << " at start, " << load_end << " at end\n\n"
              << std::left << std::setw(36) << "dispatcher" << std::right << std::setw(8) << "threads" << std::setw(28)
              << "narrow mean/p50/p90 us" << std::setw(10) << "speed-up" << std::setw(14) << "step mean us"
              << std::setw(10) << "speed-up"
              << "\n";
    for (size_t c = 0; c < configs.size(); ++c)
      std::cout << std::left << std::setw(36) << configs[c].name() << std::right << std::setw(8) << configs[c].threads
                << std::setw(28)
                << (fixed(rows[c].narrow_mean, 0) + " / " + fixed(rows[c].narrow_p50, 0) + " / " +
                    fixed(rows[c].narrow_p90, 0))
                << std::setw(10) << fixed(rows[c].narrow_speedup, 2) + "x" << std::setw(14)
                << fixed(rows[c].step_mean, 0) << std::setw(10) << fixed(rows[c].step_speedup, 2) + "x"
                << "\n";
    std::cout << "\nVPS pair tests per run: " << reference.pair_tests << " ("
              << fixed(double(reference.pair_tests) / steps, 1) << " a step); the same simulation on every thread "
              << "count: " << (identical ? "yes" : "NO") << "\n";

    if (!json_path.empty()) {
      std::ostringstream json;
      std::string command = argv[0];
      for (int a = 1; a < argc; ++a) command += std::string(" ") + argv[a];
      json << "{\n  \"command\": " << json_string(command) << ",\n  \"machine\": {\"cpu\": " << json_string(cpu_model())
           << ", \"cores\": " << sysconf(_SC_NPROCESSORS_ONLN) << ", \"usable_cores\": " << voxfmt::usable_cores()
           << ", \"load_average_start\": " << load_start << ", \"load_average_end\": " << load_end << "},\n"
           << "  \"bullet\": {\"version\": " << btGetVersion()
           << ", \"threadsafe\": " << (threadsafe ? "true" : "false") << "},\n"
           << "  \"scene\": {\"bodies\": " << bodies << ", \"steps\": " << steps << ", \"dt_s\": " << kDt
           << ", \"asset\": " << json_string(asset) << ", \"points\": " << object->point_tree().size()
           << ", \"pair_tests_per_step\": " << double(reference.pair_tests) / steps << "},\n"
           << "  \"repeat\": " << repeat << ",\n  \"identical_simulation\": " << (identical ? "true" : "false")
           << ",\n  \"configurations\": [";
      for (size_t c = 0; c < configs.size(); ++c) {
        json << (c ? "," : "") << "\n    {\"dispatcher\": " << json_string(configs[c].name())
             << ", \"threads\": " << configs[c].threads << ", \"narrow_mean_us\": " << fixed(rows[c].narrow_mean, 1)
             << ", \"narrow_p50_us\": " << fixed(rows[c].narrow_p50, 1)
             << ", \"narrow_p90_us\": " << fixed(rows[c].narrow_p90, 1)
             << ", \"narrow_speedup\": " << fixed(rows[c].narrow_speedup, 3)
             << ", \"step_mean_us\": " << fixed(rows[c].step_mean, 1)
             << ", \"step_speedup\": " << fixed(rows[c].step_speedup, 3) << ", \"runs_narrow_mean_us\": [";
        for (size_t r = 0; r < results[c].size(); ++r)
          json << (r ? ", " : "") << fixed(results[c][r].narrow_mean_us, 1);
        json << "]}";
      }
      json << "\n  ]\n}\n";
      if (const voxfmt::Status written = voxfmt::write_file_atomically(json_path, json.str()); !written)
        throw std::runtime_error(written.error().describe());
      std::cout << "wrote " << json_path << "\n";
    }
    return identical ? 0 : 1;
  } catch (const std::exception& e) {
    std::cerr << "narrowphase-threads: " << e.what() << "\n";
    return 1;
  }
}
