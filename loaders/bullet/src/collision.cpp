#include "voxfmt/bullet/collision.h"

#include <BulletCollision/BroadphaseCollision/btCollisionAlgorithm.h>
#include <BulletCollision/CollisionDispatch/btCollisionCreateFunc.h>
#include <BulletCollision/CollisionDispatch/btCollisionObjectWrapper.h>
#include <BulletCollision/CollisionDispatch/btManifoldResult.h>
#include <BulletCollision/CollisionShapes/btBoxShape.h>
#include <BulletCollision/CollisionShapes/btCapsuleShape.h>
#include <BulletCollision/CollisionShapes/btConcaveShape.h>
#include <BulletCollision/CollisionShapes/btConvexPolyhedron.h>
#include <BulletCollision/CollisionShapes/btCylinderShape.h>
#include <BulletCollision/CollisionShapes/btHeightfieldTerrainShape.h>
#include <BulletCollision/CollisionShapes/btMultiSphereShape.h>
#include <BulletCollision/CollisionShapes/btPolyhedralConvexShape.h>
#include <BulletCollision/CollisionShapes/btSphereShape.h>
#include <BulletCollision/CollisionShapes/btStaticPlaneShape.h>
#include <BulletCollision/CollisionShapes/btTriangleCallback.h>
#include <BulletCollision/NarrowPhaseCollision/btPersistentManifold.h>
#include <BulletDynamics/Dynamics/btRigidBody.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <mutex>
#include <new>
#include <string>
#include <unordered_map>

#include "bt_eigen.h"
#include "static_mesh.h"
#include "traversal/function_query.h"
#include "triangle_set.h"
#include "voxfmt/bullet/partners.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/runtime/detail/contact_reduction.h"

namespace voxfmt::bullet {
namespace {

struct Shared {
  CollisionSettings settings;
  // On a line of their own: the counters change with every pair test, the settings are read by every one.
  alignas(64) CollisionCounters counters;
  std::atomic<uint64_t> reported_types{0};  // one bit per Bullet shape type already reported as unsupported

  // The step time budget (CollisionSettings::step_time_budget_us): the time the step's pair tests took
  // together, and how many tree levels every shell drops because steps ran over.
  std::atomic<int64_t> step_ns{0};
  std::atomic<uint32_t> levels_dropped{0};
  uint32_t relaxed_steps = 0;

  void begin_step() {
    const double budget = settings.step_time_budget_us;
    const double spent_us = double(step_ns.exchange(0, std::memory_order_relaxed)) * 1e-3;
    uint32_t dropped = levels_dropped.load(std::memory_order_relaxed);
    if (budget <= 0.0) {
      dropped = 0;
    } else if (spent_us > budget) {  // over: one level coarser at once
      dropped = std::min<uint32_t>(dropped + 1, 31);
      relaxed_steps = 0;
    } else if (spent_us < 0.5 * budget && dropped > 0) {  // well under for a while: one level finer
      if (++relaxed_steps >= kRelaxedSteps) {
        --dropped;
        relaxed_steps = 0;
      }
    } else {
      relaxed_steps = 0;
    }
    levels_dropped.store(dropped, std::memory_order_relaxed);
  }
  /// The deepest level a shell of `tree` is tested to under the budget (its leaves less the levels dropped;
  /// QueryOptions::min_points keeps the coarsest levels), or no limit.
  uint32_t level_cap(const runtime::PointTree& tree) const {
    const uint32_t leaf = uint32_t(tree.level_count()) - 1;
    const uint32_t dropped = levels_dropped.load(std::memory_order_relaxed);
    if (dropped == 0) return std::numeric_limits<uint32_t>::max();
    return dropped >= leaf ? 0u : leaf - dropped;
  }
  static constexpr uint32_t kRelaxedSteps = 50;

  // Static triangle meshes indexed once each (CollisionSettings::static_mesh_index), shared by every pair that
  // meets them. A pair keeps its mesh's index and looks here only when it has none, or its generation is old.
  std::mutex meshes_mutex;
  std::unordered_map<const btCollisionShape*, std::shared_ptr<const StaticMeshIndex>> meshes;
  std::atomic<uint64_t> mesh_generation{1};  ///< moves on whenever an index is forgotten

  std::shared_ptr<const StaticMeshIndex> mesh_index(const btConcaveShape& shape) {
    const MeshSignature signature = MeshSignature::of(shape);
    std::lock_guard<std::mutex> lock(meshes_mutex);
    std::shared_ptr<const StaticMeshIndex>& index = meshes[&shape];
    if (!index || !(index->signature() == signature)) {  // new, or another mesh at a freed shape's address
      index = StaticMeshIndex::build(shape);
      ++counters.static_mesh_builds;
    }
    return index;
  }
  void forget_mesh(const btCollisionShape& shape) {
    std::lock_guard<std::mutex> lock(meshes_mutex);
    meshes.erase(&shape);
    mesh_generation.fetch_add(1, std::memory_order_relaxed);
  }

  // A pair the algorithm cannot handle produces no contacts: say so once per shape type, never silently.
  void report_unsupported(const btCollisionShape* shape) {
    ++counters.unsupported_pairs;
    const int type = shape->getShapeType();
    const uint64_t bit = uint64_t(1) << (unsigned(type) % 64);
    if (reported_types.fetch_or(bit) & bit) return;
    const std::string message = std::string("voxfmt: a VPS shape against ") + shape->getName() +
                                " (Bullet shape type " + std::to_string(type) +
                                ") is not supported: such pairs produce no contacts";
    if (settings.on_unsupported_pair)
      settings.on_unsupported_pair(message);
    else
      std::fprintf(stderr, "%s\n", message.c_str());
  }
};

// Runs A's points against a partner's distance function (world coordinates), coherently with the pair's front
// when there is one (the partner's pose `partner` fixes its function).
template <class Distance>
void points_against(const VpsShape& a, const runtime::Pose& pose_a, const runtime::Pose& partner, Distance&& distance,
                    const runtime::QueryOptions& options, runtime::ContactSet& contacts, runtime::QueryScratch& scratch,
                    runtime::TraversalFront* front) {
  if (front)
    runtime::query_against_function(a.object(), pose_a, partner, distance, options, contacts, scratch, *front);
  else
    runtime::query_against_function(a.object(), pose_a, distance, options, contacts, scratch);
}

runtime::Pose partner_pose(const btTransform& t) {
  runtime::Pose pose;
  pose.rotation = to_eigen(t.getBasis());
  pose.translation = to_eigen(t.getOrigin());
  return pose;
}

// A VPS shape (A) against a convex partner (B), both ways: A's points against B's distance function, and B's
// extreme points (corners, centres, vertices or support points, each with a radius) in A's voxelmap — a small or
// sharp partner can poke between A's points. One handler per partner kind below does both, so each kind's two
// halves sit side by side; VpsCollisionAlgorithm::collide picks the handler.
struct ConvexPair {
  const VpsShape& a;
  const runtime::Pose& pose_a;
  const btTransform& tb;
  const runtime::QueryOptions& options;
  runtime::ContactSet& contacts;
  runtime::QueryScratch& scratch;
  runtime::TraversalFront* front;

