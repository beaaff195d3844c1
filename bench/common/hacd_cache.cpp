#include "hacd_cache.h"

#include <HACD/hacdHACD.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>

namespace voxfmt_bench {
namespace {

bool read_hulls(const std::string& path, Hulls& hulls) {
  std::ifstream in(path);
  if (!in) return false;
  size_t count = 0;
  if (!(in >> count) || count == 0 || count > 1000) return false;
  hulls.assign(count, {});
  for (auto& hull : hulls) {
    size_t n = 0;
    if (!(in >> n) || n == 0 || n > 100000) return false;
    hull.resize(n);
    for (auto& p : hull) {
      double x, y, z;
      if (!(in >> x >> y >> z)) return false;
      p = btVector3(btScalar(x), btScalar(y), btScalar(z));
    }
  }
  return true;
}

void write_hulls(const std::string& path, const Hulls& hulls) {
  const std::string tmp = path + ".partial";
  {
    std::ofstream out(tmp);
    out << std::setprecision(9) << hulls.size() << "\n";
    for (const auto& hull : hulls) {
      out << hull.size() << "\n";
      for (const auto& p : hull) out << p.x() << " " << p.y() << " " << p.z() << "\n";
    }
    if (!out) return;  // a cache that cannot be written only costs time on the next run
  }
  std::filesystem::rename(tmp, path);
}

// HACD calls back thousands of times: show whole percents, in place, and only on a terminal.
int last_percent = -1;
bool hacd_progress(const char*, double progress, double, size_t) {
  const int percent = int(progress);
  if (percent != last_percent && isatty(STDERR_FILENO)) {
    std::cerr << "\r  HACD: " << percent << "%" << std::flush;
    last_percent = percent;
  }
  return true;
}

}  // namespace

Hulls hacd_decomposition(const std::vector<btVector3>& vertices, const std::vector<int>& indices,
                         const std::string& cache, double& seconds) {
  Hulls hulls;
  seconds = 0;
  if (!cache.empty() && read_hulls(cache, hulls)) return hulls;
  std::cerr << "HACD: decomposing " << indices.size() / 3 << " triangles (minutes; cached in " << cache << ")\n";
  const auto start = std::chrono::steady_clock::now();
  std::vector<HACD::Vec3<HACD::Real>> points;
  for (const btVector3& v : vertices) points.emplace_back(v.x(), v.y(), v.z());
  std::vector<HACD::Vec3<long>> triangles;
  for (size_t t = 0; t + 2 < indices.size(); t += 3) triangles.emplace_back(indices[t], indices[t + 1], indices[t + 2]);
  HACD::HACD hacd;
  hacd.SetPoints(points.data());
  hacd.SetNPoints(points.size());
  hacd.SetTriangles(triangles.data());
  hacd.SetNTriangles(triangles.size());
  hacd.SetCompacityWeight(0.1);
  hacd.SetVolumeWeight(0.0);
  hacd.SetNClusters(8);
  hacd.SetNVerticesPerCH(100);
  hacd.SetConcavity(100);
  hacd.SetAddExtraDistPoints(false);
  hacd.SetAddNeighboursDistPoints(false);
  hacd.SetAddFacesPoints(false);
  last_percent = -1;
  hacd.SetCallBack(hacd_progress);
  hacd.Compute();
  if (isatty(STDERR_FILENO)) std::cerr << "\n";
  for (size_t c = 0; c < hacd.GetNClusters(); ++c) {
    std::vector<HACD::Vec3<HACD::Real>> hull_points(hacd.GetNPointsCH(c));
    std::vector<HACD::Vec3<long>> hull_triangles(hacd.GetNTrianglesCH(c));
    hacd.GetCH(c, hull_points.data(), hull_triangles.data());
    std::vector<btVector3> hull;
    for (const auto& p : hull_points) hull.emplace_back(btScalar(p.X()), btScalar(p.Y()), btScalar(p.Z()));
    hulls.push_back(std::move(hull));
  }
  seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::cerr << "HACD: " << hulls.size() << " hulls in " << std::fixed << std::setprecision(1) << seconds << " s\n";
  if (!cache.empty()) write_hulls(cache, hulls);
  return hulls;
}

}  // namespace voxfmt_bench
