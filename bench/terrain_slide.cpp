// terrain-slide: a VPS bunny sliding over a Bullet terrain (btHeightfieldTerrainShape), one pair test a step
// through the registered collision algorithm, at several speeds, from scratch and coherent (a terrain pair keeps
// its front only while it gathers the same triangles: a sliding body gathers others nearly every step).
//
// The bunny (CGAL's bunny00.off at 0.15 m, resolution 306, 35,000 points, baked once into --cache) circles 0.5 m
// around the middle of a 4 m x 4 m terrain of 8.5 mm cells (--cell; mixed_scene's) with 2 cm waves, turning with its
// path, pressed 0.5 to 2 voxels into the surface under it. Every configuration sees the same poses; runs alternate
// between them, --repeat times, and each figure is the median of its runs. Each configuration's contacts are
// compared with the pair from scratch at every step, field by field (bit for bit).
//
// Then (--sink) the same bunny at rest at the path's start, sunk deeper and deeper under the surface (a body
// teleported or pushed into the ground): per depth, the pair test's time from scratch, the shell points below the
// surface and those that are contacts, and the deepest contact.
//
// Then (--walls) the bunny at rest 1 mm into the waves, beside a wall: the terrain rises by each height (0: no wall)
// from the first grid line at most two cells inside the body's box, so the pair gathers the ground under the body,
// the wall's steep face and a strip of its top (a tall set), and the body's side lies 1-2 cells past the top's edge
// (2-3 past the face's foot). Every contact's depth, and every point under the terrain, is checked.
#include <BulletCollision/BroadphaseCollision/btCollisionAlgorithm.h>
#include <BulletCollision/CollisionDispatch/btCollisionDispatcher.h>
#include <BulletCollision/CollisionDispatch/btCollisionObjectWrapper.h>
#include <BulletCollision/CollisionDispatch/btDefaultCollisionConfiguration.h>
#include <BulletCollision/CollisionDispatch/btManifoldResult.h>
#include <BulletCollision/CollisionShapes/btHeightfieldTerrainShape.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <iostream>

#include "common/figures.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/bullet/collision.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/cores.h"

namespace {

namespace fs = std::filesystem;
using namespace voxfmt_bench;  // quantile, mean, fixed, load_average
using Clock = std::chrono::steady_clock;
using voxfmt::bullet::CollisionSettings;
constexpr double kPi = 3.14159265358979323846;
constexpr double kTerrainM = 4.0;    // the terrain's side, metres
constexpr double kPathRadius = 0.5;  // metres
// Beside a wall each contact's depth is checked against its point's distance to the terrain's triangles: float
// positions of points 0.5 m from the origin round to about 0.03 um.
constexpr double kDepthToleranceMm = 0.01;

double wave(double x, double z) { return 0.02 * std::sin(2 * kPi * x / 0.7) * std::cos(2 * kPi * z / 0.9); }

struct Config {
  std::string name;
  bool coherent;
};

/// One VPS body against the terrain through the registered algorithm, as a world's narrow phase calls it.
class Pair {
 public:
  Pair(btCollisionShape& terrain, std::shared_ptr<const voxfmt::runtime::CollisionObject> object, const Config& config)
      : terrain_(terrain) {
    btDefaultCollisionConstructionInfo info;
    voxfmt::bullet::prepare_construction_info(info);
    configuration_ = std::make_unique<btDefaultCollisionConfiguration>(info);
    dispatcher_ = std::make_unique<btCollisionDispatcher>(configuration_.get());
    CollisionSettings settings;
    settings.coherent = config.coherent;
    settings.on_contacts = [this](const btCollisionObject*, const btCollisionObject*,
                                  const voxfmt::runtime::ContactSet& contacts) { contacts_ = contacts.contacts; };
    vps_ = voxfmt::bullet::register_vps_collision(*dispatcher_, settings);
    shape_ = std::make_unique<voxfmt::bullet::VpsMixedShape>(std::move(object));
    body_.setCollisionShape(shape_.get());
    terrain_object_.setCollisionShape(&terrain_);
    btCollisionObjectWrapper wa(nullptr, shape_.get(), &body_, body_.getWorldTransform(), -1, -1);
    btCollisionObjectWrapper wb(nullptr, &terrain_, &terrain_object_, terrain_object_.getWorldTransform(), -1, -1);
    algorithm_ = dispatcher_->findAlgorithm(&wa, &wb, nullptr, BT_CONTACT_POINT_ALGORITHMS);
  }
  ~Pair() {
    algorithm_->~btCollisionAlgorithm();
    dispatcher_->freeCollisionAlgorithm(algorithm_);
  }
  Pair(const Pair&) = delete;
  Pair& operator=(const Pair&) = delete;

