// Stage 4: evenly spread surface points and the bottom-up point-sphere tree.
#include <CGAL/Cartesian_d.h>
#include <CGAL/Min_sphere_of_spheres_d.h>
#include <CGAL/Min_sphere_of_spheres_d_traits_3.h>
#include <CGAL/Simple_cartesian.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <unordered_map>

#include "stages.h"
#include "vec3_math.h"

namespace voxfmt::bake {

namespace {

// Uniform double in [0,1) from raw generator bits: identical on every platform (std distributions are not).
double unit(std::mt19937_64& rng) { return double(rng() >> 11) * 0x1.0p-53; }

struct Candidate {
  Vec3 point;
  Vec3f inward_normal;
};

// Every 65,536 steps of a loop over candidates: throws once the bake the shell serves has failed beside it.
void stop_if_abandoned(const std::atomic<bool>* abandon, size_t step) {
  if (abandon && step % 65536 == 0 && abandon->load(std::memory_order_relaxed))
    throw BakeError(IssueCode::Internal, "point shell abandoned");
}

/// Area-weighted random points on the surface, each with its face's inward normal.
std::vector<Candidate> surface_candidates(const TriangleMesh& mesh, size_t count, uint64_t seed, double& area,
                                          const std::atomic<bool>* abandon) {
  std::vector<double> cumulative(mesh.triangles.size());
  std::vector<Vec3f> normals(mesh.triangles.size());
  area = 0;
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& tri = mesh.triangles[t];
    const Vec3 n = cross(mesh.vertices[tri[1]] - mesh.vertices[tri[0]], mesh.vertices[tri[2]] - mesh.vertices[tri[0]]);
    const double len = length(n);
    area += 0.5 * len;
    cumulative[t] = area;
    normals[t] = len > 0 ? Vec3f{float(-n[0] / len), float(-n[1] / len), float(-n[2] / len)} : Vec3f{0, 0, 1};
  }
  std::mt19937_64 rng(seed);
  std::vector<Candidate> out(count);
  for (Candidate& c : out) {
    stop_if_abandoned(abandon, size_t(&c - out.data()));
    const double pick = unit(rng) * area;
    const size_t t = std::min(size_t(std::upper_bound(cumulative.begin(), cumulative.end(), pick) - cumulative.begin()),
                              cumulative.size() - 1);
    double u = unit(rng), v = unit(rng);
    if (u + v > 1) {
      u = 1 - u;
      v = 1 - v;
    }
    const auto& tri = mesh.triangles[t];
    const Vec3 &a = mesh.vertices[tri[0]], &b = mesh.vertices[tri[1]], &cc = mesh.vertices[tri[2]];
    for (int k = 0; k < 3; ++k) c.point[k] = a[k] + u * (b[k] - a[k]) + v * (cc[k] - a[k]);
    c.inward_normal = normals[t];
  }
  return out;
}

/// Dart throwing over the candidates (already in random order): keeps a candidate when no kept point lies
/// within `radius`. A hash grid of cell `radius` makes each test look at 27 cells; a cell holds its points' own
/// coordinates (reaching them through their candidates, at random across 8 per point, was 40 % of the time).
std::vector<size_t> dart_throw(const std::vector<Candidate>& candidates, double radius, size_t limit, size_t expected,
                               const std::atomic<bool>* abandon) {
  std::unordered_map<uint64_t, std::vector<Vec3>> cells;
  cells.reserve(2 * std::min(limit, expected));
  auto key = [](int64_t x, int64_t y, int64_t z) {
    return (uint64_t(x & 0x1fffff) << 42) | (uint64_t(y & 0x1fffff) << 21) | uint64_t(z & 0x1fffff);
  };
  const double r2 = radius * radius;
  std::vector<size_t> kept;
  for (size_t c = 0; c < candidates.size() && kept.size() < limit; ++c) {
    stop_if_abandoned(abandon, c);
    const Vec3& p = candidates[c].point;
    // Cell coordinates, clamped before the conversion (hash collisions are harmless: distances decide).
    auto cell = [&](double coordinate) { return int64_t(std::clamp(std::floor(coordinate / radius), -4e18, 4e18)); };
    const int64_t x = cell(p[0]), y = cell(p[1]), z = cell(p[2]);
    bool free = true;
    for (int64_t dz = -1; dz <= 1 && free; ++dz)
      for (int64_t dy = -1; dy <= 1 && free; ++dy)
        for (int64_t dx = -1; dx <= 1 && free; ++dx) {
          auto it = cells.find(key(x + dx, y + dy, z + dz));
          if (it == cells.end()) continue;
          for (const Vec3& other : it->second)
            if (distance2(other, p) < r2) {
              free = false;
              break;
            }
        }
    if (!free) continue;
    cells[key(x, y, z)].push_back(p);
    kept.push_back(c);
  }
  return kept;
}

}  // namespace