  Eigen::Matrix3d rotation_b() const { return to_eigen(tb.getBasis()); }
  Eigen::Vector3d origin_b() const { return to_eigen(tb.getOrigin()); }
  Eigen::Vector3d world(const btVector3& local) const { return origin_b() + rotation_b() * to_eigen(local); }
  /// A's points against `distance` (x, outward) -> signed distance, when A has points.
  template <class Distance>
  void points_against_b(Distance&& distance) const {
    if (a.uses_points()) points_against(a, pose_a, partner_pose(tb), distance, options, contacts, scratch, front);
  }
  /// Points of B, each with `radius`, in A's voxelmap.
  void in_voxelmap(const Eigen::Vector3d* points, size_t count, double radius) const {
    if (count) runtime::query_points_in_voxelmap(a.object(), pose_a, points, count, radius, options, contacts);
  }
  void in_voxelmap(const std::vector<Eigen::Vector3d>& points, double radius) const {
    in_voxelmap(points.data(), points.size(), radius);
  }
  /// B's support points in 26 directions (margin included), for shapes with neither corners nor a centre.
  void support_points_in_voxelmap(const btConvexShape& b) const {
    thread_local std::vector<Eigen::Vector3d> points;
    points.clear();
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          if (dx == 0 && dy == 0 && dz == 0) continue;
          points.push_back(world(b.localGetSupportingVertex(btVector3(btScalar(dx), btScalar(dy), btScalar(dz)))));
        }
    in_voxelmap(points, 0.0);
  }
};

void collide_box(const ConvexPair& pair, const btBoxShape& b) {
  const btVector3 half = b.getHalfExtentsWithMargin();
  const Eigen::Matrix3f rbf = pair.rotation_b().cast<float>();
  const Eigen::Vector3f obf = pair.origin_b().cast<float>(), halff = to_eigen(half).cast<float>();
  pair.points_against_b(
      [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return box_distance(rbf, obf, halff, x, outward); });
  if (!pair.a.uses_voxelmap()) return;
  thread_local std::vector<Eigen::Vector3d> corners;
  corners.clear();
  for (int k = 0; k < 8; ++k)
    corners.push_back(pair.world(
        btVector3((k & 1) ? half.x() : -half.x(), (k & 2) ? half.y() : -half.y(), (k & 4) ? half.z() : -half.z())));
  pair.in_voxelmap(corners, 0.0);
}

void collide_sphere(const ConvexPair& pair, const btSphereShape& b) {
  const Eigen::Vector3f centre = pair.origin_b().cast<float>();
  const float radius = float(b.getRadius());
  pair.points_against_b(
      [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return sphere_distance(centre, radius, x, outward); });
  const Eigen::Vector3d centre_d = pair.origin_b();
  if (pair.a.uses_voxelmap()) pair.in_voxelmap(&centre_d, 1, double(b.getRadius()));
}

void collide_capsule(const ConvexPair& pair, const btCapsuleShape& b) {
  btVector3 tip(0, 0, 0);
  tip[b.getUpAxis()] = b.getHalfHeight();
  const Eigen::Vector3f top = pair.world(tip).cast<float>(), bottom = pair.world(-tip).cast<float>();
  const float radius = float(b.getRadius());
  pair.points_against_b([&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
    return capsule_distance(bottom, top, radius, x, outward);
  });
  if (!pair.a.uses_voxelmap()) return;
  // Spheres along the axis, no farther apart than a voxel of A.
  const double voxel = pair.a.object().voxelmap().voxel_size() * pair.a.scale();
  const int steps = std::clamp(int(std::ceil(2 * double(b.getHalfHeight()) / voxel)), 1, 64);
  thread_local std::vector<Eigen::Vector3d> centres;
  centres.clear();
  for (int k = 0; k <= steps; ++k) centres.push_back(pair.world(tip * btScalar(2.0 * k / steps - 1.0)));
  pair.in_voxelmap(centres, double(b.getRadius()));
}

void collide_cylinder(const ConvexPair& pair, const btCylinderShape& b) {
  const int up = b.getUpAxis();
  const Eigen::Vector3f centre = pair.origin_b().cast<float>(), axis = pair.rotation_b().col(up).cast<float>();
  const float radius = float(b.getRadius()), half = float(b.getHalfExtentsWithMargin()[up]);
  pair.points_against_b([&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
    return cylinder_distance(centre, axis, radius, half, x, outward);
  });
  if (pair.a.uses_voxelmap()) pair.support_points_in_voxelmap(b);
}

void collide_multi_sphere(const ConvexPair& pair, const btMultiSphereShape& b) {
  pair.points_against_b(
      [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return convex_distance(b, pair.tb, x, outward); });
  if (!pair.a.uses_voxelmap()) return;
  for (int k = 0; k < b.getSphereCount(); ++k) {
    const Eigen::Vector3d centre = pair.world(b.getSpherePosition(k));
    pair.in_voxelmap(&centre, 1, double(b.getSphereRadius(k)));
  }
}

void collide_polyhedron(const ConvexPair& pair, const btPolyhedralConvexShape& b) {
  if (const btConvexPolyhedron* polyhedron = b.getConvexPolyhedron()) {
    // Hulls with polyhedral features (initializePolyhedralFeatures): exact inside, GJK outside (EPA's
    // tolerance would make resting contacts jitter).
    const Eigen::Matrix3d rb = pair.rotation_b();
    const Eigen::Vector3d ob = pair.origin_b();
    thread_local std::vector<Eigen::Vector4f> planes;
    planes.clear();
    for (int f = 0; f < polyhedron->m_faces.size(); ++f) {
      const btScalar* plane = polyhedron->m_faces[f].m_plane;
      const Eigen::Vector3d n = rb * Eigen::Vector3d(plane[0], plane[1], plane[2]);
      planes.emplace_back(float(n.x()), float(n.y()), float(n.z()), float(double(plane[3]) - n.dot(ob)));
    }
    const float margin = float(b.getMargin());
    pair.points_against_b([&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
      float d;
      if (polyhedron_inside_distance(planes, margin, x, d, outward)) return d;
      return convex_distance(b, pair.tb, x, outward);
    });
  } else {
    pair.points_against_b(
        [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return convex_distance(b, pair.tb, x, outward); });
  }
  if (!pair.a.uses_voxelmap()) return;
  // Its vertices; the margin rounds the hull outward.
  thread_local std::vector<Eigen::Vector3d> vertices;
  vertices.clear();
  for (int k = 0; k < b.getNumVertices(); ++k) {
    btVector3 v;
    b.getVertex(k, v);
    vertices.push_back(pair.world(v));
  }
  pair.in_voxelmap(vertices, double(b.getMargin()));
}

// Curved convex shapes without a closed form here (cone, ...): GJK, and support points.
void collide_curved_convex(const ConvexPair& pair, const btConvexShape& b) {
  pair.points_against_b(
      [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return convex_distance(b, pair.tb, x, outward); });
  if (pair.a.uses_voxelmap()) pair.support_points_in_voxelmap(b);
}

// Collects the triangles of a static mesh or terrain, in world coordinates, that overlap A's own box (A's shape
// frame, grown by the reach): Bullet hands over everything in the world-aligned box around A, which for a
// rotated body holds several times more.
class TriangleCollector : public btTriangleCallback {
 public:
  TriangleCollector(TriangleSet& set, const btTransform& world_from_shape, bool upward, int up_axis,
                    const btTransform& a_from_world, const btVector3& a_lo, const btVector3& a_hi)
      : set_(set),
        world_from_shape_(world_from_shape),
        upward_(upward),
        up_axis_(up_axis),
        a_from_world_(a_from_world),
        a_lo_(a_lo),
        a_hi_(a_hi) {}
  void processTriangle(btVector3* triangle, int, int) override {
    btVector3 a = world_from_shape_ * triangle[0], b = world_from_shape_ * triangle[1],
              c = world_from_shape_ * triangle[2];
    btVector3 lo = a_from_world_ * a, hi = lo;
    for (const btVector3* p : {&b, &c}) {
      const btVector3 q = a_from_world_ * *p;
      lo.setMin(q);
      hi.setMax(q);
    }
    if (lo.x() > a_hi_.x() || lo.y() > a_hi_.y() || lo.z() > a_hi_.z() || hi.x() < a_lo_.x() || hi.y() < a_lo_.y() ||
        hi.z() < a_lo_.z())
      return;
    // A terrain's inside is below it: orient its triangles to face up, whatever order the grid gives them in.
    if (upward_ && (triangle[1] - triangle[0]).cross(triangle[2] - triangle[0])[up_axis_] < 0) std::swap(b, c);
    auto eigen = [](const btVector3& w) { return Eigen::Vector3f(float(w.x()), float(w.y()), float(w.z())); };
    set_.add(eigen(a), eigen(b), eigen(c));
  }

