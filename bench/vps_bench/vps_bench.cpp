// vps-bench: every collision method on exactly the same relative poses, timed per pair, in one run.
//
// Scenarios (scenarios.cpp) give two bodies and a deterministic pose set; methods (methods.cpp) are VPS through
// its Bullet algorithm, Bullet's GImpact, a cached HACD decomposition, a reduced convex hull and FCL. Each
// method runs every pose of a scenario (after a warm-up), then more passes until the repetition count or the
// time budget is reached, then once per pose with the caches evicted. Output: a markdown table on stdout and,
// with --json, the figures described in bench/README.md.
#include <sys/utsname.h>
#include <unistd.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <numeric>
#include <optional>
#include <sstream>

#include "methods.h"
#include "scenarios.h"
#include "traversal/field_simd.h"
#include "voxfmt/runtime/query.h"

#ifndef VPS_BENCH_BUNNY
#define VPS_BENCH_BUNNY "bunny00.off"
#endif

namespace {

using namespace vps_bench;
using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;

struct Options {
  std::string json_path;
  bool quick = false;
  std::vector<std::string> scenarios;
  std::vector<std::string> methods;
  size_t reps = 1000;
  size_t poses = 200;
  size_t cold = 200;
  double budget_s = 20;
  std::string cache_dir = "out/vps-bench";
  std::string bunny_mesh = VPS_BENCH_BUNNY;
  double margin = 0.001;
  bool cached_decompositions_only = false;
  bool trajectories = false;       ///< also run the trajectories
  bool pose_sets = true;           ///< run the pose sets
  size_t trajectory_steps = 1000;  ///< per trajectory
  double floor_voxel = 0;          ///< vps-fine-baked-floor's voxel, metres (0: the bunny's; --quick: 2 mm)
  bool interleave = false;         ///< pose sets: the methods take turns query by query
};

// ------------------------------------------------------------------------------------------------ figures

struct MethodFigures {
  std::string name, note, unavailable;
  std::vector<double> warm_us, cold_us;
  std::vector<QueryOutcome> per_pose;  // first pass, pose by pose
  size_t poses_measured = 0;
  bool budget_hit = false;
};

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const size_t rank = size_t(std::ceil(q * double(v.size())));
  return v[std::min(v.size() - 1, rank == 0 ? 0 : rank - 1)];
}

double mean(const std::vector<double>& v) {
  return v.empty() ? NAN : std::accumulate(v.begin(), v.end(), 0.0) / double(v.size());
}

/// Writes through a buffer twice the last-level cache so that the next query starts cold.
void evict_caches() {
  static std::vector<uint64_t> buffer(64u << 20 >> 3);
  static uint64_t counter = 0;
  ++counter;
  for (size_t i = 0; i < buffer.size(); i += 8) buffer[i] += counter;
}

double elapsed_us(Clock::time_point start) {
  return std::chrono::duration<double, std::micro>(Clock::now() - start).count();
}

// Pass 0 of every method's timing: each pose's outcome recorded (later passes only time).
void time_query(Method& method, const PosePair& pose, bool record, MethodFigures& f) {
  const auto t0 = Clock::now();
  method.query(pose);
  f.warm_us.push_back(elapsed_us(t0));
  const QueryOutcome outcome = method.outcome();
  if (record) f.per_pose.push_back(outcome);
}

void time_cold(Method& method, const Scenario& scenario, const Options& options, MethodFigures& f);

