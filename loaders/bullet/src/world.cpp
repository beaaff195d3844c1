#include "voxfmt/bullet/world.h"

#include <chrono>

namespace voxfmt::bullet {

void TimedDispatcher::dispatchAllCollisionPairs(btOverlappingPairCache* pairs, const btDispatcherInfo& info,
                                                btDispatcher* dispatcher) {
  if (vps_) vps_->begin_step();
  const auto start = std::chrono::steady_clock::now();
  btCollisionDispatcher::dispatchAllCollisionPairs(pairs, info, dispatcher);
  last_us_ = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - start).count();
}

World::World(const CollisionSettings& settings, bool register_vps) {
  btDefaultCollisionConstructionInfo info;
  prepare_construction_info(info);
  configuration_ = std::make_unique<btDefaultCollisionConfiguration>(info);
  dispatcher_ = std::make_unique<TimedDispatcher>(configuration_.get());
  broadphase_ = std::make_unique<btDbvtBroadphase>();
  solver_ = std::make_unique<btSequentialImpulseConstraintSolver>();
  world_ = std::make_unique<btDiscreteDynamicsWorld>(dispatcher_.get(), broadphase_.get(), solver_.get(),
                                                     configuration_.get());
  // Every penetration is resolved by split impulses, which move the bodies apart without giving them velocity.
  // Bullet's default keeps the velocity (Baumgarte) correction for penetrations shallower than 4 cm, which at
  // 1 kHz turns a 2 mm penetration into a 0.4 m/s push (ERP 0.2 / 1 ms): a bunny dropped on a bunny gained 13 %
  // of the energy it had released (vps-sim bunny-on-bunny), 1.3 % with split impulses.
  world_->getSolverInfo().m_splitImpulsePenetrationThreshold = 0;
  // Friction along two directions per contact, not only along the sliding one: with one, resting bodies crept
  // at 0.1-0.3 mm/s, whatever the collision method (vps-sim drop and bunny-on-bunny: at rest with two).
  world_->getSolverInfo().m_solverMode |= SOLVER_USE_2_FRICTION_DIRECTIONS;
  if (register_vps) {
    registration_ = register_vps_collision(*dispatcher_, settings);
    dispatcher_->set_vps(registration_.get());
  }
}

World::~World() {
  // Bodies leave the world before anything they point to is destroyed.
  for (auto& body : bodies_) world_->removeRigidBody(body.get());
}

btRigidBody* World::add_body(std::shared_ptr<btCollisionShape> shape, btScalar mass, const btTransform& transform,
                             const btVector3* given_inertia) {
  btVector3 inertia(0, 0, 0);
  if (mass > 0) {
    if (given_inertia)
      inertia = *given_inertia;
    else
      shape->calculateLocalInertia(mass, inertia);
  }
  motion_states_.push_back(std::make_unique<btDefaultMotionState>(transform));
  btRigidBody::btRigidBodyConstructionInfo info(mass, motion_states_.back().get(), shape.get(), inertia);
  bodies_.push_back(std::make_unique<btRigidBody>(info));
  // A static mesh is indexed as it enters the world, not in the middle of the first step that touches it.
  if (registration_ && mass == 0 && registration_->settings().static_mesh_index)
    registration_->prepare_static_mesh(*shape);
  shapes_.push_back(std::move(shape));
  world_->addRigidBody(bodies_.back().get());
  return bodies_.back().get();
}

}  // namespace voxfmt::bullet
