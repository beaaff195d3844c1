// vps-sim: every collision method simulating the same scenes from the same initial states at 1 kHz in Bullet —
// a drop, a bunny on a bunny, a pile in a bin, stacks, a chain of tori and a peg in a hole — with what a
// physics user asks of each: does it come to rest, does it gain energy, how deep do bodies sink, does anything
// escape, what does a step cost. A table, JSON (--json), a per-step CSV and PNG plots of speed and energy.
#include <BulletCollision/Gimpact/btGImpactCollisionAlgorithm.h>
#include <BulletCollision/Gimpact/btGImpactShape.h>
#include <btBulletDynamicsCommon.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>

#include "common/hacd_cache.h"
#include "common/reduced_hull.h"
#include "scenes.h"
#include "traversal/function_query.h"
#include "voxfmt/bullet/collision.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"
#include "voxfmt/detail/atomic_file.h"

namespace vps_sim {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using voxfmt::bullet::VpsMixedShape;

constexpr double kDt = 1e-3;
constexpr double kGravity = 9.81;
constexpr double kRestSpeed = 1e-4;  // m/s: at rest below this

const std::vector<std::string>& method_names() {
  static const std::vector<std::string> names = {"vps-fine", "vps-coarse", "vps-budget", "hacd", "hull", "gimpact"};
  return names;
}

struct Options {
  std::vector<std::string> scenarios = scene_names();
  std::vector<std::string> methods = method_names();
  std::string json;
  std::string out_dir = "out/vps-sim";
  std::string cache_dir;  // default: OUT/cache
  std::string meshes_dir = VOXFMT_SAMPLE_MESHES;
  size_t bodies = 50;
  bool quick = false;
  double wall_budget = 120.0;  // seconds per run before a slow method stops
  double budget_fraction = 0.5;
  double budget_us = 0.0;
  double coarse_points = 800;
  bool cached_decompositions_only = false;
  bool plots = true;
  std::string cut_level;   // empty: CollisionSettings' default
  bool refine_cut = true;  // CollisionSettings' default: refine_cut_contacts
};

// ------------------------------------------------------------------------------------------------ methods

/// The collision shapes of one method, one per geometry, shared by every body of that geometry.
class ShapeFactory {
 public:
  ShapeFactory(std::string method, const Options& options, double margin)
      : method_(std::move(method)), options_(options), margin_(btScalar(margin)) {}

  bool is_vps() const { return method_.rfind("vps-", 0) == 0; }

  /// The shape for a geometry, or null when the method cannot run (no cached decomposition in a quick run).
  std::shared_ptr<btCollisionShape> shape(const Geometry& g, bool dynamic) {
    auto& entry = shapes_[&g];
    auto& slot = dynamic ? entry.first : entry.second;
    if (!slot) slot = make(g, dynamic);
    return slot;
  }
  std::shared_ptr<btCollisionShape> box(const btVector3& half) {
    auto shape = std::make_shared<btBoxShape>(half);
    shape->setMargin(std::min(margin_, half.minAxis() > 0 ? half[half.minAxis()] / 2 : margin_));
    return shape;
  }
  double precompute_s = 0;

