#include "voxfmt/bullet/collision.h"

#include <BulletCollision/BroadphaseCollision/btCollisionAlgorithm.h>
#include <BulletCollision/CollisionDispatch/btCollisionCreateFunc.h>
#include <BulletCollision/CollisionDispatch/btCollisionObjectWrapper.h>
#include <BulletCollision/CollisionDispatch/btManifoldResult.h>
#include <BulletCollision/CollisionShapes/btBoxShape.h>
#include <BulletCollision/CollisionShapes/btSphereShape.h>
#include <BulletCollision/CollisionShapes/btStaticPlaneShape.h>
#include <BulletCollision/NarrowPhaseCollision/btPersistentManifold.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <new>

#include "bt_eigen.h"
#include "voxfmt/bullet/shape.h"
#include "voxfmt/runtime/contact_reduction.h"

namespace voxfmt::bullet {
namespace {

struct Shared {
  CollisionSettings settings;
  CollisionCounters counters;
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
  }

  void processCollision(const btCollisionObjectWrapper* body0, const btCollisionObjectWrapper* body1,
                        const btDispatcherInfo&, btManifoldResult* result) override {
    if (!manifold_) return;
    const btCollisionObjectWrapper* a_wrap = swapped_ ? body1 : body0;
    const btCollisionObjectWrapper* b_wrap = swapped_ ? body0 : body1;
    const auto* a_shape = static_cast<const VpsShape*>(a_wrap->getCollisionShape());
    const runtime::Pose pose_a = a_shape->asset_pose(a_wrap->getWorldTransform());
    const CollisionSettings& settings = shared_->settings;
    runtime::QueryOptions options;
    options.normal_source = settings.normal_source;
    options.proximity = std::max(settings.proximity, double(result->m_closestPointDistanceThreshold));

    thread_local runtime::ContactSet contacts;
    thread_local runtime::QueryScratch scratch;
    contacts.clear();
    collide(*a_shape, pose_a, b_wrap, options, contacts, scratch);

    result->setPersistentManifold(manifold_);
    CollisionCounters& counters = shared_->counters;
    ++counters.pair_tests;
    counters.raw_contacts += contacts.contacts.size();
    counters.points_tested += contacts.stats.points_tested;
    for (size_t index : runtime::reduce_contacts(contacts.contacts, settings.manifold_points)) {
      const runtime::Contact& c = contacts.contacts[index];
      // Bullet: pointOnB + normalOnB * distance = pointOnA, distance < 0 when penetrating.
      const Eigen::Vector3d on_b = c.point_of_b ? c.point : c.point + c.normal * c.depth;
      result->addContactPoint(to_bt_vector(c.normal), to_bt_vector(on_b), btScalar(-c.depth));
    }
    if (owns_manifold_) result->refreshContactPoints();
  }

  btScalar calculateTimeOfImpact(btCollisionObject*, btCollisionObject*, const btDispatcherInfo&,
                                 btManifoldResult*) override {
    return btScalar(1);
  }

  void getAllContactManifolds(btManifoldArray& manifolds) override {
    if (manifold_ && owns_manifold_) manifolds.push_back(manifold_);
  }