 private:
  TriangleSet& set_;
  const btTransform& world_from_shape_;
  bool upward_;
  int up_axis_;
  btTransform a_from_world_;
  btVector3 a_lo_, a_hi_;
};

// The triangles' corners that may be within `proximity` of A (a cheap lower bound of A's distance rules out the
// rest), whole triangles first: one lookup at the centroid with the triangle's radius settles most of them.
void corners_within_reach(const runtime::CollisionObject& a, const runtime::Pose& pose_a, const TriangleSet& triangles,
                          double proximity, std::vector<Eigen::Vector3d>& corners) {
  corners.clear();
  const runtime::SparseVoxelmap& map = a.voxelmap();
  const double to_voxels = 1.0 / (pose_a.scale * map.voxel_size());
  const double reach = proximity * to_voxels;
  auto lower_bound = [&](const Eigen::Vector3d& p) {
    const Eigen::Vector3d asset = pose_a.rotation.transpose() * (p - pose_a.translation) / pose_a.scale;
    return double(map.distance_lower_bound(map.to_grid(asset)));
  };
  for (size_t t = 0; t < triangles.size(); ++t) {
    const Eigen::Vector3d c0 = triangles.corner(t, 0).cast<double>(), c1 = triangles.corner(t, 1).cast<double>(),
                          c2 = triangles.corner(t, 2).cast<double>();
    const Eigen::Vector3d centroid = (c0 + c1 + c2) / 3.0;
    const double radius = std::sqrt(std::max({(c0 - centroid).squaredNorm(), (c1 - centroid).squaredNorm(),
                                              (c2 - centroid).squaredNorm()})) *
                          to_voxels;
    if (lower_bound(centroid) > radius + reach) continue;
    for (const Eigen::Vector3d* p : {&c0, &c1, &c2})
      if (lower_bound(*p) < reach) corners.push_back(*p);
  }
}

// A's points against the triangles of a static mesh or terrain that overlap A's box (grown by the proximity),
// signed by the triangles' sides; and those triangles' corners in A's voxelmap.
void collide_concave(const VpsShape& a, const runtime::Pose& pose_a, const btTransform& ta, const btConcaveShape& b,
                     const btTransform& tb, const runtime::QueryOptions& options, runtime::ContactSet& contacts,
                     runtime::QueryScratch& scratch) {
  btVector3 lo, hi;
  a.getAabb(ta, lo, hi);
  const btScalar grow = btScalar(options.proximity) + a.getMargin();
  lo -= btVector3(grow, grow, grow);
  hi += btVector3(grow, grow, grow);
  // The box in B's frame: the bounds of its eight corners.
  const btTransform shape_from_world = tb.inverse();
  btVector3 local_lo(SIMD_INFINITY, SIMD_INFINITY, SIMD_INFINITY), local_hi = -local_lo;
  for (int k = 0; k < 8; ++k) {
    const btVector3 corner =
        shape_from_world * btVector3((k & 1) ? hi.x() : lo.x(), (k & 2) ? hi.y() : lo.y(), (k & 4) ? hi.z() : lo.z());
    local_lo.setMin(corner);
    local_hi.setMax(corner);
  }
  thread_local TriangleSet triangles;
  triangles.clear();
  const bool terrain = b.getShapeType() == TERRAIN_SHAPE_PROXYTYPE;
  btVector3 a_lo, a_hi;  // A's box in its own frame
  a.getAabb(btTransform::getIdentity(), a_lo, a_hi);
  a_lo -= btVector3(grow, grow, grow);
  a_hi += btVector3(grow, grow, grow);
  TriangleCollector collect(triangles, tb, terrain,
                            terrain ? static_cast<const btHeightfieldTerrainShape&>(b).getUpAxis() : 1, ta.inverse(),
                            a_lo, a_hi);
  b.processAllTriangles(&collect, local_lo, local_hi);
  if (triangles.empty()) return;
  triangles.build();
  if (a.uses_points())
    runtime::query_against_function(
        a.object(), pose_a,
        [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return triangles.distance(x, outward); },
        [&](const Eigen::Vector3f& x) { return triangles.lower_bound(x); }, options, contacts, scratch);
  if (a.uses_voxelmap()) {
    thread_local std::vector<Eigen::Vector3d> corners;
    corners_within_reach(a.object(), pose_a, triangles, options.proximity, corners);
    runtime::query_points_in_voxelmap(a.object(), pose_a, corners.data(), corners.size(), 0.0, options, contacts);
  }
}

/// A static mesh's vertices that were near a VPS body (A) at an anchor pose, for coherent queries.
struct VertexCache {
  bool valid = false;
  Eigen::Matrix3d rotation;  ///< A's shape frame from the mesh's at the anchor
  Eigen::Vector3d translation;
  Eigen::Vector3d centre;  ///< the box scanned (mesh frame): centre and half diagonal
  double radius = 0;
  double to_voxels = 0;            ///< A's voxels per metre then
  double threshold = 0;            ///< vertices kept: A's distance bound below this (voxels) ...
  double pad = 0;                  ///< ... within A's box grown by this (metres)
  std::vector<uint32_t> vertices;  ///< their ids in the index, in scan order
};

/// A static mesh index's lower bound in world coordinates: one sample read, so inner nodes' points are bounded
/// before their exact distance is searched.
struct MeshBound {
  const StaticMeshIndex& mesh;
  const Eigen::Matrix3f& rt;  ///< world -> mesh frame: x_b = rt (x - t)
  const Eigen::Vector3f& t;
  float proximity;
  static constexpr bool kBoundBeforeDistance = true;
  float operator()(const Eigen::Vector3f& x) const { return mesh.lower_bound(rt * (x - t), proximity); }
};

// The mesh's vertices near A in A's voxelmap, each once: those in A's box (its own frame, grown by the reach) whose
// bound of A's distance is within reach, found by blocks of cells (a block out of reach is skipped by one bound at
// its centre). With a cache, the vertices found within a slack are kept, and reused while the relative motion
// since cannot have used the slack up.
class MeshVerticesInVoxelmap {
 public:
  MeshVerticesInVoxelmap(const VpsShape& a, const runtime::Pose& pose_a, const btTransform& ta,
                         const StaticMeshIndex& mesh, const btTransform& tb, const runtime::QueryOptions& options,
                         runtime::ContactSet& contacts, VertexCache* cache)
      : a_(a),
        pose_a_(pose_a),
        mesh_(mesh),
        options_(options),
        contacts_(contacts),
        cache_(cache),
        a_from_b_(ta.inverse() * tb),
        map_(a.object().voxelmap()),
        grow_(options.proximity + double(a.getMargin())),
        to_voxels_(1.0 / (pose_a.scale * map_.voxel_size())),
        reach_(options.proximity * to_voxels_),
        // Mesh frame -> A's asset frame: asset = R_a^T (tb * x - t_a) / s.
        to_asset_rotation_(pose_a.rotation.transpose() * to_eigen(tb.getBasis()) / pose_a.scale),
        to_asset_offset_(pose_a.rotation.transpose() * (to_eigen(tb.getOrigin()) - pose_a.translation) / pose_a.scale),
        rb_(to_eigen(tb.getBasis())),
        ob_(to_eigen(tb.getOrigin())) {
    a.getAabb(btTransform::getIdentity(), a_lo_, a_hi_);
  }

