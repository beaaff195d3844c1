// Haptic rendering in real time: a 0.15 m bunny tool (~35,000 points) on a scripted 6-DoF device approaches a
// second bunny, presses 2 mm in, slides along its surface while turning, and pulls out — against 1 object and
// against 10 (ten CGAL sample meshes, 0.15 m each, stacked where the bunny is, so that every pair is in contact
// during the press: the worst case), at 1 kHz and at 5 kHz, on RealtimeLoop.
//
// Writes, per run, a CSV of every cycle (device pose, wrench, penetration, cycle time) and a PNG plot (force,
// torque, cycle time against time) into --out, and with --json the figures of every run:
//   {"runs": [{"pairs", "rate_hz", "points_per_tool", "cycles", "cycle_us": {"p50", "p99", "p999", "max"},
//              "overruns", "levels_completed_min", "max_force_jump_n", "max_penetration_m",
//              "realtime_priority", "memory_locked", "cpu"}, ...]}
// plus "tree_levels", "max_force_jump_on_time_n" (jumps between cycles that both ran on time: after an overrun
// the step covers the missed periods, and the force moves further), "max_force_n", "seconds" and "csv".
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <thread>

#include "voxfmt/bake/bake.h"
#include "voxfmt/exports/exports.h"
#include "voxfmt/runtime/haptics.h"

namespace {

namespace fs = std::filesystem;
using voxfmt::runtime::CollisionObject;
using voxfmt::runtime::HapticRenderer;
using voxfmt::runtime::Pose;
using Clock = std::chrono::steady_clock;

std::shared_ptr<const CollisionObject> baked(const std::string& mesh, const std::string& out, int resolution,
                                             uint32_t points, double unit_scale) {
  voxfmt::bake::Settings settings;
  settings.import.unit_scale = unit_scale;
  settings.voxelmap.resolution = resolution;
  settings.point_shell.points = points;
  if (!voxfmt::bake::asset_is_current(out, mesh, settings)) {  // another --meshes folder: baked again
    std::cerr << "bake: " << fs::path(mesh).filename().string() << " -> " << out << "\n";
    const auto summary = voxfmt::bake::bake_to_file(mesh, out, settings);
    if (!summary) throw std::runtime_error(summary.error().describe());
  }
  auto loaded = CollisionObject::load(out);
  if (!loaded) throw std::runtime_error(loaded.error().describe());
  return loaded.value();
}

struct SceneObject {
  std::shared_ptr<const CollisionObject> object;
  Pose pose;
};

// The device's script: poses of the tool along time, built against the scene's surface so that "press 2 mm"
// means 2 mm below where the tool first touches, wherever it slides.
class Script {
 public:
  Script(HapticRenderer& probe, double seconds) : seconds_(seconds) {
    for (int i = 0; i <= kSamples; ++i) {
      const double s = double(i) / kSamples;
      touch_.push_back(touch_height(probe, slide_x(s), turn(s)));
    }
    // The touching height is rough where few points touch (it jumps between features of the surface); a device
    // following it exactly would shake. Smoothed ([1 2 1] / 4, 20 passes: about +-8 samples, 2 mm of slide).
    for (int pass = 0; pass < 20; ++pass) {
      std::vector<double> smoothed = touch_;
      for (size_t i = 1; i + 1 < touch_.size(); ++i)
        smoothed[i] = 0.25 * (touch_[i - 1] + 2 * touch_[i] + touch_[i + 1]);
      touch_ = smoothed;
    }
  }
  Pose operator()(double t) const {
    // Phases (fractions of the run): approach 0-0.15, press 0.15-0.25, slide and turn 0.25-0.85, pull out.
    const double f = std::clamp(t / seconds_, 0.0, 1.0);
    const double s = smooth(std::clamp((f - 0.25) / 0.6, 0.0, 1.0));  // progress of the slide, from rest to rest
    const double surface = interpolated_touch(s);
    double offset;  // above the touching height: + is above
    if (f < 0.15)
      offset = kClearance * (1 - smooth(f / 0.15));
    else if (f < 0.25)
      offset = -kPress * smooth((f - 0.15) / 0.1);
    else if (f < 0.85)
      offset = -kPress;
    else
      offset = -kPress + (kPress + kClearance) * smooth((f - 0.85) / 0.15);
    return pose(slide_x(s), turn(s), surface + offset);
  }
  static Pose pose(double x, double angle, double height) {
    Pose p;
    p.rotation = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitY()).toRotationMatrix();
    p.translation = {x, height, 0.0};
    return p;
  }