namespace {

double target_for_area(double area, const PointShellSettings& options) {
  const double s = options.point_spacing;
  return s > 0 ? std::ceil(area / (0.75 * s * s)) : double(options.points);
}

}  // namespace

double point_shell_target(const TriangleMesh& mesh, const PointShellSettings& options) {
  if (options.point_spacing == 0) return double(options.points);
  return target_for_area(surface_area(mesh), options);
}

PointShell sample_point_shell(const TriangleMesh& mesh, const PointShellSettings& options,
                              const std::atomic<bool>* abandon) {
  double area = surface_area(mesh);
  if (!(area > 0)) throw BakeError(IssueCode::ZeroVolume, "the surface has zero area");
  const double wanted = target_for_area(area, options);
  if (!(wanted >= 1)) throw BakeError(IssueCode::BadOption, "the point shell needs at least one point");
  if (!(wanted <= 50e6))
    throw BakeError(IssueCode::BadOption,
                    "the point shell would need more than 50 million points (point spacing too small)");
  const size_t target = size_t(wanted);
  const std::vector<Candidate> candidates =
      surface_candidates(mesh, std::max<size_t>(8 * target, 64), options.seed, area, abandon);

  std::vector<size_t> kept;
  if (options.point_spacing > 0) {
    kept = dart_throw(candidates, options.point_spacing, candidates.size(), target, abandon);
  } else {
    // A maximal Poisson-disk set of radius r holds about 0.7 * area / r^2 points; aim a little denser than
    // the target, keeping the first `target` accepted (a random subset, still at least r apart).
    double radius = std::sqrt(0.7 * area / double(target));
    for (int iteration = 0; iteration < 8; ++iteration) {
      kept = dart_throw(candidates, radius, target, target, abandon);  // the first `target` kept do not change
      if (kept.size() >= target) break;
      radius *= std::sqrt(double(kept.size()) / double(target)) * 0.97;
    }
  }
  PointShell shell;
  for (size_t c : kept) {
    shell.points.push_back(candidates[c].point);
    shell.normals.push_back(candidates[c].inward_normal);
  }
  shell.point_spacing = std::sqrt(area / (0.75 * double(shell.points.size())));  // nominal neighbour spacing
  shell.branching.reset();
  return shell;
}