  void run() {
    corners().clear();
    ids().clear();
    if (!reuse_cache()) scan();
    in_voxelmap();
  }

 private:
  static std::vector<Eigen::Vector3d>& corners() {
    thread_local std::vector<Eigen::Vector3d> c;
    return c;
  }
  static std::vector<uint32_t>& ids() {
    thread_local std::vector<uint32_t> i;
    return i;
  }
  double lower_bound(const Eigen::Vector3f& x) const {
    return double(map_.distance_lower_bound(map_.to_grid(to_asset_rotation_ * x.cast<double>() + to_asset_offset_)));
  }
  bool in_a_box(const Eigen::Vector3f& x, double pad) const {
    const btVector3 q = a_from_b_ * btVector3(x.x(), x.y(), x.z());
    const btScalar p = btScalar(pad);
    return q.x() >= a_lo_.x() - p && q.y() >= a_lo_.y() - p && q.z() >= a_lo_.z() - p && q.x() <= a_hi_.x() + p &&
           q.y() <= a_hi_.y() + p && q.z() <= a_hi_.z() + p;
  }
  void take(const Eigen::Vector3f& v, uint32_t id) {
    if (!in_a_box(v, grow_) || !(lower_bound(v) < reach_)) return;
    corners().push_back(rb_ * v.cast<double>() + ob_);
    ids().push_back(id);
  }
  // A vertex's contact is numbered by the vertex (its id in the index), not by its place in this test's list,
  // which holds vertices out of reach too and differs between a kept list and a fresh scan.
  void in_voxelmap() {
    const size_t first = contacts_.contacts.size();
    runtime::query_points_in_voxelmap(a_.object(), pose_a_, corners().data(), corners().size(), 0.0, options_,
                                      contacts_);
    for (size_t i = first; i < contacts_.contacts.size(); ++i)
      contacts_.contacts[i].point_index = ids()[contacts_.contacts[i].point_index];
  }
  // The kept vertices, if the motion since the cache's anchor cannot have brought another within reach.
  bool reuse_cache() {
    if (!cache_ || !cache_->valid || cache_->to_voxels != to_voxels_) return false;
    // How far any vertex of the region can have moved relative to A since the anchor: |dR c + dt| + |dR| r.
    const Eigen::Matrix3d d_rotation = to_eigen(a_from_b_.getBasis()) - cache_->rotation;
    const double moved = (d_rotation * cache_->centre + to_eigen(a_from_b_.getOrigin()) - cache_->translation).norm() +
                         d_rotation.norm() * cache_->radius + 1e-6 * cache_->radius;
    // A vertex left out had a bound of at least `threshold` (or lay beyond the box grown by `pad`); A's distance is
    // not below a bound less the motion (as the traversal's pruning assumes), so it stays out of reach.
    if (!(reach_ + moved * to_voxels_ <= cache_->threshold && grow_ + moved <= cache_->pad)) return false;
    for (const uint32_t id : cache_->vertices) take(mesh_.vertex(id), id);
    return true;
  }
  void scan() {
    // The slack: 4 voxels of A (a body at rest keeps its vertices for good, one sliding at 1 m/s for a step or two).
    const double slack = cache_ ? 4.0 / to_voxels_ : 0.0;
    const double pad = grow_ + slack, threshold = reach_ + slack * to_voxels_;
    const btTransform b_from_a = a_from_b_.inverse();
    Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::infinity()), hi = -lo;
    for (int k = 0; k < 8; ++k) {
      const btVector3 corner = b_from_a * btVector3((k & 1) ? a_hi_.x() + btScalar(pad) : a_lo_.x() - btScalar(pad),
                                                    (k & 2) ? a_hi_.y() + btScalar(pad) : a_lo_.y() - btScalar(pad),
                                                    (k & 4) ? a_hi_.z() + btScalar(pad) : a_lo_.z() - btScalar(pad));
      const Eigen::Vector3f c(float(corner.x()), float(corner.y()), float(corner.z()));
      lo = lo.cwiseMin(c);
      hi = hi.cwiseMax(c);
    }
    if (cache_) cache_->vertices.clear();
    mesh_.vertices_in_box(
        lo, hi,
        [&](const Eigen::Vector3f& centre, float radius) {
          return in_a_box(centre, double(radius) + pad) &&
                 lower_bound(centre) <= double(radius) * to_voxels_ + threshold;
        },
        [&](const Eigen::Vector3f& v, uint32_t id) {
          if (!cache_) return take(v, id);
          if (!in_a_box(v, pad) || !(lower_bound(v) < threshold)) return;
          cache_->vertices.push_back(id);
          take(v, id);
        });
    if (!cache_) return;
    cache_->valid = true;
    cache_->rotation = to_eigen(a_from_b_.getBasis());
    cache_->translation = to_eigen(a_from_b_.getOrigin());
    cache_->centre = 0.5 * (lo + hi).cast<double>();
    cache_->radius = 0.5 * double((hi - lo).norm());
    cache_->to_voxels = to_voxels_;
    cache_->threshold = threshold;
    cache_->pad = pad;
  }