  /// The pair test's contacts with the body at `at`, and its time (microseconds).
  double test(const btTransform& at) {
    body_.setWorldTransform(at);
    btCollisionObjectWrapper wa(nullptr, shape_.get(), &body_, body_.getWorldTransform(), -1, -1);
    btCollisionObjectWrapper wb(nullptr, &terrain_, &terrain_object_, terrain_object_.getWorldTransform(), -1, -1);
    btManifoldResult result(&wa, &wb);
    contacts_.clear();
    const auto start = Clock::now();
    algorithm_->processCollision(&wa, &wb, btDispatcherInfo(), &result);
    return std::chrono::duration<double, std::micro>(Clock::now() - start).count();
  }
  const std::vector<voxfmt::runtime::Contact>& contacts() const { return contacts_; }
  uint64_t points_tested() const { return vps_->counters().points_tested; }

 private:
  btCollisionShape& terrain_;
  std::unique_ptr<btDefaultCollisionConfiguration> configuration_;
  std::unique_ptr<btCollisionDispatcher> dispatcher_;
  std::unique_ptr<voxfmt::bullet::VpsCollisionRegistration> vps_;
  std::unique_ptr<voxfmt::bullet::VpsMixedShape> shape_;
  btCollisionObject body_, terrain_object_;
  btCollisionAlgorithm* algorithm_ = nullptr;
  std::vector<voxfmt::runtime::Contact> contacts_;
};

bool same_contacts(const std::vector<voxfmt::runtime::Contact>& a, const std::vector<voxfmt::runtime::Contact>& b) {
  return std::equal(a.begin(), a.end(), b.begin(), b.end(), [](const auto& x, const auto& y) {
    return x.point_index == y.point_index && x.point_of_b == y.point_of_b && x.depth == y.depth && x.point == y.point &&
           x.normal == y.normal;
  });
}

/// The body's poses along the circle at `speed_m` a step: turning with its path, its lowest shell point pressed
/// 0.5-2 voxels below the terrain under it.
std::vector<btTransform> circle_path(const std::shared_ptr<const voxfmt::runtime::CollisionObject>& body,
                                     double speed_m, int steps) {
  const voxfmt::bullet::VpsMixedShape shape(body);
  const voxfmt::runtime::CollisionObject& object = *body;
  const double h = object.voxelmap().voxel_size();
  std::vector<btTransform> poses;
  for (int s = 0; s < steps; ++s) {
    const double angle = speed_m * s / kPathRadius;
    const double x = kPathRadius * std::cos(angle), z = kPathRadius * std::sin(angle);
    const btQuaternion q = btQuaternion(btVector3(0, 1, 0), btScalar(-angle)) * btQuaternion(btVector3(1, 0, 1), 0.3f);
    btTransform t(q, btVector3(0, 0, 0));
    const voxfmt::runtime::Pose pose = shape.asset_pose(t);
    double lowest = 1e30;
    for (size_t i = 0; i < object.point_tree().size(); ++i) {
      const Eigen::Vector3d w = pose.apply(object.point_tree().asset_point(i));
      lowest = std::min(lowest, w.y() - wave(w.x() + x, w.z() + z));
    }
    const double depth = h * (1.25 + 0.75 * std::sin(0.1 * s));
    t.setOrigin(btVector3(btScalar(x), btScalar(-lowest - depth), btScalar(z)));
    poses.push_back(t);
  }
  return poses;
}

/// The body at the path's start, its lowest shell point `sunk_m` below the terrain under it; `below`: how far each
/// shell point is below the surface (negative above it).
btTransform sunk_pose(const std::shared_ptr<const voxfmt::runtime::CollisionObject>& body, double sunk_m,
                      std::vector<double>& below) {
  btTransform t = circle_path(body, 0.0, 1)[0];
  const voxfmt::runtime::Pose pose = voxfmt::bullet::VpsMixedShape(body).asset_pose(t);
  below.clear();
  double deepest = -1e30;
  for (size_t i = 0; i < body->point_tree().size(); ++i) {
    const Eigen::Vector3d w = pose.apply(body->point_tree().asset_point(i));
    below.push_back(wave(w.x(), w.z()) - w.y());
    deepest = std::max(deepest, below.back());
  }
  t.setOrigin(t.getOrigin() - btVector3(0, btScalar(sunk_m - deepest), 0));
  for (double& b : below) b += sunk_m - deepest;
  return t;
}

/// Per depth in `sunk_mm`, `tests` pair tests from scratch: prints a row each and returns their JSON.
nlohmann::json sink(btCollisionShape& terrain, const std::shared_ptr<const voxfmt::runtime::CollisionObject>& object,
                    const std::vector<double>& sunk_mm, int tests) {
  std::cout << "\n"
            << std::setw(10) << "sunk mm" << std::setw(22) << "pair test p50/max us" << std::setw(18) << "below waves"
            << std::setw(14) << "contacts" << std::setw(16) << "deepest mm"
            << "\n";
  nlohmann::json rows = nlohmann::json::array();
  Pair pair(terrain, object, {"from scratch", false});
  for (const double mm : sunk_mm) {
    std::vector<double> below;
    const btTransform at = sunk_pose(object, mm * 1e-3, below);
    std::vector<double> us;
    for (int t = 0; t < tests; ++t) us.push_back(pair.test(at));
    size_t submerged = 0, touching = 0;
    for (const double b : below) submerged += b > 1e-6;
    double deepest = 0;
    for (const voxfmt::runtime::Contact& c : pair.contacts())
      if (!c.point_of_b && c.depth > 0) {
        ++touching;
        deepest = std::max(deepest, c.depth);
      }
    std::cout << std::setw(10) << fixed(mm, 0) << std::setw(22)
              << (fixed(quantile(us, 0.5), 0) + " / " + fixed(*std::max_element(us.begin(), us.end()), 0))
              << std::setw(18) << submerged << std::setw(14) << touching << std::setw(16) << fixed(deepest * 1e3, 1)
              << "\n";
    rows.push_back({{"sunk_mm", mm},
                    {"p50_us", quantile(us, 0.5)},
                    {"max_us", *std::max_element(us.begin(), us.end())},
                    {"tests", tests},
                    {"points_below_surface", submerged},
                    {"points_in_contact", touching},
                    {"deepest_contact_mm", deepest * 1e3}});
  }
  return rows;
}

struct Run {
  double mean_us, p50_us, p90_us, points_per_step;
  size_t contacts = 0, differing_steps = 0;
};

/// One configuration along one path; `reference` holds the from-scratch pair's contacts per step (filled by the
/// first configuration, which is from scratch).
Run run(btCollisionShape& terrain, const std::shared_ptr<const voxfmt::runtime::CollisionObject>& object,
        const Config& config, const std::vector<btTransform>& poses,
        std::vector<std::vector<voxfmt::runtime::Contact>>& reference) {
  Pair pair(terrain, object, config);
  std::vector<double> us;
  Run result{};
  const bool fill = reference.empty();
  for (size_t s = 0; s < poses.size(); ++s) {
    us.push_back(pair.test(poses[s]));
    result.contacts += pair.contacts().size();
    if (fill)
      reference.push_back(pair.contacts());
    else if (!same_contacts(pair.contacts(), reference[s]))
      ++result.differing_steps;
  }
  result.mean_us = mean(us);
  result.p50_us = quantile(us, 0.5);
  result.p90_us = quantile(us, 0.9);
  result.points_per_step = double(pair.points_tested()) / double(poses.size());
  return result;
}

/// Every configuration along one path, alternated `repeat` times: prints a row each and returns their JSON;
/// adds the steps whose contacts differ from the pair from scratch's to `differing`.
nlohmann::json compare_on_path(btCollisionShape& terrain,
                               const std::shared_ptr<const voxfmt::runtime::CollisionObject>& object,
                               const std::vector<Config>& configs, const std::vector<btTransform>& poses, double speed,
                               int repeat, size_t& differing) {
  std::vector<std::vector<Run>> runs(configs.size());
  for (int r = 0; r < repeat; ++r) {
    std::vector<std::vector<voxfmt::runtime::Contact>> reference;
    for (size_t c = 0; c < configs.size(); ++c) runs[c].push_back(run(terrain, object, configs[c], poses, reference));
  }
  nlohmann::json rows = nlohmann::json::array();
  const auto median = [&](size_t c, double Run::*field) {
    std::vector<double> v;
    for (const Run& x : runs[c]) v.push_back(x.*field);
    return quantile(v, 0.5);
  };
  for (size_t c = 0; c < configs.size(); ++c) {
    // The speed-up over the from-scratch pair, within each round, then the median over the rounds.
    std::vector<double> ratios;
    size_t differ = 0;
    for (int r = 0; r < repeat; ++r) {
      ratios.push_back(runs[0][size_t(r)].mean_us / runs[c][size_t(r)].mean_us);
      differ = std::max(differ, runs[c][size_t(r)].differing_steps);
      differing += runs[c][size_t(r)].differing_steps;
    }
    const double speedup = quantile(ratios, 0.5);
    std::cout << std::left << std::setw(10) << fixed(speed, 1) << std::setw(16) << configs[c].name << std::right
              << std::setw(28)
              << (fixed(median(c, &Run::mean_us), 0) + " / " + fixed(median(c, &Run::p50_us), 0) + " / " +
                  fixed(median(c, &Run::p90_us), 0))
              << std::setw(10) << fixed(speedup, 2) + "x" << std::setw(14) << fixed(median(c, &Run::points_per_step), 0)
              << std::setw(14) << runs[c][0].contacts << std::setw(12) << differ << "\n";
    rows.push_back({{"pair", configs[c].name},
                    {"coherent", configs[c].coherent},
                    {"mean_us", median(c, &Run::mean_us)},
                    {"p50_us", median(c, &Run::p50_us)},
                    {"p90_us", median(c, &Run::p90_us)},
                    {"speedup_vs_scratch", speedup},
                    {"points_per_step", median(c, &Run::points_per_step)},
                    {"contacts", runs[c][0].contacts},
                    {"steps_differing_from_scratch", differ}});
  }
  return rows;
}

/// A load average's text as a JSON number (null where it could not be read).
nlohmann::json as_number(const std::string& text) {
  return text == "null" ? nlohmann::json() : nlohmann::json(std::stod(text));
}

/// The asset given, or the bunny baked once into the cache.
std::string load_or_bake(const std::string& mesh, const std::string& cache, std::string asset) {
  if (!asset.empty()) return asset;
  fs::create_directories(cache);
  asset = cache + "/bunny00-0.15m-r306-p35000.vox.h5";
  voxfmt::bake::Settings settings;
  settings.import.unit_scale = 0.15;
  settings.voxelmap.resolution = 306;
  settings.point_shell.points = 35000;
  if (voxfmt::bake::asset_is_current(asset, mesh, settings)) return asset;  // else another --mesh: baked again
  std::cerr << "bake: " << mesh << " -> " << asset << "\n";
  const auto summary = voxfmt::bake::bake_to_file(mesh, asset, settings);
  if (!summary) throw std::runtime_error(summary.error().describe());
  return asset;
}

/// The waves' heights on a square of kTerrainM metres, cells of about `cell_mm`, and Bullet's terrain over them.
struct Terrain {
  int cells = 0;
  double cell_m = 0;
  std::vector<float> heights;  ///< read in place by the shape
  std::unique_ptr<btHeightfieldTerrainShape> shape;
};

/// The terrain's cells a side for cells of about `cell_mm`.
int terrain_cells(double cell_mm) { return int(std::lround(kTerrainM / (cell_mm * 1e-3))); }

/// `rise(x, z)`: metres added to the waves (a wall).
Terrain make_terrain(double cell_mm, const std::function<double(double, double)>& rise = {}) {
  Terrain t;
  t.cells = terrain_cells(cell_mm);
  t.cell_m = kTerrainM / t.cells;
  const int n = t.cells + 1;
  t.heights.resize(size_t(n) * size_t(n));
  for (int k = 0; k < n; ++k)
    for (int i = 0; i < n; ++i) {
      const double x = -kTerrainM / 2 + t.cell_m * i, z = -kTerrainM / 2 + t.cell_m * k;
      t.heights[size_t(k * n + i)] = float(wave(x, z) + (rise ? rise(x, z) : 0.0));
    }
  // Bullet centres a terrain on its declared height range: [-1, 1] keeps height 0 at the origin, and reaches as deep
  // as a world must for Bullet to pair a body sunk a metre with it.
  t.shape = std::make_unique<btHeightfieldTerrainShape>(n, n, t.heights.data(), 1.0f, -1.0f, 1.0f, 1, PHY_FLOAT, false);
  t.shape->setLocalScaling(btVector3(btScalar(t.cell_m), 1, btScalar(t.cell_m)));
  return t;
}

using Triangle = std::array<Eigen::Vector3d, 3>;

/// The terrain's triangles (Bullet's own split of its cells) over x in [x_lo, x_hi], |z| < 0.3 m.
std::vector<Triangle> triangles_in(btHeightfieldTerrainShape& terrain, double x_lo, double x_hi) {
  struct Collect : btTriangleCallback {
    std::vector<Triangle> triangles;
    void processTriangle(btVector3* t, int, int) override {
      Triangle out;
      for (int c = 0; c < 3; ++c) out[size_t(c)] = Eigen::Vector3d(t[c].x(), t[c].y(), t[c].z());
      triangles.push_back(out);
    }
  } collect;
  terrain.processAllTriangles(&collect, btVector3(btScalar(x_lo), -1, -0.3f), btVector3(btScalar(x_hi), 1, 0.3f));
  return collect.triangles;
}

/// The distance from x to the nearest of `triangles`, written plainly (the plane where x projects inside the
/// triangle, else the nearest edge): a check on the pair's search, not a copy of it.
double distance_to(const std::vector<Triangle>& triangles, const Eigen::Vector3d& x) {
  const auto to_segment = [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    const Eigen::Vector3d ab = b - a;
    const double t = ab.squaredNorm() > 0 ? std::clamp((x - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
    return (a + t * ab - x).norm();
  };
  double best = std::numeric_limits<double>::infinity();
  for (const auto& [a, b, c] : triangles) {
    const Eigen::Vector3d n = (b - a).cross(c - a);
    const bool inside = n.squaredNorm() > 0 && n.dot((b - a).cross(x - a)) >= 0 && n.dot((c - b).cross(x - b)) >= 0 &&
                        n.dot((a - c).cross(x - c)) >= 0;
    best = std::min(best, inside ? std::abs(n.normalized().dot(x - a))
                                 : std::min({to_segment(a, b), to_segment(b, c), to_segment(c, a)}));
  }
  return best;
}

/// The height of the terrain's surface over (x, z): the plane of the triangle (Bullet's own split of the cell) whose
/// projection holds it; -infinity off the terrain.
double surface_height(btHeightfieldTerrainShape& terrain, double x, double z) {
  struct Over : btTriangleCallback {
    double x, z, height = -std::numeric_limits<double>::infinity();
    void processTriangle(btVector3* t, int, int) override {
      const Eigen::Vector3d a(t[0].x(), t[0].y(), t[0].z()), b(t[1].x(), t[1].y(), t[1].z()),
          c(t[2].x(), t[2].y(), t[2].z());
      // Barycentric coordinates of (x, z) in the triangle's projection along y.
      const double det = (b.x() - a.x()) * (c.z() - a.z()) - (c.x() - a.x()) * (b.z() - a.z());
      if (det == 0) return;
      const double u = ((x - a.x()) * (c.z() - a.z()) - (c.x() - a.x()) * (z - a.z())) / det;
      const double v = ((b.x() - a.x()) * (z - a.z()) - (x - a.x()) * (b.z() - a.z())) / det;
      if (u >= -1e-12 && v >= -1e-12 && u + v <= 1 + 1e-12)
        height = std::max(height, a.y() + u * (b.y() - a.y()) + v * (c.y() - a.y()));
    }
  } over;
  over.x = x;
  over.z = z;
  const btScalar e = 1e-4f;
  terrain.processAllTriangles(&over, btVector3(btScalar(x) - e, -1, btScalar(z) - e),
                              btVector3(btScalar(x) + e, 1, btScalar(z) + e));
  return over.height;
}

/// The pair's contacts beside a wall against the terrain's triangles: each as deep as its point lies, and every
/// shell point under the triangles deeper than the tolerance a contact (a missed one counts its depth as error).
struct WallCheck {
  size_t touching = 0, submerged = 0, missed = 0;
  double deepest = 0, worst_error = 0;
};

WallCheck check_contacts(btHeightfieldTerrainShape& terrain, const voxfmt::runtime::CollisionObject& object,
                         const voxfmt::runtime::Pose& pose, double x_max,
                         const std::vector<voxfmt::runtime::Contact>& contacts) {
  WallCheck check;
  const std::vector<Triangle> near = triangles_in(terrain, x_max - 0.4, x_max + 0.2);
  const auto world = [&](size_t i) { return pose.apply(object.point_tree().asset_point(i)); };
  std::vector<bool> contact(object.point_tree().size(), false);
  for (const voxfmt::runtime::Contact& c : contacts)
    if (!c.point_of_b && c.depth > 0) {
      ++check.touching;
      contact[c.point_index] = true;
      check.deepest = std::max(check.deepest, c.depth);
      check.worst_error = std::max(check.worst_error, std::abs(c.depth - distance_to(near, world(c.point_index))));
    }
  for (size_t i = 0; i < object.point_tree().size(); ++i) {
    const Eigen::Vector3d x = world(i);
    if (!(x.y() < surface_height(terrain, x.x(), x.z()))) continue;
    ++check.submerged;
    if (contact[i]) continue;
    const double depth = distance_to(near, x);
    if (depth > kDepthToleranceMm * 1e-3) {
      ++check.missed;
      check.worst_error = std::max(check.worst_error, depth);
    }
  }
  return check;
}

/// Per wall height in `walls_m`, `tests` pair tests from scratch of the bunny at rest 1 mm into the waves beside a
/// wall whose top starts at the first grid line at most two cells inside the body's box: prints a row each, returns
/// the JSON.
nlohmann::json beside_walls(const std::shared_ptr<const voxfmt::runtime::CollisionObject>& object, double cell_mm,
                            const std::vector<double>& walls_m, int tests) {
  std::vector<double> below;
  const btTransform at = sunk_pose(object, 1e-3, below);
  const voxfmt::runtime::Pose pose = voxfmt::bullet::VpsMixedShape(object).asset_pose(at);
  double x_max = -1e30;
  for (size_t i = 0; i < object->point_tree().size(); ++i)
    x_max = std::max(x_max, pose.apply(object->point_tree().asset_point(i)).x());
  std::cout << "\n"
            << std::setw(10) << "wall m" << std::setw(22) << "pair test p50/max us" << std::setw(18) << "below surface"
            << std::setw(14) << "contacts" << std::setw(16) << "deepest mm" << std::setw(18) << "depth error mm"
            << "\n";
  nlohmann::json rows = nlohmann::json::array();
  for (const double wall : walls_m) {
    // The wall's top starts at the first grid line past x_max less two cells; its face spans the cell before it.
    const double cell_m = kTerrainM / terrain_cells(cell_mm);
    const double top_from = -kTerrainM / 2 + cell_m * std::ceil((x_max - 2 * cell_m + kTerrainM / 2) / cell_m);
    const auto rise = [&](double x, double) { return x >= top_from - 1e-9 ? wall : 0.0; };
    const Terrain terrain = make_terrain(cell_mm, rise);
    Pair pair(*terrain.shape, object, {"from scratch", false});
    std::vector<double> us;
    for (int t = 0; t < tests; ++t) us.push_back(pair.test(at));
    const WallCheck check = check_contacts(*terrain.shape, *object, pose, x_max, pair.contacts());
    std::cout << std::setw(10) << fixed(wall, 2) << std::setw(22)
              << (fixed(quantile(us, 0.5), 0) + " / " + fixed(*std::max_element(us.begin(), us.end()), 0))
              << std::setw(18) << check.submerged << std::setw(14) << check.touching << std::setw(16)
              << fixed(check.deepest * 1e3, 1) << std::setw(18) << fixed(check.worst_error * 1e3, 4) << "\n";
    rows.push_back({{"wall_m", wall},
                    {"wall_top_from_x_m", top_from},
                    {"body_max_x_m", x_max},
                    {"p50_us", quantile(us, 0.5)},
                    {"max_us", *std::max_element(us.begin(), us.end())},
                    {"tests", tests},
                    {"points_below_surface", check.submerged},
                    {"points_in_contact", check.touching},
                    {"points_below_surface_missed", check.missed},
                    {"deepest_contact_mm", check.deepest * 1e3},
                    {"largest_depth_error_mm", check.worst_error * 1e3}});
  }
  return rows;
}

}  // namespace

int main(int argc, char** argv) {
  std::string mesh = VOXFMT_SAMPLE_MESHES "/bunny00.off", cache = "out/terrain_slide", asset, json_path;
  std::vector<double> speeds_mm = {0.3, 1, 3, 10}, sunk_mm = {1, 10, 50, 100, 200, 400, 600},
                      walls_m = {0, 0.1, 0.3, 0.9};
  int steps = 400, repeat = 3;
  double cell_mm = 8.5;
  CLI::App app{
      "terrain-slide — a VPS bunny sliding over a Bullet terrain: the pair test's time per step, from "
      "scratch and coherent, at several speeds"};
  app.add_option("--mesh", mesh, "mesh of the body, baked at 0.15 m, resolution 306, 35,000 points")
      ->capture_default_str();
  app.add_option("--cache", cache, "folder for the baked asset")->capture_default_str();
  app.add_option("--asset", asset, "an asset to use as it is instead of baking --mesh");
  app.add_option("--speeds", speeds_mm, "the body's speeds, millimetres a step")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_option("--sink", sunk_mm, "depths of the body sunk under the surface at rest, millimetres")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::Range(0.0, 2000.0));
  app.add_option("--walls", walls_m, "heights of a wall beside the body at rest, metres (0: none)")
      ->delimiter(',')
      ->capture_default_str()
      ->check(CLI::Range(0.0, 0.95));
  app.add_option("--cell", cell_mm, "the terrain's cell, millimetres (mixed_scene's terrain: 8.5)")
      ->capture_default_str()
      ->check(CLI::Range(2.0, 100.0));
  app.add_option("--steps", steps, "steps per path")->capture_default_str()->check(CLI::Range(1, 100000));
  app.add_option("--repeat", repeat, "runs per configuration and path (alternating); the median is reported")
      ->capture_default_str()
      ->check(CLI::Range(1, 100));
  app.add_option("--json", json_path, "write the results as JSON");
  CLI11_PARSE(app, argc, argv);

  try {
    asset = load_or_bake(mesh, cache, asset);
    auto loaded = voxfmt::runtime::CollisionObject::load(asset);
    if (!loaded) throw std::runtime_error(loaded.error().describe());
    const auto object = loaded.value();

    const Terrain terrain = make_terrain(cell_mm);
    const int cells = terrain.cells;
    const double cell_m = terrain.cell_m;

    const std::vector<Config> configs = {{"from scratch", false}, {"coherent", true}};

    const std::string load_start = load_average();
    nlohmann::json paths = nlohmann::json::array();
    size_t differing = 0;
    std::cout << "terrain-slide: " << asset << " (" << object->point_tree().size() << " points, voxel "
              << fixed(object->voxelmap().voxel_size() * 1e3, 3) << " mm) on a " << cells << " x " << cells
              << " terrain of " << fixed(cell_m * 1e3, 2) << " mm cells, " << steps << " steps a path, median of "
              << repeat << " alternated runs\n\n"
              << std::left << std::setw(10) << "mm/step" << std::setw(16) << "pair" << std::right << std::setw(28)
              << "pair test mean/p50/p90 us" << std::setw(10) << "speed-up" << std::setw(14) << "points/step"
              << std::setw(14) << "contacts" << std::setw(12) << "differ"
              << "\n";
    for (double speed : speeds_mm) {
      const std::vector<btTransform> poses = circle_path(object, speed * 1e-3, steps);
      paths.push_back(
          {{"speed_mm_per_step", speed},
           {"configurations", compare_on_path(*terrain.shape, object, configs, poses, speed, repeat, differing)}});
    }
    const nlohmann::json sunk = sink(*terrain.shape, object, sunk_mm, repeat * 3);
    const nlohmann::json walls = beside_walls(object, cell_mm, walls_m, repeat * 3);
    if (!json_path.empty()) {
      std::string command = argv[0];
      for (int a = 1; a < argc; ++a) command += std::string(" ") + argv[a];
      const nlohmann::json out = {{"command", command},
                                  {"machine",
                                   {{"usable_cores", voxfmt::usable_cores()},
                                    {"load_average_start", as_number(load_start)},
                                    {"load_average_end", as_number(load_average())}}},
                                  {"asset", asset},
                                  {"points", object->point_tree().size()},
                                  {"steps", steps},
                                  {"repeat", repeat},
                                  {"terrain", {{"cells", cells}, {"cell_m", cell_m}, {"side_m", kTerrainM}}},
                                  {"paths", paths},
                                  {"sunk", sunk},
                                  {"walls", walls}};
      if (const voxfmt::Status written = voxfmt::write_file_atomically(json_path, out.dump(1) + "\n"); !written)
        throw std::runtime_error(written.error().describe());
      std::cout << "wrote " << json_path << "\n";
    }
    if (differing) std::cerr << "terrain-slide: contacts differ from the pair from scratch\n";
    bool inexact = false;
    for (const nlohmann::json& row : walls) inexact |= row["largest_depth_error_mm"].get<double>() > kDepthToleranceMm;
    if (inexact)
      std::cerr << "terrain-slide: beside a wall, a contact is not as deep as its point lies or a point under the "
                   "terrain is no contact\n";
    return differing || inexact ? 1 : 0;
  } catch (const std::exception& e) {
    std::cerr << "terrain-slide: " << e.what() << "\n";
    return 1;
  }
}