 private:
  std::shared_ptr<btCollisionShape> make(const Geometry& g, bool dynamic) {
    if (is_vps()) {
      auto shape = std::make_shared<VpsMixedShape>(g.object);
      if (method_ == "vps-coarse") {
        // The seed's coarse shell: the tree levels that hold about coarse_points points together.
        const voxfmt::runtime::PointTree& tree = g.object->point_tree();
        uint32_t level = 0;
        while (level + 1 < tree.level_count() &&
               double(tree.points_up_to_level(level + 1)) <= options_.coarse_points * 1.25)
          ++level;
        shape->set_max_level(level);
      }
      return shape;
    }
    if (method_ == "hull") {
      auto hull = std::make_shared<btConvexHullShape>();
      for (const btVector3& p : voxfmt_bench::reduced_hull_points(g.vertices)) hull->addPoint(p, false);
      hull->recalcLocalAabb();
      hull->setMargin(margin_);
      return hull;
    }
    if (method_ == "hacd") {
      if ((options_.quick || options_.cached_decompositions_only) && !fs::exists(g.hacd_cache)) return nullptr;
      double seconds = 0;
      const voxfmt_bench::Hulls hulls =
          voxfmt_bench::hacd_decomposition(g.hacd_vertices, g.hacd_indices, g.hacd_cache, seconds);
      precompute_s += seconds;
      auto compound = std::make_shared<btCompoundShape>();
      for (const auto& points : hulls) {
        auto hull = std::make_shared<btConvexHullShape>();
        for (const btVector3& p : points) hull->addPoint(p, false);
        hull->recalcLocalAabb();
        hull->setMargin(margin_);
        compound->addChildShape(btTransform::getIdentity(), hull.get());
        children_.push_back(hull);
      }
      return compound;
    }
    if (method_ == "gimpact") {
      // Bullet reads the triangles through these pointers: the geometry outlives the factory.
      auto& mesh = meshes_.emplace_back(std::make_unique<btTriangleIndexVertexArray>(
          int(g.indices.size() / 3), const_cast<int*>(g.indices.data()), int(3 * sizeof(int)), int(g.vertices.size()),
          const_cast<btScalar*>(&g.vertices[0][0]), int(sizeof(btVector3))));
      auto shape = std::make_shared<btGImpactMeshShape>(mesh.get());
      shape->setMargin(margin_);
      shape->updateBound();
      (void)dynamic;
      return shape;
    }
    throw std::invalid_argument("unknown method '" + method_ + "'");
  }

  std::string method_;
  const Options& options_;
  btScalar margin_;
  std::map<const Geometry*, std::pair<std::shared_ptr<btCollisionShape>, std::shared_ptr<btCollisionShape>>> shapes_;
  std::vector<std::shared_ptr<btCollisionShape>> children_;
  std::vector<std::unique_ptr<btTriangleIndexVertexArray>> meshes_;
};

// ------------------------------------------------------------------------------------------------ the runs

struct Sample {
  float t, speed, energy;
};

struct RunResult {
  std::string scene, method;
  bool skipped = false;
  std::string note;
  double simulated_s = 0;
  bool stopped_early = false;
  double first_contact_s = NAN;
  double rest_time_s = NAN;  // NaN: not at rest at the end
  double residual_speed = 0;
  double energy_gain_rel = 0;
  double max_penetration_mm = 0, max_penetration_voxels = 0;
  int escaped = 0;
  double step_ms_p50 = 0, step_ms_p99 = 0, narrow_ms_p50 = 0, narrow_contact_us_p99 = 0;
  double budget_us = 0, cut_fraction = 0;
  double precompute_s = 0;
  nlohmann::json outcome = nlohmann::json::object();
  std::vector<Sample> series;
};

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(q * double(v.size())))];
}

/// The deepest penetration between the scene's bodies as the fine assets see it, whatever method moved them:
/// each geometry's points in the other's voxelmap (both ways), and its points against the boxes. Millimetres
/// and voxels of the voxelmap (or the point's own asset, against a box).
class PenetrationProbe {
 public:
  PenetrationProbe(const Scene& scene) : scene_(scene) {
    for (const BodySpec& b : scene.bodies)
      if (b.geometry && !frames_.count(b.geometry.get()))
        frames_[b.geometry.get()] = std::make_shared<VpsMixedShape>(b.geometry->object);
  }

  void measure(const std::vector<btRigidBody*>& bodies, double& mm, double& voxels) {
    for (size_t i = 0; i < bodies.size(); ++i)
      for (size_t j = i + 1; j < bodies.size(); ++j) {
        const BodySpec &a = scene_.bodies[i], &b = scene_.bodies[j];
        if (!a.dynamic && !b.dynamic) continue;
        if (!a.geometry && !b.geometry) continue;
        if (a.geometry && b.geometry)
          geometry_pair(a, *bodies[i], b, *bodies[j], mm, voxels);
        else if (a.geometry)
          against_box(a, *bodies[i], b, *bodies[j], mm, voxels);
        else
          against_box(b, *bodies[j], a, *bodies[i], mm, voxels);
      }
  }

