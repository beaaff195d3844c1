// vps-sim scenes: the bodies of each scenario (one geometry per kind of body, shared by every method) and their
// initial states, the same for every method.
#pragma once

#include <LinearMath/btTransform.h>

#include <memory>
#include <string>
#include <vector>

#include "voxfmt/runtime/collision_object.h"

namespace vps_sim {

/// One rigid geometry: its baked asset and its mesh, both in the shape frame every method shares (the asset's
/// principal frame at its centre of mass, as VpsShape uses), so every method has the same mass properties.
struct Geometry {
  std::string name;
  std::shared_ptr<const voxfmt::runtime::CollisionObject> object;
  btTransform shape_to_asset;       ///< the shape frame in the asset frame
  std::vector<btVector3> vertices;  ///< shape frame
  std::vector<int> indices;         ///< three per triangle
  /// What HACD decomposes (a coarser tessellation of the same surface where the fine one would take HACD an
  /// hour), shape frame, and where its decomposition is cached.
  std::vector<btVector3> hacd_vertices;
  std::vector<int> hacd_indices;
  std::string hacd_cache;
  double density = 1000.0;  ///< kg/m^3
  double mass() const { return density * object->volume(); }
  /// Principal moments for this mass (the shape frame is the principal frame).
  btVector3 inertia() const;
  /// Radius of the sphere about the centre of mass that holds the body: point speeds from spin.
  double radius() const { return object->bounding_radius(); }
};

/// One body of a scene: a geometry, or a box (tables, bins, walls) when `geometry` is null.
struct BodySpec {
  std::shared_ptr<Geometry> geometry;
  btVector3 box_half{0, 0, 0};
  btTransform transform = btTransform::getIdentity();  ///< of the shape frame, world
  bool dynamic = true;
  double friction = 0.6;
  btVector3 force{0, 0, 0};  ///< constant force at the centre of mass, newtons (the peg's push)
};

struct Scene {
  std::string name;
  std::string description;
  double seconds = 3.0;  ///< simulated
  /// Bullet margin of the convex and GImpact peers, metres: small against the scene's clearances.
  double margin = 0.001;
  std::vector<BodySpec> bodies;
  /// Where every dynamic body must still be at the end (its centre of mass), or it counts as escaped.
  btVector3 keep_lo{-1e9, -1e9, -1e9}, keep_hi{1e9, 1e9, 1e9};

  /// bunny-on-bunny: the upper body's index and the height its centre of mass stays above while on the other.
  int upper = -1;
  double on_top_y = 0;
  /// peg-in-hole: the peg's body index, its lowest point in its shape frame, the block's top and the hole's depth.
  int peg = -1;
  btVector3 peg_tip{0, 0, 0};
  double hole_top_y = 0, hole_depth = 0;
  /// chain: the links' body indices from the static anchor down, and the largest centre distance two linked
  /// rings can have (their tubes touching through each other's holes).
  std::vector<int> chain;
  double chain_link_reach = 0;
};

struct SceneSettings {
  std::string cache_dir = "out/vps-sim";  ///< baked assets, generated meshes, HACD decompositions
  std::string meshes_dir;                 ///< CGAL's sample meshes (bunny00.off and the pile's)
  size_t pile_bodies = 50;
  uint64_t seed = 20261125;
  bool quick = false;  ///< smaller assets where the scenario allows
};

/// Scenario names in the order the program runs them.
const std::vector<std::string>& scene_names();

/// Builds a scene, baking (or loading from the cache) the assets it needs. Throws std::runtime_error naming the
/// problem.
Scene make_scene(const std::string& name, const SceneSettings& settings);

}  // namespace vps_sim