 private:
  void collide(const VpsShape& a, const runtime::Pose& pose_a, const btCollisionObjectWrapper* b_wrap,
               runtime::QueryOptions options, runtime::ContactSet& contacts, runtime::QueryScratch& scratch) const {
    const btCollisionShape* b_shape = b_wrap->getCollisionShape();
    const btTransform& tb = b_wrap->getWorldTransform();
    options.point_budget = a.point_budget();
    switch (b_shape->getShapeType()) {
      case VpsShape::kShapeType: {
        const auto& b = static_cast<const VpsShape&>(*b_shape);
        const runtime::Pose pose_b = b.asset_pose(tb);
        const bool a_in_b = a.uses_points() && b.uses_voxelmap();
        const bool b_in_a = b.uses_points() && a.uses_voxelmap();
        runtime::QueryDirection direction = shared_->settings.direction;
        if (direction == runtime::QueryDirection::Auto)
          direction = a_in_b && b_in_a
                          ? runtime::resolve_direction(a.object(), pose_a, b.object(), pose_b, direction)
                          : (a_in_b ? runtime::QueryDirection::APointsInB : runtime::QueryDirection::BPointsInA);
        if (a_in_b &&
            (direction == runtime::QueryDirection::APointsInB || direction == runtime::QueryDirection::Both)) {
          options.direction = runtime::QueryDirection::APointsInB;
          options.point_budget = a.point_budget();
          runtime::query_contacts(a.object(), pose_a, b.object(), pose_b, options, contacts, scratch);
        }
        if (b_in_a &&
            (direction == runtime::QueryDirection::BPointsInA || direction == runtime::QueryDirection::Both)) {
          options.direction = runtime::QueryDirection::BPointsInA;
          options.point_budget = b.point_budget();
          runtime::query_contacts(a.object(), pose_a, b.object(), pose_b, options, contacts, scratch);
        }
        return;
      }
      case STATIC_PLANE_PROXYTYPE: {
        if (!a.uses_points()) return;
        const auto& plane = static_cast<const btStaticPlaneShape&>(*b_shape);
        const Eigen::Vector3f n = (to_eigen(tb.getBasis()) * to_eigen(plane.getPlaneNormal())).cast<float>();
        const float c = float(plane.getPlaneConstant()) + n.dot(to_eigen(tb.getOrigin()).cast<float>());
        runtime::query_against_function(
            a.object(), pose_a,
            [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
              outward = n;
              return n.dot(x) - c;
            },
            options, contacts, scratch);
        return;
      }
      case BOX_SHAPE_PROXYTYPE: {
        const auto& box = static_cast<const btBoxShape&>(*b_shape);
        const Eigen::Vector3d half = to_eigen(box.getHalfExtentsWithMargin());
        const Eigen::Matrix3d rb = to_eigen(tb.getBasis());
        const Eigen::Vector3d ob = to_eigen(tb.getOrigin());
        if (a.uses_points()) {
          const Eigen::Matrix3f rbf = rb.cast<float>();
          const Eigen::Vector3f obf = ob.cast<float>(), hf = half.cast<float>();
          runtime::query_against_function(
              a.object(), pose_a,
              [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
                return box_distance(rbf, obf, hf, x, outward);
              },
              options, contacts, scratch);
        }
        if (a.uses_voxelmap()) {  // the box's corners in A's voxelmap
          std::array<Eigen::Vector3d, 8> corners;
          for (int k = 0; k < 8; ++k)
            corners[size_t(k)] =
                ob + rb * Eigen::Vector3d((k & 1) ? half.x() : -half.x(), (k & 2) ? half.y() : -half.y(),
                                          (k & 4) ? half.z() : -half.z());
          runtime::query_points_in_voxelmap(a.object(), pose_a, corners.data(), corners.size(), 0.0, options, contacts);
        }
        return;
      }
      case SPHERE_SHAPE_PROXYTYPE: {
        const auto& sphere = static_cast<const btSphereShape&>(*b_shape);
        const Eigen::Vector3d centre = to_eigen(tb.getOrigin());
        const double radius = double(sphere.getRadius());
        if (a.uses_points()) {
          const Eigen::Vector3f cf = centre.cast<float>();
          const float rf = float(radius);
          runtime::query_against_function(
              a.object(), pose_a,
              [&](const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
                const Eigen::Vector3f v = x - cf;
                const float len = v.norm();
                outward = len > 0.0f ? Eigen::Vector3f(v / len) : Eigen::Vector3f::UnitZ();
                return len - rf;
              },
              options, contacts, scratch);
        }
        if (a.uses_voxelmap())
          runtime::query_points_in_voxelmap(a.object(), pose_a, &centre, 1, radius, options, contacts);
        return;
      }
      default:
        return;
    }
  }

  // Signed distance to an oriented box and its outward normal.
  static float box_distance(const Eigen::Matrix3f& rotation, const Eigen::Vector3f& origin, const Eigen::Vector3f& half,
                            const Eigen::Vector3f& x, Eigen::Vector3f& outward) {
    const Eigen::Vector3f local = rotation.transpose() * (x - origin);
    const Eigen::Vector3f q = local.cwiseAbs() - half;
    const Eigen::Vector3f sign = local.unaryExpr([](float v) { return v < 0.0f ? -1.0f : 1.0f; });
    if ((q.array() > 0.0f).any()) {
      const Eigen::Vector3f out = q.cwiseMax(0.0f).cwiseProduct(sign);
      const float d = out.norm();
      outward = rotation * (out / d);
      return d;
    }
    int axis = 0;
    q.maxCoeff(&axis);
    Eigen::Vector3f n = Eigen::Vector3f::Zero();
    n[axis] = sign[axis];
    outward = rotation * n;
    return q[axis];
  }

  btPersistentManifold* manifold_;
  bool owns_manifold_ = false;
  bool swapped_;
  Shared* shared_;
};

// Bullet's pool slots are sized from its own algorithms; ours must not be larger (see prepare_construction_info).
static_assert(sizeof(VpsCollisionAlgorithm) <= 64, "keep the algorithm small: it lives in the dispatcher's pool");

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
    for (int other : {int(VpsShape::kShapeType), int(STATIC_PLANE_PROXYTYPE), int(BOX_SHAPE_PROXYTYPE),
                      int(SPHERE_SHAPE_PROXYTYPE)}) {
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

 private:
  Shared shared_;
  CreateFunc direct_;
  CreateFunc swapped_;
};

}  // namespace

std::unique_ptr<VpsCollisionRegistration> register_vps_collision(btCollisionDispatcher& dispatcher,
                                                                 const CollisionSettings& settings) {
  return std::make_unique<Registration>(dispatcher, settings);
}

void prepare_construction_info(btDefaultCollisionConstructionInfo& info) {
  info.m_customCollisionAlgorithmMaxElementSize =
      std::max(info.m_customCollisionAlgorithmMaxElementSize, int(sizeof(VpsCollisionAlgorithm)));
}

}  // namespace voxfmt::bullet
