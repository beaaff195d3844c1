#include "methods.h"

#include <BulletCollision/CollisionDispatch/btCollisionObjectWrapper.h>
#include <BulletCollision/Gimpact/btGImpactCollisionAlgorithm.h>
#include <BulletCollision/Gimpact/btGImpactShape.h>
#include <btBulletDynamicsCommon.h>
#include <fcl/narrowphase/collision.h>

#include <algorithm>
#include <filesystem>
#include <iomanip>
#include <sstream>
#include <stdexcept>

#include "../common/hacd_cache.h"
#include "../common/reduced_hull.h"
#include "traversal/field_simd.h"
#include "voxfmt/bullet/collision.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/bullet/world.h"

namespace vps_bench {
namespace {

using voxfmt::bullet::VpsMixedShape;

btTransform to_bt(const Eigen::Isometry3d& pose) {
  const Eigen::Matrix3d& r = pose.linear();
  const Eigen::Vector3d& t = pose.translation();
  return btTransform(
      btMatrix3x3(btScalar(r(0, 0)), btScalar(r(0, 1)), btScalar(r(0, 2)), btScalar(r(1, 0)), btScalar(r(1, 1)),
                  btScalar(r(1, 2)), btScalar(r(2, 0)), btScalar(r(2, 1)), btScalar(r(2, 2))),
      btVector3(btScalar(t.x()), btScalar(t.y()), btScalar(t.z())));
}

/// Bullet's triangle arrays for a mesh (the arrays must outlive the shapes that use them).
struct BulletMesh {
  std::vector<btVector3> vertices;
  std::vector<int> indices;
  std::unique_ptr<btTriangleIndexVertexArray> array;

  explicit BulletMesh(const Mesh& mesh) {
    for (const auto& v : mesh.vertices) vertices.emplace_back(btScalar(v.x()), btScalar(v.y()), btScalar(v.z()));
    for (const auto& t : mesh.triangles) indices.insert(indices.end(), t.begin(), t.end());
    array = std::make_unique<btTriangleIndexVertexArray>(int(indices.size() / 3), indices.data(), 3 * sizeof(int),
                                                         int(vertices.size()), &vertices[0][0], sizeof(btVector3));
  }
};

/// Counts the contact points the manifold accepts and keeps the deepest (Bullet: distance < 0 penetrates).
class CountingResult : public btManifoldResult {
 public:
  using btManifoldResult::btManifoldResult;
  size_t contacts = 0;
  double deepest = -1e30;
  void addContactPoint(const btVector3& normal, const btVector3& point, btScalar distance) override {
    if (m_manifoldPtr && distance > m_manifoldPtr->getContactBreakingThreshold()) return;
    ++contacts;
    deepest = std::max(deepest, -double(distance));
    btManifoldResult::addContactPoint(normal, point, distance);
  }
};

/// Any pair of Bullet shapes through the dispatcher's algorithm for them (VPS and GImpact registered), as a
/// Bullet world's narrow phase calls it.
class BulletMethod : public Method {
 public:
  /// `coherent`: VPS pairs keep their last traversal from query to query (CollisionSettings::coherent).
  BulletMethod(std::shared_ptr<btCollisionShape> a, std::shared_ptr<btCollisionShape> b, std::string note,
               bool coherent = false, voxfmt::runtime::CutLevel cut_level = voxfmt::runtime::CutLevel::Spheres)
      : a_shape_(std::move(a)), b_shape_(std::move(b)), note_(std::move(note)) {
    btDefaultCollisionConstructionInfo info;
    voxfmt::bullet::prepare_construction_info(info);
    config_ = std::make_unique<btDefaultCollisionConfiguration>(info);
    dispatcher_ = std::make_unique<btCollisionDispatcher>(config_.get());
    vps_ = voxfmt::bullet::register_vps_collision(*dispatcher_);
    vps_->settings().coherent = coherent;
    // A detection benchmark: a cut level's points stand for their spheres, so vps-coarse finds every contact
    // the full tree finds (dynamics use the level's points, CollisionSettings::cut_level).
    vps_->settings().query.cut_level = cut_level;
    btGImpactCollisionAlgorithm::registerAlgorithm(dispatcher_.get());
    a_.setCollisionShape(a_shape_.get());
    b_.setCollisionShape(b_shape_.get());
    btCollisionObjectWrapper wa(nullptr, a_shape_.get(), &a_, a_.getWorldTransform(), -1, -1);
    btCollisionObjectWrapper wb(nullptr, b_shape_.get(), &b_, b_.getWorldTransform(), -1, -1);
    algorithm_ = dispatcher_->findAlgorithm(&wa, &wb, nullptr, BT_CONTACT_POINT_ALGORITHMS);
    if (!algorithm_) throw std::runtime_error("Bullet has no algorithm for this pair");
    // A static mesh is indexed as a world indexes it when the mesh is added, before any query is timed.
    if (a_shape_->getShapeType() == voxfmt::bullet::VpsShape::kShapeType &&
        b_shape_->getShapeType() == TRIANGLE_MESH_SHAPE_PROXYTYPE && vps_->settings().static_mesh_index) {
      const voxfmt::bullet::StaticMeshInfo mesh = vps_->prepare_static_mesh(*b_shape_);
      std::ostringstream index;
      index << std::setprecision(3) << "; mesh index " << double(mesh.memory_bytes) / 1e6 << " MB, built in "
            << mesh.build_seconds * 1e3 << " ms";
      note_ += index.str();
    }
  }
  ~BulletMethod() override {
    algorithm_->~btCollisionAlgorithm();
    dispatcher_->freeCollisionAlgorithm(algorithm_);
  }

