// The haptic renderer's contact wrench along a path, for bench/force_quality.py: HapticRenderer::contact_wrench_at
// (the full trees; the per-point penalty along the tool's own point normals, classical VPS) at every pose.
//
//   haptic-wrench TOOL.vox.h5 OBJECT.vox.h5 POSES OUT --stiffness K [--tricubic]
//
// POSES: the tool's poses in the object's frame, N row-major 4x4 float64 matrices (raw, little-endian); OUT gets N
// rows of force and torque (about the tool's centre of mass), 6 float64 each. Prints the microseconds per pose of
// the wrenches alone (loading excluded).
#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <vector>

#include "voxfmt/runtime/collision_object.h"
#include "voxfmt/runtime/haptics.h"

namespace rt = voxfmt::runtime;

namespace {

std::shared_ptr<const rt::CollisionObject> load_or_exit(const std::string& path) {
  auto object = rt::CollisionObject::load(path);
  if (!object) {
    std::cerr << "haptic-wrench: " << path << ": " << object.error().message << "\n";
    std::exit(2);
  }
  return object.value();
}

rt::Pose pose_of(const double* m) {
  rt::Pose pose;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) pose.rotation(r, c) = m[4 * r + c];
    pose.translation[r] = m[4 * r + 3];
  }
  return pose;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"The haptic renderer's contact wrench at each of a path's poses (bench/force_quality.py)"};
  std::string tool_path, object_path, poses_path, out_path;
  double stiffness = 1000.0;
  app.add_option("tool", tool_path, "The tool's asset (its point shell is used)")->required();
  app.add_option("object", object_path, "The static object's asset (its voxelmap is used), at the identity")
      ->required();
  app.add_option("poses", poses_path, "N row-major 4x4 float64 poses of the tool")->required();
  app.add_option("out", out_path, "N x 6 float64: force, torque")->required();
  app.add_option("--stiffness", stiffness, "N/m per penetrating point")->capture_default_str();
  bool tricubic = false;
  app.add_flag("--tricubic", tricubic, "Depths interpolated tricubically (QueryOptions::interpolation)");
  CLI11_PARSE(app, argc, argv);

  std::ifstream in(poses_path, std::ios::binary | std::ios::ate);
  const std::streamoff bytes = in ? std::streamoff(in.tellg()) : 0;
  if (bytes <= 0 || bytes % std::streamoff(16 * sizeof(double)) != 0) {
    std::cerr << "haptic-wrench: " << poses_path << ": not a whole number of 4x4 float64 poses\n";
    return 2;
  }
  std::vector<double> poses(size_t(bytes) / sizeof(double));
  in.seekg(0);
  if (!in.read(reinterpret_cast<char*>(poses.data()), bytes)) {
    std::cerr << "haptic-wrench: cannot read " << poses_path << "\n";
    return 2;
  }

  const auto tool = load_or_exit(tool_path);
  const auto object = load_or_exit(object_path);
  rt::HapticParameters parameters;
  parameters.contact_stiffness = stiffness;
  if (tricubic) parameters.query.interpolation = rt::Interpolation::Tricubic;
  rt::HapticRenderer renderer(tool, pose_of(poses.data()), parameters);
  renderer.add_object(object, rt::Pose{});
  std::vector<double> out;
  out.reserve(poses.size() / 16 * 6);
  const auto start = std::chrono::steady_clock::now();
  for (size_t k = 0; k < poses.size() / 16; ++k) {
    const rt::Wrench w = renderer.contact_wrench_at(pose_of(&poses[16 * k]));
    for (int a = 0; a < 3; ++a) out.push_back(w.force[a]);
    for (int a = 0; a < 3; ++a) out.push_back(w.torque[a]);
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::cout << "us_per_pose " << seconds * 1e6 / double(poses.size() / 16) << "\n";
  std::ofstream file(out_path, std::ios::binary);
  file.write(reinterpret_cast<const char*>(out.data()), std::streamsize(out.size() * sizeof(double)));
  if (!file) {
    std::cerr << "haptic-wrench: cannot write " << out_path << "\n";
    return 2;
  }
  return 0;
}