/// Every method on every pose in turn (--interleave): the methods see the machine's noise alike, so their
/// ratios hold even where the absolute times drift between runs. No budget: every method gets `reps` queries.
std::vector<MethodFigures> measure_interleaved(const std::vector<Method*>& methods, const Scenario& scenario,
                                               const Options& options) {
  std::vector<MethodFigures> figures(methods.size());
  const auto& poses = scenario.poses;
  for (Method* method : methods)
    for (size_t i = 0; i < std::min<size_t>(10, poses.size()); ++i) {
      method->query(poses[i]);
      method->outcome();
    }
  for (size_t pass = 0; figures[0].warm_us.size() < options.reps || pass == 0; ++pass)
    for (size_t i = 0; i < poses.size(); ++i)
      for (size_t k = 0; k < methods.size(); ++k) {
        // The order alternates so that no method always runs on caches another one warmed.
        const size_t m = (i + pass) % 2 ? methods.size() - 1 - k : k;
        time_query(*methods[m], poses[i], pass == 0, figures[m]);
      }
  for (size_t m = 0; m < methods.size(); ++m) {
    figures[m].poses_measured = figures[m].per_pose.size();
    time_cold(*methods[m], scenario, options, figures[m]);
  }
  return figures;
}

MethodFigures measure(Method& method, const Scenario& scenario, const Options& options) {
  MethodFigures f;
  const auto& poses = scenario.poses;
  const auto start = Clock::now();
  auto over_budget = [&] { return std::chrono::duration<double>(Clock::now() - start).count() > options.budget_s; };
  for (size_t i = 0; i < std::min<size_t>(10, poses.size()); ++i) {  // warm-up: code, caches, allocations
    method.query(poses[i]);
    method.outcome();
  }
  // Pass 0 records each pose's outcome; later passes only time.
  for (size_t pass = 0; f.warm_us.size() < options.reps || pass == 0; ++pass) {
    for (size_t i = 0; i < poses.size(); ++i) {
      time_query(method, poses[i], pass == 0, f);
      // A slow method stops at the budget, but measures at least 20 poses.
      if (over_budget() && f.warm_us.size() >= std::min<size_t>(20, poses.size())) {
        f.budget_hit = f.warm_us.size() < options.reps;
        break;
      }
    }
    if (over_budget()) break;
  }
  f.poses_measured = f.per_pose.size();
  time_cold(method, scenario, options, f);
  return f;
}

// The first poses again, each with the caches evicted.
void time_cold(Method& method, const Scenario& scenario, const Options& options, MethodFigures& f) {
  const auto& poses = scenario.poses;
  const size_t cold = std::min(options.cold, f.poses_measured);
  const auto cold_start = Clock::now();
  for (size_t i = 0; i < cold; ++i) {
    // Slow methods: a quarter of the budget for the cold queries (at least 5).
    if (i >= 5 && std::chrono::duration<double>(Clock::now() - cold_start).count() > options.budget_s / 4) break;
    evict_caches();
    const auto t0 = Clock::now();
    method.query(poses[i]);
    f.cold_us.push_back(elapsed_us(t0));
    method.outcome();
  }
  f.note = method.note();
}

volatile float g_lookup_sink = 0;  // the lookups' sum goes here, so the compiler keeps them

/// The cost of the distance lookups alone for the points vps-fine tests, per pose (VPS-VPS scenarios): how
/// far the traversal is from its own limit.
std::vector<double> lookup_floor_us(const Scenario& s, size_t poses) {
  std::vector<double> floor;
  if (s.b->kind != Body::Kind::BakedMesh) return floor;
  using namespace voxfmt::runtime;
  QueryOptions options;
  options.normal_source = NormalSource::DistanceGradient;
  std::vector<Eigen::Vector3f> tested;
  QueryScratch scratch;
  scratch.record_tested_points(&tested);
  ContactSet contacts;
  for (size_t i = 0; i < std::min(poses, s.poses.size()); ++i) {
    // Asset poses of both bodies: world_from_shape * shape_from_asset.
    auto asset_pose = [](const Body& body, const Eigen::Isometry3d& world_from_shape) {
      Pose pose;
      pose.rotation = world_from_shape.linear() * body.vps->principal_axes().transpose();
      pose.translation = world_from_shape.translation() - pose.rotation * body.vps->center_of_mass();
      return pose;
    };
    const Pose pa = asset_pose(*s.a, s.poses[i].a), pb = asset_pose(*s.b, s.poses[i].b);
    tested.clear();
    contacts.clear();
    query_contacts(*s.a->vps, pa, *s.b->vps, pb, options, contacts, scratch);
    const QueryDirection direction = resolve_direction(*s.a->vps, pa, *s.b->vps, pb, QueryDirection::Auto);
    const SparseVoxelmap& map = (direction == QueryDirection::APointsInB ? s.b : s.a)->vps->voxelmap();
    std::vector<double> runs;
    for (int r = 0; r < 5; ++r) {
      const auto t0 = Clock::now();
      float sum = 0;
      for (const Eigen::Vector3f& u : tested) sum += map.sample(u).distance;
      runs.push_back(elapsed_us(t0));
      g_lookup_sink = sum;
    }
    floor.push_back(quantile(runs, 0.5));
  }
  return floor;
}