  void query(const PosePair& pose) override {
    a_.setWorldTransform(to_bt(pose.a));
    b_.setWorldTransform(to_bt(pose.b) * b_offset_);
    btCollisionObjectWrapper wa(nullptr, a_shape_.get(), &a_, a_.getWorldTransform(), -1, -1);
    btCollisionObjectWrapper wb(nullptr, b_shape_.get(), &b_, b_.getWorldTransform(), -1, -1);
    result_.emplace(&wa, &wb);
    algorithm_->processCollision(&wa, &wb, dispatch_info_, &*result_);
  }

  QueryOutcome outcome() override {
    QueryOutcome out;
    out.contacts = result_->contacts;
    out.deepest = result_->deepest;
    voxfmt::bullet::CollisionCounters& counters = vps_->counters();
    if (counters.pair_tests > 0) {  // a VPS pair: the raw contacts before reduction to Bullet's 4
      out.contacts = counters.raw_contacts;
      out.nodes_visited = counters.nodes_visited;
      out.points_tested = counters.points_tested;
    }
    counters = {};
    // On a pose set, persistent manifolds would carry this pose's points into the next query.
    if (!keep_state_)
      for (int m = 0; m < dispatcher_->getNumManifolds(); ++m)
        dispatcher_->getManifoldByIndexInternal(m)->clearManifold();
    return out;
  }

  std::string note() const override { return note_; }
  void keep_state(bool keep) override {
    keep_state_ = keep;
    if (coherent_in_worlds_) vps_->settings().coherent = keep;
  }
  /// B's shape frame in B's pose frame (a VPS shape standing for a mesh: the asset's principal frame).
  void set_b_offset(const btTransform& offset) { b_offset_ = offset; }
  /// Coherent on trajectories, as in a world; from scratch on pose sets.
  void set_coherent_in_worlds() { coherent_in_worlds_ = true; }

