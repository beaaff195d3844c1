// Stage 2: check and repair with CGAL's polygon mesh processing.
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Polygon_mesh_processing/connected_components.h>
#include <CGAL/Polygon_mesh_processing/orient_polygon_soup.h>
#include <CGAL/Polygon_mesh_processing/orientation.h>
#include <CGAL/Polygon_mesh_processing/polygon_soup_to_polygon_mesh.h>
#include <CGAL/Polygon_mesh_processing/repair_polygon_soup.h>
#include <CGAL/Polygon_mesh_processing/self_intersections.h>
#include <CGAL/Surface_mesh.h>

#include <algorithm>
#include <cstring>
#include <numeric>

#include "stages.h"
#include "voxfmt/detail/isolated_call.h"
#include "voxfmt/io.h"

namespace voxfmt::bake {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using SurfaceMesh = CGAL::Surface_mesh<Point>;
namespace PMP = CGAL::Polygon_mesh_processing;

void warn(RepairReport& report, const char* code, const std::string& message) {
  report.warnings.push_back({code, message});
}

// Whether the soup already is what orient_polygon_soup makes of it: every directed edge used once (edges
// shared by at most two faces, in opposite directions) and the faces around every vertex one fan (no pinched
// vertices). Most meshes are; this check is a sort and a union-find, far cheaper than CGAL's orientation of
// the soup or its is_polygon_soup_a_polygon_mesh (std::set based: ~0.2 s each for the bunny's 75k faces).
bool is_oriented_manifold_soup(const std::vector<std::array<size_t, 3>>& triangles, size_t vertex_count) {
  const size_t corners = 3 * triangles.size();
  if (vertex_count > (size_t(1) << 32) || corners > (size_t(1) << 32)) return false;  // keys and corners are 32-bit
  struct DirectedEdge {
    uint64_t key;     // from << 32 | to
    uint32_t corner;  // 3 * face + the corner the edge starts at
  };
  std::vector<DirectedEdge> edges(corners);
  for (size_t f = 0; f < triangles.size(); ++f)
    for (size_t c = 0; c < 3; ++c) {
      const size_t from = triangles[f][c], to = triangles[f][(c + 1) % 3];
      if (from == to || from >= vertex_count || to >= vertex_count) return false;
      edges[3 * f + c] = {uint64_t(from) << 32 | uint64_t(to), uint32_t(3 * f + c)};
    }
  std::sort(edges.begin(), edges.end(), [](const DirectedEdge& a, const DirectedEdge& b) { return a.key < b.key; });
  for (size_t e = 1; e < corners; ++e)
    if (edges[e].key == edges[e - 1].key) return false;
  // Corners at the same vertex are joined across each edge they share: corner (f, c) starts edge v -> w; the
  // face holding w -> v has its corner at v right after that edge's start.
  std::vector<uint32_t> parent(corners);
  std::iota(parent.begin(), parent.end(), 0u);
  auto root = [&](uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (const DirectedEdge& e : edges) {
    const uint64_t reverse = (e.key & 0xffffffffu) << 32 | (e.key >> 32);
    const auto it = std::lower_bound(edges.begin(), edges.end(), reverse,
                                     [](const DirectedEdge& a, uint64_t k) { return a.key < k; });
    if (it == edges.end() || it->key != reverse) continue;  // a border edge
    const uint32_t other_at_v = it->corner - it->corner % 3 + (it->corner % 3 + 1) % 3;
    parent[root(e.corner)] = root(other_at_v);
  }
  std::vector<uint32_t> fan(vertex_count, ~0u);
  for (uint32_t corner = 0; corner < corners; ++corner) {
    uint32_t& first = fan[triangles[corner / 3][corner % 3]];
    const uint32_t r = root(corner);
    if (first == ~0u)
      first = r;
    else if (first != r)
      return false;
  }
  return true;
}

// Signed volume of the (possibly open) surface: the sign tells whether faces point outward.
double signed_volume(const SurfaceMesh& sm) {
  double six_v = 0;
  for (auto f : sm.faces()) {
    auto h = sm.halfedge(f);
    const Point& a = sm.point(sm.target(h));
    const Point& b = sm.point(sm.target(sm.next(h)));
    const Point& c = sm.point(sm.target(sm.next(sm.next(h))));
    six_v += CGAL::to_double(CGAL::determinant(a - CGAL::ORIGIN, b - CGAL::ORIGIN, c - CGAL::ORIGIN));
  }
  return six_v / 6.0;
}

// The soup steps of the repair — CGAL's merge of duplicates and its orientation of the soup — and what they did.
struct Soup {
  std::vector<Vec3> points;
  std::vector<std::array<uint64_t, 3>> triangles;
  uint64_t merged_vertices = 0, removed_faces = 0, non_manifold_vertices = 0;
  bool consistently_oriented = false;
  bool failed = false;  // with `code` and `message`
  IssueCode code = IssueCode::Internal;
  std::string message;
};

Soup repair_soup(const TriangleMesh& mesh) {
  std::vector<Point> points;
  points.reserve(mesh.vertices.size());
  for (const Vec3& v : mesh.vertices) points.emplace_back(v[0], v[1], v[2]);
  std::vector<std::array<size_t, 3>> triangles;
  triangles.reserve(mesh.triangles.size());
  size_t collinear = 0, bad_index = 0;
  for (const auto& t : mesh.triangles) {
    if (t[0] >= points.size() || t[1] >= points.size() || t[2] >= points.size()) {
      ++bad_index;
      continue;
    }
    // Zero-area faces carry no surface and break orientation; exact predicate, so no tolerance to tune.
    if (t[0] != t[1] && t[1] != t[2] && t[0] != t[2] && CGAL::collinear(points[t[0]], points[t[1]], points[t[2]])) {
      ++collinear;
      continue;
    }
    triangles.push_back({t[0], t[1], t[2]});
  }
  const size_t points_before = points.size(), faces_before = triangles.size();
  PMP::repair_polygon_soup(points, triangles);
  // CGAL's soup repair can leave a triangle whose three corners are one merged point (a soup of nothing but
  // such triangles: found by fuzz_mesh_gltf); the mesh builder drops it, and an empty mesh crashed the
  // orientation that follows.
  triangles.erase(std::remove_if(triangles.begin(), triangles.end(),
                                 [](const auto& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; }),
                  triangles.end());
  Soup soup;
  soup.merged_vertices = points_before - points.size();
  soup.removed_faces = collinear + bad_index + (faces_before - triangles.size());
  if (triangles.empty()) {
    soup.failed = true;
    soup.code = IssueCode::EmptyScene;
    soup.message = "no non-degenerate triangle is left after repair";
    return soup;
  }
  const size_t points_oriented_before = points.size();
  soup.consistently_oriented =
      is_oriented_manifold_soup(triangles, points.size()) || PMP::orient_polygon_soup(points, triangles);
  soup.non_manifold_vertices = points.size() - points_oriented_before;
  soup.points.reserve(points.size());
  for (const Point& p : points) soup.points.push_back({p.x(), p.y(), p.z()});
  soup.triangles.reserve(triangles.size());
  for (const auto& t : triangles) soup.triangles.push_back({t[0], t[1], t[2]});
  return soup;
}

#if !defined(_WIN32)
// CGAL's soup orientation has looped forever on a fuzzed mesh (a face whose corners merged into one point sent its
// walk around a vertex in circles), and a stage that can hang on its input must not hang the bake: the soup steps
// run in a child process, like the import, and a crash or a hang there is REPAIR_FAILED. They are sequential code
// (no thread pool in the forked child).
Soup repair_soup_isolated(const TriangleMesh& mesh, double time_limit_s) {
  const double limit_s = time_limit_s > 0 ? time_limit_s : 30.0 + double(mesh.triangles.size()) / 5e4;
  Soup soup;
  // A child asleep for kAsleepS without CPU holds a lock inherited from another thread at the fork (clang's ASan
  // allocator has no fork handler), which says nothing about the mesh: once more.
  constexpr double kAsleepS = 5.0;
  auto attempt = [&] {
    return detail::run_isolated(
        detail::Watchdog{limit_s, 0, nullptr, kAsleepS}, soup,
        [&] {
          try {
            return repair_soup(mesh);
          } catch (const std::bad_alloc&) {
            Soup failed;
            failed.failed = true;
            failed.code = IssueCode::OutOfMemory;
            failed.message = "out of memory repairing the mesh";
            return failed;
          }
        },
        [](auto& w, auto& s) {
          w.array(s.points);
          w.array(s.triangles);
          w.pod(s.merged_vertices);
          w.pod(s.removed_faces);
          w.pod(s.non_manifold_vertices);
          w.pod(s.consistently_oriented);
          w.pod(s.failed);
          w.pod(s.code);
          w.text(s.message);
        });
  };
  detail::ChildOutcome outcome = attempt();
  if (outcome.kind == detail::ChildOutcome::TimedOut && outcome.asleep) outcome = attempt();
  switch (outcome.kind) {
    case detail::ChildOutcome::Finished:
      return soup;
    case detail::ChildOutcome::CannotStart:
      throw BakeError(IssueCode::Internal, "cannot repair the mesh in isolation: " + outcome.detail);
    case detail::ChildOutcome::Died:
      throw BakeError(IssueCode::RepairFailed, "CGAL's repair of the triangle soup died of signal " +
                                                   std::to_string(outcome.signal) + " (" + strsignal(outcome.signal) +
                                                   ") on this mesh (run in isolation)");
    case detail::ChildOutcome::TimedOut:
      throw BakeError(IssueCode::RepairFailed, "CGAL's repair of the triangle soup did not finish within " +
                                                   std::to_string(int(limit_s)) + " s on this mesh (stopped)");
    case detail::ChildOutcome::OutOfMemory:
      throw BakeError(IssueCode::OutOfMemory, "out of memory receiving the repaired mesh");
    case detail::ChildOutcome::Malformed:
      break;
  }
  throw BakeError(IssueCode::RepairFailed, "the isolated repair failed (out of memory, or malformed data)");
}
#endif

// The repaired soup as a CGAL surface mesh (the soup's own checks reported; its points freed).
SurfaceMesh soup_to_mesh(Soup& soup, RepairReport& report) {
  report.merged_vertices = soup.merged_vertices;
  report.removed_faces = soup.removed_faces;
  if (report.removed_faces)
    warn(report, "DEGENERATE_FACES", std::to_string(report.removed_faces) + " degenerate or duplicate face(s) removed");
  report.consistently_oriented = soup.consistently_oriented;
  report.non_manifold_vertices = soup.non_manifold_vertices;
  if (!report.consistently_oriented)
    warn(report, "NON_MANIFOLD",
         "the surface is non-manifold or not orientable; " + std::to_string(report.non_manifold_vertices) +
             " vertex copies were made to orient it");
  std::vector<Point> points;
  points.reserve(soup.points.size());
  for (const Vec3& p : soup.points) points.emplace_back(p[0], p[1], p[2]);
  std::vector<std::array<size_t, 3>> triangles;
  triangles.reserve(soup.triangles.size());
  for (const auto& t : soup.triangles) {
    if (t[0] >= points.size() || t[1] >= points.size() || t[2] >= points.size())
      throw BakeError(IssueCode::RepairFailed, "the isolated repair sent back a triangle with a corner out of range");
    triangles.push_back({size_t(t[0]), size_t(t[1]), size_t(t[2])});
  }
  std::vector<Vec3>().swap(soup.points);
  SurfaceMesh sm;
  PMP::polygon_soup_to_polygon_mesh(points, triangles, sm);
  // The orientation after assumes every face made it into the mesh; refuse rather than let CGAL read past the
  // end of its own per-component arrays.
  if (sm.number_of_faces() != triangles.size())
    throw BakeError(IssueCode::Internal, "repair: " + std::to_string(triangles.size() - sm.number_of_faces()) +
                                             " face(s) could not be joined into a mesh after orientation");
  return sm;
}

// The mesh's defects as the report's counts and warnings: borders, components, self-intersections.
void check_mesh(SurfaceMesh& sm, bool check_self_intersections, RepairReport& report) {
  for (auto h : sm.halfedges()) report.border_edges += sm.is_border(h);
  report.closed = report.border_edges == 0;
  if (!report.closed)
    warn(report, "OPEN_BORDER", std::to_string(report.border_edges) + " border edge(s): the surface has holes");
  auto component_map = sm.add_property_map<SurfaceMesh::Face_index, std::size_t>("f:component").first;
  report.components = PMP::connected_components(sm, component_map);
  if (report.components > 1)
    warn(report, "MULTIPLE_COMPONENTS", std::to_string(report.components) + " connected components");
  if (!check_self_intersections) {
    warn(report, "SELF_INTERSECTION_CHECK_SKIPPED",
         "self-intersections were not checked; the sign assumes there are none");
    return;
  }
  std::vector<std::pair<SurfaceMesh::Face_index, SurfaceMesh::Face_index>> pairs;
  PMP::self_intersections<CGAL::Parallel_if_available_tag>(sm.faces(), sm, std::back_inserter(pairs));
  report.self_intersecting_pairs = pairs.size();
  if (!pairs.empty())
    warn(report, "SELF_INTERSECTIONS", std::to_string(pairs.size()) + " pair(s) of self-intersecting faces");
}

TriangleMesh mesh_to_triangles(const SurfaceMesh& sm) {
  TriangleMesh out;
  out.vertices.reserve(sm.number_of_vertices());
  for (auto v : sm.vertices()) {
    const Point& p = sm.point(v);
    out.vertices.push_back({p.x(), p.y(), p.z()});
  }
  out.triangles.reserve(sm.number_of_faces());
  for (auto f : sm.faces()) {
    std::array<uint32_t, 3> t{};
    int i = 0;
    for (auto v : CGAL::vertices_around_face(sm.halfedge(f), sm)) t[i++] = uint32_t(v.idx());
    out.triangles.push_back(t);
  }
  return out;
}

}  // namespace

TriangleMesh repair_mesh(const TriangleMesh& mesh, RepairReport& report, bool check_self_intersections,
                         double time_limit_s) {
#if !defined(_WIN32)
  Soup soup = read_isolation() ? repair_soup_isolated(mesh, time_limit_s) : repair_soup(mesh);
#else
  Soup soup = repair_soup(mesh);
#endif
  if (soup.failed) throw BakeError(soup.code, soup.message);
  SurfaceMesh sm = soup_to_mesh(soup, report);
  check_mesh(sm, check_self_intersections, report);
  // Outward orientation: nested closed components bound a volume correctly; open ones go by signed volume.
  if (report.closed && report.consistently_oriented && report.self_intersecting_pairs == 0)
    PMP::orient_to_bound_a_volume(sm);
  else if (signed_volume(sm) < 0)
    PMP::reverse_face_orientations(sm);
  return mesh_to_triangles(sm);
}

}  // namespace voxfmt::bake