namespace {

using SphereTraits = CGAL::Min_sphere_of_spheres_d_traits_3<CGAL::Simple_cartesian<double>, double>;
using MinSphere = CGAL::Min_sphere_of_spheres_d<SphereTraits>;

struct Node {
  uint32_t point;                  ///< index into the sampled points
  std::vector<uint32_t> children;  ///< node indices (into the nodes array)
  Vec3 mass_sum{};                 ///< sum of the points of the subtree
  double mass_count = 0;
};

// Splits `ids` (node indices, positions given) into `groups` spatially compact groups of nearly equal size by
// recursive median cuts along the longest axis.
void median_split(std::vector<uint32_t>& ids, size_t begin, size_t end, size_t groups, const std::vector<Vec3>& pos,
                  std::vector<std::pair<size_t, size_t>>& out) {
  if (groups <= 1 || end - begin <= 1) {
    out.emplace_back(begin, end);
    return;
  }
  Vec3 lo = pos[ids[begin]], hi = lo;
  for (size_t i = begin; i < end; ++i)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], pos[ids[i]][a]);
      hi[a] = std::max(hi[a], pos[ids[i]][a]);
    }
  int axis = 0;
  for (int a = 1; a < 3; ++a)
    if (hi[a] - lo[a] > hi[axis] - lo[axis]) axis = a;
  const size_t left_groups = groups / 2;
  const size_t mid = begin + (end - begin) * left_groups / groups;
  std::nth_element(ids.begin() + begin, ids.begin() + mid, ids.begin() + end, [&](uint32_t a, uint32_t b) {
    return pos[a][axis] < pos[b][axis] || (pos[a][axis] == pos[b][axis] && a < b);
  });
  median_split(ids, begin, mid, left_groups, pos, out);
  median_split(ids, mid, end, groups - left_groups, pos, out);
}

// One level's clusters become parents: each cluster's member closest to the cluster's centre of mass becomes the
// parent (it moves up a level), the others its children. A promoted parent's previous children would then sit two
// levels below it, so they are adopted by the sibling closest to them: every node's children stay on the level right
// below it and every point appears once. Returns the parents, the next level up.
std::vector<uint32_t> promote_parents(const std::vector<uint32_t>& level,
                                      const std::vector<std::pair<size_t, size_t>>& clusters,
                                      const std::vector<Vec3>& centre_of, std::vector<Node>& nodes) {
  std::vector<uint32_t> parents;
  for (auto [begin, end] : clusters) {
    Vec3 sum{};
    double count = 0;
    for (size_t i = begin; i < end; ++i) {
      const Node& m = nodes[level[i]];
      for (int a = 0; a < 3; ++a) sum[a] += m.mass_sum[a];
      count += m.mass_count;
    }
    const Vec3 com = {sum[0] / count, sum[1] / count, sum[2] / count};
    size_t best = begin;
    for (size_t i = begin + 1; i < end; ++i)
      if (distance2(centre_of[level[i]], com) < distance2(centre_of[level[best]], com)) best = i;
    const uint32_t parent = level[best];
    std::vector<uint32_t> orphans = std::move(nodes[parent].children);
    nodes[parent].children.clear();
    for (size_t i = begin; i < end; ++i)
      if (i != best) nodes[parent].children.push_back(level[i]);
    if (!orphans.empty()) {
      Vec3 orphan_centre{};
      for (uint32_t o : orphans)
        for (int a = 0; a < 3; ++a) orphan_centre[a] += centre_of[o][a] / double(orphans.size());
      uint32_t adopter = nodes[parent].children.front();
      for (uint32_t c : nodes[parent].children)
        if (distance2(centre_of[c], orphan_centre) < distance2(centre_of[adopter], orphan_centre)) adopter = c;
      auto& kids = nodes[adopter].children;
      kids.insert(kids.end(), orphans.begin(), orphans.end());
    }
    nodes[parent].mass_sum = sum;
    nodes[parent].mass_count = count;
    parents.push_back(parent);
  }
  return parents;
}

// Bottom-up: each level is clustered by median splits and its clusters promote their parents, until one is left.
// Returns the root.
uint32_t cluster_bottom_up(const PointShell& shell, double branching, std::vector<Node>& nodes) {
  const size_t n = shell.points.size();
  std::vector<uint32_t> level(n);
  std::iota(level.begin(), level.end(), 0u);
  std::vector<Vec3> centre_of(n);
  while (level.size() > 1) {
    for (uint32_t id : level) centre_of[id] = shell.points[nodes[id].point];
    // At most size/2 groups, so every cluster has >= 2 members and its parent has a child to hand orphans to.
    const size_t groups =
        std::clamp<size_t>(size_t(std::llround(double(level.size()) / branching)), 1, level.size() / 2);
    std::vector<std::pair<size_t, size_t>> clusters;
    median_split(level, 0, level.size(), groups, centre_of, clusters);
    level = promote_parents(level, clusters, centre_of, nodes);
  }
  return level.front();
}