 private:
  btTransform b_offset_ = btTransform::getIdentity();
  bool coherent_in_worlds_ = false;
  std::shared_ptr<btCollisionShape> a_shape_, b_shape_;
  std::string note_;
  std::unique_ptr<btDefaultCollisionConfiguration> config_;
  std::unique_ptr<btCollisionDispatcher> dispatcher_;
  std::unique_ptr<voxfmt::bullet::VpsCollisionRegistration> vps_;
  btCollisionObject a_, b_;
  btCollisionAlgorithm* algorithm_ = nullptr;
  btDispatcherInfo dispatch_info_;
  std::optional<CountingResult> result_;
  bool keep_state_ = false;
};

/// Shapes that live as long as the program (GImpact and BVH shapes keep pointers to the triangle arrays,
/// compounds to their children).
std::vector<std::shared_ptr<void>> keep_alive;

template <class T>
std::shared_ptr<T> keep(std::shared_ptr<T> p) {
  keep_alive.push_back(p);
  return p;
}

std::shared_ptr<btCollisionShape> hull_of(const std::vector<btVector3>& points, double margin) {
  auto shape = std::make_shared<btConvexHullShape>();
  for (const btVector3& p : points) shape->addPoint(p, false);
  shape->recalcLocalAabb();
  shape->setMargin(btScalar(margin));
  return shape;
}

/// The static partner of a scenario as a Bullet shape, for every Bullet-based method.
std::shared_ptr<btCollisionShape> static_partner(const Body& body, double margin) {
  switch (body.kind) {
    case Body::Kind::Plane: {
      auto plane = std::make_shared<btStaticPlaneShape>(btVector3(0, 1, 0), btScalar(0));
      plane->setMargin(btScalar(margin));
      return plane;
    }
    case Body::Kind::Box: {
      const Eigen::Vector3d& h = body.half_extents;
      auto box = std::make_shared<btBoxShape>(btVector3(btScalar(h.x()), btScalar(h.y()), btScalar(h.z())));
      box->setMargin(btScalar(margin));  // inside the extents for boxes
      return box;
    }
    case Body::Kind::StaticMesh: {
      auto mesh = keep(std::make_shared<BulletMesh>(body.mesh));
      auto shape = std::make_shared<btBvhTriangleMeshShape>(mesh->array.get(), true);
      shape->setMargin(btScalar(margin));
      return shape;
    }
    case Body::Kind::BakedMesh:
      break;
  }
  return nullptr;
}

std::string vps_note(const VpsMixedShape& shape) {
  const auto& tree = shape.object().point_tree();
  std::ostringstream note;
  if (shape.max_level() < tree.level_count())
    note << "levels 0-" << shape.max_level() << " (" << tree.points_up_to_level(shape.max_level()) << " of "
         << tree.size() << " points)";
  else
    note << tree.size() << " points";
  if (shape.proximity() > 0) note << ", proximity " << shape.proximity() * 1000 << " mm";
  return note.str();
}

std::unique_ptr<Method> vps_method(const std::string& name, const Scenario& s, const MethodSettings& settings) {
  auto make = [&](const Body& body) {
    auto shape = std::make_shared<VpsMixedShape>(body.vps);
    if (name == "vps-coarse") {
      const auto& tree = body.vps->point_tree();
      uint32_t level = 0;
      for (size_t l = 0; l < tree.level_count(); ++l)
        if (double(tree.points_up_to_level(l)) <= double(settings.coarse_points) * 1.25) level = uint32_t(l);
      shape->set_max_level(level);
    }
    if (name == "vps-fine-prox") shape->set_proximity(settings.margin);
    return shape;
  };
  auto a = make(*s.a);
  std::shared_ptr<btCollisionShape> b = s.b->kind == Body::Kind::BakedMesh
                                            ? std::shared_ptr<btCollisionShape>(make(*s.b))
                                            : static_partner(*s.b, settings.margin);
  const bool coherent = name == "vps-fine-coherent";
  return std::make_unique<BulletMethod>(a, b, vps_note(*a) + (coherent ? ", coherent" : ""), coherent);
}

/// vps-fine with the scalar lower-bound kernel (the runtime picks AVX2 where the CPU has it): the SIMD kernel's
/// gain, measured on the same poses (with --interleave, query by query).
class ScalarLookups : public Method {
 public:
  explicit ScalarLookups(std::unique_ptr<Method> inner) : inner_(std::move(inner)) {}
  void query(const PosePair& pose) override {
    namespace core = voxfmt::runtime::core;
    const core::SimdKernel chosen = core::simd_kernel();
    core::use_simd_kernel(core::SimdKernel::Scalar);
    inner_->query(pose);
    core::use_simd_kernel(chosen);
  }
  QueryOutcome outcome() override { return inner_->outcome(); }
  std::string note() const override { return inner_->note() + ", scalar lookups"; }
  void keep_state(bool keep) override { inner_->keep_state(keep); }

