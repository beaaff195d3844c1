#include "hacd_cache.h"

#include <HACD/hacdHACD.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>

namespace voxfmt_bench {
namespace {

// HACD's parameters: set in one place, and part of the cache key.
constexpr double kCompacityWeight = 0.1, kVolumeWeight = 0.0, kConcavity = 100;
constexpr size_t kClusters = 8, kVerticesPerHull = 100;
constexpr char kCacheFormat[] = "voxfmt-hacd-cache 1";

std::string parameters() {
  std::ostringstream text;
  text << "compacity=" << kCompacityWeight << " volume=" << kVolumeWeight << " clusters=" << kClusters
       << " vertices_per_hull=" << kVerticesPerHull << " concavity=" << kConcavity
       << " extra_dist_points=0 neighbours_dist_points=0 faces_points=0";
  return text.str();
}

// FNV-1a, 64 bits: a cache key, not a defence against crafted files.
void fnv1a(uint64_t& h, const std::string& bytes) {
  for (unsigned char c : bytes) h = (h ^ c) * 1099511628211ull;
}

bool read_hulls(const std::string& path, const std::string& key, Hulls& hulls) {
  std::ifstream in(path);
  if (!in) return false;
  std::string header;
  if (!std::getline(in, header) || header != key) return false;
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

void write_hulls(const std::string& path, const std::string& key, const Hulls& hulls) {
  const std::string tmp = path + ".partial";
  {
    std::ofstream out(tmp);
    out << key << "\n" << std::setprecision(9) << hulls.size() << "\n";
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

std::string hacd_cache_key(const std::vector<btVector3>& vertices, const std::vector<int>& indices) {
  uint64_t h = 14695981039346656037ull;
  char number[32];
  for (const btVector3& v : vertices)
    for (int i = 0; i < 3; ++i) {
      std::snprintf(number, sizeof number, "%.6e ", double(v[i]));
      fnv1a(h, number);
    }
  for (int i : indices) fnv1a(h, std::to_string(i) + " ");
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(h));
  return std::string(kCacheFormat) + " mesh=" + hex + " vertices=" + std::to_string(vertices.size()) +
         " triangles=" + std::to_string(indices.size() / 3) + " " + parameters();
}

Hulls hacd_decomposition(const std::vector<btVector3>& vertices, const std::vector<int>& indices,
                         const std::string& cache, double& seconds, const std::string& shipped) {
  Hulls hulls;
  seconds = 0;
  const std::string key = hacd_cache_key(vertices, indices);
  if (!cache.empty() && read_hulls(cache, key, hulls)) return hulls;
  if (!shipped.empty() && read_hulls(shipped, key, hulls)) {
    if (!cache.empty()) write_hulls(cache, key, hulls);
    return hulls;
  }
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
  hacd.SetCompacityWeight(kCompacityWeight);
  hacd.SetVolumeWeight(kVolumeWeight);
  hacd.SetNClusters(kClusters);
  hacd.SetNVerticesPerCH(kVerticesPerHull);
  hacd.SetConcavity(kConcavity);
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
  if (!cache.empty()) write_hulls(cache, key, hulls);
  return hulls;
}

}  // namespace voxfmt_bench
