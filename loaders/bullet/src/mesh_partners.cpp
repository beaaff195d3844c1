// A VPS shape against static meshes and terrain (partner_pairs.h): the triangles Bullet hands over near A, or a
// mesh's own index built once; and the mesh's vertices near A in A's voxelmap.
#include <BulletCollision/CollisionShapes/btHeightfieldTerrainShape.h>
#include <BulletCollision/CollisionShapes/btTriangleCallback.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "partner_pairs.h"
#include "static_mesh.h"
#include "triangle_set.h"

namespace voxfmt::bullet::detail {

namespace {

// A's own box (its shape frame, grown by the reach) seen from a terrain's frame and swept up its axis: the terrain's
// triangles in the box or above any part of it, those a point of A lies under or near (a terrain is solid below; a
// buried point's nearest may lie beside the box, and is then missed: its depth comes out too large). Tested on the
// separating axes that do not depend on the triangle (the sweep's sides, then the box's faces): a few triangles near
// the box's edges pass that a full test would refuse, which costs a little search (a point's nearest is then looked for
// among more of the terrain), and the whole test costs less than the full one (measured: sliding 5 % faster than with
// the box tested in A's frame, which left out the triangles over a buried body; 8 % slower with the triangles' axes
// too).
struct SweptBox {
  struct Axis {
    btVector3 normal;
    btScalar lo, hi;  ///< the swept box's extent along the normal
  };
  Axis axes[6];
  int up_axis;

  SweptBox(const btTransform& terrain_from_a, const btVector3& a_lo, const btVector3& a_hi, int axis) : up_axis(axis) {
    const btVector3 centre = terrain_from_a * ((a_lo + a_hi) * btScalar(0.5));
    btVector3 up(0, 0, 0), half_axes[3];
    up[axis] = 1;
    for (int i = 0; i < 3; ++i)
      half_axes[i] = terrain_from_a.getBasis().getColumn(i) * ((a_hi[i] - a_lo[i]) * btScalar(0.5));
    // Along n the box spans its centre's projection plus or minus its radius, and the sweep reaches to infinity on
    // the side that rises.
    const auto along = [&](const btVector3& n) {
      btScalar radius = 0;
      for (const btVector3& h : half_axes) radius += btFabs(n.dot(h));
      const btScalar mid = n.dot(centre), rise = n.dot(up);
      return Axis{n, rise < 0 ? -SIMD_INFINITY : mid - radius, rise > 0 ? SIMD_INFINITY : mid + radius};
    };
    for (int i = 0; i < 3; ++i) {
      axes[i] = along(half_axes[i].cross(up));
      axes[3 + i] = along(half_axes[i]);
    }
  }
  /// Whether triangle t (terrain frame) may meet the swept box: no axis of `axes` separates them.
  bool meets(const btVector3* t) const {
    for (const Axis& axis : axes) {
      const btScalar p0 = axis.normal.dot(t[0]), p1 = axis.normal.dot(t[1]), p2 = axis.normal.dot(t[2]);
      if (std::min({p0, p1, p2}) > axis.hi || std::max({p0, p1, p2}) < axis.lo) return false;
    }
    return true;
  }
};

void add_in_world(TriangleSet& set, const btVector3& a, const btVector3& b, const btVector3& c) {
  auto eigen = [](const btVector3& w) { return Eigen::Vector3f(float(w.x()), float(w.y()), float(w.z())); };
  set.add(eigen(a), eigen(b), eigen(c));
}

// Collects, in world coordinates, a static mesh's triangles that overlap A's own box (A's shape frame, grown by the
// reach): Bullet hands over everything in the world-aligned box around A, which for a rotated body holds several
// times more.
class MeshCollector : public btTriangleCallback {
 public:
  MeshCollector(TriangleSet& set, const btTransform& world_from_shape, const btTransform& a_from_world,
                const btVector3& a_lo, const btVector3& a_hi, bool mirrored)
      : set_(set),
        world_from_shape_(world_from_shape),
        a_from_world_(a_from_world),
        a_lo_(a_lo),
        a_hi_(a_hi),
        mirrored_(mirrored) {}
  void processTriangle(btVector3* triangle, int, int) override {
    const btVector3 a = world_from_shape_ * triangle[0], b = world_from_shape_ * triangle[1],
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
    if (mirrored_)  // turned over by a mirroring scale: turned back (StaticMeshIndex::build does the same)
      add_in_world(set_, a, c, b);
    else
      add_in_world(set_, a, b, c);
  }