 private:
  std::unique_ptr<Method> inner_;
};

/// bunny-static-mesh's floor baked offline (baked_floor) as a voxelmap-only VPS shape; the bunny's points go
/// into it.
std::unique_ptr<Method> baked_floor_method(const Scenario& s, const MethodSettings& settings, std::string& why) {
  if (s.b->kind != Body::Kind::StaticMesh) {
    why = "only bunny-static-mesh has a mesh floor to bake";
    return nullptr;
  }
  const double voxel = settings.baked_floor_voxel > 0 ? settings.baked_floor_voxel : s.a->vps->voxelmap().voxel_size();
  const BakedFloor floor = baked_floor(settings.cache_dir, voxel);
  auto b = std::make_shared<voxfmt::bullet::VpsVoxelmapShape>(floor.object);
  auto a = std::make_shared<VpsMixedShape>(s.a->vps);
  std::ostringstream note;
  note << vps_note(*a) << "; floor baked offline as a " << floor.triangles << "-triangle slab at "
       << floor.voxel_size * 1e3 << " mm voxels: " << std::setprecision(3) << floor.bake_s << " s, peak "
       << floor.bake_peak_mb << " MB (the process), " << floor.runtime_mb << " MB in the runtime, " << floor.file_mb
       << " MB file; coherent on trajectories";
  auto method = std::make_unique<BulletMethod>(a, b, note.str());
  method->set_b_offset(b->asset_to_shape().inverse());
  method->set_coherent_in_worlds();
  return method;
}

std::shared_ptr<btCollisionShape> gimpact_of(const Body& body, double margin) {
  auto mesh = keep(std::make_shared<BulletMesh>(body.mesh));
  auto shape = std::make_shared<btGImpactMeshShape>(mesh->array.get());
  shape->setMargin(btScalar(margin));
  shape->updateBound();
  return shape;
}

std::string hacd_cache(const Body& body, const MethodSettings& settings) {
  return (std::filesystem::path(settings.cache_dir) / (body.name + ".hacd.txt")).string();
}

std::shared_ptr<btCollisionShape> hacd_of(const Body& body, const MethodSettings& settings, size_t& hull_count) {
  BulletMesh mesh(body.decomposition_mesh.triangles.empty() ? body.mesh : body.decomposition_mesh);
  double seconds = 0;
  const std::string cache = hacd_cache(body, settings);
  const voxfmt_bench::Hulls hulls = voxfmt_bench::hacd_decomposition(mesh.vertices, mesh.indices, cache, seconds);
  auto compound = std::make_shared<btCompoundShape>();
  for (const auto& hull : hulls) {
    auto child = keep(hull_of(hull, settings.margin));
    compound->addChildShape(btTransform::getIdentity(), child.get());
  }
  hull_count = hulls.size();
  return compound;
}

std::shared_ptr<btCollisionShape> reduced_hull_of(const Body& body, double margin, size_t& vertex_count) {
  const std::vector<btVector3> points = voxfmt_bench::reduced_hull_points(BulletMesh(body.mesh).vertices);
  vertex_count = points.size();
  return hull_of(points, margin);
}

// ------------------------------------------------------------------------------------------------ FCL

class FclMethod : public Method {
 public:
  FclMethod(std::shared_ptr<fcl::CollisionGeometryd> a, std::shared_ptr<fcl::CollisionGeometryd> b,
            const Eigen::Vector3d& b_offset, std::string note)
      : a_(std::move(a)), b_(std::move(b)), note_(std::move(note)) {
    b_offset_.translation() = b_offset;
    request_.num_max_contacts = 1000000;
    request_.enable_contact = true;
    // GJK: libccd (FCL's default). FCL's own solver (GST_INDEP) was slower here and its triangle-box depths
    // were wrong (0-10 % of penetrating poses reported as penetrating).
  }
  void query(const PosePair& pose) override {
    a_.setTransform(pose.a);
    b_.setTransform(pose.b * b_offset_);
    result_.clear();
    fcl::collide(&a_, &b_, request_, result_);
  }
  QueryOutcome outcome() override {
    QueryOutcome out;
    out.contacts = result_.numContacts();
    for (size_t i = 0; i < out.contacts; ++i)
      out.deepest = std::max(out.deepest, result_.getContact(i).penetration_depth);
    return out;
  }
  std::string note() const override { return note_; }

