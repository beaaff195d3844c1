#include "scenarios.h"

#include <fcl/narrowphase/distance.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <stdexcept>

#include "voxfmt/bake/bake.h"

namespace vps_bench {
namespace {

namespace fs = std::filesystem;
constexpr double kPi = 3.14159265358979323846;

/// Portable deterministic random numbers (std distributions differ between standard libraries).
class Random {
 public:
  explicit Random(uint64_t seed) : state_(seed) {}
  uint64_t next() {  // SplitMix64
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  double uniform() { return double(next() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  /// Uniformly distributed rotation (Shoemake).
  Eigen::Quaterniond rotation() {
    const double u1 = uniform(), u2 = uniform(), u3 = uniform();
    const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
    return Eigen::Quaterniond(a * std::sin(2 * kPi * u2), a * std::cos(2 * kPi * u2), b * std::sin(2 * kPi * u3),
                              b * std::cos(2 * kPi * u3))
        .normalized();
  }
  Eigen::Vector3d direction() {
    const double z = uniform(-1, 1), phi = uniform(0, 2 * kPi), r = std::sqrt(1 - z * z);
    return {r * std::cos(phi), r * std::sin(phi), z};
  }

 private:
  uint64_t state_;
};

Eigen::Isometry3d make_pose(const Eigen::Quaterniond& q, const Eigen::Vector3d& t) {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = q.toRotationMatrix();
  pose.translation() = t;
  return pose;
}

// ------------------------------------------------------------------------------------------- baked bodies

/// Asset frame -> the VPS shapes' frame (principal axes at the centre of mass), as VpsShape::asset_to_shape.
Eigen::Vector3d to_shape_frame(const voxfmt::runtime::CollisionObject& object, const Eigen::Vector3d& asset_point) {
  return object.principal_axes().transpose() * (asset_point - object.center_of_mass());
}

struct BakeRequest {
  std::string name;       // file stem in the cache
  std::string mesh_path;  // input mesh
  double unit_scale = 1.0;
  uint32_t resolution = 306;
  uint32_t points = 35000;
};

std::shared_ptr<Body> baked_body(const BakeRequest& request, const ScenarioSettings& settings) {
  fs::create_directories(settings.cache_dir);
  std::ostringstream stem;
  stem << request.name << "-r" << request.resolution << "-p" << request.points;
  const std::string asset_path = (fs::path(settings.cache_dir) / (stem.str() + ".vox.h5")).string();
  if (!fs::exists(asset_path)) {
    if (settings.verbose)
      std::cerr << "bake: " << request.mesh_path << " -> " << asset_path << " (resolution " << request.resolution
                << ", " << request.points << " points)\n";
    voxfmt::bake::Settings bake;
    bake.import.unit_scale = request.unit_scale;
    bake.voxelmap.resolution = request.resolution;
    bake.point_shell.points = request.points;
    const auto summary = voxfmt::bake::bake_to_file(request.mesh_path, asset_path, bake);
    if (!summary) throw std::runtime_error("baking " + request.mesh_path + ": " + summary.error().describe());
  }
  auto loaded = voxfmt::runtime::CollisionObject::load(asset_path);
  if (!loaded) throw std::runtime_error("loading " + asset_path + ": " + loaded.error().describe());
  auto body = std::make_shared<Body>();
  body->kind = Body::Kind::BakedMesh;
  body->name = request.name;
  body->vps = loaded.value();
  body->mesh_path = request.mesh_path;
  body->asset_path = asset_path;
  voxfmt::bake::ImportSettings import;
  import.unit_scale = request.unit_scale;
  const auto mesh = voxfmt::bake::read_mesh(request.mesh_path, import);
  if (!mesh) throw std::runtime_error("reading " + request.mesh_path + ": " + mesh.error().describe());
  // The shape frame of the VPS shapes (principal frame at the centre of mass), for every method.
  for (const voxfmt::Vec3& v : mesh.value().vertices)
    body->mesh.vertices.push_back(to_shape_frame(*body->vps, Eigen::Vector3d(v[0], v[1], v[2])));
  for (const auto& t : mesh.value().triangles) body->mesh.triangles.push_back({int(t[0]), int(t[1]), int(t[2])});
  return body;
}

/// A torus around the y axis: `major` x `minor` vertices, minor angle 0 at the outer equator so that the
/// top and bottom circles (angles 90 and 270 degrees) are vertex rings when `minor` is a multiple of 4.
std::string torus_mesh(const ScenarioSettings& settings, double R, double r, int major, int minor) {
  std::ostringstream name;
  name << "torus-R" << R << "-r" << r << "-" << major << "x" << minor << ".off";
  const std::string path = (fs::path(settings.cache_dir) / name.str()).string();
  if (fs::exists(path)) return path;
  fs::create_directories(settings.cache_dir);
  const std::string partial = path + ".partial";
  {
    std::ofstream out(partial);
    out << std::setprecision(17) << "OFF\n" << major * minor << " " << 2 * major * minor << " 0\n";
    for (int i = 0; i < major; ++i) {
      const double u = 2 * kPi * i / major;
      for (int j = 0; j < minor; ++j) {
        const double v = 2 * kPi * j / minor;
        out << (R + r * std::cos(v)) * std::cos(u) << " " << r * std::sin(v) << " "
            << (R + r * std::cos(v)) * std::sin(u) << "\n";
      }
    }
    auto index = [&](int i, int j) { return ((i + major) % major) * minor + (j + minor) % minor; };
    for (int i = 0; i < major; ++i)
      for (int j = 0; j < minor; ++j) {  // outward orientation
        out << "3 " << index(i, j) << " " << index(i, j + 1) << " " << index(i + 1, j + 1) << "\n";
        out << "3 " << index(i, j) << " " << index(i + 1, j + 1) << " " << index(i + 1, j) << "\n";
      }
    if (!out) throw std::runtime_error("cannot write " + partial);
  }
  fs::rename(partial, path);
  return path;
}

constexpr double kTorusMajor = 0.05, kTorusMinor = 0.02;             // 0.14 m across
constexpr int kTorusMajorSegments = 358, kTorusMinorSegments = 100;  // 35,800 vertices

std::shared_ptr<Body> torus_body(const ScenarioSettings& settings) {
  static std::shared_ptr<Body> cached;
  if (cached) return cached;
  const std::string mesh = torus_mesh(settings, kTorusMajor, kTorusMinor, kTorusMajorSegments, kTorusMinorSegments);
  cached = baked_body({"torus", mesh, 1.0, 306, 35000}, settings);
  // HACD needs over 30 minutes on the 71,600-triangle torus; its result (8 hulls of <= 100 vertices) hardly
  // depends on the tessellation, so it decomposes the same torus at 120 x 40 (its vertices on the surface).
  const int major = 120, minor = 40;
  Mesh& coarse = cached->decomposition_mesh;
  for (int i = 0; i < major; ++i)
    for (int j = 0; j < minor; ++j) {
      const double u = 2 * kPi * i / major, v = 2 * kPi * j / minor;
      const Eigen::Vector3d p((kTorusMajor + kTorusMinor * std::cos(v)) * std::cos(u), kTorusMinor * std::sin(v),
                              (kTorusMajor + kTorusMinor * std::cos(v)) * std::sin(u));
      coarse.vertices.push_back(to_shape_frame(*cached->vps, p));
    }
  auto index = [&](int i, int j) { return ((i + major) % major) * minor + (j + minor) % minor; };
  for (int i = 0; i < major; ++i)
    for (int j = 0; j < minor; ++j) {
      coarse.triangles.push_back({index(i, j), index(i, j + 1), index(i + 1, j + 1)});
      coarse.triangles.push_back({index(i, j), index(i + 1, j + 1), index(i + 1, j)});
    }
  return cached;
}

/// The torus's symmetry axis in its shape frame: the principal axis of the largest moment.
Eigen::Vector3d torus_axis(const Body& torus) {
  const Eigen::Vector3d moments = torus.vps->principal_moments();
  int axis = 0;
  for (int k = 1; k < 3; ++k)
    if (moments[k] > moments[axis]) axis = k;
  return Eigen::Vector3d::Unit(axis);
}

/// Rotation taking the torus's shape frame to a frame where its axis is +y, spun by `angle` about it.
Eigen::Quaterniond torus_upright(const Body& torus, double angle) {
  const Eigen::Quaterniond to_y = Eigen::Quaterniond::FromTwoVectors(torus_axis(torus), Eigen::Vector3d::UnitY());
  return Eigen::Quaterniond(Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitY())) * to_y;
}

// -------------------------------------------------------------------------------------------- static bodies

std::shared_ptr<Body> plane_body() {
  auto body = std::make_shared<Body>();
  body->kind = Body::Kind::Plane;
  body->name = "plane";
  return body;
}

std::shared_ptr<Body> box_body(double half) {
  auto body = std::make_shared<Body>();
  body->kind = Body::Kind::Box;
  body->name = "box";
  body->half_extents = Eigen::Vector3d::Constant(half);
  return body;
}

/// The floor's height field: gentle waves (3 mm, 0.1 m period), triangulated on a 194 x 194 grid.
double floor_height(double x, double z) { return 0.003 * std::sin(2 * kPi * x / 0.1) * std::cos(2 * kPi * z / 0.13); }
constexpr double kFloorHalf = 0.3;
constexpr int kFloorGrid = 194;  // 2 * 193^2 = 74,498 triangles

std::shared_ptr<Body> floor_body() {
  auto body = std::make_shared<Body>();
  body->kind = Body::Kind::StaticMesh;
  body->name = "mesh-floor";
  const double step = 2 * kFloorHalf / (kFloorGrid - 1);
  for (int i = 0; i < kFloorGrid; ++i)
    for (int j = 0; j < kFloorGrid; ++j) {
      const double x = -kFloorHalf + i * step, z = -kFloorHalf + j * step;
      body->mesh.vertices.emplace_back(x, floor_height(x, z), z);
    }
  for (int i = 0; i + 1 < kFloorGrid; ++i)
    for (int j = 0; j + 1 < kFloorGrid; ++j) {
      const int v = i * kFloorGrid + j;
      body->mesh.triangles.push_back({v, v + 1, v + kFloorGrid + 1});  // normals +y
      body->mesh.triangles.push_back({v, v + kFloorGrid + 1, v + kFloorGrid});
    }
  return body;
}

/// The floor closed into a solid slab: the floor's grid on top (normals +y), a wall under each edge down to
/// y = -depth, and a flat bottom fanned from its centre; every triangle facing out.
Mesh floor_slab(double depth) {
  Mesh slab = floor_body()->mesh;
  const int n = kFloorGrid;
  // The boundary of the top grid as one loop of grid positions (i, j), counter-clockwise seen from above.
  std::vector<std::array<int, 2>> loop;
  for (int j = 0; j + 1 < n; ++j) loop.push_back({0, j});
  for (int i = 0; i + 1 < n; ++i) loop.push_back({i, n - 1});
  for (int j = n - 1; j > 0; --j) loop.push_back({n - 1, j});
  for (int i = n - 1; i > 0; --i) loop.push_back({i, 0});
  const int below = int(slab.vertices.size());
  for (const auto& p : loop) {
    const Eigen::Vector3d& top = slab.vertices[size_t(p[0] * n + p[1])];
    slab.vertices.emplace_back(top.x(), -depth, top.z());
  }
  const int centre = int(slab.vertices.size());
  slab.vertices.emplace_back(0.0, -depth, 0.0);
  // Orients each new triangle away from `inside` (a point within the slab on the triangle's side).
  auto add = [&](int a, int b, int c, const Eigen::Vector3d& outward) {
    const Eigen::Vector3d normal = (slab.vertices[size_t(b)] - slab.vertices[size_t(a)])
                                       .cross(slab.vertices[size_t(c)] - slab.vertices[size_t(a)]);
    if (normal.dot(outward) < 0) std::swap(b, c);
    slab.triangles.push_back({a, b, c});
  };
  const int m = int(loop.size());
  for (int k = 0; k < m; ++k) {
    const int next = (k + 1) % m;
    const int t0 = loop[size_t(k)][0] * n + loop[size_t(k)][1], t1 = loop[size_t(next)][0] * n + loop[size_t(next)][1];
    const Eigen::Vector3d mid = 0.5 * (slab.vertices[size_t(t0)] + slab.vertices[size_t(t1)]);
    const Eigen::Vector3d out(mid.x(), 0.0, mid.z());  // walls face away from the centre line
    add(t0, t1, below + next, out);
    add(t0, below + next, below + k, out);
    add(centre, below + k, below + next, -Eigen::Vector3d::UnitY());
  }
  return slab;
}

// ------------------------------------------------------------------------------------------------ poses

/// A resting-like pose on the plane y = 0 (or the box top): random orientation, the lowest vertex `depth`
/// below the surface (negative: a gap). For a plane the deepest penetration is exactly that vertex's.
PosePair pose_on_plane(const Body& bunny, Random& random, double top, double xz_range, double depth) {
  const Eigen::Quaterniond q = random.rotation();
  double lowest = 1e30;
  for (const Eigen::Vector3d& v : bunny.mesh.vertices) lowest = std::min(lowest, (q * v).y());
  const Eigen::Vector3d t(random.uniform(-xz_range, xz_range), top - depth - lowest,
                          random.uniform(-xz_range, xz_range));
  PosePair pose;
  pose.a = make_pose(q, t);
  pose.exact_depth = depth;
  return pose;
}

using FclMesh = fcl::BVHModel<fcl::OBBRSSd>;

/// A approaches B (fixed at the origin) along -direction from far away until the meshes touch (conservative
/// advancement on exact mesh distances), then moves `depth` further (negative: stops short).
PosePair pose_touching(const Body& a, const Body& b, const std::shared_ptr<FclMesh>& fa,
                       const std::shared_ptr<FclMesh>& fb, const Eigen::Quaterniond& qa,
                       const Eigen::Vector3d& direction, double depth) {
  double reach = 0;
  for (const auto& v : a.mesh.vertices) reach = std::max(reach, v.norm());
  for (const auto& v : b.mesh.vertices) reach = std::max(reach, v.norm());
  double t = 2.5 * reach;
  fcl::CollisionObjectd oa(fa), ob(fb);
  ob.setTransform(fcl::Transform3d::Identity());
  fcl::DistanceRequestd request;
  for (int iteration = 0; iteration < 200; ++iteration) {
    fcl::Transform3d ta = fcl::Transform3d::Identity();
    ta.linear() = qa.toRotationMatrix();
    ta.translation() = t * direction;
    oa.setTransform(ta);
    fcl::DistanceResultd result;
    fcl::distance(&oa, &ob, request, result);
    if (result.min_distance < 1e-7) break;
    t -= result.min_distance;  // moving by the distance along any direction cannot make them overlap
  }
  PosePair pose;
  pose.a = make_pose(qa, (t - depth) * direction);
  return pose;
}

}  // namespace

std::shared_ptr<fcl::BVHModel<fcl::OBBRSSd>> fcl_mesh(const Mesh& mesh) {
  auto model = std::make_shared<fcl::BVHModel<fcl::OBBRSSd>>();
  std::vector<fcl::Triangle> triangles;
  for (const auto& t : mesh.triangles) triangles.emplace_back(t[0], t[1], t[2]);
  model->beginModel();
  model->addSubModel(mesh.vertices, triangles);
  model->endModel();
  return model;
}

const std::vector<std::string>& scenario_names() {
  static const std::vector<std::string> names = {"bunny-plane",  "bunny-box",   "bunny-static-mesh", "bunny-bunny",
                                                 "tori-stacked", "tori-linked", "tori-gap"};
  return names;
}

std::shared_ptr<Body> bunny_body(const ScenarioSettings& settings) {
  // CGAL's bunny00.off is 1 m across: 0.15 scales it to a 0.15 m bunny.
  static std::shared_ptr<Body> cached;
  if (!cached) cached = baked_body({"bunny00-0.15m", settings.bunny_mesh, 0.15, 306, 35000}, settings);
  return cached;
}

Scenario make_scenario(const std::string& name, const ScenarioSettings& settings) {
  Scenario s;
  s.name = name;
  Random random(settings.seed ^ std::hash<std::string>()(name));
  if (name == "bunny-plane" || name == "bunny-box") {
    const bool box = name == "bunny-box";
    s.a = bunny_body(settings);
    s.b = box ? box_body(0.15) : plane_body();
    // Box: a 0.3 m cube whose top face is at y = 0; the bunny stays over its middle.
    s.poses.reserve(settings.poses);
    for (size_t i = 0; i < settings.poses; ++i) {
      PosePair pose = pose_on_plane(*s.a, random, 0.0, box ? 0.03 : 0.1, random.uniform(-0.0005, 0.0015));
      if (box) pose.b.translation() = Eigen::Vector3d(0, -0.15, 0);
      s.poses.push_back(pose);
    }
    s.description = box ? "0.15 m bunny on a 0.3 m box, random orientations, lowest vertex 0.5 mm above to 1.5 mm "
                          "below the top"
                        : "0.15 m bunny on a plane, random orientations, lowest vertex 0.5 mm above to 1.5 mm below";
  } else if (name == "bunny-static-mesh") {
    s.a = bunny_body(settings);
    s.b = floor_body();
    for (size_t i = 0; i < settings.poses; ++i) {
      const Eigen::Quaterniond q = random.rotation();
      const double x = random.uniform(-0.15, 0.15), z = random.uniform(-0.15, 0.15);
      const double depth = random.uniform(-0.0005, 0.0015);
      double lowest = 1e30;  // vertex height above the floor below it
      for (const Eigen::Vector3d& v : s.a->mesh.vertices) {
        const Eigen::Vector3d w = q * v;
        lowest = std::min(lowest, w.y() - floor_height(w.x() + x, w.z() + z));
      }
      PosePair pose;
      pose.a = make_pose(q, Eigen::Vector3d(x, -lowest - depth, z));
      s.poses.push_back(pose);
    }
    s.description =
        "0.15 m bunny on a static 74,498-triangle wavy floor (btBvhTriangleMeshShape for Bullet), "
        "lowest vertex 0.5 mm above to 1.5 mm below the floor under it";
  } else if (name == "bunny-bunny") {
    s.a = s.b = bunny_body(settings);
    const auto fa = fcl_mesh(s.a->mesh);
    for (size_t i = 0; i < settings.poses; ++i) {
      const Eigen::Quaterniond q = random.rotation();
      const Eigen::Vector3d d = random.direction();
      s.poses.push_back(pose_touching(*s.a, *s.b, fa, fa, q, d, random.uniform(-0.0005, 0.0015)));
    }
    s.description =
        "two 0.15 m bunnies: one approaches the other from a random direction in a random "
        "orientation until the meshes touch (exact mesh distances), then 0.5 mm short to 1.5 mm in";
  } else if (name == "tori-stacked" || name == "tori-gap") {
    s.a = s.b = torus_body(settings);
    const bool gap = name == "tori-gap";
    const double offset = 2 * kTorusMinor + (gap ? 0.001 : -0.0005);
    for (size_t i = 0; i < settings.poses; ++i) {
      // The same relative placement, at random spins about the common axis and a random common rotation.
      const Eigen::Quaterniond world = random.rotation();
      const Eigen::Vector3d shift(random.uniform(-0.05, 0.05), random.uniform(-0.05, 0.05),
                                  random.uniform(-0.05, 0.05));
      PosePair pose;
      pose.b = make_pose(world * torus_upright(*s.b, random.uniform(0, 2 * kPi)), shift);
      pose.a = make_pose(world * torus_upright(*s.a, random.uniform(0, 2 * kPi)),
                         shift + world * Eigen::Vector3d(0, offset, 0));
      pose.exact_depth = gap ? -0.001 : 0.0005;
      s.poses.push_back(pose);
    }
    s.description = gap ? "two tori (35,800 vertices, 0.14 m across) stacked on a common axis, 1 mm apart"
                        : "two tori (35,800 vertices, 0.14 m across) stacked on a common axis, overlapping 0.5 mm "
                          "along the whole ring";
  } else if (name == "tori-linked") {
    s.a = s.b = torus_body(settings);
    // B in the xz plane; A's ring passes through B's hole, in the xy plane, centred at c on the x axis: the
    // tubes' axes come closest at one spot, 2R - c apart, so the overlap there is 2r - (2R - c).
    const double c = 2 * kTorusMajor - 2 * kTorusMinor + 0.0005;
    const Eigen::Quaterniond into_xy(Eigen::AngleAxisd(kPi / 2, Eigen::Vector3d::UnitX()));
    for (size_t i = 0; i < settings.poses; ++i) {
      const Eigen::Quaterniond world = random.rotation();
      PosePair pose;
      pose.b = make_pose(world * torus_upright(*s.b, random.uniform(0, 2 * kPi)), Eigen::Vector3d::Zero());
      pose.a = make_pose(world * into_xy * torus_upright(*s.a, random.uniform(0, 2 * kPi)),
                         world * Eigen::Vector3d(c, 0, 0));
      pose.exact_depth = 0.0005;
      s.poses.push_back(pose);
    }
    s.description = "two linked tori (chain links pulled apart), overlapping 0.5 mm at one spot";
  } else {
    std::string known;
    for (const auto& n : scenario_names()) known += " " + n;
    throw std::runtime_error("unknown scenario '" + name + "' (known:" + known + ")");
  }
  return s;
}

BakedFloor baked_floor(const std::string& cache_dir, double voxel_size, bool verbose) {
  constexpr double kDepth = 0.02;
  fs::create_directories(cache_dir);
  std::ostringstream stem;
  stem << "mesh-floor-slab-v" << voxel_size * 1e3 << "mm";
  const fs::path base = fs::path(cache_dir) / stem.str();
  const std::string asset_path = base.string() + ".vox.h5", figures_path = base.string() + ".bake.txt";
  const Mesh slab = floor_slab(kDepth);
  BakedFloor floor;
  floor.voxel_size = voxel_size;
  floor.triangles = slab.triangles.size();
  if (!fs::exists(asset_path) || !fs::exists(figures_path)) {
    const std::string mesh_path = base.string() + ".off";
    {
      std::ofstream out(mesh_path);
      out << std::setprecision(17) << "OFF\n" << slab.vertices.size() << " " << slab.triangles.size() << " 0\n";
      for (const auto& v : slab.vertices) out << v.x() << " " << v.y() << " " << v.z() << "\n";
      for (const auto& t : slab.triangles) out << "3 " << t[0] << " " << t[1] << " " << t[2] << "\n";
      if (!out) throw std::runtime_error("cannot write " + mesh_path);
    }
    if (verbose)
      std::cerr << "bake: the floor as a " << kDepth * 1e3 << " mm slab (" << slab.triangles.size() << " triangles), "
                << voxel_size * 1e3 << " mm voxels -> " << asset_path << "\n";
    voxfmt::bake::Settings bake;
    bake.voxelmap.voxel_size = voxel_size;
    bake.point_shell.points = 2000;  // never used: the floor is a voxelmap only
    const auto summary = voxfmt::bake::bake_to_file(mesh_path, asset_path, bake);
    if (!summary) throw std::runtime_error("baking the floor: " + summary.error().describe());
    std::ofstream figures(figures_path);
    figures << summary.value().total_s << " " << double(summary.value().peak_memory_bytes) / 1e6 << "\n";
  }
  std::ifstream figures(figures_path);
  figures >> floor.bake_s >> floor.bake_peak_mb;
  voxfmt::runtime::LoadOptions load;
  load.load_point_shell = false;
  auto loaded = voxfmt::runtime::CollisionObject::load(asset_path, load);
  if (!loaded) throw std::runtime_error("loading " + asset_path + ": " + loaded.error().describe());
  floor.object = loaded.value();
  floor.file_mb = double(fs::file_size(asset_path)) / 1e6;
  floor.runtime_mb = double(floor.object->memory_bytes()) / 1e6;
  return floor;
}

}  // namespace vps_bench