 private:
  void geometry_pair(const BodySpec& a, const btRigidBody& ba, const BodySpec& b, const btRigidBody& bb, double& mm,
                     double& voxels) {
    const double reach = a.geometry->radius() + b.geometry->radius();
    if ((ba.getCenterOfMassPosition() - bb.getCenterOfMassPosition()).length() > reach) return;
    const VpsMixedShape &sa = *frames_[a.geometry.get()], &sb = *frames_[b.geometry.get()];
    voxfmt::runtime::QueryOptions options;
    options.direction = voxfmt::runtime::QueryDirection::Both;
    contacts_.clear();
    voxfmt::runtime::query_contacts(sa.object(), sa.asset_pose(ba.getWorldTransform()), sb.object(),
                                    sb.asset_pose(bb.getWorldTransform()), options, contacts_, scratch_);
    for (const auto& c : contacts_.contacts) {
      const double voxel = (c.point_of_b ? sa : sb).object().voxelmap().voxel_size();
      mm = std::max(mm, c.depth * 1e3);
      voxels = std::max(voxels, c.depth / voxel);
    }
  }
  void against_box(const BodySpec& a, const btRigidBody& ba, const BodySpec& box, const btRigidBody& bb, double& mm,
                   double& voxels) {
    const btTransform& t = bb.getWorldTransform();
    const btVector3 local = t.invXform(ba.getCenterOfMassPosition());
    btVector3 outside(0, 0, 0);
    for (int k = 0; k < 3; ++k) outside[k] = std::max(btScalar(0), std::fabs(local[k]) - box.box_half[k]);
    if (double(outside.length()) > a.geometry->radius()) return;
    const VpsMixedShape& sa = *frames_[a.geometry.get()];
    Eigen::Matrix3f rotation;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) rotation(r, c) = float(t.getBasis()[r][c]);
    const Eigen::Vector3f centre(float(t.getOrigin().x()), float(t.getOrigin().y()), float(t.getOrigin().z()));
    const Eigen::Vector3f half(float(box.box_half.x()), float(box.box_half.y()), float(box.box_half.z()));
    voxfmt::runtime::QueryOptions options;
    contacts_.clear();
    voxfmt::runtime::query_against_function(
        sa.object(), sa.asset_pose(ba.getWorldTransform()),
        [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
          return voxfmt::bullet::box_distance(rotation, centre, half, x, outward);
        },
        options, contacts_, scratch_);
    const double voxel = sa.object().voxelmap().voxel_size();
    for (const auto& c : contacts_.contacts) {
      mm = std::max(mm, c.depth * 1e3);
      voxels = std::max(voxels, c.depth / voxel);
    }
  }

  const Scene& scene_;
  std::map<const Geometry*, std::shared_ptr<VpsMixedShape>> frames_;
  voxfmt::runtime::ContactSet contacts_;
  voxfmt::runtime::QueryScratch scratch_;
};

