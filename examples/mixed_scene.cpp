// mixed_scene: VPS bodies against every kind of Bullet partner in one world. A row of stations, one per partner
// kind (ground plane, box, sphere, capsule rails, cylinder, cone, convex hull, compound, triangle-mesh floor,
// terrain, a thin VPS shelf), each with a 0.15 m VPS bunny dropped on it, plus a dynamic capsule, hull and compound
// dropped on a static VPS bunny; the scene settles for 5 s at 1 kHz. Writes a picture of the final scene (front
// view of the point shells and the partners' outlines) and, with --json, per partner kind: contacts per step,
// deepest penetration, residual speed, narrow-phase time per pair and where the station's bunny ended.
// --drop-offset moves every drop and --friction-anchors turns on Bullet's friction anchors on the bunnies:
// bench/rest_grid.py runs the scene over a grid of drops to judge a setting by more than one landing.
#include <BulletCollision/CollisionShapes/btHeightfieldTerrainShape.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>

#include "voxfmt/bake/bake.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"
#include "voxfmt/exports/exports.h"

namespace {

namespace fs = std::filesystem;
using voxfmt::bullet::VpsShape;
using Clock = std::chrono::steady_clock;

constexpr double kDt = 1e-3;
constexpr double kStation = 0.4;  // metres between stations along x

const std::vector<std::string> kKinds = {"vps",  "plane",       "box",      "sphere",      "capsule",    "cylinder",
                                         "cone", "convex-hull", "compound", "static-mesh", "heightfield"};

/// The partner kind of a shape, as the JSON names it.
std::string kind_of(const btCollisionShape* shape) {
  switch (shape->getShapeType()) {
    case VpsShape::kShapeType:
      return "vps";
    case STATIC_PLANE_PROXYTYPE:
      return "plane";
    case BOX_SHAPE_PROXYTYPE:
      return "box";
    case SPHERE_SHAPE_PROXYTYPE:
      return "sphere";
    case CAPSULE_SHAPE_PROXYTYPE:
      return "capsule";
    case CYLINDER_SHAPE_PROXYTYPE:
      return "cylinder";
    case CONE_SHAPE_PROXYTYPE:
      return "cone";
    case CONVEX_HULL_SHAPE_PROXYTYPE:
      return "convex-hull";
    case COMPOUND_SHAPE_PROXYTYPE:
      return "compound";
    case TRIANGLE_MESH_SHAPE_PROXYTYPE:
      return "static-mesh";
    case TERRAIN_SHAPE_PROXYTYPE:
      return "heightfield";
    default:
      return shape->getName();
  }
}

struct KindStats {
  std::vector<double> narrow_us;  // per step: time on this kind's pairs
  double contacts = 0;
  size_t pair_steps = 0;
  double max_penetration = 0;  // metres, over the last second
  const btRigidBody* subject = nullptr;
  btVector3 subject_before;
};

std::map<std::string, double> g_step_us;  // this step's narrow-phase time per partner kind

// Times each pair with a VPS body and files it under the partner's kind (VPS-VPS pairs under "vps").
void timed_near_callback(btBroadphasePair& pair, btCollisionDispatcher& dispatcher, const btDispatcherInfo& info) {
  const auto* a = static_cast<const btCollisionObject*>(pair.m_pProxy0->m_clientObject);
  const auto* b = static_cast<const btCollisionObject*>(pair.m_pProxy1->m_clientObject);
  const bool a_vps = a->getCollisionShape()->getShapeType() == VpsShape::kShapeType;
  const bool b_vps = b->getCollisionShape()->getShapeType() == VpsShape::kShapeType;
  const auto start = Clock::now();
  btCollisionDispatcher::defaultNearCallback(pair, dispatcher, info);
  if (!a_vps && !b_vps) return;
  const std::string kind = a_vps && b_vps ? "vps" : kind_of((a_vps ? b : a)->getCollisionShape());
  g_step_us[kind] += std::chrono::duration<double, std::micro>(Clock::now() - start).count();
}

std::string baked(const std::string& mesh, const std::string& out, voxfmt::bake::Settings settings) {
  if (voxfmt::bake::asset_is_current(out, mesh, settings)) return out;  // else another --mesh or settings: again
  std::cerr << "bake: " << mesh << " -> " << out << "\n";
  settings.threads = 0;
  const auto summary = voxfmt::bake::bake_to_file(mesh, out, settings);
  if (!summary) throw std::runtime_error(summary.error().describe());
  return out;
}

std::shared_ptr<const voxfmt::runtime::CollisionObject> load(const std::string& path) {
  auto loaded = voxfmt::runtime::CollisionObject::load(path);
  if (!loaded) throw std::runtime_error(loaded.error().describe());
  return loaded.value();
}

btTransform at(double x, double y, double z, const btQuaternion& q = btQuaternion::getIdentity()) {
  return btTransform(q, btVector3(btScalar(x), btScalar(y), btScalar(z)));
}

}  // namespace