  const VpsShape& a_;
  const runtime::Pose& pose_a_;
  const StaticMeshIndex& mesh_;
  const runtime::QueryOptions& options_;
  runtime::ContactSet& contacts_;
  VertexCache* cache_;
  const btTransform a_from_b_;
  const runtime::SparseVoxelmap& map_;
  const double grow_, to_voxels_, reach_;
  const Eigen::Matrix3d to_asset_rotation_;
  const Eigen::Vector3d to_asset_offset_;
  const Eigen::Matrix3d rb_;
  const Eigen::Vector3d ob_;
  btVector3 a_lo_, a_hi_;
};

// A's points against a static mesh's index (which holds the whole mesh in its shape frame, so nothing is gathered
// per query), coherently with the pair's front when there is one; and the mesh's vertices near A in A's voxelmap.
void collide_indexed(const VpsShape& a, const runtime::Pose& pose_a, const btTransform& ta, const StaticMeshIndex& mesh,
                     const btTransform& tb, const runtime::QueryOptions& options, runtime::ContactSet& contacts,
                     runtime::QueryScratch& scratch, runtime::TraversalFront* front, VertexCache* cache) {
  if (mesh.empty()) return;
  if (a.uses_points()) {
    // The mesh's frame: x_b = R^T (x - t).
    const Eigen::Matrix3f rt = to_eigen(tb.getBasis()).transpose().cast<float>();
    const Eigen::Vector3f t = to_eigen(tb.getOrigin()).cast<float>();
    const float proximity = float(options.proximity);
    auto distance = [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
      Eigen::Vector3f n;
      const float d = mesh.distance(rt * (x - t), proximity, n);
      outward = rt.transpose() * n;
      return d;
    };
    MeshBound bound{mesh, rt, t, proximity};
    if (front)
      runtime::query_against_function(a.object(), pose_a, partner_pose(tb), distance, bound, options, contacts, scratch,
                                      *front);
    else
      runtime::query_against_function(a.object(), pose_a, distance, bound, options, contacts, scratch);
  }
  if (a.uses_voxelmap()) MeshVerticesInVoxelmap(a, pose_a, ta, mesh, tb, options, contacts, cache).run();
}

/// What a pair keeps between its tests: the traversal fronts (CollisionSettings::coherent) and its static mesh's
/// index (CollisionSettings::static_mesh_index).
struct PairState {
  runtime::QueryState query;
  std::shared_ptr<const StaticMeshIndex> mesh;
  uint64_t mesh_generation = 0;
  VertexCache vertices;
  void reset() {
    query.reset();
    vertices.valid = false;
  }
};

/// Contacts of a VPS shape (A) with any supported partner (B), reduced and fed to a persistent manifold
/// created as (A, B): normals are "on B" and points on B's surface, whatever order Bullet calls us in.
class VpsCollisionAlgorithm : public btCollisionAlgorithm {
 public:
  VpsCollisionAlgorithm(const btCollisionAlgorithmConstructionInfo& ci, const btCollisionObjectWrapper* body0,
                        const btCollisionObjectWrapper* body1, bool swapped, Shared& shared)
      : btCollisionAlgorithm(ci), manifold_(ci.m_manifold), swapped_(swapped), shared_(&shared) {
    const btCollisionObjectWrapper* a = swapped_ ? body1 : body0;
    const btCollisionObjectWrapper* b = swapped_ ? body0 : body1;
    if (!manifold_ && m_dispatcher->needsCollision(a->getCollisionObject(), b->getCollisionObject())) {
      manifold_ = m_dispatcher->getNewManifold(a->getCollisionObject(), b->getCollisionObject());
      owns_manifold_ = true;
    }
  }

  ~VpsCollisionAlgorithm() override {
    if (owns_manifold_ && manifold_) m_dispatcher->releaseManifold(manifold_);
    for (btPersistentManifold* m : extra_)
      if (m) m_dispatcher->releaseManifold(m);
  }