RunResult run(const Scene& scene, const std::string& method, const Options& options, double budget_us) {
  RunResult result;
  result.scene = scene.name;
  result.method = method;
  ShapeFactory factory(method, options, scene.margin);

  voxfmt::bullet::CollisionSettings settings;
  if (method == "vps-budget") settings.step_time_budget_us = budget_us;

  if (options.cut_level == "points") settings.query.cut_level = voxfmt::runtime::CutLevel::Points;
  if (options.cut_level == "spheres") settings.query.cut_level = voxfmt::runtime::CutLevel::Spheres;
  settings.query.refine_cut_contacts = options.refine_cut;
  voxfmt::bullet::World world(settings, factory.is_vps());
  btGImpactCollisionAlgorithm::registerAlgorithm(&world.dispatcher());
  world.dynamics().setGravity(btVector3(0, btScalar(-kGravity), 0));

  std::vector<btRigidBody*> bodies;
  for (const BodySpec& spec : scene.bodies) {
    std::shared_ptr<btCollisionShape> shape =
        spec.geometry ? factory.shape(*spec.geometry, spec.dynamic) : factory.box(spec.box_half);
    if (!shape) {
      result.skipped = true;
      result.note = "no cached HACD decomposition (a quick run never computes one)";
      return result;
    }
    const double mass = spec.dynamic ? spec.geometry->mass() : 0.0;
    const btVector3 inertia = spec.dynamic ? spec.geometry->inertia() : btVector3(0, 0, 0);
    btRigidBody* body = world.add_body(shape, btScalar(mass), spec.transform, &inertia);
    body->setFriction(btScalar(spec.friction));
    if (spec.dynamic) body->setActivationState(DISABLE_DEACTIVATION);  // no sleeping: rest is measured, not declared
    bodies.push_back(body);
  }
  result.precompute_s = factory.precompute_s;

  // Kinetic and potential energy of the dynamic bodies, the constant forces' potential included.
  auto energy = [&] {
    double e = 0;
    for (size_t i = 0; i < bodies.size(); ++i) {
      if (!scene.bodies[i].dynamic) continue;
      const btRigidBody& b = *bodies[i];
      const double m = 1.0 / double(b.getInvMass());
      const btVector3 w = b.getWorldTransform().getBasis().transpose() * b.getAngularVelocity();
      const btVector3 inertia = b.getLocalInertia();
      e += 0.5 * m * double(b.getLinearVelocity().length2()) +
           0.5 * double(inertia.x() * w.x() * w.x() + inertia.y() * w.y() * w.y() + inertia.z() * w.z() * w.z()) +
           m * kGravity * double(b.getCenterOfMassPosition().y()) -
           double(scene.bodies[i].force.dot(b.getCenterOfMassPosition()));
    }
    return e;
  };
  // The fastest point of any body, from its motion over the last kWindow steps: the largest displacement of
  // its bounding box's corners, over the window's time. From positions, not from Bullet's velocities, which at
  // rest hold the solver's residual against gravity that split impulses cancel in the positions; over a window,
  // because single-precision poses move by rounding steps of ~1e-7 m.
  constexpr int kWindow = 10;
  std::vector<std::array<btVector3, 8>> corners(bodies.size());
  for (size_t i = 0; i < bodies.size(); ++i) {
    if (!scene.bodies[i].dynamic) continue;
    btVector3 lo, hi;
    bodies[i]->getCollisionShape()->getAabb(btTransform::getIdentity(), lo, hi);
    if (scene.bodies[i].geometry) {  // the same box for every method: the mesh's, not the shape's with margins
      lo = hi = scene.bodies[i].geometry->vertices.front();
      for (const btVector3& v : scene.bodies[i].geometry->vertices) {
        lo.setMin(v);
        hi.setMax(v);
      }
    }
    for (int k = 0; k < 8; ++k)
      corners[i][size_t(k)] =
          btVector3((k & 1) ? hi.x() : lo.x(), (k & 2) ? hi.y() : lo.y(), (k & 4) ? hi.z() : lo.z());
  }
  std::vector<std::array<btTransform, kWindow>> history(bodies.size());
  for (size_t i = 0; i < bodies.size(); ++i) history[i].fill(bodies[i]->getWorldTransform());
  auto fastest = [&](int step) {
    double speed = 0;
    const size_t slot = size_t(step % kWindow);
    for (size_t i = 0; i < bodies.size(); ++i) {
      if (!scene.bodies[i].dynamic) continue;
      const btTransform& now = bodies[i]->getWorldTransform();
      const btTransform& then = history[i][slot];
      for (const btVector3& c : corners[i]) speed = std::max(speed, double((now(c) - then(c)).length()));
      history[i][slot] = now;
    }
    return speed / (kWindow * kDt);
  };
  PenetrationProbe probe(scene);
  const int steps = int(std::lround(scene.seconds / kDt));
  const int probe_every = scene.bodies.size() > 20 ? 20 : 10;
  std::vector<double> step_ms, narrow_ms, narrow_contact_us;
  const double start_energy = energy();
  double lowest_energy = start_energy, min_since_contact = INFINITY, gain = 0;
  int last_moving = -1;
  double speed = 0;
  std::vector<double> final_speeds;
  uint64_t pair_tests_before = 0;
  const auto wall_start = Clock::now();
  int step = 0;
  for (; step < steps; ++step) {
    for (size_t i = 0; i < bodies.size(); ++i)
      if (!scene.bodies[i].force.isZero()) bodies[i]->applyCentralForce(scene.bodies[i].force);
    const auto t0 = Clock::now();
    world.step(btScalar(kDt));
    step_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    const double narrow_us = world.dispatcher().last_narrow_phase_us();
    narrow_ms.push_back(narrow_us * 1e-3);

    bool touching = false;
    for (int m = 0; m < world.dispatcher().getNumManifolds() && !touching; ++m)
      touching = world.dispatcher().getManifoldByIndexInternal(m)->getNumContacts() > 0;
    if (touching && std::isnan(result.first_contact_s)) result.first_contact_s = (step + 1) * kDt;
    if (!std::isnan(result.first_contact_s)) narrow_contact_us.push_back(narrow_us);

    const double e = energy();
    speed = fastest(step);
    if (!std::isfinite(e)) {
      result.note = "the simulation blew up (non-finite state)";
      break;
    }
    lowest_energy = std::min(lowest_energy, e);
    if (!std::isnan(result.first_contact_s)) {
      min_since_contact = std::min(min_since_contact, e);
      gain = std::max(gain, e - min_since_contact);
      if ((step + 1) % probe_every == 0)
        probe.measure(bodies, result.max_penetration_mm, result.max_penetration_voxels);
    }
    if (speed >= kRestSpeed) last_moving = step;
    if (step >= steps - 100) final_speeds.push_back(speed);
    if (step % 10 == 0) result.series.push_back({float((step + 1) * kDt), float(speed), float(e)});
    if (std::chrono::duration<double>(Clock::now() - wall_start).count() > options.wall_budget) {
      result.stopped_early = true;
      result.note = "stopped at the wall-clock budget (" + std::to_string(int(options.wall_budget)) + " s)";
      ++step;
      break;
    }
  }
  (void)pair_tests_before;
  result.simulated_s = step * kDt;
  probe.measure(bodies, result.max_penetration_mm, result.max_penetration_voxels);
  const double released = start_energy - lowest_energy;
  result.energy_gain_rel = released > 0 ? gain / released : 0.0;
  // At rest: the fastest point slower than kRestSpeed from then on, for at least the last 100 steps.
  if (!result.stopped_early && step == steps && last_moving < steps - 100) result.rest_time_s = (last_moving + 1) * kDt;
  double sum = 0;
  for (double s : final_speeds) sum += s;
  result.residual_speed = final_speeds.empty() ? speed : sum / double(final_speeds.size());
  for (size_t i = 0; i < bodies.size(); ++i) {
    if (!scene.bodies[i].dynamic) continue;
    const btVector3 p = bodies[i]->getCenterOfMassPosition();
    bool inside = true;
    for (int k = 0; k < 3; ++k) inside &= p[k] >= scene.keep_lo[k] && p[k] <= scene.keep_hi[k];
    result.escaped += !inside;
  }
  result.step_ms_p50 = quantile(step_ms, 0.5);
  result.step_ms_p99 = quantile(step_ms, 0.99);
  result.narrow_ms_p50 = quantile(narrow_ms, 0.5);
  result.narrow_contact_us_p99 = quantile(narrow_contact_us, 0.99);
  if (method == "vps-budget") {
    result.budget_us = budget_us;
    const auto& counters = world.vps()->counters();
    result.cut_fraction = counters.pair_tests > 0 ? double(counters.budget_cuts) / double(counters.pair_tests) : 0.0;
  }
  if (scene.peg >= 0) {
    const btVector3 tip = bodies[size_t(scene.peg)]->getWorldTransform() * scene.peg_tip;
    const double inserted_mm = (scene.hole_top_y - double(tip.y())) * 1e3;
    const bool in_hole = std::hypot(double(tip.x()), double(tip.z())) < 0.005 && result.escaped == 0;
    result.outcome["inserted_mm"] = in_hole ? inserted_mm : 0.0;
    result.outcome["in_hole"] = in_hole;
    // At the hole's bottom, within half a millimetre.
    result.outcome["inserted"] = in_hole && std::fabs(inserted_mm - scene.hole_depth * 1e3) <= 0.5;
  }
  if (scene.upper >= 0) {
    const double y = double(bodies[size_t(scene.upper)]->getCenterOfMassPosition().y());
    result.outcome["upper_centre_of_mass_y_m"] = y;
    result.outcome["on_bunny"] = y > scene.on_top_y;
  }
  if (!scene.chain.empty()) {
    double longest = 0;
    for (size_t k = 0; k + 1 < scene.chain.size(); ++k)
      longest = std::max(longest, double((bodies[size_t(scene.chain[k])]->getCenterOfMassPosition() -
                                          bodies[size_t(scene.chain[k + 1])]->getCenterOfMassPosition())
                                             .length()));
    result.outcome["longest_link_mm"] = longest * 1e3;
    // Two rings can be no farther apart than their tubes touching through each other's holes.
    result.outcome["linked"] = longest <= scene.chain_link_reach + 0.002;
  }
  return result;
}