 private:
  fcl::CollisionObjectd a_, b_;
  fcl::Transform3d b_offset_ = fcl::Transform3d::Identity();
  fcl::CollisionRequestd request_;
  fcl::CollisionResultd result_;
  std::string note_;
};

std::shared_ptr<fcl::CollisionGeometryd> fcl_geometry(const Body& body) {
  switch (body.kind) {
    case Body::Kind::Plane:  // a 20 x 1 x 20 m box under y = 0 (see make_method)
      return std::make_shared<fcl::Boxd>(20.0, 1.0, 20.0);
    case Body::Kind::Box:
      return std::make_shared<fcl::Boxd>(2 * body.half_extents);
    case Body::Kind::BakedMesh:
    case Body::Kind::StaticMesh:
      return fcl_mesh(body.mesh);
  }
  return nullptr;
}

}  // namespace

const std::vector<std::string>& method_names() {
  static const std::vector<std::string> names = {
      "vps-fine", "vps-fine-scalar", "vps-coarse", "vps-fine-prox", "vps-fine-baked-floor", "gimpact", "hacd", "hull",
      "fcl"};
  return names;
}

const std::vector<std::string>& trajectory_method_names() {
  static const std::vector<std::string> names = {
      "vps-fine", "vps-fine-coherent", "vps-fine-baked-floor", "gimpact", "hacd", "hull", "fcl"};
  return names;
}

namespace {

/// The unit direction A falls in: down onto a plane, box or floor, towards the centre of a baked B.
Eigen::Vector3d fall_direction(const Scenario& s, const PosePair& pose) {
  if (s.b->kind != Body::Kind::BakedMesh) return -Eigen::Vector3d::UnitY();
  const Eigen::Vector3d d = pose.b.translation() - pose.a.translation();
  return d.norm() > 0 ? Eigen::Vector3d(d.normalized()) : Eigen::Vector3d(-Eigen::Vector3d::UnitY());
}

Eigen::Isometry3d from_bt(const btTransform& t) {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) pose.linear()(r, c) = double(t.getBasis()[r][c]);
    pose.translation()[r] = double(t.getOrigin()[r]);
  }
  return pose;
}

}  // namespace

Trajectory simulated_drop(const Scenario& s, size_t steps, double margin) {
  if (s.poses.empty()) throw std::runtime_error("scenario " + s.name + " has no poses");
  PosePair start = s.poses.front();
  const Eigen::Vector3d down = fall_direction(s, start);
  start.a.translation() -= 0.01 * down;
  voxfmt::bullet::World world;
  world.dynamics().setGravity(
      btVector3(btScalar(9.81 * down.x()), btScalar(9.81 * down.y()), btScalar(9.81 * down.z())));
  std::shared_ptr<btCollisionShape> b =
      s.b->kind == Body::Kind::BakedMesh ? std::shared_ptr<btCollisionShape>(std::make_shared<VpsMixedShape>(s.b->vps))
                                         : static_partner(*s.b, margin);
  world.add_body(b, 0, to_bt(start.b));
  btRigidBody* a = world.add_body(std::make_shared<VpsMixedShape>(s.a->vps), 1, to_bt(start.a));
  a->setFriction(0.6f);
  a->setActivationState(DISABLE_DEACTIVATION);  // a body asleep would leave the pair untested
  Trajectory t{s.name, "drop", "", 1000.0, {}};
  t.steps.reserve(steps);
  for (size_t i = 0; i < steps; ++i) {
    world.step(btScalar(1e-3));
    PosePair pose;
    pose.a = from_bt(a->getWorldTransform());
    pose.b = start.b;
    t.steps.push_back(pose);
  }
  t.description = "A dropped from 10 mm onto B at 1 kHz (Bullet, VPS), " + std::to_string(steps) + " steps";
  return t;
}