  void processCollision(const btCollisionObjectWrapper* body0, const btCollisionObjectWrapper* body1,
                        const btDispatcherInfo& info, btManifoldResult* result) override {
    if (!manifold_) return;
    const btCollisionObjectWrapper* a_wrap = swapped_ ? body1 : body0;
    const btCollisionObjectWrapper* b_wrap = swapped_ ? body0 : body1;
    const auto* a_shape = static_cast<const VpsShape*>(a_wrap->getCollisionShape());
    const runtime::Pose pose_a = a_shape->asset_pose(a_wrap->getWorldTransform());
    const CollisionSettings& settings = shared_->settings;
    const runtime::QueryOptions options = query_options(*a_shape, a_wrap, b_wrap, info, *result);
    const bool budgeted = settings.step_time_budget_us > 0.0;
    const auto start = budgeted ? std::chrono::steady_clock::now() : std::chrono::steady_clock::time_point{};
    thread_local runtime::ContactSet contacts;
    thread_local runtime::QueryScratch scratch;
    contacts.clear();
    if (!state_) state_ = std::make_unique<PairState>();
    if (!settings.coherent) state_->reset();
    const bool cut = collide(*a_shape, a_wrap->getWorldTransform(), pose_a, b_wrap, options, contacts, scratch,
                             settings.coherent ? &state_->query : nullptr);
    if (budgeted)
      shared_->step_ns.fetch_add(
          std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count(),
          std::memory_order_relaxed);
    if (settings.on_contacts)
      settings.on_contacts(a_wrap->getCollisionObject(), b_wrap->getCollisionObject(), contacts);
    result->setPersistentManifold(manifold_);
    CollisionCounters& counters = shared_->counters;  // atomic: pairs may run on several threads at once
    ++counters.pair_tests;
    counters.raw_contacts += contacts.contacts.size();
    counters.points_tested += contacts.stats.points_tested;
    counters.nodes_visited += contacts.stats.nodes_visited;
    if (cut) ++counters.budget_cuts;
    const size_t regions = owns_manifold_ ? std::clamp<size_t>(settings.contact_regions, 1, kMaxRegions) : 1;
    if (regions == 1) {
      add_to_manifold(contacts.contacts, manifold_, *result);
      if (owns_manifold_) result->refreshContactPoints();
      return;
    }
    add_by_region(contacts.contacts, *a_shape, pose_a, regions, a_wrap, b_wrap, *result);
  }

 private:
  // The pair's query: the settings', with the largest proximity any of its parts asks for (the settings, Bullet's
  // closest-point threshold, either shape's, and the speculative distance of this step).
  runtime::QueryOptions query_options(const VpsShape& a_shape, const btCollisionObjectWrapper* a_wrap,
                                      const btCollisionObjectWrapper* b_wrap, const btDispatcherInfo& info,
                                      const btManifoldResult& result) const {
    const CollisionSettings& settings = shared_->settings;
    runtime::QueryOptions options = settings.query;
    options.proximity =
        std::max({options.proximity, double(result.m_closestPointDistanceThreshold), a_shape.proximity()});
    if (b_wrap->getCollisionShape()->getShapeType() == VpsShape::kShapeType)
      options.proximity =
          std::max(options.proximity, static_cast<const VpsShape*>(b_wrap->getCollisionShape())->proximity());
    if (settings.speculative_contacts)
      options.proximity = std::max(options.proximity, speculative_distance(a_wrap, b_wrap, info.m_timeStep));
    return options;
  }

  // Up to the settings' manifold points of `set` into `manifold`.
  void add_to_manifold(const std::vector<runtime::Contact>& set, btPersistentManifold* manifold,
                       btManifoldResult& result) const {
    const runtime::ReducedContacts chosen = runtime::reduce_contacts(set, shared_->settings.manifold_points);
    std::array<btVector3, 4> on_b;
    for (size_t i = 0; i < chosen.size(); ++i) {
      const runtime::Contact& c = set[chosen.index[i]];
      // Bullet: pointOnB + normalOnB * distance = pointOnA, distance < 0 when penetrating.
      on_b[i] = to_bt_vector(c.point_of_b ? c.point : c.point + c.normal * c.depth);
    }
    // Points of earlier steps that none of this step's is near (Bullet matches them within its breaking threshold)
    // are gone: kept, a stale point holds a body where it was (a peg on a hole's rim climbed out).
    const btScalar near2 = manifold->getContactBreakingThreshold() * manifold->getContactBreakingThreshold();
    for (int p = manifold->getNumContacts() - 1; p >= 0; --p) {
      bool matched = false;
      for (size_t i = 0; i < chosen.size() && !matched; ++i)
        matched = (manifold->getContactPoint(p).m_positionWorldOnB - on_b[i]).length2() <= near2;
      if (!matched) manifold->removeContactPoint(p);
    }
    for (size_t i = 0; i < chosen.size(); ++i) {
      const runtime::Contact& c = set[chosen.index[i]];
      result.addContactPoint(to_bt_vector(c.normal), on_b[i], btScalar(-c.depth));
    }
  }

  // Each contact's region: its cell in A's asset frame (cells as wide as A's bounding radius, fixed to A, so a
  // contact keeps its region from step to step), folded onto the manifolds; each region keeps its own points.
  void add_by_region(const std::vector<runtime::Contact>& set, const VpsShape& a_shape, const runtime::Pose& pose_a,
                     size_t regions, const btCollisionObjectWrapper* a_wrap, const btCollisionObjectWrapper* b_wrap,
                     btManifoldResult& result) {
    thread_local std::array<std::vector<runtime::Contact>, kMaxRegions> groups;
    for (auto& g : groups) g.clear();
    const double cell = a_shape.object().bounding_radius() * pose_a.scale;
    for (const runtime::Contact& c : set) {
      const Eigen::Vector3d local = pose_a.rotation.transpose() * (c.point - pose_a.translation) / cell;
      const auto key = [](double x) { return uint64_t(int64_t(std::floor(x))); };
      const uint64_t hash = key(local.x()) * 73856093u ^ key(local.y()) * 19349663u ^ key(local.z()) * 83492791u;
      groups[hash % regions].push_back(c);
    }
    for (size_t k = 0; k < regions; ++k) {
      btPersistentManifold*& manifold = k == 0 ? manifold_ : extra_[k - 1];
      if (!manifold) {
        if (groups[k].empty()) continue;
        manifold = m_dispatcher->getNewManifold(a_wrap->getCollisionObject(), b_wrap->getCollisionObject());
      }
      result.setPersistentManifold(manifold);
      add_to_manifold(groups[k], manifold, result);
      result.refreshContactPoints();
    }
  }

 public:
  /// How far the pair can close in one step: the relative speed of the centres plus each body's spin times its
  /// bounding radius, times the step (0 outside a dynamics step). Points within it become speculative contacts,
  /// which Bullet's solver lets close only that gap: nothing passes through a thin wall in one step.
  static double speculative_distance(const btCollisionObjectWrapper* a, const btCollisionObjectWrapper* b,
                                     btScalar time_step) {
    if (!(time_step > 0)) return 0.0;
    double speed = 0.0;
    btVector3 relative(0, 0, 0);
    for (const btCollisionObjectWrapper* wrap : {a, b}) {
      const btRigidBody* body = btRigidBody::upcast(wrap->getCollisionObject());
      if (!body) continue;
      const btVector3 linear = body->getLinearVelocity();
      relative = wrap == a ? linear : relative - linear;
      const double spin = double(body->getAngularVelocity().length());
      if (spin == 0.0) continue;  // static and resting bodies: no bounding sphere needed
      btVector3 centre;
      btScalar radius = 0;
      wrap->getCollisionShape()->getBoundingSphere(centre, radius);
      speed += spin * double(radius + centre.length());
    }
    speed += double(relative.length());
    return speed * double(time_step);
  }