// Breadth-first numbering from the root: node order = point order in the file. Fills the shell's points, normals,
// children and level offsets in that order (spheres left to bound_spheres).
PointShell number_breadth_first(const PointShell& shell, double branching, const std::vector<Node>& nodes,
                                uint32_t root) {
  const size_t n = shell.points.size();
  std::vector<uint32_t> order{root};
  std::vector<uint32_t> level_offsets{0, 1};
  for (size_t head = 0; head < order.size();) {
    const size_t level_end = order.size();
    for (; head < level_end; ++head)
      for (uint32_t c : nodes[order[head]].children) order.push_back(c);
    if (order.size() > level_end) level_offsets.push_back(uint32_t(order.size()));
  }
  if (order.size() != n) throw BakeError(IssueCode::Internal, "point-sphere tree lost points");
  std::vector<uint32_t> new_index(n);
  for (uint32_t i = 0; i < n; ++i) new_index[order[i]] = i;
  PointShell out;
  out.point_spacing = shell.point_spacing;
  out.branching = branching;
  out.level_offsets = level_offsets;
  out.points.resize(n);
  out.normals.resize(n);
  out.sphere_centers.resize(n);
  out.sphere_radii.resize(n);
  out.child_begin.assign(n, uint32_t(n));
  out.child_count.assign(n, 0);
  for (uint32_t i = 0; i < n; ++i) {
    const Node& node = nodes[order[i]];
    out.points[i] = shell.points[node.point];
    out.normals[i] = shell.normals[node.point];
    if (!node.children.empty()) {
      out.child_begin[i] = new_index[node.children.front()];
      out.child_count[i] = uint32_t(node.children.size());
    }
  }
  return out;
}

// Spheres bottom-up (reverse breadth-first): the minimal sphere around the node's point and its children's spheres
// encloses every descendant point.
void bound_spheres(PointShell& out) {
  for (size_t i = out.points.size(); i-- > 0;) {
    std::vector<MinSphere::Sphere> spheres;
    spheres.emplace_back(SphereTraits::Point(out.points[i][0], out.points[i][1], out.points[i][2]), 0.0);
    for (uint32_t c = out.child_begin[i]; c < out.child_begin[i] + out.child_count[i]; ++c)
      spheres.emplace_back(
          SphereTraits::Point(out.sphere_centers[c][0], out.sphere_centers[c][1], out.sphere_centers[c][2]),
          out.sphere_radii[c]);
    MinSphere ms(spheres.begin(), spheres.end());
    auto centre = ms.center_cartesian_begin();
    out.sphere_centers[i] = {centre[0], centre[1], centre[2]};
    double radius = ms.radius();
    // Guard against rounding: the sphere must contain its own point and its children's spheres.
    for (const auto& s : spheres) {
      const Vec3 sc = {s.first.x(), s.first.y(), s.first.z()};
      radius = std::max(radius, std::sqrt(distance2(sc, out.sphere_centers[i])) + s.second);
    }
    out.sphere_radii[i] = radius * (1 + 1e-12);
  }
}

}  // namespace

void build_sphere_tree(PointShell& shell, double branching) {
  if (!(branching >= 2)) throw BakeError(IssueCode::BadOption, "branching must be >= 2");
  std::vector<Node> nodes(shell.points.size());
  for (uint32_t i = 0; i < nodes.size(); ++i) {
    nodes[i].point = i;
    nodes[i].mass_sum = shell.points[i];
    nodes[i].mass_count = 1;
  }
  const uint32_t root = cluster_bottom_up(shell, branching, nodes);
  PointShell out = number_breadth_first(shell, branching, nodes, root);
  bound_spheres(out);
  shell = std::move(out);
}

}  // namespace voxfmt::bake