// ------------------------------------------------------------------------------------------------ reporting

nlohmann::json number_or_null(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

nlohmann::json to_json(const RunResult& r) {
  nlohmann::json j;
  j["scenario"] = r.scene;
  j["method"] = r.method;
  j["skipped"] = r.skipped;
  if (!r.note.empty()) j["note"] = r.note;
  if (r.skipped) return j;
  j["simulated_s"] = r.simulated_s;
  j["stopped_early"] = r.stopped_early;
  j["first_contact_s"] = number_or_null(r.first_contact_s);
  j["rest_time_s"] = number_or_null(r.rest_time_s);
  j["residual_speed_mps"] = r.residual_speed;
  j["energy_gain_rel"] = r.energy_gain_rel;
  j["max_penetration_mm"] = r.max_penetration_mm;
  j["max_penetration_voxels"] = r.max_penetration_voxels;
  j["escaped"] = r.escaped;
  j["step_ms_p50"] = r.step_ms_p50;
  j["step_ms_p99"] = r.step_ms_p99;
  j["narrow_phase_ms_p50"] = r.narrow_ms_p50;
  j["narrow_phase_in_contact_us_p99"] = r.narrow_contact_us_p99;
  j["precompute_s"] = r.precompute_s;
  if (r.method == "vps-budget") {
    j["step_budget_us"] = r.budget_us;
    j["budget_cut_fraction"] = r.cut_fraction;
  }
  j["outcome"] = r.outcome;
  return j;
}

std::string fixed(double v, int digits) {
  if (!std::isfinite(v)) return "–";
  std::ostringstream s;
  s << std::fixed << std::setprecision(digits) << v;
  return s.str();
}

std::string scientific(double v) {
  std::ostringstream s;
  s << std::scientific << std::setprecision(1) << v;
  return s.str();
}

std::string outcome_text(const RunResult& r) {
  std::string text;
  if (r.outcome.contains("inserted_mm"))
    text = !r.outcome["in_hole"].get<bool>() ? "not in the hole" + std::string(r.escaped ? " (fell through)" : "")
                                             : fixed(r.outcome["inserted_mm"].get<double>(), 1) + " mm in, " +
                                                   (r.outcome["inserted"].get<bool>() ? "inserted" : "jammed");
  if (r.outcome.contains("on_bunny")) text = r.outcome["on_bunny"].get<bool>() ? "on the bunny" : "fell off the bunny";
  if (r.outcome.contains("linked")) text = r.outcome["linked"].get<bool>() ? "linked" : "came apart";
  if (!r.note.empty()) text += (text.empty() ? "" : "; ") + r.note;
  return text;
}

void print_table(const std::vector<RunResult>& results) {
  std::cout << "\n| scenario | method | rest s | residual m/s | energy gain | max pen mm | pen voxels | escaped | "
               "step ms p50 | p99 | narrow ms p50 | outcome |\n|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|---|\n";
  for (const RunResult& r : results) {
    if (r.skipped) {
      std::cout << "| " << r.scene << " | " << r.method << " | skipped: " << r.note << " |||||||||\n";
      continue;
    }
    std::cout << "| " << r.scene << " | " << r.method << " | " << fixed(r.rest_time_s, 2) << " | "
              << scientific(r.residual_speed) << " | " << fixed(r.energy_gain_rel, 4) << " | "
              << fixed(r.max_penetration_mm, 3) << " | " << fixed(r.max_penetration_voxels, 2) << " | " << r.escaped
              << " | " << fixed(r.step_ms_p50, 3) << " | " << fixed(r.step_ms_p99, 3) << " | "
              << fixed(r.narrow_ms_p50, 3) << " | " << outcome_text(r) << " |\n";
  }
}

void write_series(const std::string& path, const std::vector<RunResult>& results) {
  std::ostringstream csv;
  csv << "scenario,method,t,speed,energy\n";
  for (const RunResult& r : results)
    for (const Sample& s : r.series)
      csv << r.scene << "," << r.method << "," << s.t << "," << s.speed << "," << s.energy << "\n";
  const auto written = voxfmt::write_file_atomically(path, csv.str());
  if (!written) throw std::runtime_error(written.error().describe());
}

}  // namespace
}  // namespace vps_sim