// ------------------------------------------------------------------------------------------------ trajectories

struct TrajectoryFigures {
  std::string name, note, unavailable;
  std::vector<double> step_us;
  std::vector<QueryOutcome> per_step;
  bool budget_hit = false;
};

/// The steps in order, as a world would run them: one pass to warm up (its state carried into the timed pass,
/// like one more step), then one timed pass; a slow method stops at the budget.
TrajectoryFigures measure_trajectory(Method& method, const Trajectory& t, const Options& options) {
  TrajectoryFigures f;
  method.keep_state(true);
  const auto start = Clock::now();
  auto over_budget = [&] { return std::chrono::duration<double>(Clock::now() - start).count() > options.budget_s; };
  for (size_t i = 0; i < t.steps.size() && !over_budget(); ++i) {
    method.query(t.steps[i]);
    method.outcome();
  }
  for (size_t i = 0; i < t.steps.size(); ++i) {
    const auto t0 = Clock::now();
    method.query(t.steps[i]);
    f.step_us.push_back(elapsed_us(t0));
    f.per_step.push_back(method.outcome());
    if (over_budget() && f.step_us.size() >= std::min<size_t>(20, t.steps.size())) {
      f.budget_hit = f.step_us.size() < t.steps.size();
      break;
    }
  }
  f.note = method.note();
  return f;
}

// ------------------------------------------------------------------------------------------------ output

std::string json_number(double v) {
  if (!std::isfinite(v)) return "null";
  std::ostringstream out;
  out << std::setprecision(6) << v;
  return out.str();
}

std::string json_string(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\')
      out += '\\', out += c;
    else if (static_cast<unsigned char>(c) < 0x20)
      out += ' ';
    else
      out += c;
  }
  return out + "\"";
}

struct Summary {  // derived figures of one method in one scenario
  double p50, p90, p99, p999, max, cold_p50, contacts_mean, touching_share, reported_share, depth_err_max;
  double detects_where_fine, nodes_mean, points_mean;
};

Summary summarise(const MethodFigures& f, const Scenario& s, const MethodFigures* fine) {
  Summary r{};
  r.p50 = quantile(f.warm_us, 0.5);
  r.p90 = quantile(f.warm_us, 0.9);
  r.p99 = quantile(f.warm_us, 0.99);
  r.p999 = quantile(f.warm_us, 0.999);
  r.max = f.warm_us.empty() ? NAN : *std::max_element(f.warm_us.begin(), f.warm_us.end());
  r.cold_p50 = quantile(f.cold_us, 0.5);
  std::vector<double> contacts, touching, reported, nodes, points;
  double depth_err = NAN;
  size_t fine_touching = 0, detected = 0;
  for (size_t i = 0; i < f.per_pose.size(); ++i) {
    const QueryOutcome& o = f.per_pose[i];
    contacts.push_back(double(o.contacts));
    touching.push_back(o.contacts > 0 && o.deepest > 0 ? 1 : 0);
    reported.push_back(o.contacts > 0 ? 1 : 0);
    nodes.push_back(double(o.nodes_visited));
    points.push_back(double(o.points_tested));
    const auto& exact = s.poses[i].exact_depth;
    if (exact && *exact > 0) {
      const double found = o.contacts > 0 ? o.deepest : 0.0;  // nothing found: the whole depth is missed
      const double err = std::abs(found - *exact);
      depth_err = std::isnan(depth_err) ? err : std::max(depth_err, err);
    }
    if (fine && i < fine->per_pose.size() && fine->per_pose[i].contacts > 0 && fine->per_pose[i].deepest > 0) {
      ++fine_touching;
      detected += o.contacts > 0 ? 1 : 0;
    }
  }
  r.contacts_mean = mean(contacts);
  r.touching_share = mean(touching);
  r.reported_share = mean(reported);
  r.depth_err_max = depth_err;
  r.detects_where_fine = fine_touching ? double(detected) / double(fine_touching) : NAN;
  const bool vps = f.name.rfind("vps", 0) == 0;
  r.nodes_mean = vps ? mean(nodes) : NAN;
  r.points_mean = vps ? mean(points) : NAN;
  return r;
}