  btScalar calculateTimeOfImpact(btCollisionObject*, btCollisionObject*, const btDispatcherInfo&,
                                 btManifoldResult*) override {
    return btScalar(1);
  }

  void getAllContactManifolds(btManifoldArray& manifolds) override {
    if (manifold_ && owns_manifold_) manifolds.push_back(manifold_);
    for (btPersistentManifold* m : extra_)
      if (m) manifolds.push_back(m);
  }

 private:
  // Everything a partner kind's handler needs of one pair test.
  struct PartnerTest {
    const VpsCollisionAlgorithm& algorithm;
    const VpsShape& a;
    const btTransform& ta;
    const runtime::Pose& pose_a;
    const btCollisionShape& b;
    const btTransform& tb;
    const runtime::QueryOptions& options;
    runtime::ContactSet& contacts;
    runtime::QueryScratch& scratch;
    runtime::QueryState* state;
    runtime::TraversalFront* front() const { return state ? &state->a_in_b : nullptr; }
    ConvexPair convex() const { return ConvexPair{a, pose_a, tb, options, contacts, scratch, front()}; }
  };
  using PartnerHandler = void (*)(const PartnerTest&);

  // One handler per partner kind that has one (Bullet's shape type), filled once. VPS pairs come before the table
  // (both bodies are shells), and convex kinds without a handler of their own after it (GJK and EPA).
  static const std::array<PartnerHandler, MAX_BROADPHASE_COLLISION_TYPES>& partner_handlers() {
    static const std::array<PartnerHandler, MAX_BROADPHASE_COLLISION_TYPES> table = [] {
      std::array<PartnerHandler, MAX_BROADPHASE_COLLISION_TYPES> t{};
      t[STATIC_PLANE_PROXYTYPE] = [](const PartnerTest& p) {
        if (!p.a.uses_points()) return;
        const auto& plane = static_cast<const btStaticPlaneShape&>(p.b);
        const Eigen::Vector3f n = (to_eigen(p.tb.getBasis()) * to_eigen(plane.getPlaneNormal())).cast<float>();
        const float c = float(plane.getPlaneConstant()) + n.dot(to_eigen(p.tb.getOrigin()).cast<float>());
        points_against(
            p.a, p.pose_a, partner_pose(p.tb),
            [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return plane_distance(n, c, x, outward); },
            p.options, p.contacts, p.scratch, p.front());
      };
      t[TRIANGLE_MESH_SHAPE_PROXYTYPE] = t[SCALED_TRIANGLE_MESH_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        const auto& concave = static_cast<const btConcaveShape&>(p.b);
        if (!p.algorithm.shared_->settings.static_mesh_index)
          return collide_concave(p.a, p.pose_a, p.ta, concave, p.tb, p.options, p.contacts, p.scratch);
        collide_indexed(p.a, p.pose_a, p.ta, p.algorithm.mesh_index(concave), p.tb, p.options, p.contacts, p.scratch,
                        p.front(), p.state ? &p.algorithm.state_->vertices : nullptr);
      };
      t[TERRAIN_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_concave(p.a, p.pose_a, p.ta, static_cast<const btConcaveShape&>(p.b), p.tb, p.options, p.contacts,
                        p.scratch);
      };
      t[BOX_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_box(p.convex(), static_cast<const btBoxShape&>(p.b));
      };
      t[SPHERE_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_sphere(p.convex(), static_cast<const btSphereShape&>(p.b));
      };
      t[CAPSULE_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_capsule(p.convex(), static_cast<const btCapsuleShape&>(p.b));
      };
      t[CYLINDER_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_cylinder(p.convex(), static_cast<const btCylinderShape&>(p.b));
      };
      t[MULTI_SPHERE_SHAPE_PROXYTYPE] = [](const PartnerTest& p) {
        collide_multi_sphere(p.convex(), static_cast<const btMultiSphereShape&>(p.b));
      };
      return t;
    }();
    return table;
  }

  /// Returns whether the step time budget cut a shell above its leaves.
  bool collide(const VpsShape& a, const btTransform& ta, const runtime::Pose& pose_a,
               const btCollisionObjectWrapper* b_wrap, runtime::QueryOptions options, runtime::ContactSet& contacts,
               runtime::QueryScratch& scratch, runtime::QueryState* state) const {
    const btCollisionShape& b = *b_wrap->getCollisionShape();
    const btTransform& tb = b_wrap->getWorldTransform();
    bool cut = false;
    limit_to(a, options, cut);
    if (b.getShapeType() == VpsShape::kShapeType) {
      collide_vps(a, pose_a, static_cast<const VpsShape&>(b), tb, options, cut, contacts, scratch, state);
      return cut;
    }
    const PartnerTest test{*this, a, ta, pose_a, b, tb, options, contacts, scratch, state};
    const int type = b.getShapeType();
    if (type >= 0 && type < MAX_BROADPHASE_COLLISION_TYPES && partner_handlers()[size_t(type)])
      partner_handlers()[size_t(type)](test);
    else if (b.isPolyhedral())
      collide_polyhedron(test.convex(), static_cast<const btPolyhedralConvexShape&>(b));
    else if (b.isConvex())
      collide_curved_convex(test.convex(), static_cast<const btConvexShape&>(b));
    else
      shared_->report_unsupported(&b);
    return cut;
  }

  // A shell's limits: the settings' query's, and on top its shape's own or else the step budget's level cap, which
  // always leaves the levels within step_budget_min_points (then `cut`). The tighter limit wins.
  void limit_to(const VpsShape& shell, runtime::QueryOptions& options, bool& cut) const {
    const runtime::QueryOptions& query = shared_->settings.query;
    options.point_budget = std::min(query.point_budget, shell.point_budget());
    options.min_points = query.min_points;
    uint32_t level = shell.max_level();
    if (shell.max_level() == std::numeric_limits<uint32_t>::max() &&
        shell.point_budget() == std::numeric_limits<size_t>::max()) {
      level = shared_->level_cap(shell.object().point_tree());
      if (level != std::numeric_limits<uint32_t>::max()) {
        cut = true;
        options.min_points = std::max(options.min_points, shared_->settings.step_budget_min_points);
      }
    }
    options.max_level = std::min(query.max_level, level);
  }