 private:
  TriangleSet& set_;
  const btTransform& world_from_shape_;
  btTransform a_from_world_;
  btVector3 a_lo_, a_hi_;
  bool mirrored_;
};

// Collects, in world coordinates, a terrain's triangles that may meet A's box swept up its axis (SweptBox),
// oriented to face up it (a terrain's inside is below it), whatever order the grid gives them in.
class TerrainCollector : public btTriangleCallback {
 public:
  TerrainCollector(TriangleSet& set, const btTransform& world_from_shape, const SweptBox& swept)
      : set_(set), world_from_shape_(world_from_shape), swept_(swept) {}
  void processTriangle(btVector3* triangle, int, int) override {
    if (!swept_.meets(triangle)) return;
    const btVector3 a = world_from_shape_ * triangle[0], b = world_from_shape_ * triangle[1],
                    c = world_from_shape_ * triangle[2];
    if ((triangle[1] - triangle[0]).cross(triangle[2] - triangle[0])[swept_.up_axis] < 0)
      add_in_world(set_, a, c, b);
    else
      add_in_world(set_, a, b, c);
  }

 private:
  TriangleSet& set_;
  const btTransform& world_from_shape_;
  const SweptBox& swept_;
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

// Into `gathered` (world coordinates), the triangles of B that A, its box grown by `grow`, may meet: a static
// mesh's that overlap A's box, a terrain's that meet it swept up the terrain's axis (a terrain is solid below).
void gather(const VpsShape& a, const btTransform& ta, const btConcaveShape& b, const btTransform& tb, btScalar grow,
            TriangleSet& gathered) {
  btVector3 lo, hi;
  a.getAabb(ta, lo, hi);
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
  gathered.clear();
  const bool terrain = b.getShapeType() == TERRAIN_SHAPE_PROXYTYPE;
  gathered.set_solid_below(terrain);
  btVector3 a_lo, a_hi;  // A's box in its own frame
  a.getAabb(btTransform::getIdentity(), a_lo, a_hi);
  a_lo -= btVector3(grow, grow, grow);
  a_hi += btVector3(grow, grow, grow);
  if (terrain) {
    // Every triangle over the body too: Bullet's terrain passes over those above the box it is given (however high:
    // heights may be changed in place beyond the declared range, and the range's top rounds).
    const int up = static_cast<const btHeightfieldTerrainShape&>(b).getUpAxis();
    local_hi[up] = BT_LARGE_FLOAT;
    const SweptBox swept(shape_from_world * ta, a_lo, a_hi, up);
    TerrainCollector collect(gathered, tb, swept);
    b.processAllTriangles(&collect, local_lo, local_hi);
  } else {
    MeshCollector collect(gathered, tb, ta.inverse(), a_lo, a_hi, mirrors(b.getLocalScaling()));
    b.processAllTriangles(&collect, local_lo, local_hi);
  }
}

}  // namespace

// A's points against the triangles of a static mesh or terrain near A (gather, its box grown by the proximity),
// signed by the triangles' sides, coherently while they are the pair's kept ones; and their corners in A's voxelmap.
void collide_concave(const VpsShape& a, const runtime::Pose& pose_a, const btTransform& ta, const btConcaveShape& b,
                     const btTransform& tb, const runtime::QueryOptions& options, runtime::ContactSet& contacts,
                     runtime::QueryScratch& scratch, TriangleSet* kept, runtime::TraversalFront* front) {
  thread_local TriangleSet gathered;
  gather(a, ta, b, tb, btScalar(options.proximity) + a.getMargin(), gathered);
  if (gathered.empty()) return;
  // The front holds while the triangles are the very ones it was made with. Others replace the kept ones (copied:
  // a pair's buffers grow to its own largest set only) and this test queries from the root, as without a front.
  bool same = false;
  if (kept && front) {
    same = kept->same_triangles(gathered);
    if (!same) {
      *kept = gathered;
      kept->build();
      front->reset();
    }
  } else {
    gathered.build();
  }
  const TriangleSet& triangles = kept && front ? *kept : gathered;
  auto distance = [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) { return triangles.distance(x, outward); };
  auto bound = [&](const Eigen::Vector3f& x) { return triangles.lower_bound(x); };
  if (a.uses_points() && same)  // the triangles are in world coordinates: the partner's pose is the identity
    runtime::query_against_function(a.object(), pose_a, runtime::Pose{}, distance, bound, options, contacts, scratch,
                                    *front);
  else if (a.uses_points())
    runtime::query_against_function(a.object(), pose_a, distance, bound, options, contacts, scratch);
  if (a.uses_voxelmap()) {
    thread_local std::vector<Eigen::Vector3d> corners;
    corners_within_reach(a.object(), pose_a, triangles, options.proximity, corners);
    runtime::query_points_in_voxelmap(a.object(), pose_a, corners.data(), corners.size(), 0.0, options, contacts);
  }
}

namespace {

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

}  // namespace

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

}  // namespace voxfmt::bullet::detail