 private:
  static constexpr int kSamples = 240;
  static constexpr double kPress = 0.002, kClearance = 0.02;
  static double smooth(double u) { return u * u * (3 - 2 * u); }
  static double slide_x(double s) { return 0.02 * std::sin(2 * M_PI * s); }
  static double turn(double s) { return 0.35 * std::sin(M_PI * s); }
  double interpolated_touch(double s) const {
    const double u = s * kSamples;
    const int i = std::min(int(u), kSamples - 1);
    return touch_[i] + (touch_[i + 1] - touch_[i]) * (u - i);
  }
  // The lowest height at which the tool, at (x, turn), does not penetrate the scene (bisection, 10 µm).
  static double touch_height(HapticRenderer& probe, double x, double angle) {
    double low = -0.3, high = 0.3;
    while (high - low > 1e-5) {
      const double mid = 0.5 * (low + high);
      probe.contact_wrench_at(pose(x, angle, mid));
      (probe.contacts().empty() ? high : low) = mid;
    }
    return high;
  }
  double seconds_;
  std::vector<double> touch_;
};

struct Record {
  double time;
  Pose device;
  voxfmt::runtime::Wrench wrench;
  double penetration, cycle_us;
  uint32_t levels;
  size_t contacts;
};

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(q * double(v.size())))];
}

