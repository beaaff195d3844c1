// bunny_drop: the DLR seed's Figure 2. The CGAL bunny is dropped onto a table and, in a second scene, onto
// another bunny, at 1 kHz, with each collision method: VPS fine (all points), VPS coarse (~800 points),
// Bullet's GImpact, an HACD convex decomposition (8 hulls of <= 100 vertices) and a 42-vertex hull
// (btShapeHull). Writes a per-step CSV and a summary JSON; scripts/plot_bunny_drop.py draws them (log-scale
// narrow-phase time and speed panels).
#include <BulletCollision/Gimpact/btGImpactCollisionAlgorithm.h>
#include <BulletCollision/Gimpact/btGImpactShape.h>
#include <btBulletDynamicsCommon.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "common/hacd_cache.h"
#include "common/reduced_hull.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"

namespace {

using voxfmt::bullet::VpsMixedShape;
using voxfmt::bullet::World;
namespace fs = std::filesystem;

struct Options {
  std::string asset = "out/bunny00.vox.h5";
  std::string mesh = "build/cgal-data/data/meshes/bunny00.off";
  std::string out_dir = "out/bunny_drop";
  std::string hacd_cache;
  std::string hacd_shipped = BUNNY_DROP_HACD_DATA;  // the repository's decomposition of CGAL's bunny
  double seconds = 2.0;
  double wall_budget = 60.0;  // per run; GImpact bunny-on-bunny can take ~0.1 s a step
  double coarse_points = 800;
  std::vector<std::string> methods = {"vps-fine", "vps-coarse", "gimpact", "hacd", "hull"};
};

/// The bunny in the shape frame shared by every method: principal axes at the centre of mass.
struct BunnyGeometry {
  std::shared_ptr<const voxfmt::runtime::CollisionObject> object;
  std::shared_ptr<VpsMixedShape> frame;  ///< defines the shared frame and the inertia of every method
  std::vector<btVector3> vertices;       // shape frame
  std::vector<btVector3> mesh_vertices;  // the mesh's own frame: HACD's input, so its cache key is the mesh's
  std::vector<int> indices;
};

// ------------------------------------------------------------------------------------------------ the runs

struct StepRecord {
  int step;
  double narrow_us;
  int pairs;
  int contacts;
  double speed;
};

struct RunResult {
  std::string scene, method;
  std::vector<StepRecord> steps;
  bool stopped_early = false;
  double final_height = 0;  // centre of mass y
};

/// One shape per method, built once and shared by the bodies of both scenes.
struct MethodShapes {
  std::shared_ptr<btCollisionShape> dynamic_shape, static_shape;
};

std::shared_ptr<btCollisionShape> hull_shape(const std::vector<btVector3>& points) {
  auto shape = std::make_shared<btConvexHullShape>();
  for (const btVector3& p : points) shape->addPoint(p, false);
  shape->recalcLocalAabb();
  return shape;
}

MethodShapes make_shapes(const std::string& method, const BunnyGeometry& bunny, const Options& options,
                         btTriangleIndexVertexArray& triangles, double& precompute_seconds) {
  MethodShapes shapes;
  precompute_seconds = 0;
  if (method == "vps-fine" || method == "vps-coarse") {
    auto shape = std::make_shared<VpsMixedShape>(bunny.object);
    if (method == "vps-coarse") {
      // Whole tree levels up to ~coarse_points (the seed's coarse shell).
      const voxfmt::runtime::PointTree& tree = bunny.object->point_tree();
      size_t budget = tree.points_up_to_level(0);
      for (size_t l = 0; l < tree.level_count(); ++l)
        if (double(tree.points_up_to_level(l)) <= options.coarse_points * 1.25) budget = tree.points_up_to_level(l);
      shape->set_point_budget(budget);
    }
    shapes.dynamic_shape = shapes.static_shape = shape;
  } else if (method == "gimpact") {
    auto shape = std::make_shared<btGImpactMeshShape>(&triangles);
    shape->updateBound();
    shapes.dynamic_shape = shapes.static_shape = shape;
  } else if (method == "hacd") {
    voxfmt_bench::Hulls hulls = voxfmt_bench::hacd_decomposition(bunny.mesh_vertices, bunny.indices, options.hacd_cache,
                                                                 precompute_seconds, options.hacd_shipped);
    for (auto& hull : hulls)
      for (btVector3& p : hull) p = bunny.frame->asset_to_shape()(p);
    auto compound = std::make_shared<btCompoundShape>();
    static std::vector<std::shared_ptr<btCollisionShape>> children;  // owned for the program's lifetime
    for (const auto& hull : hulls) {
      children.push_back(hull_shape(hull));
      compound->addChildShape(btTransform::getIdentity(), children.back().get());
    }
    shapes.dynamic_shape = shapes.static_shape = compound;
  } else if (method == "hull") {
    const auto start = std::chrono::steady_clock::now();
    const std::vector<btVector3> points = voxfmt_bench::reduced_hull_points(bunny.vertices);
    shapes.dynamic_shape = shapes.static_shape = hull_shape(points);
    precompute_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::cerr << "hull: " << points.size() << " vertices\n";
  } else {
    throw std::invalid_argument("unknown method '" + method + "' (vps-fine, vps-coarse, gimpact, hacd, hull)");
  }
  return shapes;
}

/// Body transform that puts the bunny's asset frame at `offset` (shape frame = principal frame).
btTransform place(const BunnyGeometry& bunny, const btVector3& offset) {
  btTransform t = bunny.frame->asset_to_shape().inverse();
  t.setOrigin(t.getOrigin() + offset);
  return t;
}

RunResult run(const std::string& scene, const std::string& method, const MethodShapes& shapes,
              const BunnyGeometry& bunny, const Options& options) {
  World world;
  btGImpactCollisionAlgorithm::registerAlgorithm(&world.dispatcher());
  world.dynamics().setGravity(btVector3(0, -9.81f, 0));
  const btScalar bottom = btScalar(bunny.object->bounds_min().y());
  const btScalar height = btScalar(bunny.object->bounds_max().y()) - bottom;
  // The table: a static box whose top is at y = 0.
  btTransform table = btTransform::getIdentity();
  table.setOrigin(btVector3(0, -0.05f, 0));
  world.add_body(std::make_shared<btBoxShape>(btVector3(3, 0.05f, 3)), 0, table);
  btScalar drop_base = 0;
  if (scene == "bunny") {
    world.add_body(shapes.static_shape, 0, place(bunny, btVector3(0, -bottom, 0)));
    drop_base = height;
  }
  const btScalar mass = 1;
  // Same mass properties for every method: those of the asset.
  btVector3 inertia;
  bunny.frame->calculateLocalInertia(mass, inertia);
  btRigidBody* body = world.add_body(shapes.dynamic_shape, mass,
                                     place(bunny, btVector3(0.1f, drop_base - bottom + 0.1f, 0.05f)), &inertia);
  body->setFriction(0.6f);

  RunResult result{scene, method, {}, false, 0};
  const int steps = int(std::lround(options.seconds * 1000.0));
  const auto start = std::chrono::steady_clock::now();
  for (int step = 0; step < steps; ++step) {
    world.step(btScalar(1e-3));
    int contacts = 0;
    for (int m = 0; m < world.dispatcher().getNumManifolds(); ++m)
      contacts += world.dispatcher().getManifoldByIndexInternal(m)->getNumContacts();
    const int pairs = world.dynamics().getBroadphase()->getOverlappingPairCache()->getNumOverlappingPairs();
    result.steps.push_back(
        {step, world.dispatcher().last_narrow_phase_us(), pairs, contacts, double(body->getLinearVelocity().length())});
    if (std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() > options.wall_budget) {
      result.stopped_early = true;
      break;
    }
  }
  result.final_height = double(body->getCenterOfMassPosition().y());
  return result;
}

// ------------------------------------------------------------------------------------------------ reporting

struct Figures {
  double p50 = 0, p90 = 0, mean = 0, per_pair_p50 = 0;
  size_t samples = 0;
};

Figures figures(const RunResult& r) {
  std::vector<double> times, per_pair;
  for (const StepRecord& s : r.steps)
    if (s.pairs > 0) {
      times.push_back(s.narrow_us);
      per_pair.push_back(s.narrow_us / s.pairs);
    }
  Figures f;
  f.samples = times.size();
  if (times.empty()) return f;
  auto quantile = [](std::vector<double> v, double q) {
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, size_t(q * double(v.size())))];
  };
  f.p50 = quantile(times, 0.5);
  f.p90 = quantile(times, 0.9);
  f.per_pair_p50 = quantile(per_pair, 0.5);
  for (double t : times) f.mean += t;
  f.mean /= double(times.size());
  return f;
}