int main(int argc, char** argv) {
  std::string bunny_mesh = VOXFMT_SAMPLE_MESHES "/bunny00.off", cache = "out/mixed_scene", json_path,
              png_path = "out/mixed_scene/mixed_scene.png";
  double seconds = 5.0;
  std::vector<double> drop_offset{0.0, 0.0};
  bool friction_anchors = false;
  CLI::App app{"mixed_scene — VPS bunnies against every kind of Bullet partner, settling for a few seconds"};
  app.add_option("--mesh", bunny_mesh, "the mesh of the VPS bodies (scaled to 0.15 m)")->capture_default_str();
  app.add_option("--cache", cache, "folder for the baked assets")->capture_default_str();
  app.add_option("--png", png_path, "picture of the final scene")->capture_default_str();
  app.add_option("--json", json_path, "per partner kind: contacts, penetration, residual speed, narrow-phase time");
  app.add_option("--seconds", seconds, "simulated seconds at 1 kHz")
      ->capture_default_str()
      ->check(CLI::Range(0.2, 60.0));
  app.add_option("--drop-offset", drop_offset, "every bunny dropped this far from its station's centre, x and z (m)")
      ->delimiter(',')
      ->expected(2)
      ->capture_default_str()
      ->check(CLI::Range(-0.02, 0.02));
  app.add_flag(
      "--friction-anchors", friction_anchors,
      "Bullet's friction anchors on the dropped bunnies (CF_HAS_FRICTION_ANCHOR): a contact point is kept while its "
      "friction is inside the cone, and pulled back to where it was");
  CLI11_PARSE(app, argc, argv);

  try {
    fs::create_directories(cache);
    // The bunny at 0.15 m, and a 0.4 x 0.3 m shelf board: an open sheet baked as a 6 mm solid shell.
    voxfmt::bake::Settings bunny_settings;
    bunny_settings.import.unit_scale = 0.15;
    bunny_settings.voxelmap.resolution = 128;
    bunny_settings.point_shell.points = 10000;
    const auto bunny = load(baked(bunny_mesh, cache + "/bunny.vox.h5", bunny_settings));
    const std::string sheet = cache + "/shelf.obj";
    if (!fs::exists(sheet)) {
      std::ofstream obj(sheet);
      obj << "v -0.2 0 -0.15\nv 0.2 0 -0.15\nv 0.2 0 0.15\nv -0.2 0 0.15\nf 1 3 2\nf 1 4 3\n";
    }
    voxfmt::bake::Settings shelf_settings;
    shelf_settings.voxelmap.voxel_size = 0.002;
    shelf_settings.voxelmap.shell_thickness = 0.006;
    shelf_settings.point_shell.points = 4000;
    const auto shelf = load(baked(sheet, cache + "/shelf.vox.h5", shelf_settings));
    const double h = bunny->voxelmap().voxel_size();

    voxfmt::bullet::World world;
    world.dynamics().setGravity(btVector3(0, -9.81f, 0));
    world.dispatcher().setNearCallback(timed_near_callback);
    std::map<std::string, KindStats> stats;

    std::vector<std::shared_ptr<VpsShape>> vps_shapes;  // for the picture
    std::vector<const btRigidBody*> vps_bodies;
    auto add_vps = [&](std::shared_ptr<const voxfmt::runtime::CollisionObject> object, double mass,
                       const btTransform& where) {
      auto shape = std::make_shared<voxfmt::bullet::VpsMixedShape>(object);
      btRigidBody* body = world.add_body(shape, btScalar(mass), where);
      body->setFriction(0.8f);
      // Dynamic ones only: a pair is anchored if either body asks, and the static bunny's partners are not measured.
      if (friction_anchors && mass > 0)
        body->setCollisionFlags(body->getCollisionFlags() | btCollisionObject::CF_HAS_FRICTION_ANCHOR);
      body->setActivationState(DISABLE_DEACTIVATION);
      vps_shapes.push_back(shape);
      vps_bodies.push_back(body);
      return body;
    };
    // A bunny dropped with its lowest point 2 cm above `top` at station x.
    auto drop_bunny = [&](double x, double top) {
      auto shape = std::make_shared<voxfmt::bullet::VpsMixedShape>(bunny);
      btTransform t = shape->asset_to_shape().inverse();
      t.setOrigin(t.getOrigin() + btVector3(btScalar(x + drop_offset[0]),
                                            btScalar(top - bunny->bounds_min().y() + 0.02), btScalar(drop_offset[1])));
      return add_vps(bunny, 1.0, t);
    };
    auto add_static = [&](std::shared_ptr<btCollisionShape> shape, const btTransform& where) {
      return world.add_body(std::move(shape), 0, where);
    };

    // The ground (the "plane" station stands directly on it).
    add_static(std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), btScalar(0)), at(0, 0, 0));
    double x = 0;
    stats["plane"].subject = drop_bunny(x, 0.0);
    x += kStation;
    add_static(std::make_shared<btBoxShape>(btVector3(0.12f, 0.05f, 0.12f)), at(x, 0.05, 0));
    stats["box"].subject = drop_bunny(x, 0.1);
    x += kStation;
    add_static(std::make_shared<btSphereShape>(btScalar(0.12)), at(x, 0.0, 0));
    stats["sphere"].subject = drop_bunny(x, 0.12);
    x += kStation;
    auto rail = std::make_shared<btCapsuleShapeX>(btScalar(0.015), btScalar(0.3));
    add_static(rail, at(x, 0.06, -0.035));
    add_static(rail, at(x, 0.06, 0.035));
    stats["capsule"].subject = drop_bunny(x, 0.075);
    x += kStation;
    add_static(std::make_shared<btCylinderShape>(btVector3(0.09f, 0.05f, 0.09f)), at(x, 0.05, 0));
    stats["cylinder"].subject = drop_bunny(x, 0.1);
    x += kStation;
    {
      // A low mound of a cone (11 degree slopes). Cones and hulls carry Bullet's 4 cm default margin outside
      // their surface: 1 mm here.
      auto cone = std::make_shared<btConeShape>(btScalar(0.19), btScalar(0.04));
      cone->setMargin(0.001f);
      add_static(cone, at(x, 0.02, 0));
      stats["cone"].subject = drop_bunny(x, 0.04);
    }
    x += kStation;
    {
      auto hull = std::make_shared<btConvexHullShape>();
      for (int i = 0; i < 12; ++i) {  // a low, irregular dome
        const double a = 2 * M_PI * i / 12;
        hull->addPoint(btVector3(btScalar(0.13 * std::cos(a)), 0, btScalar(0.11 * std::sin(a))), false);
        hull->addPoint(btVector3(btScalar(0.07 * std::cos(a + 0.3)), btScalar(0.06 + 0.01 * (i % 3)),
                                 btScalar(0.06 * std::sin(a + 0.3))),
                       false);
      }
      hull->recalcLocalAabb();
      hull->setMargin(0.001f);
      hull->initializePolyhedralFeatures();
      add_static(hull, at(x, 0, 0));
      stats["convex-hull"].subject = drop_bunny(x, 0.08);
    }
    x += kStation;
    static auto step_low = std::make_shared<btBoxShape>(btVector3(0.17f, 0.03f, 0.14f));
    static auto step_high = std::make_shared<btBoxShape>(btVector3(0.04f, 0.03f, 0.14f));
    {
      auto compound = std::make_shared<btCompoundShape>();
      compound->addChildShape(at(0, 0.03, 0), step_low.get());
      compound->addChildShape(at(0.13, 0.09, 0), step_high.get());
      add_static(compound, at(x, 0, 0));
      stats["compound"].subject = drop_bunny(x - 0.04, 0.06);
    }
    x += kStation;
    // A wavy triangle-mesh floor tile and a terrain tile (heights stored row by row).
    static std::vector<btVector3> tile_vertices;
    static std::vector<int> tile_indices;
    const int n = 41;
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < n; ++k) {
        const double u = -0.17 + 0.34 * i / (n - 1), w = -0.17 + 0.34 * k / (n - 1);
        tile_vertices.emplace_back(btScalar(u), btScalar(0.04 + 0.006 * std::sin(20 * u) * std::cos(17 * w)),
                                   btScalar(w));
      }
    for (int i = 0; i + 1 < n; ++i)
      for (int k = 0; k + 1 < n; ++k) {
        const int v = i * n + k;
        tile_indices.insert(tile_indices.end(), {v, v + 1, v + n + 1, v, v + n + 1, v + n});
      }
    static btTriangleIndexVertexArray tile(int(tile_indices.size() / 3), tile_indices.data(), 3 * sizeof(int),
                                           int(tile_vertices.size()), &tile_vertices[0][0], sizeof(btVector3));
    add_static(std::make_shared<btBvhTriangleMeshShape>(&tile, true), at(x, 0, 0));
    stats["static-mesh"].subject = drop_bunny(x, 0.046);
    x += kStation;
    static std::vector<float> heights;
    for (int k = 0; k < n; ++k)
      for (int i = 0; i < n; ++i)
        heights.push_back(float(0.02 + 0.01 * std::sin(12.0 * i / n) + 0.008 * std::cos(9.0 * k / n)));
    auto terrain =
        std::make_shared<btHeightfieldTerrainShape>(n, n, heights.data(), 1.0f, 0.0f, 0.04f, 1, PHY_FLOAT, false);
    terrain->setLocalScaling(btVector3(0.34f / (n - 1), 1.0f, 0.34f / (n - 1)));
    add_static(terrain, at(x, 0.02, 0));  // Bullet centres the terrain on its height range
    stats["heightfield"].subject = drop_bunny(x, 0.045);
    x += kStation;
    // The shelf: a static VPS board 0.15 m up, a bunny dropped on it.
    {
      auto shape = std::make_shared<voxfmt::bullet::VpsMixedShape>(shelf);
      btTransform t = shape->asset_to_shape().inverse();
      t.setOrigin(t.getOrigin() + btVector3(btScalar(x), 0.15f, 0));
      add_vps(shelf, 0, t);
      stats["vps"].subject = drop_bunny(x, 0.153);
    }
    x += kStation;
    // A static VPS bunny with a dynamic capsule, hull and compound dropped on it (more capsule, convex-hull and
    // compound pairs, the other way round).
    {
      auto shape = std::make_shared<voxfmt::bullet::VpsMixedShape>(bunny);
      btTransform t = shape->asset_to_shape().inverse();
      t.setOrigin(t.getOrigin() + btVector3(btScalar(x), btScalar(-bunny->bounds_min().y()), 0));
      add_vps(bunny, 0, t);
      const double top = bunny->bounds_max().y() - bunny->bounds_min().y();
      world.add_body(std::make_shared<btCapsuleShape>(btScalar(0.012), btScalar(0.05)), 0.1,
                     at(x - 0.03, top + 0.05, 0.0, btQuaternion(btVector3(1, 0, 0), btScalar(M_PI / 2))));
      auto pebble = std::make_shared<btConvexHullShape>();
      for (int i = 0; i < 8; ++i)
        pebble->addPoint(btVector3(btScalar(0.02 * ((i & 1) ? 1 : -1)), btScalar(0.015 * ((i & 2) ? 1 : -1)),
                                   btScalar(0.018 * ((i & 4) ? 1 : -1))),
                         false);
      pebble->setMargin(0.001f);
      world.add_body(pebble, 0.1, at(x + 0.02, top + 0.12, 0.01));
      static auto cube = std::make_shared<btBoxShape>(btVector3(0.01f, 0.01f, 0.01f));
      auto pair = std::make_shared<btCompoundShape>();
      pair->addChildShape(at(-0.015, 0, 0), cube.get());
      pair->addChildShape(at(0.015, 0, 0), cube.get());
      world.add_body(pair, 0.1, at(x, top + 0.2, -0.01));
    }
    const double scene_width = x;

    // ---- simulate
    const int steps = int(std::lround(seconds / kDt));
    const int last_second = std::max(0, steps - 1000), last_tenth = std::max(0, steps - 100);
    const auto wall_start = Clock::now();
    for (int step = 0; step < steps; ++step) {
      if (step == last_tenth)
        for (auto& [kind, s] : stats)
          if (s.subject) s.subject_before = s.subject->getCenterOfMassPosition();
      g_step_us.clear();
      world.step(btScalar(kDt));
      for (const auto& [kind, us] : g_step_us) stats[kind].narrow_us.push_back(us);
      for (int m = 0; m < world.dispatcher().getNumManifolds(); ++m) {
        const btPersistentManifold* manifold = world.dispatcher().getManifoldByIndexInternal(m);
        const auto* a = manifold->getBody0();
        const auto* b = manifold->getBody1();
        const bool a_vps = a->getCollisionShape()->getShapeType() == VpsShape::kShapeType;
        const bool b_vps = b->getCollisionShape()->getShapeType() == VpsShape::kShapeType;
        if (!a_vps && !b_vps) continue;
        KindStats& s = stats[a_vps && b_vps ? "vps" : kind_of((a_vps ? b : a)->getCollisionShape())];
        s.contacts += manifold->getNumContacts();
        ++s.pair_steps;
        if (step >= last_second)
          for (int c = 0; c < manifold->getNumContacts(); ++c)
            s.max_penetration = std::max(s.max_penetration, -double(manifold->getContactPoint(c).getDistance()));
      }
      if (step % 500 == 499)
        std::cerr << "\rsimulated " << std::fixed << std::setprecision(1) << (step + 1) * kDt << " of " << seconds
                  << " s" << std::flush;
    }
    std::cerr << "\n";
    const double wall = std::chrono::duration<double>(Clock::now() - wall_start).count();

    // ---- report
    std::ostringstream json;
    json << "{\n  \"seconds\": " << seconds << ", \"steps\": " << steps << ", \"wall_s\": " << wall
         << ", \"voxel_m\": " << h << ", \"drop_offset_m\": [" << drop_offset[0] << ", " << drop_offset[1]
         << "], \"friction_anchors\": " << (friction_anchors ? "true" : "false") << ",\n  \"pairs\": [";
    std::cout << std::left << std::setw(13) << "partner" << std::right << std::setw(10) << "contacts" << std::setw(14)
              << "max pen vox" << std::setw(16) << "residual m/s" << std::setw(15) << "narrow us p50"
              << "\n";
    bool first = true;
    for (const std::string& kind : kKinds) {
      KindStats& s = stats[kind];
      std::vector<double> us = s.narrow_us;
      std::sort(us.begin(), us.end());
      const double p50 = us.empty() ? 0 : us[us.size() / 2];
      const double contacts = s.pair_steps ? s.contacts / double(s.pair_steps) : 0;
      const double speed = s.subject ? double((s.subject->getCenterOfMassPosition() - s.subject_before).length()) /
                                           (std::min(100, steps) * kDt)
                                     : 0;
      json << (first ? "" : ",") << "\n    {\"partner\": \"" << kind << "\", \"contacts_mean\": " << contacts
           << ", \"max_penetration_voxels\": " << s.max_penetration / h << ", \"residual_speed_mps\": " << speed
           << ", \"narrow_us_p50\": " << p50;
      if (s.subject) {
        const btVector3 c = s.subject->getCenterOfMassPosition();
        json << ", \"final_position_m\": [" << c.x() << ", " << c.y() << ", " << c.z() << "]";
      }
      json << "}";
      first = false;
      std::cout << std::left << std::setw(13) << kind << std::right << std::fixed << std::setprecision(2)
                << std::setw(10) << contacts << std::setw(14) << s.max_penetration / h << std::setw(16)
                << std::setprecision(6) << speed << std::setw(15) << std::setprecision(1) << p50 << "\n";
    }
    json << "\n  ]\n}\n";
    std::cout << "simulated " << seconds << " s in " << std::setprecision(1) << wall << " s wall\n";
    if (!json_path.empty()) {
      std::ofstream out(json_path);
      out << json.str();
      if (!out.flush()) throw std::runtime_error("cannot write " + json_path);
      std::cout << "wrote " << json_path << "\n";
    }

    // ---- picture: front view (x right, y up), point shells in colour, other bodies as grey outlines
    const double px_per_m = 1500.0 / (scene_width + 0.4), x0 = -0.2, y_top = 0.45;
    voxfmt::exports::RasterImage image(int(std::lround((scene_width + 0.4) * px_per_m)),
                                       int(std::lround(0.55 * px_per_m)) + 30, {255, 255, 255});
    auto to_px = [&](double wx, double wy) {
      return std::pair<int, int>(int(std::lround((wx - x0) * px_per_m)), int(std::lround((y_top - wy) * px_per_m)));
    };
    for (int i = 0; i < world.dynamics().getNumCollisionObjects(); ++i) {
      const btCollisionObject* object = world.dynamics().getCollisionObjectArray()[i];
      if (object->getCollisionShape()->getShapeType() == VpsShape::kShapeType ||
          object->getCollisionShape()->getShapeType() == STATIC_PLANE_PROXYTYPE)
        continue;
      btVector3 lo, hi;
      object->getCollisionShape()->getAabb(object->getWorldTransform(), lo, hi);
      const auto [ax, ay] = to_px(lo.x(), hi.y());
      const auto [bx, by] = to_px(hi.x(), lo.y());
      image.fill_rect(ax, ay, bx - ax + 1, by - ay + 1, {200, 200, 200});
    }
    const voxfmt::exports::Rgb colours[] = {{200, 60, 40}, {40, 110, 200}, {40, 150, 70}, {170, 90, 170}};
    for (size_t b = 0; b < vps_shapes.size(); ++b) {
      const auto pose = vps_shapes[b]->asset_pose(vps_bodies[b]->getWorldTransform());
      const voxfmt::runtime::PointTree& tree = vps_shapes[b]->object().point_tree();
      for (size_t i = 0; i < tree.size(); ++i) {
        const Eigen::Vector3d w = pose.apply(tree.asset_point(i));
        const auto [px, py] = to_px(w.x(), w.y());
        image.set(px, py, colours[b % 4]);
      }
    }
    const int gy = to_px(x0, 0.0).second;
    image.fill_rect(0, gy, image.width(), 2, {60, 60, 60});  // the ground plane
    for (size_t k = 0; k < kKinds.size(); ++k) {
      const std::string& label = k == 0 ? std::string("shelf (vps)") : kKinds[k];
      const double station = k == 0 ? 10 * kStation : double(k - 1) * kStation;
      const auto [lx, ly] = to_px(station, -0.01);
      image.text(lx - voxfmt::exports::RasterImage::text_width(label, 1) / 2, ly + 4, label, 1, {0, 0, 0});
    }
    fs::create_directories(fs::path(png_path).parent_path().empty() ? "." : fs::path(png_path).parent_path());
    const voxfmt::Status written = image.write_png(png_path);
    if (!written) throw std::runtime_error(written.error().describe());
    std::cout << "wrote " << png_path << "\n";
  } catch (const std::exception& e) {
    std::cerr << "mixed_scene: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