int main(int argc, char** argv) {
  using namespace vps_sim;
  Options options;
  CLI::App app{
      "vps-sim — every collision method simulating the same scenes from the same initial states at 1 kHz in "
      "Bullet (drop, bunny-on-bunny, pile, stack, chain, peg-in-hole): rest, energy, penetration, escapes, step "
      "time; a table, JSON, a per-step CSV and PNG plots"};
  app.add_option("--scenario", options.scenarios, "scenarios to run (default: all)")->delimiter(',');
  app.add_option("--method", options.methods, "methods to run (default: all)")->delimiter(',');
  app.add_option("--json", options.json, "write the figures as JSON to this file");
  app.add_option("-o,--out", options.out_dir, "folder for the CSV, the plots and (by default) the cache")
      ->capture_default_str();
  app.add_option("--cache", options.cache_dir,
                 "baked assets, generated meshes, HACD decompositions (default: OUT/cache)");
  app.add_option("--meshes", options.meshes_dir, "CGAL's sample meshes")->capture_default_str();
  app.add_option("--bodies", options.bodies, "bodies in the pile")->capture_default_str();
  app.add_flag("--quick", options.quick,
               "a short run for CI: drop, pile of 12, chain and the 0.5 mm peg for 1.5 s each, no GImpact, HACD "
               "only where cached");
  app.add_option("--wall-budget", options.wall_budget, "wall-clock seconds per run before a slow method stops")
      ->capture_default_str();
  app.add_option("--budget-fraction", options.budget_fraction,
                 "vps-budget: the step budget as a fraction of vps-fine's narrow phase in contact (p99)")
      ->capture_default_str();
  app.add_option("--budget-us", options.budget_us, "vps-budget: a fixed step budget in microseconds instead");
  app.add_flag("--cached-decompositions-only", options.cached_decompositions_only,
               "run hacd only where a decomposition is cached (never spend minutes computing one)");
  app.add_flag("!--no-plots", options.plots, "skip the PNG plots");
  app.add_option("--cut-level", options.cut_level,
                 "what a cut shell's last level reports in vps-coarse and vps-budget (default: the library's)")
      ->check(CLI::IsMember({"points", "spheres"}));
  app.add_flag("!--no-refine-cut", options.refine_cut,
               "vps-coarse and vps-budget: do not walk on below the cut where the shell touches "
               "(query.refine_cut_contacts off, as before 0.4.0)");
  app.footer(
      "\nExamples:\n"
      "  vps-sim --quick --json out/vps-sim/quick.json\n"
      "  vps-sim --scenario pile --bodies 50 --method vps-fine,hacd,hull\n"
      "  vps-sim --json bench/results/vps-sim-polyglot-2core.json");
  CLI11_PARSE(app, argc, argv);
  if (options.cache_dir.empty()) options.cache_dir = (fs::path(options.out_dir) / "cache").string();
  if (options.quick) {
    if (app.count("--bodies") == 0) options.bodies = 12;
    if (app.count("--method") == 0) options.methods = {"vps-fine", "vps-coarse", "vps-budget", "hacd", "hull"};
    if (app.count("--scenario") == 0) options.scenarios = {"drop", "pile", "chain", "peg-in-hole-0.5mm"};
    if (app.count("--wall-budget") == 0) options.wall_budget = 60;
  }
  for (const auto& m : options.methods)
    if (std::find(method_names().begin(), method_names().end(), m) == method_names().end()) {
      std::cerr << "vps-sim: unknown method '" << m << "' (vps-fine vps-coarse vps-budget hacd hull gimpact)\n";
      return 2;
    }
  // vps-budget's budget comes from vps-fine's cost in the same scene: run vps-fine first.
  std::stable_sort(options.methods.begin(), options.methods.end(),
                   [](const std::string& a, const std::string& b) { return a == "vps-fine" && b != "vps-fine"; });

  try {
    fs::create_directories(options.out_dir);
    SceneSettings scene_settings;
    scene_settings.cache_dir = options.cache_dir;
    scene_settings.meshes_dir = options.meshes_dir;
    scene_settings.pile_bodies = options.bodies;
    scene_settings.quick = options.quick;
    std::vector<RunResult> results;
    for (const std::string& name : options.scenarios) {
      Scene scene = make_scene(name, scene_settings);
      if (options.quick) scene.seconds = std::min(scene.seconds, 1.5);
      std::cerr << "scenario " << scene.name << ": " << scene.description << " (" << scene.seconds << " s)\n";
      double fine_contact_us = 0;
      for (const std::string& method : options.methods) {
        double budget_us = options.budget_us;
        if (method == "vps-budget" && budget_us <= 0)
          budget_us = fine_contact_us > 0 ? options.budget_fraction * fine_contact_us : 20.0;
        std::cerr << "  " << method << "..." << std::flush;
        const auto start = Clock::now();
        RunResult r = run(scene, method, options, budget_us);
        std::cerr << " " << fixed(std::chrono::duration<double>(Clock::now() - start).count(), 1) << " s"
                  << (r.skipped ? " (skipped)" : "") << "\n";
        if (method == "vps-fine") fine_contact_us = r.narrow_contact_us_p99;
        results.push_back(std::move(r));
      }
    }
    print_table(results);

    const std::string csv = (fs::path(options.out_dir) / "vps-sim-series.csv").string();
    write_series(csv, results);
    std::cout << "\nper-step speed and energy: " << csv << "\n";
    if (options.json.size()) {
      nlohmann::json doc;
      doc["time_step_s"] = kDt;
      doc["rest_speed_mps"] = kRestSpeed;
      doc["quick"] = options.quick;
      doc["pile_bodies"] = options.bodies;
      doc["cut_level"] = options.cut_level.empty() ? "points" : options.cut_level;
      doc["refine_cut_contacts"] = options.refine_cut;
      doc["runs"] = nlohmann::json::array();
      for (const RunResult& r : results) doc["runs"].push_back(to_json(r));
      const auto written = voxfmt::write_file_atomically(options.json, doc.dump(2) + "\n");
      if (!written) throw std::runtime_error(written.error().describe());
      std::cout << "wrote " << options.json << "\n";
    }
    std::cout << std::flush;  // the plot script's line comes after the table
    if (options.plots) {
      const std::string command =
          "'" VPS_SIM_PYTHON "' '" VPS_SIM_PLOT_SCRIPT "' '" + csv + "' '" + options.out_dir + "'";
      if (std::system(command.c_str()) != 0)
        std::cerr << "vps-sim: the plots were not drawn (python3 with matplotlib needed: " << command << ")\n";
    }
  } catch (const std::exception& e) {
    std::cerr << "vps-sim: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