// A plot of three panels (|force|, |torque|, cycle time) against time.
void plot(const std::vector<Record>& records, double budget_us, const std::string& title, const std::string& path) {
  using voxfmt::exports::RasterImage;
  using voxfmt::exports::Rgb;
  const int width = 1200, panel = 220, top = 40, left = 80, gap = 30;
  RasterImage image(width, top + 3 * (panel + gap), Rgb{255, 255, 255});
  image.text(left, 12, title, 2, Rgb{0, 0, 0});
  const double t_end = records.empty() ? 1 : records.back().time;
  auto draw_panel = [&](int index, const std::string& label, auto value, double limit_line, Rgb colour) {
    const int y0 = top + index * (panel + gap);
    double vmax = limit_line;
    for (const Record& r : records) vmax = std::max(vmax, value(r));
    vmax = vmax > 0 ? vmax * 1.1 : 1;
    image.fill_rect(left, y0, width - left - 20, panel, Rgb{245, 245, 245});
    std::ostringstream text;
    text << label << "  (max " << std::setprecision(3) << vmax / 1.1 << ")";
    image.text(left + 6, y0 + 6, text.str(), 2, Rgb{40, 40, 40});
    auto px = [&](double t) { return left + int((width - left - 21) * t / t_end); };
    auto py = [&](double v) { return y0 + panel - 1 - int((panel - 2) * std::clamp(v / vmax, 0.0, 1.0)); };
    if (limit_line > 0)
      for (int x = left; x < width - 20; x += 4) image.set(x, py(limit_line), Rgb{200, 0, 0});
    int last_x = -1, last_y = 0;
    for (const Record& r : records) {
      const int x = px(r.time), y = py(value(r));
      if (last_x >= 0)
        for (int yy = std::min(y, last_y); yy <= std::max(y, last_y); ++yy) image.set(x, yy, colour);
      image.set(x, y, colour);
      last_x = x;
      last_y = y;
    }
    image.text(left - 70, y0 + panel - 14, "0", 2, Rgb{0, 0, 0});
  };
  draw_panel(
      0, "FORCE N", [](const Record& r) { return r.wrench.force.norm(); }, 0, Rgb{0, 90, 200});
  draw_panel(
      1, "TORQUE NM", [](const Record& r) { return r.wrench.torque.norm(); }, 0, Rgb{0, 150, 60});
  draw_panel(
      2, "CYCLE US (RED: BUDGET)", [](const Record& r) { return r.cycle_us; }, budget_us, Rgb{120, 0, 160});
  image.text(width - 200, top + 3 * (panel + gap) - 24, "TIME " + std::to_string(int(t_end)) + " S", 2, Rgb{0, 0, 0});
  if (auto written = image.write_png(path); !written) throw std::runtime_error(written.error().describe());
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Haptic rendering in real time: a bunny tool on a scripted device against 1 and 10 objects"};
  std::string meshes = VOXFMT_SAMPLE_MESHES, cache = "out/haptic_loop", out = "out/haptic_loop", json_path;
  double seconds = 10;
  bool quick = false;
  app.add_option("--meshes", meshes, "folder of CGAL's sample meshes")->capture_default_str();
  app.add_option("--cache", cache, "folder for the baked assets")->capture_default_str();
  app.add_option("--out", out, "folder for the CSV files and plots")->capture_default_str();
  app.add_option("--seconds", seconds, "simulated (and real) seconds per run")
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  app.add_flag("--quick", quick, "2 s per run");
  bool no_realtime = false;
  app.add_flag("--no-realtime", no_realtime,
               "do not ask for SCHED_FIFO, locked memory and a pinned CPU (by default asked for, and used where "
               "the system permits; the JSON says what was granted)");
  app.add_option("--json", json_path, "figures of every run (the shape is in the file's header comment)");
  CLI11_PARSE(app, argc, argv);
  const bool realtime = !no_realtime;
  if (quick) seconds = 2;
  try {
    fs::create_directories(cache);
    fs::create_directories(out);
    const std::string bunny_mesh = meshes + "/bunny00.off";
    const auto bunny = baked(bunny_mesh, cache + "/bunny-r306-p35000.vox.h5", 306, 35000, 0.15);
    // Nine more objects, baked in their own units and scaled to 0.15 m by their pose, centred on the bunny.
    std::vector<SceneObject> ten{{bunny, Pose{}}};
    for (const char* name : {"elephant", "cow", "bear", "camel", "dino", "pig", "fandisk", "rotor", "mushroom"}) {
      auto object = baked(meshes + "/" + name + ".off", cache + "/" + name + "-r128.vox.h5", 128, 4000, 1.0);
      Pose pose;
      pose.scale = 0.15 / (object->bounds_max() - object->bounds_min()).maxCoeff();
      const Eigen::Vector3d centre = 0.5 * (object->bounds_max() + object->bounds_min());
      const Eigen::Vector3d bunny_centre = 0.5 * (bunny->bounds_max() + bunny->bounds_min());
      pose.translation = bunny_centre - pose.scale * centre;
      ten.push_back({object, pose});
    }
    // The tool starts above the scene; the script puts it where the device is.
    std::ostringstream json;
    json << "{\"runs\": [";
    bool first_run = true;
    std::cout << std::left << std::setw(7) << "pairs" << std::setw(8) << "rate" << std::setw(9) << "cycles"
              << std::setw(9) << "p50 us" << std::setw(9) << "p99 us" << std::setw(10) << "p99.9 us" << std::setw(9)
              << "max us" << std::setw(10) << "overruns" << std::setw(8) << "levels" << std::setw(12) << "max jump N"
              << "max pen mm\n";
    for (size_t pairs : {size_t(1), size_t(10)}) {
      for (double rate : {1000.0, 5000.0}) {
        voxfmt::runtime::HapticParameters parameters;
        // Three quarters of the period for the queries; the rest is the step, the loop and the kernel's wake-up.
        parameters.time_budget_us = 0.75e6 / rate;
        HapticRenderer probe(bunny, Pose{}, parameters);
        for (size_t i = 0; i < pairs; ++i) probe.add_object(ten[i].object, ten[i].pose);
        const Script script(probe, seconds);
        HapticRenderer renderer(bunny, script(0), parameters);
        for (size_t i = 0; i < pairs; ++i) renderer.add_object(ten[i].object, ten[i].pose);
        voxfmt::runtime::ScriptedDevice device([&](double t) { return script(t); });

        const auto cycles = uint64_t(std::llround(seconds * rate));
        std::vector<Record> records;
        records.reserve(cycles + 1);
        voxfmt::runtime::LoopSettings loop_settings{rate, 80.0};
        loop_settings.realtime_priority = loop_settings.lock_memory = realtime;
        loop_settings.cpu = realtime ? int(std::thread::hardware_concurrency()) - 1 : -1;
        voxfmt::runtime::RealtimeLoop loop(loop_settings, [&](double t, double dt) {
          const auto start = Clock::now();
          const Pose pose = device.read_pose(t);
          const auto& cycle = renderer.step(pose, dt);
          device.write_wrench(cycle.device_wrench);
          const double us = std::chrono::duration<double, std::micro>(Clock::now() - start).count();
          records.push_back(
              {t, pose, cycle.device_wrench, cycle.max_penetration, us, cycle.levels_completed, cycle.contacts});
        });
        if (const voxfmt::Status started = loop.start(cycles); !started) {
          std::cerr << "haptic_loop: " << started.error().describe() << "\n";
          return 1;
        }
        loop.join();

        std::vector<double> cycle_us;
        double max_jump = 0, max_jump_on_time = 0, max_penetration = 0;
        uint32_t levels_min = UINT32_MAX;
        for (size_t i = 0; i < records.size(); ++i) {
          cycle_us.push_back(records[i].cycle_us);
          max_penetration = std::max(max_penetration, records[i].penetration);
          if (records[i].contacts > 0) levels_min = std::min(levels_min, records[i].levels);
          if (i > 0) {
            const double jump = (records[i].wrench.force - records[i - 1].wrench.force).norm();
            max_jump = std::max(max_jump, jump);
            // After an overrun the step covers the skipped periods: the device moved further, a jump follows.
            if (records[i].time - records[i - 1].time < 1.5 / rate) max_jump_on_time = std::max(max_jump_on_time, jump);
          }
        }
        if (levels_min == UINT32_MAX) levels_min = 0;
        const std::string stem =
            out + "/haptic_loop-" + std::to_string(pairs) + "pairs-" + std::to_string(int(rate / 1000)) + "khz";
        std::ofstream csv(stem + ".csv");
        csv << "time_s,x,y,z,qw,qx,qy,qz,fx,fy,fz,tx,ty,tz,penetration_m,contacts,levels,cycle_us\n";
        csv << std::setprecision(9);
        for (const Record& r : records) {
          const Eigen::Quaterniond q(r.device.rotation);
          csv << r.time << ',' << r.device.translation.x() << ',' << r.device.translation.y() << ','
              << r.device.translation.z() << ',' << q.w() << ',' << q.x() << ',' << q.y() << ',' << q.z() << ','
              << r.wrench.force.x() << ',' << r.wrench.force.y() << ',' << r.wrench.force.z() << ','
              << r.wrench.torque.x() << ',' << r.wrench.torque.y() << ',' << r.wrench.torque.z() << ',' << r.penetration
              << ',' << r.contacts << ',' << r.levels << ',' << r.cycle_us << '\n';
        }
        if (!csv) throw std::runtime_error("cannot write " + stem + ".csv");
        std::ostringstream title;
        title << "HAPTIC LOOP: BUNNY TOOL VS " << pairs << (pairs == 1 ? " OBJECT" : " OBJECTS") << " AT "
              << int(rate / 1000) << " KHZ";
        plot(records, parameters.time_budget_us, title.str(), stem + ".png");

        const auto stats = loop.stats();
        const double p50 = percentile(cycle_us, 0.5), p99 = percentile(cycle_us, 0.99),
                     p999 = percentile(cycle_us, 0.999), max = percentile(cycle_us, 1.0);
        std::cout << std::setw(7) << pairs << std::setw(8) << rate << std::setw(9) << records.size() << std::fixed
                  << std::setprecision(1) << std::setw(9) << p50 << std::setw(9) << p99 << std::setw(10) << p999
                  << std::setw(9) << max << std::setw(10) << stats.overruns << std::setw(8) << levels_min
                  << std::setprecision(4) << std::setw(12) << max_jump << std::setprecision(3) << max_penetration * 1e3
                  << std::defaultfloat << "\n";
        json << (first_run ? "" : ",") << "\n  {\"pairs\": " << pairs << ", \"rate_hz\": " << rate
             << ", \"points_per_tool\": " << bunny->point_tree().size() << ", \"cycles\": " << records.size()
             << ", \"cycle_us\": {\"p50\": " << p50 << ", \"p99\": " << p99 << ", \"p999\": " << p999
             << ", \"max\": " << max << "}, \"overruns\": " << stats.overruns
             << ", \"realtime_priority\": " << (stats.realtime_priority ? "true" : "false")
             << ", \"memory_locked\": " << (stats.memory_locked ? "true" : "false") << ", \"cpu\": " << stats.cpu
             << ", \"levels_completed_min\": " << levels_min
             << ", \"tree_levels\": " << bunny->point_tree().level_count() << ", \"max_force_jump_n\": " << max_jump
             << ", \"max_force_jump_on_time_n\": " << max_jump_on_time << ", \"max_penetration_m\": " << max_penetration
             << ", \"max_force_n\": "
             << std::max_element(
                    records.begin(), records.end(),
                    [](const Record& a, const Record& b) { return a.wrench.force.norm() < b.wrench.force.norm(); })
                    ->wrench.force.norm()
             << ", \"seconds\": " << seconds << ", \"csv\": \"" << stem << ".csv\"}";
        first_run = false;
      }
    }
    json << "\n]}\n";
    if (!json_path.empty()) {
      std::ofstream file(json_path);
      file << json.str();
      if (!file) throw std::runtime_error("cannot write " + json_path);
    }
    std::cout << "CSV files and plots in " << out << "/\n";
  } catch (const std::exception& e) {
    std::cerr << "haptic_loop: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