std::string json_escape(const std::string& s) {
  std::string out;
  for (char c : s) out += (c == '"' || c == '\\') ? std::string("\\") + c : std::string(1, c);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  Options options;
  CLI::App app{
      "bunny_drop — the seed's Figure 2: drop the CGAL bunny onto a table and onto a bunny with VPS, "
      "GImpact, an HACD decomposition and a convex hull; writes CSV and JSON (scripts/plot_bunny_drop.py draws them)"};
  app.add_option("--asset", options.asset,
                 "baked bunny asset (voxfmt build bunny00.off --resolution 306 --points 35000)")
      ->capture_default_str();
  app.add_option("--mesh", options.mesh, "the bunny mesh, for GImpact, HACD and the hull")->capture_default_str();
  app.add_option("-o,--out", options.out_dir, "output folder for bunny_drop.csv and .json")->capture_default_str();
  app.add_option("--hacd-cache", options.hacd_cache, "HACD decomposition cache (default: OUT/bunny00.hacd.txt)");
  app.add_option("--hacd-shipped", options.hacd_shipped,
                 "a decomposition to use when the cache has none for this mesh and HACD's parameters")
      ->capture_default_str();
  app.add_option("--seconds", options.seconds, "simulated seconds per run (1 kHz steps)")->capture_default_str();
  app.add_option("--wall-budget", options.wall_budget, "wall-clock seconds after which a run stops early")
      ->capture_default_str();
  app.add_option("--methods", options.methods, "subset of vps-fine vps-coarse gimpact hacd hull")
      ->delimiter(',')
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (options.hacd_cache.empty()) options.hacd_cache = options.out_dir + "/bunny00.hacd.txt";

  try {
    fs::create_directories(options.out_dir);
    BunnyGeometry bunny;
    const auto load_start = std::chrono::steady_clock::now();
    auto loaded = voxfmt::runtime::CollisionObject::load(options.asset);
    if (!loaded) {
      std::cerr << "bunny_drop: " << loaded.error().message << "\n";
      return 1;
    }
    bunny.object = loaded.value();
    const double load_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - load_start).count();
    const double runtime_mb = double(bunny.object->memory_bytes()) / 1e6;
    std::cout << "loaded " << options.asset << " in " << std::setprecision(3) << load_seconds << " s: " << runtime_mb
              << " MB in runtime structures (voxelmap " << double(bunny.object->voxelmap().memory_bytes()) / 1e6
              << " MB)\n";
    const voxfmt::Result<voxfmt::bake::TriangleMesh> read = voxfmt::bake::read_mesh(options.mesh);
    if (!read) {
      std::cerr << "bunny_drop: " << read.error().message << "\n";
      return 1;
    }
    const voxfmt::bake::TriangleMesh& mesh = read.value();
    bunny.frame = std::make_shared<VpsMixedShape>(bunny.object);
    for (const voxfmt::Vec3& v : mesh.vertices) {
      bunny.mesh_vertices.emplace_back(btScalar(v[0]), btScalar(v[1]), btScalar(v[2]));
      bunny.vertices.push_back(bunny.frame->asset_to_shape()(bunny.mesh_vertices.back()));
    }
    for (const auto& t : mesh.triangles)
      for (uint32_t i : t) bunny.indices.push_back(int(i));
    btTriangleIndexVertexArray triangles(int(bunny.indices.size() / 3), bunny.indices.data(), 3 * sizeof(int),
                                         int(bunny.vertices.size()), &bunny.vertices[0][0], sizeof(btVector3));

    std::vector<RunResult> results;
    std::map<std::string, double> precompute;
    for (const std::string& method : options.methods) {
      double seconds = 0;
      const MethodShapes shapes = make_shapes(method, bunny, options, triangles, seconds);
      precompute[method] = seconds;
      for (const std::string scene : {"table", "bunny"}) {
        std::cerr << "run: " << scene << " / " << method << "\n";
        results.push_back(run(scene, method, shapes, bunny, options));
      }
    }

    const std::string csv_path = options.out_dir + "/bunny_drop.csv";
    std::ofstream csv(csv_path);
    csv << "scene,method,step,narrow_phase_us,pairs,contacts,linear_speed\n";
    for (const RunResult& r : results)
      for (const StepRecord& s : r.steps)
        csv << r.scene << "," << r.method << "," << s.step << "," << s.narrow_us << "," << s.pairs << "," << s.contacts
            << "," << s.speed << "\n";
    csv.close();

    const std::string json_path = options.out_dir + "/bunny_drop.json";
    std::ofstream json(json_path);
    json << "{\n  \"asset\": \"" << json_escape(options.asset)
         << "\",\n  \"points\": " << bunny.object->point_tree().size() << ",\n  \"load_s\": " << load_seconds
         << ",\n  \"runtime_memory_mb\": " << runtime_mb << ",\n  \"time_step_s\": 0.001,\n  \"runs\": [\n";
    std::cout << std::left << std::setw(7) << "scene" << std::setw(12) << "method" << std::right << std::setw(8)
              << "steps" << std::setw(14) << "p50 us/pair" << std::setw(12) << "p90 us" << std::setw(12) << "mean us"
              << std::setw(14) << "final speed" << std::setw(10) << "early"
              << "\n";
    std::map<std::string, double> p50;
    for (size_t i = 0; i < results.size(); ++i) {
      const RunResult& r = results[i];
      const Figures f = figures(r);
      p50[r.scene + "/" + r.method] = f.per_pair_p50;
      json << "    {\"scene\": \"" << r.scene << "\", \"method\": \"" << r.method << "\", \"steps\": " << r.steps.size()
           << ", \"steps_with_pairs\": " << f.samples << ", \"narrow_phase_us_per_pair_p50\": " << f.per_pair_p50
           << ", \"narrow_phase_us_p50\": " << f.p50 << ", \"narrow_phase_us_p90\": " << f.p90
           << ", \"narrow_phase_us_mean\": " << f.mean
           << ", \"final_linear_speed\": " << (r.steps.empty() ? 0.0 : r.steps.back().speed)
           << ", \"final_center_of_mass_y\": " << r.final_height
           << ", \"stopped_early\": " << (r.stopped_early ? "true" : "false")
           << ", \"precompute_s\": " << precompute[r.method] << "}" << (i + 1 < results.size() ? "," : "") << "\n";
      std::cout << std::left << std::setw(7) << r.scene << std::setw(12) << r.method << std::right << std::setw(8)
                << r.steps.size() << std::setw(14) << std::fixed << std::setprecision(1) << f.per_pair_p50
                << std::setw(12) << f.p90 << std::setw(12) << f.mean << std::setw(14) << std::setprecision(5)
                << (r.steps.empty() ? 0.0 : r.steps.back().speed) << std::setw(10) << (r.stopped_early ? "yes" : "")
                << "\n";
    }
    json << "  ],\n  \"speedups\": {";
    bool first = true;
    for (const std::string scene : {"table", "bunny"})
      for (const auto& [slow, fast] :
           {std::pair{"gimpact", "vps-fine"}, std::pair{"hacd", "vps-coarse"}, std::pair{"hacd", "vps-fine"}}) {
        const std::string a = scene + "/" + slow, b = scene + "/" + fast;
        if (!p50.count(a) || !p50.count(b) || p50[b] <= 0) continue;
        json << (first ? "" : ",") << "\n    \"" << scene << ": " << slow << " / " << fast << "\": " << p50[a] / p50[b];
        std::cout << scene << ": " << slow << " p50 / " << fast << " p50 = " << std::setprecision(1) << p50[a] / p50[b]
                  << "x\n";
        first = false;
      }
    json << "\n  }\n}\n";
    json.close();
    std::cout << "wrote " << csv_path << " and " << json_path << "\n";

  } catch (const std::exception& e) {
    std::cerr << "bunny_drop: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
