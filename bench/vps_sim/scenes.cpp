#include "scenes.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>
#include <stdexcept>

#include "voxfmt/bake/bake.h"
#include "voxfmt/bullet/shape.h"

namespace vps_sim {
namespace {

namespace fs = std::filesystem;
constexpr double kPi = 3.14159265358979323846;

/// Deterministic random numbers, the same on every standard library (SplitMix64).
class Random {
 public:
  explicit Random(uint64_t seed) : state_(seed) {}
  double uniform() {
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return double((z ^ (z >> 31)) >> 11) * 0x1.0p-53;
  }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  /// A uniformly distributed rotation (Shoemake).
  btQuaternion rotation() {
    const double u1 = uniform(), u2 = uniform(), u3 = uniform();
    const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
    return btQuaternion(btScalar(a * std::cos(2 * kPi * u2)), btScalar(b * std::sin(2 * kPi * u3)),
                        btScalar(b * std::cos(2 * kPi * u3)), btScalar(a * std::sin(2 * kPi * u2)));
  }

 private:
  uint64_t state_;
};

// ------------------------------------------------------------------------------------------ generated meshes

struct Mesh {
  std::vector<std::array<double, 3>> vertices;
  std::vector<std::array<int, 3>> triangles;
  int add(double x, double y, double z) {
    vertices.push_back({x, y, z});
    return int(vertices.size()) - 1;
  }
};

/// Writes an OFF file once (kept in the cache: the bake's asset is keyed by its name).
std::string write_off(const SceneSettings& settings, const std::string& name, const Mesh& mesh) {
  const std::string path = (fs::path(settings.cache_dir) / name).string();
  if (fs::exists(path)) return path;
  fs::create_directories(settings.cache_dir);
  const std::string partial = path + ".partial";
  {
    std::ofstream out(partial);
    out << std::setprecision(17) << "OFF\n" << mesh.vertices.size() << " " << mesh.triangles.size() << " 0\n";
    for (const auto& v : mesh.vertices) out << v[0] << " " << v[1] << " " << v[2] << "\n";
    for (const auto& t : mesh.triangles) out << "3 " << t[0] << " " << t[1] << " " << t[2] << "\n";
    if (!out) throw std::runtime_error("cannot write " + partial);
  }
  fs::rename(partial, path);
  return path;
}

/// A torus about the y axis (major radius R, tube radius r), `major` x `minor` vertices, outward triangles.
Mesh torus_mesh(double R, double r, int major, int minor) {
  Mesh mesh;
  for (int i = 0; i < major; ++i) {
    const double u = 2 * kPi * i / major;
    for (int j = 0; j < minor; ++j) {
      const double v = 2 * kPi * j / minor;
      mesh.add((R + r * std::cos(v)) * std::cos(u), r * std::sin(v), (R + r * std::cos(v)) * std::sin(u));
    }
  }
  auto index = [&](int i, int j) { return ((i + major) % major) * minor + (j + minor) % minor; };
  for (int i = 0; i < major; ++i)
    for (int j = 0; j < minor; ++j) {
      mesh.triangles.push_back({index(i, j), index(i, j + 1), index(i + 1, j + 1)});
      mesh.triangles.push_back({index(i, j), index(i + 1, j + 1), index(i + 1, j)});
    }
  return mesh;
}

/// A round peg along +y from y = 0 to `length`, radius `radius`, its bottom edge chamfered at 45 degrees by
/// `chamfer`: a profile revolved in `segments` steps, closed by two fans.
Mesh peg_mesh(double radius, double length, double chamfer, int segments) {
  Mesh mesh;
  const std::array<std::array<double, 2>, 3> profile = {
      {{radius - chamfer, 0.0}, {radius, chamfer}, {radius, length}}};  // (radius, y), bottom to top
  const int bottom = mesh.add(0, 0, 0), top = mesh.add(0, length, 0);
  for (int i = 0; i < segments; ++i) {
    const double a = 2 * kPi * i / segments;
    for (const auto& p : profile) mesh.add(p[0] * std::cos(a), p[1], p[0] * std::sin(a));
  }
  auto ring = [&](int i, int k) { return 2 + ((i + segments) % segments) * 3 + k; };
  for (int i = 0; i < segments; ++i) {
    mesh.triangles.push_back({bottom, ring(i, 0), ring(i + 1, 0)});
    for (int k = 0; k < 2; ++k) {
      mesh.triangles.push_back({ring(i, k), ring(i, k + 1), ring(i + 1, k + 1)});
      mesh.triangles.push_back({ring(i, k), ring(i + 1, k + 1), ring(i + 1, k)});
    }
    mesh.triangles.push_back({top, ring(i + 1, 2), ring(i, 2)});
  }
  return mesh;
}

/// A block 2 * half wide (x, z) from y = 0 to `height` with a round blind hole of `hole_radius`, `hole_depth`
/// deep, down from the middle of its top. `segments` (a multiple of 8) around the hole; the top face joins the
/// hole's rim to the square's edge along rays from the centre, so the square's corners are vertices.
Mesh block_with_hole_mesh(double half, double height, double hole_radius, double hole_depth, int segments) {
  Mesh mesh;
  std::vector<int> rim, edge, rim_bottom;
  for (int i = 0; i < segments; ++i) {
    const double a = 2 * kPi * i / segments, c = std::cos(a), s = std::sin(a);
    const double to_edge = half / std::max(std::fabs(c), std::fabs(s));
    rim.push_back(mesh.add(hole_radius * c, height, hole_radius * s));
    edge.push_back(mesh.add(to_edge * c, height, to_edge * s));
    rim_bottom.push_back(mesh.add(hole_radius * c, height - hole_depth, hole_radius * s));
  }
  const int hole_bottom = mesh.add(0, height - hole_depth, 0);
  // Bottom corners, counter-clockwise seen from above, at the angles of the top corners (45, 135, ... degrees).
  std::array<int, 4> corner;
  for (int q = 0; q < 4; ++q) {
    const double a = kPi / 4 + q * kPi / 2;
    corner[size_t(q)] = mesh.add(half * std::sqrt(2.0) * std::cos(a), 0, half * std::sqrt(2.0) * std::sin(a));
  }
  const int n = segments;
  for (int i = 0; i < n; ++i) {
    const int j = (i + 1) % n;
    // Top face (normal +y): the angle grows from +x towards +z, which seen from above (+y) is clockwise.
    mesh.triangles.push_back({rim[size_t(i)], rim[size_t(j)], edge[size_t(j)]});
    mesh.triangles.push_back({rim[size_t(i)], edge[size_t(j)], edge[size_t(i)]});
    // Hole wall (normal towards the hole's axis) and bottom (normal +y).
    mesh.triangles.push_back({rim[size_t(i)], rim_bottom[size_t(j)], rim[size_t(j)]});
    mesh.triangles.push_back({rim[size_t(i)], rim_bottom[size_t(i)], rim_bottom[size_t(j)]});
    mesh.triangles.push_back({hole_bottom, rim_bottom[size_t(j)], rim_bottom[size_t(i)]});
  }
  // Side walls: each side's top edge (the edge vertices between two corners) fanned to its bottom corners.
  for (int q = 0; q < 4; ++q) {
    const int first = n / 8 + q * n / 4, last = first + n / 4;  // top corners of side q
    const int b0 = corner[size_t(q)], b1 = corner[size_t((q + 1) % 4)];
    for (int i = first; i < last; ++i) mesh.triangles.push_back({edge[size_t(i % n)], edge[size_t((i + 1) % n)], b0});
    mesh.triangles.push_back({edge[size_t(last % n)], b1, b0});
  }
  mesh.triangles.push_back({corner[0], corner[1], corner[2]});  // bottom face (normal -y)
  mesh.triangles.push_back({corner[0], corner[2], corner[3]});
  return mesh;
}

// ------------------------------------------------------------------------------------------- baked geometry

struct GeometryRequest {
  std::string name;  ///< cache stem
  std::string mesh_path;
  double unit_scale = 1.0;
  double voxel_size = 0.0;  ///< metres; 0: `resolution`
  uint32_t resolution = 128;
  uint32_t points = 10000;
  std::string hacd_mesh_path;  ///< empty: the mesh itself
  double density = 1000.0;
};

std::vector<btVector3> shape_frame_vertices(const voxfmt::bake::TriangleMesh& mesh, const btTransform& to_shape) {
  std::vector<btVector3> out;
  for (const voxfmt::Vec3& v : mesh.vertices)
    out.push_back(to_shape(btVector3(btScalar(v[0]), btScalar(v[1]), btScalar(v[2]))));
  return out;
}

std::shared_ptr<Geometry> load_geometry(const GeometryRequest& request, const SceneSettings& settings) {
  static std::map<std::string, std::shared_ptr<Geometry>> loaded;  // one geometry per asset, for every scene
  std::ostringstream stem;
  stem << request.name << "-";
  if (request.voxel_size > 0)
    stem << "v" << request.voxel_size * 1e6 << "um";
  else
    stem << "r" << request.resolution;
  stem << "-p" << request.points;
  const std::string asset_path = (fs::path(settings.cache_dir) / (stem.str() + ".vox.h5")).string();
  if (auto it = loaded.find(asset_path); it != loaded.end()) return it->second;
  fs::create_directories(settings.cache_dir);
  voxfmt::bake::ImportSettings import;
  import.unit_scale = request.unit_scale;
  if (!fs::exists(asset_path)) {
    std::cerr << "bake: " << request.mesh_path << " -> " << asset_path << "\n";
    voxfmt::bake::Settings bake;
    bake.import = import;
    bake.voxelmap.resolution = request.resolution;
    bake.voxelmap.voxel_size = request.voxel_size;
    bake.point_shell.points = request.points;
    const auto summary = voxfmt::bake::bake_to_file(request.mesh_path, asset_path, bake);
    if (!summary) throw std::runtime_error("baking " + request.mesh_path + ": " + summary.error().describe());
  }
  auto object = voxfmt::runtime::CollisionObject::load(asset_path);
  if (!object) throw std::runtime_error("loading " + asset_path + ": " + object.error().describe());
  auto geometry = std::make_shared<Geometry>();
  geometry->name = request.name;
  geometry->object = object.value();
  geometry->density = request.density;
  const btTransform to_shape = voxfmt::bullet::VpsMixedShape(geometry->object).asset_to_shape();
  geometry->shape_to_asset = to_shape.inverse();
  const auto mesh = voxfmt::bake::read_mesh(request.mesh_path, import);
  if (!mesh) throw std::runtime_error("reading " + request.mesh_path + ": " + mesh.error().describe());
  geometry->vertices = shape_frame_vertices(mesh.value(), to_shape);
  for (const auto& t : mesh.value().triangles)
    for (uint32_t i : t) geometry->indices.push_back(int(i));
  if (request.hacd_mesh_path.empty()) {
    geometry->hacd_vertices = geometry->vertices;
    geometry->hacd_indices = geometry->indices;
  } else {
    const auto coarse = voxfmt::bake::read_mesh(request.hacd_mesh_path, import);
    if (!coarse) throw std::runtime_error("reading " + request.hacd_mesh_path + ": " + coarse.error().describe());
    geometry->hacd_vertices = shape_frame_vertices(coarse.value(), to_shape);
    for (const auto& t : coarse.value().triangles)
      for (uint32_t i : t) geometry->hacd_indices.push_back(int(i));
  }
  geometry->hacd_cache = (fs::path(settings.cache_dir) / (request.name + ".hacd.txt")).string();
  loaded[asset_path] = geometry;
  return geometry;
}

/// The largest extent of a mesh file's bounding box (its units), to scale sample meshes to a common size.
double mesh_extent(const std::string& path) {
  const auto mesh = voxfmt::bake::read_mesh(path);
  if (!mesh) throw std::runtime_error("reading " + path + ": " + mesh.error().describe());
  std::array<double, 3> lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
  for (const voxfmt::Vec3& v : mesh.value().vertices)
    for (int a = 0; a < 3; ++a) {
      lo[size_t(a)] = std::min(lo[size_t(a)], v[size_t(a)]);
      hi[size_t(a)] = std::max(hi[size_t(a)], v[size_t(a)]);
    }
  return std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
}

// ------------------------------------------------------------------------------------------------- scenes

constexpr double kTorusMajor = 0.05, kTorusMinor = 0.02;  // 0.14 m across
// A chain's links: a ring's hole must hold the tubes of both its neighbours (2 (R - r) >= 4 r), and the rings two
// apart, in the same plane, must clear each other when taut (2R - 2r >= R + r): a thinner tube.
constexpr double kLinkMajor = 0.05, kLinkMinor = 0.012;

std::shared_ptr<Geometry> bunny(const SceneSettings& settings) {
  // The seed's bunny: CGAL's bunny00.off as it is (about 1 m), 306 voxels, 35,000 points.
  return load_geometry(
      {"bunny00", (fs::path(settings.meshes_dir) / "bunny00.off").string(), 1.0, 0.0, 306, 35000, "", 1000.0},
      settings);
}

std::shared_ptr<Geometry> small_bunny(const SceneSettings& settings) {
  // The bunny at 20 cm (a stack of five 1 m bunnies would be a 5 m tower).
  const std::string path = (fs::path(settings.meshes_dir) / "bunny00.off").string();
  return load_geometry({"bunny00-0.2m", path, 0.2 / mesh_extent(path), 0.0, 200, 20000, "", 1000.0}, settings);
}

std::shared_ptr<Geometry> torus(const SceneSettings& settings) {
  const std::string fine = write_off(settings, "torus-fine.off", torus_mesh(kTorusMajor, kTorusMinor, 240, 96));
  // HACD's cost grows fast with the triangles: it decomposes the same torus at 60 x 24.
  const std::string coarse = write_off(settings, "torus-coarse.off", torus_mesh(kTorusMajor, kTorusMinor, 60, 24));
  return load_geometry({"torus", fine, 1.0, 0.0, settings.quick ? 160u : 240u, 20000, coarse, 1000.0}, settings);
}

std::shared_ptr<Geometry> chain_link(const SceneSettings& settings) {
  const std::string fine = write_off(settings, "link-fine.off", torus_mesh(kLinkMajor, kLinkMinor, 240, 64));
  const std::string coarse = write_off(settings, "link-coarse.off", torus_mesh(kLinkMajor, kLinkMinor, 60, 16));
  return load_geometry({"link", fine, 1.0, 0.0, settings.quick ? 160u : 240u, 20000, coarse, 1000.0}, settings);
}

btTransform at(const btVector3& origin) { return btTransform(btQuaternion::getIdentity(), origin); }

/// Places a geometry with its asset frame turned by `rotation` (the asset's own up stays up without one), its
/// centre of mass above (x, z) and its lowest point at `floor_y`: the body's shape-frame transform.
btTransform resting_on(const Geometry& g, double floor_y, double x, double z,
                       const btQuaternion& rotation = btQuaternion::getIdentity()) {
  const btTransform turned = btTransform(rotation) * g.shape_to_asset;
  btScalar lowest = BT_LARGE_FLOAT;
  for (const btVector3& v : g.vertices) lowest = std::min(lowest, (turned * v).y());
  return btTransform(turned.getBasis(),
                     btVector3(btScalar(x), turned.getOrigin().y() + btScalar(floor_y) - lowest, btScalar(z)));
}

/// The shape-frame transform of a geometry whose asset frame is at `asset_in_world`.
btTransform asset_at(const Geometry& g, const btTransform& asset_in_world) { return asset_in_world * g.shape_to_asset; }

BodySpec table_body(double half_width = 3.0) {
  BodySpec table;
  table.box_half = btVector3(btScalar(half_width), 0.05f, btScalar(half_width));
  table.transform = at(btVector3(0, -0.05f, 0));
  table.dynamic = false;
  return table;
}

BodySpec body_of(std::shared_ptr<Geometry> g, const btTransform& transform, bool dynamic = true) {
  BodySpec b;
  b.geometry = std::move(g);
  b.transform = transform;
  b.dynamic = dynamic;
  return b;
}

Scene drop_scene(const SceneSettings& settings) {
  Scene scene;
  scene.name = "drop";
  scene.description = "the seed's bunny (1 m) dropped from 10 cm onto a table";
  scene.seconds = 3.0;
  const auto g = bunny(settings);
  scene.bodies.push_back(table_body());
  btTransform t = resting_on(*g, 0.1, 0.1, 0.05);
  scene.bodies.push_back(body_of(g, t));
  scene.keep_lo = btVector3(-3, -0.05f, -3);
  return scene;
}

/// Four static walls around the square [-half, half]^2 (x, z), `height` tall, standing on the table.
void add_walls(Scene& scene, double half, double height, double thickness = 0.05) {
  for (int side = 0; side < 4; ++side) {
    BodySpec w;
    const bool along_z = side % 2 == 0;  // walls at x = +-(half + thickness/2) run along z
    const double offset = (side < 2 ? 1 : -1) * (half + thickness / 2);
    w.box_half = along_z ? btVector3(btScalar(thickness / 2), btScalar(height / 2), btScalar(half + thickness))
                         : btVector3(btScalar(half + thickness), btScalar(height / 2), btScalar(thickness / 2));
    w.transform = at(along_z ? btVector3(btScalar(offset), btScalar(height / 2), 0)
                             : btVector3(0, btScalar(height / 2), btScalar(offset)));
    w.dynamic = false;
    scene.bodies.push_back(w);
  }
}

Scene bunny_on_bunny_scene(const SceneSettings& settings) {
  Scene scene;
  scene.name = "bunny-on-bunny";
  scene.description =
      "a bunny dropped from 10 cm onto a static bunny, turned a quarter, in a box 10 cm wider "
      "than the bunnies (without walls it tumbles off onto the table with every method)";
  scene.seconds = 4.0;
  const auto g = bunny(settings);
  scene.bodies.push_back(table_body());
  const btTransform lower = resting_on(*g, 0.0, 0.0, 0.0);
  scene.bodies.push_back(body_of(g, lower, false));
  btVector3 lo(BT_LARGE_FLOAT, BT_LARGE_FLOAT, BT_LARGE_FLOAT), hi = -lo;
  for (const btVector3& v : g->vertices) {
    lo.setMin(lower * v);
    hi.setMax(lower * v);
  }
  const double half = std::max({double(hi.x()), double(-lo.x()), double(hi.z()), double(-lo.z())}) + 0.1;
  add_walls(scene, half, 2.5 * double(hi.y()));
  scene.bodies.push_back(
      body_of(g, resting_on(*g, double(hi.y()) + 0.1, 0.0, 0.0, btQuaternion(btVector3(0, 1, 0), btScalar(kPi / 2)))));
  scene.upper = int(scene.bodies.size()) - 1;
  scene.bodies.back().friction = 1.0;
  // On the table, the upper bunny's centre of mass would be where the lower one's is.
  scene.on_top_y = double(lower.getOrigin().y()) + 0.25 * double(hi.y());
  scene.keep_lo = btVector3(btScalar(-half), -0.05f, btScalar(-half));
  scene.keep_hi = btVector3(btScalar(half), 100, btScalar(half));
  return scene;
}

Scene pile_scene(const SceneSettings& settings) {
  Scene scene;
  scene.name = "pile";
  scene.description = std::to_string(settings.pile_bodies) +
                      " CGAL sample meshes of 8 kinds, 10 cm each, randomly turned, dropped into a 0.72 m bin";
  scene.seconds = 4.0;
  // Closed, manifold meshes only: the bake warns of holes in pig and mushroom and of self-intersections in cow,
  // whose insides are then a matter of interpretation (winding numbers), not a test of the collision method.
  static const std::array<const char*, 8> kinds = {"rotor", "spool",  "cactus",       "elephant",
                                                   "eight", "anchor", "couplingdown", "joint"};
  std::vector<std::shared_ptr<Geometry>> geometries;
  for (const char* kind : kinds) {
    const std::string path = (fs::path(settings.meshes_dir) / (std::string(kind) + ".off")).string();
    const double scale = 0.1 / mesh_extent(path);
    geometries.push_back(
        load_geometry({std::string("pile-") + kind, path, scale, 0.0, 96, 4000, "", 1000.0}, settings));
  }
  // A bin: a floor and four walls 0.4 m high around a 0.72 m square.
  const double inner = 0.36;
  scene.bodies.push_back(table_body(1.0));
  add_walls(scene, inner, 0.4, 0.02);
  // Layers of 4 x 4 bodies, their centres of mass as far apart as the largest bounding sphere is wide (no two
  // bodies overlap, whichever way they are turned), each turned at random, the first layer clear of the floor.
  double radius = 0;
  for (const auto& g : geometries) radius = std::max(radius, g->radius());
  const double spacing = 2 * radius + 0.005;
  if (1.5 * spacing + radius > inner) throw std::runtime_error("pile: the bodies do not fit in the bin");
  Random random(settings.seed);
  for (size_t i = 0; i < settings.pile_bodies; ++i) {
    const size_t layer = i / 16, cell = i % 16;
    const double x = spacing * (double(cell % 4) - 1.5), z = spacing * (double(cell / 4) - 1.5);
    const double y = radius + 0.005 + spacing * double(layer);
    const auto& g = geometries[i % geometries.size()];
    scene.bodies.push_back(
        body_of(g, asset_at(*g, btTransform(random.rotation(), btVector3(btScalar(x), btScalar(y), btScalar(z))))));
  }
  scene.keep_lo = btVector3(btScalar(-inner), -0.01f, btScalar(-inner));
  scene.keep_hi = btVector3(btScalar(inner), 100, btScalar(inner));
  return scene;
}

Scene stack_scene(const SceneSettings& settings) {
  Scene scene;
  scene.name = "stack";
  scene.description = "five 20 cm bunnies, and beside them five 14 cm tori, stacked 1 cm apart and let go";
  scene.seconds = 4.0;
  scene.bodies.push_back(table_body());
  const auto b = small_bunny(settings);
  double floor_y = 0.0;
  for (int k = 0; k < 5; ++k) {
    const btTransform t = resting_on(*b, floor_y + 0.01, -0.3, 0.0);
    scene.bodies.push_back(body_of(b, t));
    btScalar top = -BT_LARGE_FLOAT;
    for (const btVector3& v : b->vertices) top = std::max(top, (t * v).y());
    floor_y = double(top);
  }
  // Tori lying flat (the mesh's axis is up), each 1 cm above the one below.
  const auto t = torus(settings);
  for (int k = 0; k < 5; ++k)
    scene.bodies.push_back(body_of(t, resting_on(*t, 0.01 + k * (2 * kTorusMinor + 0.01), 0.3, 0.0)));
  scene.keep_lo = btVector3(-3, -0.05f, -3);
  return scene;
}

Scene chain_scene(const SceneSettings& settings) {
  Scene scene;
  scene.name = "chain";
  scene.description =
      "five tori hanging in a chain from a static one, each through the one above, let go 1 cm "
      "short of taut";
  scene.seconds = 3.0;
  const auto t = chain_link(settings);
  // Rings in vertical planes (the mesh's axis, y, turned to z, then alternately to x), 66 mm apart: each tube
  // passes through its neighbours' holes 16 mm from their centres, and the rings two apart (in the same plane)
  // clear each other by 8 mm. Taut, they are 2R - 2r = 76 mm apart: the links drop a centimetre each.
  const btQuaternion face_z(btVector3(1, 0, 0), btScalar(kPi / 2));
  const btQuaternion face_x = btQuaternion(btVector3(0, 1, 0), btScalar(kPi / 2)) * face_z;
  const double top = 1.0, spacing = 0.066;
  for (int k = 0; k < 6; ++k) {
    const btQuaternion q = k % 2 == 0 ? face_z : face_x;
    scene.bodies.push_back(
        body_of(t, asset_at(*t, btTransform(q, btVector3(0, btScalar(top - k * spacing), 0))), k > 0));
    scene.chain.push_back(int(scene.bodies.size()) - 1);
  }
  scene.chain_link_reach = 2 * kLinkMajor - 2 * kLinkMinor;
  return scene;
}

Scene peg_scene(const SceneSettings& settings, double clearance) {
  Scene scene;
  std::ostringstream name;
  name << "peg-in-hole-" << clearance * 1e3 << "mm";
  scene.name = name.str();
  scene.description =
      "a 12 mm peg with a 1 mm chamfer, pushed down by 2 N, 0.6 mm off the axis and tilted 0.5 "
      "degrees, into a 15 mm deep hole with " +
      std::to_string(clearance * 1e3).substr(0, 3) + " mm radial clearance";
  scene.seconds = 1.5;
  scene.margin = 0.00005;  // 50 um: a quarter of the smaller clearance
  const double peg_radius = 0.006, peg_length = 0.025, chamfer = 0.001;
  const double half = 0.015, height = 0.02, depth = 0.015, hole_radius = peg_radius + clearance;
  const double voxel = 0.00005;  // 50 um: the 0.2 mm clearance is 4 voxels
  std::ostringstream block_name;
  block_name << "block-hole-" << clearance * 1e3 << "mm";
  const std::string block_mesh =
      write_off(settings, block_name.str() + ".off", block_with_hole_mesh(half, height, hole_radius, depth, 128));
  const std::string peg_path = write_off(settings, "peg.off", peg_mesh(peg_radius, peg_length, chamfer, 128));
  const auto block = load_geometry({block_name.str(), block_mesh, 1.0, voxel, 0, 20000, "", 7800.0}, settings);
  const auto peg = load_geometry({"peg", peg_path, 1.0, voxel, 0, 20000, "", 7800.0}, settings);
  scene.bodies.push_back(table_body(0.1));
  // The block's asset frame is the world's (its bottom at 0, the hole's axis on the y axis).
  scene.bodies.push_back(body_of(block, asset_at(*block, btTransform::getIdentity()), false));
  // The peg upright above the hole, its tip 1 mm above the block, 0.6 mm off the axis, tilted 0.5 degrees.
  const btQuaternion tilt(btVector3(0, 0, 1), btScalar(0.5 * kPi / 180));
  BodySpec p = body_of(peg, asset_at(*peg, btTransform(tilt, btVector3(0.0006f, btScalar(height + 0.001), 0))));
  p.force = btVector3(0, -2, 0);
  p.friction = 0.3f;
  scene.bodies.push_back(p);
  scene.peg = int(scene.bodies.size()) - 1;
  scene.peg_tip = peg->shape_to_asset.inverse()(btVector3(0, 0, 0));
  scene.hole_top_y = height;
  scene.hole_depth = depth;
  scene.keep_lo = btVector3(-0.1f, -0.01f, -0.1f);
  return scene;
}

}  // namespace

btVector3 Geometry::inertia() const {
  const Eigen::Vector3d m = object->principal_moments() * density;
  return btVector3(btScalar(m.x()), btScalar(m.y()), btScalar(m.z()));
}

const std::vector<std::string>& scene_names() {
  static const std::vector<std::string> names = {
      "drop", "bunny-on-bunny", "pile", "stack", "chain", "peg-in-hole-0.5mm", "peg-in-hole-0.2mm"};
  return names;
}

Scene make_scene(const std::string& name, const SceneSettings& settings) {
  if (name == "drop") return drop_scene(settings);
  if (name == "bunny-on-bunny") return bunny_on_bunny_scene(settings);
  if (name == "pile") return pile_scene(settings);
  if (name == "stack") return stack_scene(settings);
  if (name == "chain") return chain_scene(settings);
  if (name == "peg-in-hole-0.5mm") return peg_scene(settings, 0.0005);
  if (name == "peg-in-hole-0.2mm") return peg_scene(settings, 0.0002);
  std::string known;
  for (const auto& n : scene_names()) known += " " + n;
  throw std::runtime_error("unknown scenario '" + name + "' (known:" + known + ")");
}

}  // namespace vps_sim