  // Two VPS bodies: the direction the settings ask (Auto: the runtime's choice), each way with its shell's limits.
  void collide_vps(const VpsShape& a, const runtime::Pose& pose_a, const VpsShape& b, const btTransform& tb,
                   runtime::QueryOptions options, bool& cut, runtime::ContactSet& contacts,
                   runtime::QueryScratch& scratch, runtime::QueryState* state) const {
    const runtime::Pose pose_b = b.asset_pose(tb);
    const bool a_in_b = a.uses_points() && b.uses_voxelmap();
    const bool b_in_a = b.uses_points() && a.uses_voxelmap();
    runtime::QueryDirection direction = shared_->settings.query.direction;
    if (direction == runtime::QueryDirection::Auto)
      direction = a_in_b && b_in_a
                      ? runtime::resolve_direction(a.object(), pose_a, b.object(), pose_b, direction)
                      : (a_in_b ? runtime::QueryDirection::APointsInB : runtime::QueryDirection::BPointsInA);
    auto query = [&](runtime::QueryDirection way, const VpsShape& shell) {
      options.direction = way;
      limit_to(shell, options, cut);
      if (state)
        runtime::query_contacts(a.object(), pose_a, b.object(), pose_b, options, contacts, scratch, *state);
      else
        runtime::query_contacts(a.object(), pose_a, b.object(), pose_b, options, contacts, scratch);
    };
    const bool both = direction == runtime::QueryDirection::Both;
    if (a_in_b && (both || direction == runtime::QueryDirection::APointsInB))
      query(runtime::QueryDirection::APointsInB, a);
    if (b_in_a && (both || direction == runtime::QueryDirection::BPointsInA))
      query(runtime::QueryDirection::BPointsInA, b);
  }

  static constexpr size_t kMaxRegions = 4;
  btPersistentManifold* manifold_;
  std::array<btPersistentManifold*, kMaxRegions - 1> extra_{};  ///< the other regions' manifolds, made on first use
  bool owns_manifold_ = false;
  bool swapped_;
  Shared* shared_;
  /// The pair's static mesh index, looked up in the shared cache when the pair has none or it is stale (the mesh
  /// changed, or was forgotten); a new index starts the fronts afresh (their bounds are of the old one).
  const StaticMeshIndex& mesh_index(const btConcaveShape& shape) const {
    PairState& state = *state_;
    const uint64_t generation = shared_->mesh_generation.load(std::memory_order_relaxed);
    if (!state.mesh || state.mesh_generation != generation || !(state.mesh->signature() == MeshSignature::of(shape))) {
      state.mesh = shared_->mesh_index(shape);
      state.mesh_generation = generation;
      state.reset();
    }
    return *state.mesh;
  }

  std::unique_ptr<PairState> state_;  ///< made on first use (a pointer: the algorithm lives in Bullet's pool)
};

// Bullet's pool slots are sized from its own algorithms; ours must not be larger (see prepare_construction_info).
static_assert(sizeof(VpsCollisionAlgorithm) <= 96, "keep the algorithm small: it lives in the dispatcher's pool");

class CreateFunc : public btCollisionAlgorithmCreateFunc {
 public:
  CreateFunc(Shared& shared, bool swapped) : shared_(shared) { m_swapped = swapped; }
  btCollisionAlgorithm* CreateCollisionAlgorithm(btCollisionAlgorithmConstructionInfo& ci,
                                                 const btCollisionObjectWrapper* body0,
                                                 const btCollisionObjectWrapper* body1) override {
    void* memory = ci.m_dispatcher1->allocateCollisionAlgorithm(sizeof(VpsCollisionAlgorithm));
    return new (memory) VpsCollisionAlgorithm(ci, body0, body1, m_swapped, shared_);
  }

 private:
  Shared& shared_;
};

class Registration : public VpsCollisionRegistration {
 public:
  Registration(btCollisionDispatcher& dispatcher, const CollisionSettings& settings)
      : direct_(shared_, false), swapped_(shared_, true) {
    shared_.settings = settings;
    const int vps = VpsShape::kShapeType;
    // Every partner type: convex shapes, planes, static meshes and terrains are handled; the rest report
    // themselves once. Compounds stay with Bullet's compound algorithm, which meets us child by child.
    for (int other = 0; other < MAX_BROADPHASE_COLLISION_TYPES; ++other) {
      if (other == COMPOUND_SHAPE_PROXYTYPE || other == EMPTY_SHAPE_PROXYTYPE || other == INVALID_SHAPE_PROXYTYPE)
        continue;
      // Simulation (contact) and closest-point (contactTest, compounds) tables, both orders.
      dispatcher.registerCollisionCreateFunc(vps, other, &direct_);
      dispatcher.registerClosestPointsCreateFunc(vps, other, &direct_);
      if (other != vps) {
        dispatcher.registerCollisionCreateFunc(other, vps, &swapped_);
        dispatcher.registerClosestPointsCreateFunc(other, vps, &swapped_);
      }
    }
  }
  CollisionSettings& settings() override { return shared_.settings; }
  CollisionCounters& counters() override { return shared_.counters; }
  void begin_step() override { shared_.begin_step(); }
  StaticMeshInfo prepare_static_mesh(const btCollisionShape& shape) override {
    const int type = shape.getShapeType();
    if (type != TRIANGLE_MESH_SHAPE_PROXYTYPE && type != SCALED_TRIANGLE_MESH_SHAPE_PROXYTYPE) return {};
    const std::shared_ptr<const StaticMeshIndex> index = shared_.mesh_index(static_cast<const btConcaveShape&>(shape));
    const StaticMeshIndex::Info& built = index->info();
    StaticMeshInfo info;
    info.triangles = built.triangles;
    info.vertices = built.vertices;
    info.cells = built.cells;
    info.memory_bytes = built.memory_bytes;
    info.build_seconds = built.build_seconds;
    return info;
  }
  void forget_static_mesh(const btCollisionShape& shape) override { shared_.forget_mesh(shape); }

 private:
  Shared shared_;
  CreateFunc direct_;
  CreateFunc swapped_;
};

}  // namespace

runtime::QueryOptions physics_query_defaults() {
  runtime::QueryOptions query;
  query.cut_level = runtime::CutLevel::Points;
  return query;
}

std::unique_ptr<VpsCollisionRegistration> register_vps_collision(btCollisionDispatcher& dispatcher,
                                                                 const CollisionSettings& settings) {
  return std::make_unique<Registration>(dispatcher, settings);
}

void prepare_construction_info(btDefaultCollisionConstructionInfo& info) {
  info.m_customCollisionAlgorithmMaxElementSize =
      std::max(info.m_customCollisionAlgorithmMaxElementSize, int(sizeof(VpsCollisionAlgorithm)));
}

}  // namespace voxfmt::bullet