std::string machine_json() {
  utsname u{};
  uname(&u);
  std::string cpu = "unknown";
  std::ifstream info("/proc/cpuinfo");
  for (std::string line; std::getline(info, line);)
    if (line.rfind("model name", 0) == 0) {
      cpu = line.substr(line.find(':') + 2);
      break;
    }
  std::ostringstream out;
  char host[256] = {};
  gethostname(host, sizeof host - 1);
  out << "{\"host\": " << json_string(host) << ", \"cpu\": " << json_string(cpu)
      << ", \"cores\": " << sysconf(_SC_NPROCESSORS_ONLN)
      << ", \"os\": " << json_string(std::string(u.sysname) + " " + u.release)
      << ", \"compiler\": " << json_string(__VERSION__) << "}";
  return out.str();
}

std::string fixed(double v, int precision) {
  if (!std::isfinite(v)) return "–";
  std::ostringstream out;
  out << std::fixed << std::setprecision(precision) << v;
  return out.str();
}

}  // namespace

int main(int argc, char** argv) {
  Options options;
  CLI::App app{
      "vps-bench — every collision method on exactly the same relative poses, timed per pair, in one run "
      "(VPS, GImpact, a cached HACD decomposition, a convex hull, FCL)"};
  app.add_option("--json", options.json_path, "write the figures as JSON to this file");
  app.add_flag("--quick", options.quick,
               "a short run (20 poses, 60 repetitions, 10 cold queries, 2 s per method; hacd only from a cached "
               "decomposition)");
  app.add_option("--scenario", options.scenarios, "scenarios to run (default: all)")->delimiter(',');
  app.add_option("--method", options.methods, "methods to run (default: all)")->delimiter(',');
  app.add_option("--reps", options.reps, "timed queries per method and scenario, over all poses")
      ->capture_default_str();
  app.add_option("--poses", options.poses, "poses per scenario")->capture_default_str();
  app.add_option("--cold", options.cold, "queries timed with caches evicted")->capture_default_str();
  app.add_option("--budget", options.budget_s, "seconds per method and scenario before a slow method stops")
      ->capture_default_str();
  app.add_option("--cache", options.cache_dir, "folder for baked assets, generated meshes, HACD decompositions")
      ->capture_default_str();
  app.add_option("--bunny", options.bunny_mesh, "CGAL's bunny00.off")->capture_default_str();
  app.add_option("--margin", options.margin, "Bullet collision margin and vps-fine-prox proximity, metres")
      ->capture_default_str();
  app.add_flag("--cached-decompositions-only", options.cached_decompositions_only,
               "run hacd only where a decomposition is cached (never spend minutes computing one)");
  app.add_flag("--trajectories", options.trajectories,
               "also run trajectories: consecutive poses of a 1 kHz simulated drop for each scenario and a 5 kHz "
               "haptic path (bunny-bunny), every method keeping its state across steps as in a world, with "
               "vps-fine (from scratch each step) beside vps-fine-coherent");
  app.add_flag("!--no-pose-sets", options.pose_sets, "skip the pose sets (with --trajectories: trajectories only)");
  app.add_option("--steps", options.trajectory_steps, "steps per trajectory")->capture_default_str();
  app.add_flag("--interleave", options.interleave,
               "pose sets: the methods take turns query by query (same poses, same moments: ratios that hold on a "
               "noisy machine); every method gets all --reps, no --budget");
  app.add_option("--floor-voxel", options.floor_voxel,
                 "voxel of the floor vps-fine-baked-floor bakes, metres (default: the bunny's; --quick: 0.002)");
  CLI11_PARSE(app, argc, argv);
  if (options.quick) {
    options.poses = std::min<size_t>(options.poses, 20);
    options.reps = std::min<size_t>(options.reps, 60);
    options.cold = std::min<size_t>(options.cold, 10);
    options.budget_s = std::min(options.budget_s, 2.0);
    options.trajectory_steps = std::min<size_t>(options.trajectory_steps, 300);
    if (options.floor_voxel <= 0) options.floor_voxel = 0.002;
  }
  if (options.scenarios.empty()) options.scenarios = scenario_names();
  const bool methods_given = !options.methods.empty();
  for (const auto& m : options.methods)
    if (std::find(method_names().begin(), method_names().end(), m) == method_names().end() &&
        std::find(trajectory_method_names().begin(), trajectory_method_names().end(), m) ==
            trajectory_method_names().end()) {
      std::cerr << "vps-bench: unknown method '" << m << "'\n";
      return 2;
    }
  for (const auto& s : options.scenarios)
    if (std::find(scenario_names().begin(), scenario_names().end(), s) == scenario_names().end()) {
      std::cerr << "vps-bench: unknown scenario '" << s << "'\n";
      return 2;
    }
  if (!fs::exists(options.bunny_mesh)) {
    std::cerr << "vps-bench: bunny mesh not found: " << options.bunny_mesh << " (--bunny)\n";
    return 2;
  }

  try {
    ScenarioSettings scenario_settings;
    scenario_settings.cache_dir = options.cache_dir;
    scenario_settings.bunny_mesh = options.bunny_mesh;
    scenario_settings.poses = options.poses;
    MethodSettings method_settings;
    method_settings.margin = options.margin;
    method_settings.cache_dir = options.cache_dir;
    method_settings.compute_decompositions = !options.quick && !options.cached_decompositions_only;
    method_settings.baked_floor_voxel = options.floor_voxel;

    const auto bunny = bunny_body(scenario_settings);
    const double runtime_mb = double(bunny->vps->memory_bytes()) / 1e6;
    const double file_mb = double(fs::file_size(bunny->asset_path)) / 1e6;
    std::cout << "# vps-bench\n\nbunny asset (resolution 306, " << bunny->vps->point_tree().size()
              << " points): " << fixed(runtime_mb, 1) << " MB in the runtime, " << fixed(file_mb, 1)
              << " MB on disk. Times in µs per pair; ratio = p50 / vps-fine p50. Margin and vps-fine-prox "
                 "proximity: "
              << options.margin * 1000 << " mm.\n";

    std::ostringstream json;
    json << "{\n  \"machine\": " << machine_json() << ",\n  \"settings\": {\"poses\": " << options.poses
         << ", \"reps\": " << options.reps << ", \"cold\": " << options.cold << ", \"budget_s\": " << options.budget_s
         << ", \"margin_m\": " << options.margin << ", \"quick\": " << (options.quick ? "true" : "false")
         << ", \"interleave\": " << (options.interleave ? "true" : "false") << ", \"lookup_kernel\": \""
         << voxfmt::runtime::core::simd_kernel_name(voxfmt::runtime::core::simd_kernel()) << "\""
         << "},\n  \"scenarios\": [";
    const std::vector<std::string> pose_set_methods = methods_given ? options.methods : method_names();
    for (size_t si = 0; si < options.scenarios.size() && options.pose_sets; ++si) {
      const Scenario scenario = make_scenario(options.scenarios[si], scenario_settings);
      std::cerr << "scenario " << scenario.name << ": " << scenario.poses.size() << " poses\n";
      std::vector<MethodFigures> results;
      std::vector<std::unique_ptr<Method>> interleaved;
      std::vector<size_t> interleaved_at;
      for (const std::string& name : pose_set_methods) {
        std::string why;
        std::unique_ptr<Method> method = make_method(name, scenario, method_settings, why);
        if (!method) {
          MethodFigures f;
          f.name = name;
          f.unavailable = why;
          results.push_back(f);
          continue;
        }
        if (options.interleave) {
          interleaved_at.push_back(results.size());
          results.emplace_back().name = name;
          interleaved.push_back(std::move(method));
          continue;
        }
        std::cerr << "  " << name << "…" << std::flush;
        MethodFigures f = measure(*method, scenario, options);
        f.name = name;
        std::cerr << " p50 " << fixed(quantile(f.warm_us, 0.5), 1) << " µs\n";
        results.push_back(std::move(f));
      }
      if (!interleaved.empty()) {
        std::vector<Method*> turns;
        for (const auto& m : interleaved) turns.push_back(m.get());
        std::cerr << "  " << turns.size() << " methods interleaved…" << std::flush;
        std::vector<MethodFigures> figures = measure_interleaved(turns, scenario, options);
        for (size_t k = 0; k < figures.size(); ++k) {
          figures[k].name = results[interleaved_at[k]].name;
          results[interleaved_at[k]] = std::move(figures[k]);
        }
        std::cerr << " done\n";
      }
      const MethodFigures* fine = nullptr;
      for (const auto& r : results)
        if (r.name == "vps-fine" && !r.per_pose.empty()) fine = &r;
      const std::vector<double> floor = lookup_floor_us(scenario, options.quick ? 20 : 200);

      std::cout << "\n## " << scenario.name << "\n\n" << scenario.description << ".\n\n";
      std::cout << "| method | p50 | p90 | p99 | p99.9 | max | cold p50 | ratio | contacts | touching | detects "
                   "fine's | depth err mm | nodes | points | samples | note |\n"
                   "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|---|\n";
      const double fine_p50 = fine ? quantile(fine->warm_us, 0.5) : NAN;
      json << (si ? "," : "") << "\n    {\"name\": " << json_string(scenario.name)
           << ", \"description\": " << json_string(scenario.description) << ", \"poses\": " << scenario.poses.size()
           << ", \"floor_p50_us\": " << json_number(quantile(floor, 0.5)) << ", \"methods\": [";
      for (size_t mi = 0; mi < results.size(); ++mi) {
        const MethodFigures& f = results[mi];
        json << (mi ? "," : "") << "\n      {\"name\": " << json_string(f.name);
        if (!f.unavailable.empty()) {
          std::cout << "| " << f.name << " | cannot run: " << f.unavailable << " |||||||||||||||\n";
          json << ", \"unavailable\": " << json_string(f.unavailable) << "}";
          continue;
        }
        const Summary r = summarise(f, scenario, fine);
        std::cout << "| " << f.name << " | " << fixed(r.p50, 1) << " | " << fixed(r.p90, 1) << " | " << fixed(r.p99, 1)
                  << " | " << fixed(r.p999, 1) << " | " << fixed(r.max, 1) << " | " << fixed(r.cold_p50, 1) << " | "
                  << fixed(r.p50 / fine_p50, 2) << " | " << fixed(r.contacts_mean, 1) << " | "
                  << fixed(100 * r.touching_share, 0) << "% | "
                  << (std::isnan(r.detects_where_fine) ? "–" : fixed(100 * r.detects_where_fine, 0) + "%") << " | "
                  << fixed(r.depth_err_max * 1000, 3) << " | " << fixed(r.nodes_mean, 0) << " | "
                  << fixed(r.points_mean, 0) << " | " << f.warm_us.size() << (f.budget_hit ? " (budget)" : "") << " | "
                  << f.note << " |\n";
        json << ", \"p50_us\": " << json_number(r.p50) << ", \"p90_us\": " << json_number(r.p90)
             << ", \"p99_us\": " << json_number(r.p99) << ", \"p999_us\": " << json_number(r.p999)
             << ", \"max_us\": " << json_number(r.max) << ", \"cold_p50_us\": " << json_number(r.cold_p50)
             << ", \"contacts_mean\": " << json_number(r.contacts_mean)
             << ", \"touching_share\": " << json_number(r.touching_share)
             << ", \"reported_share\": " << json_number(r.reported_share)
             << ", \"detects_where_fine_touches\": " << json_number(r.detects_where_fine)
             << ", \"depth_err_max_m\": " << json_number(r.depth_err_max)
             << ", \"nodes_visited_mean\": " << json_number(r.nodes_mean)
             << ", \"points_tested_mean\": " << json_number(r.points_mean)
             << ", \"ratio_to_vps_fine\": " << json_number(r.p50 / fine_p50) << ", \"samples\": " << f.warm_us.size()
             << ", \"poses_measured\": " << f.poses_measured
             << ", \"budget_hit\": " << (f.budget_hit ? "true" : "false") << ", \"note\": " << json_string(f.note)
             << "}";
      }
      json << "\n    ]}";
      if (!floor.empty())
        std::cout << "\nfloor: the distance lookups alone for the points vps-fine tests take "
                  << fixed(quantile(floor, 0.5), 2) << " µs (p50), " << fixed(fine_p50 / quantile(floor, 0.5), 1)
                  << "x below vps-fine's p50.\n";
      std::cout << std::flush;
    }
    json << "\n  ],\n  \"trajectories\": [";
    if (options.trajectories) {
      const std::vector<std::string> methods = methods_given ? options.methods : trajectory_method_names();
      // A drop per scenario with a dynamic body on a partner it can rest on; the haptic path on bunny-bunny.
      std::vector<std::pair<std::string, std::string>> runs;  // scenario, kind
      for (const std::string& name : options.scenarios)
        if (name != "tori-gap" && name != "bunny-box") runs.push_back({name, "drop"});
      if (std::find(options.scenarios.begin(), options.scenarios.end(), "bunny-bunny") != options.scenarios.end())
        runs.push_back({"bunny-bunny", "haptic"});
      for (size_t ti = 0; ti < runs.size(); ++ti) {
        const Scenario scenario = make_scenario(runs[ti].first, scenario_settings);
        const Trajectory trajectory = runs[ti].second == "drop"
                                          ? simulated_drop(scenario, options.trajectory_steps, options.margin)
                                          : haptic_path(scenario, 5 * options.trajectory_steps);
        std::cerr << "trajectory " << trajectory.scenario << " (" << trajectory.kind << "): " << trajectory.steps.size()
                  << " steps\n";
        std::vector<TrajectoryFigures> results;
        for (const std::string& name : methods) {
          std::string why;
          std::unique_ptr<Method> method = make_method(name, scenario, method_settings, why);
          TrajectoryFigures f;
          if (method) {
            std::cerr << "  " << name << "…" << std::flush;
            f = measure_trajectory(*method, trajectory, options);
            std::cerr << " p50 " << fixed(quantile(f.step_us, 0.5), 1) << " µs\n";
          }
          f.name = name;
          f.unavailable = why;
          results.push_back(std::move(f));
        }
        double coherent_p50 = NAN;
        const TrajectoryFigures *scratch = nullptr, *coherent = nullptr;
        for (const auto& r : results) {
          if (r.name == "vps-fine-coherent") coherent_p50 = quantile(r.step_us, 0.5), coherent = &r;
          if (r.name == "vps-fine") scratch = &r;
        }
        // The coherent query's contacts against the query from scratch, step by step (the same count and the
        // same deepest penetration), over the steps both measured.
        size_t compared = 0, differing = 0;
        if (scratch && coherent) {
          compared = std::min(scratch->per_step.size(), coherent->per_step.size());
          for (size_t i = 0; i < compared; ++i)
            differing += scratch->per_step[i].contacts != coherent->per_step[i].contacts ||
                         scratch->per_step[i].deepest != coherent->per_step[i].deepest;
        }
        std::cout << "\n## trajectory: " << trajectory.scenario << ", " << trajectory.kind << "\n\n"
                  << trajectory.description << " (" << trajectory.rate_hz << " Hz). Times in µs per step; ratio = "
                  << "p50 / vps-fine-coherent p50.\n\n"
                  << "| method | p50 | p99 | max | p99/p50 | ratio | contacts | nodes | points | steps | note |\n"
                  << "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|---|\n";
        json << (ti ? "," : "") << "\n    {\"scenario\": " << json_string(trajectory.scenario)
             << ", \"kind\": " << json_string(trajectory.kind) << ", \"rate_hz\": " << trajectory.rate_hz
             << ", \"steps\": " << trajectory.steps.size()
             << ", \"description\": " << json_string(trajectory.description) << ", \"methods\": [";
        for (size_t mi = 0; mi < results.size(); ++mi) {
          const TrajectoryFigures& f = results[mi];
          json << (mi ? "," : "") << "\n      {\"name\": " << json_string(f.name);
          if (!f.unavailable.empty()) {
            std::cout << "| " << f.name << " | cannot run: " << f.unavailable << " ||||||||||\n";
            json << ", \"unavailable\": " << json_string(f.unavailable) << "}";
            continue;
          }
          std::vector<double> contacts, nodes, points;
          for (const QueryOutcome& o : f.per_step) {
            contacts.push_back(double(o.contacts));
            nodes.push_back(double(o.nodes_visited));
            points.push_back(double(o.points_tested));
          }
          const bool vps = f.name.rfind("vps", 0) == 0;
          const double p50 = quantile(f.step_us, 0.5), p99 = quantile(f.step_us, 0.99);
          const double max = f.step_us.empty() ? NAN : *std::max_element(f.step_us.begin(), f.step_us.end());
          const double nodes_mean = vps ? mean(nodes) : NAN, points_mean = vps ? mean(points) : NAN;
          std::cout << "| " << f.name << " | " << fixed(p50, 1) << " | " << fixed(p99, 1) << " | " << fixed(max, 1)
                    << " | " << fixed(p99 / p50, 1) << " | " << fixed(p50 / coherent_p50, 2) << " | "
                    << fixed(mean(contacts), 1) << " | " << fixed(nodes_mean, 0) << " | " << fixed(points_mean, 0)
                    << " | " << f.step_us.size() << (f.budget_hit ? " (budget)" : "") << " | " << f.note << " |\n";
          json << ", \"step_p50_us\": " << json_number(p50) << ", \"step_p99_us\": " << json_number(p99)
               << ", \"step_max_us\": " << json_number(max) << ", \"nodes_mean\": " << json_number(nodes_mean)
               << ", \"points_tested_mean\": " << json_number(points_mean)
               << ", \"contacts_mean\": " << json_number(mean(contacts))
               << ", \"ratio_to_vps_fine_coherent\": " << json_number(p50 / coherent_p50)
               << ", \"steps_measured\": " << f.step_us.size();
          if (&f == coherent)
            json << ", \"steps_compared_with_vps_fine\": " << compared
                 << ", \"steps_differing_from_vps_fine\": " << differing;
          json << ", \"budget_hit\": " << (f.budget_hit ? "true" : "false") << ", \"note\": " << json_string(f.note)
               << "}";
        }
        json << "\n    ]}";
        if (coherent && scratch)
          std::cout << "\nvps-fine-coherent against vps-fine: " << differing << " of " << compared
                    << " steps differ (contact count or deepest penetration).\n";
        std::cout << std::flush;
      }
    }
    json << "\n  ],\n  \"asset\": {\"runtime_mb\": " << json_number(runtime_mb)
         << ", \"file_mb\": " << json_number(file_mb) << ", \"points\": " << bunny->vps->point_tree().size()
         << ", \"resolution\": 306}\n}\n";
    if (!options.json_path.empty()) {
      const std::string partial = options.json_path + ".partial";
      std::ofstream out(partial);
      out << json.str();
      out.close();
      if (!out) throw std::runtime_error("cannot write " + options.json_path);
      fs::rename(partial, options.json_path);
      std::cout << "\nwrote " << options.json_path << "\n";
    }
  } catch (const std::exception& e) {
    std::cerr << "vps-bench: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