Trajectory haptic_path(const Scenario& s, size_t steps) {
  if (s.poses.empty()) throw std::runtime_error("scenario " + s.name + " has no poses");
  const PosePair& touching = s.poses.front();
  const Eigen::Vector3d in = fall_direction(s, touching);  // from A towards B
  const Eigen::Vector3d along = in.unitOrthogonal();
  Trajectory t{s.name, "haptic", "", 5000.0, {}};
  for (size_t i = 0; i < steps; ++i) {
    const double u = steps > 1 ? double(i) / double(steps - 1) : 0.0;
    // Offset along `in` (positive: pressed in), slide along the surface, turn about `in`.
    double press = 0, slide = 0, turn = 0;
    if (u < 0.3) {
      press = -0.005 + 0.007 * (u / 0.3);
    } else if (u < 0.8) {
      press = 0.002;
      slide = 0.02 * (u - 0.3) / 0.5;
      turn = 0.3 * (u - 0.3) / 0.5;
    } else {
      press = 0.002 - 0.007 * (u - 0.8) / 0.2;
      slide = 0.02;
      turn = 0.3;
    }
    PosePair pose = touching;
    pose.exact_depth.reset();
    pose.a.translation() += press * in + slide * along;
    pose.a.linear() = Eigen::AngleAxisd(turn, in).toRotationMatrix() * touching.a.linear();
    t.steps.push_back(pose);
  }
  t.description = "a 5 kHz haptic path: approach, press 2 mm, slide 20 mm turning 0.3 rad, pull out; " +
                  std::to_string(steps) + " steps";
  return t;
}

std::unique_ptr<Method> make_method(const std::string& name, const Scenario& s, const MethodSettings& settings,
                                    std::string& why) {
  why.clear();
  const bool b_dynamic = s.b->kind == Body::Kind::BakedMesh;
  if (name == "vps-fine" || name == "vps-coarse" || name == "vps-fine-prox" || name == "vps-fine-coherent")
    return vps_method(name, s, settings);
  if (name == "vps-fine-baked-floor") return baked_floor_method(s, settings, why);
  if (name == "vps-fine-scalar") return std::make_unique<ScalarLookups>(vps_method("vps-fine", s, settings));
  if (name == "gimpact") {
    auto a = gimpact_of(*s.a, settings.margin);
    auto b = b_dynamic ? (s.b == s.a ? a : gimpact_of(*s.b, settings.margin)) : static_partner(*s.b, settings.margin);
    return std::make_unique<BulletMethod>(a, b, std::to_string(s.a->mesh.triangles.size()) + " triangles");
  }
  if (name == "hacd") {
    for (const Body* body : {s.a.get(), s.b.get()})
      if (body->kind == Body::Kind::BakedMesh && !settings.compute_decompositions &&
          !std::filesystem::exists(hacd_cache(*body, settings))) {
        why = "no cached decomposition of " + body->name + " (a run without --quick computes it: minutes)";
        return nullptr;
      }
    size_t hulls = 0;
    auto a = hacd_of(*s.a, settings, hulls);
    auto b = b_dynamic ? (s.b == s.a ? a : hacd_of(*s.b, settings, hulls)) : static_partner(*s.b, settings.margin);
    return std::make_unique<BulletMethod>(
        a, b,
        std::to_string(hulls) + " cached hulls" +
            (s.a->decomposition_mesh.triangles.empty()
                 ? std::string()
                 : " of a " + std::to_string(s.a->decomposition_mesh.triangles.size()) + "-triangle tessellation"));
  }
  if (name == "hull") {
    size_t vertices = 0;
    auto a = reduced_hull_of(*s.a, settings.margin, vertices);
    auto b = b_dynamic ? (s.b == s.a ? a : reduced_hull_of(*s.b, settings.margin, vertices))
                       : static_partner(*s.b, settings.margin);
    return std::make_unique<BulletMethod>(a, b, std::to_string(vertices) + "-vertex hull (btShapeHull), convex");
  }
  if (name == "fcl") {
    auto a = fcl_geometry(*s.a);
    auto b = s.b == s.a ? a : fcl_geometry(*s.b);
    // FCL's halfspace has an unbounded bounding volume, so every triangle of the mesh is tested against it
    // (42 ms a query for the bunny): a large box is FCL's fast plane.
    const bool plane = s.b->kind == Body::Kind::Plane;
    return std::make_unique<FclMethod>(
        a, b, plane ? Eigen::Vector3d(0, -0.5, 0) : Eigen::Vector3d::Zero(),
        std::string("OBBRSS, all contacts with depth") + (plane ? "; plane as a 20 m box" : ""));
  }
  std::string known;
  for (const auto& n : trajectory_method_names()) known += " " + n;
  known += " vps-coarse vps-fine-prox vps-fine-scalar";
  throw std::runtime_error("unknown method '" + name + "' (known:" + known + ")");
}

}  // namespace vps_bench
