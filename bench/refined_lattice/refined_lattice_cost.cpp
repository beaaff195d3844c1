// What exact distances on a finer lattice in flagged coarse bricks would cost a bake (issue "fidelity", the coarse
// half of a format 2.2 candidate; bench/coarse_refinement.py measured what they give).
//
//   refined-lattice-cost ASSET MESH [--near VOXELS] [--ridge DEGREES] [--carry [--carry-steps STEPS]] [--threads N]
//                        [--json OUT]
//
// The bake's own nearest-triangle hierarchy (tools/bake's ClosestTriangle) over MESH, in the asset's frame. First the
// brick corners (the asset's lattice points): each one's nearest triangle and surface point, searched within the
// lattice value (what the bake's lattice stage already holds; timed apart). A coarse brick is flagged when a corner
// is within NEAR voxels of the surface or two corners' directions to their nearest surface points differ by more
// than RIDGE degrees (bench/coarse_refinement.py's flags). Then what the refinement would add to the bake: exact
// distances at the flagged bricks' points every 4 voxels (27 a brick, the 19 that are not corners, shared between
// neighbours), each searched within the distance to the nearest of its brick's corners' nearest triangles (carried,
// as the bake's lattice stage carries them); and, for the ridge bricks alone, every 2 voxels (125 a brick). Prints
// the counts and the seconds; each distance is checked against its corners' (1-Lipschitz) as it goes. `--carry`
// also finds the every-4 points' distances with no search at all (carry_points) and says how far above exact ones;
// `--carry-steps` stops it early (corners' triangles only, no walk, or no offers) to see which steps that needs.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include <nlohmann/json.hpp>

#include "closest_triangle.h"
#include "stages.h"
#include "triangle_closest_point.h"
#include "voxfmt/io.h"

namespace {

using voxfmt::Vec3;
using voxfmt::Voxelmap;
using voxfmt::bake::ClosestTriangle;

using voxfmt::bake::distance2;
using voxfmt::bake::dot;
using voxfmt::bake::operator-;

/// The point of triangle (a, b, c) nearest p: the bake's own routine (degenerate triangles included).
Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  voxfmt::bake::Feature feature;
  return voxfmt::bake::closest_on_triangle(p, a, b, c, feature);
}

double seconds_since(std::chrono::steady_clock::time_point& start) {
  const auto now = std::chrono::steady_clock::now();
  const double s = std::chrono::duration<double>(now - start).count();
  start = now;
  return s;
}

/// body(n) for n in [0, count) on `threads` threads, each taking every threads-th one.
template <class Body>
void parallel(size_t count, unsigned threads, const Body& body) {
  auto every = [&](unsigned first) {
    for (size_t n = first; n < count; n += threads) body(n);
  };
  std::vector<std::thread> workers;
  for (unsigned t = 1; t < threads; ++t) workers.emplace_back(every, t);
  every(0);
  for (std::thread& w : workers) w.join();
}

struct Corner {
  double distance = 0;  // metres
  uint32_t triangle = 0;
  Vec3 direction{};  // to the nearest surface point, unit (zero on the surface)
};

struct Search {
  const Voxelmap& vm;
  const std::vector<std::array<Vec3, 3>>& corners;
  const ClosestTriangle& tree;
  Vec3 at(int64_t i, int64_t j, int64_t k) const { return vm.voxel_center(uint32_t(i), uint32_t(j), uint32_t(k)); }
};

/// A voxel as a key i | j << 21 | k << 42, and back.
uint64_t key_of(const std::array<int64_t, 3>& v) {
  return uint64_t(v[0]) | uint64_t(v[1]) << 21 | uint64_t(v[2]) << 42;
}
std::array<int64_t, 3> voxel_of(uint64_t key) {
  return {int64_t(key & 0x1fffff), int64_t(key >> 21 & 0x1fffff), int64_t(key >> 42)};
}

/// The brick whose cell holds voxel v (the last brick along an axis for the grid's last voxel).
std::array<uint32_t, 3> brick_of(const Voxelmap& vm, const std::array<int64_t, 3>& v) {
  const auto bd = vm.brick_dims();
  constexpr uint32_t edge = Voxelmap::kBrickEdge;
  return {std::min(uint32_t(v[0]) / edge, bd[0] - 1), std::min(uint32_t(v[1]) / edge, bd[1] - 1),
          std::min(uint32_t(v[2]) / edge, bd[2] - 1)};
}

/// The nearest to p of the nearest triangles of brick b's 8 corners: its squared distance and index.
std::pair<double, uint32_t> nearest_corner_triangle(const Search& s, const std::vector<Corner>& lattice, const Vec3& p,
                                                    const std::array<uint32_t, 3>& b) {
  double best = 1e300;
  uint32_t triangle = 0;
  for (int q = 0; q < 8; ++q) {
    const uint32_t f = lattice[s.vm.lattice_index(b[0] + (q & 1), b[1] + (q >> 1 & 1), b[2] + (q >> 2))].triangle;
    const double d2 = distance2(closest_on_triangle(p, s.corners[f][0], s.corners[f][1], s.corners[f][2]), p);
    if (d2 < best) best = d2, triangle = f;
  }
  return {best, triangle};
}

/// Exact distances at the voxels `points` (keys, key_of), each within the least over its brick's corners of their
/// distance plus the way to them; returns the largest excess of a distance over that bound, relative to the bound
/// (at most the search's own 1e-9 unless something is wrong); the distances into `distances` if given.
double search_points(const Search& s, const std::vector<uint64_t>& points, const std::vector<Corner>& lattice,
                     unsigned threads, double slack, std::vector<double>* distances = nullptr) {
  std::vector<double> excess(threads, -1e30);
  if (distances) distances->assign(points.size(), 0);
  parallel(points.size(), threads, [&](size_t n) {
    const auto v = voxel_of(points[n]);
    const Vec3 p = s.at(v[0], v[1], v[2]);
    const auto b = brick_of(s.vm, v);
    // The corners' nearest triangles bound it (carried, as the bake's lattice stage carries them), and the least
    // corner distance plus the way to that corner is the bound a distance must keep.
    double bound = 1e300;
    for (int q = 0; q < 8; ++q) {
      const uint32_t a = b[0] + (q & 1), c = b[1] + (q >> 1 & 1), d = b[2] + (q >> 2);
      const Vec3 cp = s.vm.lattice_point_center(a, c, d);
      bound = std::min(bound, lattice[s.vm.lattice_index(a, c, d)].distance + std::sqrt(distance2(p, cp)));
    }
    const auto [carried2, hint] = nearest_corner_triangle(s, lattice, p, b);
    const double bound2 = std::min(bound * bound, carried2) * (1 + 1e-9);
    const auto [d2, f] = s.tree.nearest(p, bound2, hint, slack);
    (void)f;
    if (distances) (*distances)[n] = std::sqrt(d2);
    excess[n % threads] = std::max(excess[n % threads], (std::sqrt(d2) - bound) / std::max(bound, 1e-300));
  });
  return *std::max_element(excess.begin(), excess.end());
}

/// Each brick corner's nearest triangle and direction to it, searched within its lattice value (an upper bound of the
/// exact distance); `over` counts the corners whose exact distance is above their value (a broken lattice).
std::vector<Corner> find_corners(const Search& s, unsigned threads, size_t& over) {
  const Voxelmap& vm = s.vm;
  const auto bd = vm.brick_dims();
  std::vector<Corner> lattice(size_t(bd[0] + 1) * (bd[1] + 1) * (bd[2] + 1));
  std::atomic<size_t> above{0};
  parallel(size_t(bd[2] + 1), threads, [&](size_t c) {
    for (uint32_t b = 0; b <= bd[1]; ++b)
      for (uint32_t a = 0; a <= bd[0]; ++a) {
        const Vec3 p = vm.lattice_point_center(a, b, uint32_t(c));
        const double l = vm.lattice[vm.lattice_index(a, b, uint32_t(c))];
        auto [d2, f] = s.tree.nearest(p, (l * l) * (1 + 1e-6) + 1e-18, 0, 0.0);
        if (!(d2 < (l * l) * (1 + 1e-6) + 1e-18)) std::tie(d2, f) = s.tree.nearest(p, 1e300, 0, 0.0), ++above;
        Corner& corner = lattice[vm.lattice_index(a, b, uint32_t(c))];
        corner.distance = std::sqrt(d2);
        corner.triangle = f;
        const Vec3 d = closest_on_triangle(p, s.corners[f][0], s.corners[f][1], s.corners[f][2]) - p;
        const double n = std::sqrt(dot(d, d));
        corner.direction = n > 0 ? Vec3{d[0] / n, d[1] / n, d[2] / n} : Vec3{0, 0, 0};
      }
  });
  over = above;
  return lattice;
}

/// Triangles sharing a vertex with each triangle (compressed rows, each once), for a walk over the surface.
struct Rings {
  std::vector<uint32_t> begin, around;
  Rings(const std::vector<std::array<uint32_t, 3>>& triangles, size_t vertex_count) {
    std::vector<uint32_t> first(vertex_count + 1, 0), of_vertex;
    for (const auto& t : triangles)
      for (uint32_t v : t) ++first[v + 1];
    for (size_t v = 0; v < vertex_count; ++v) first[v + 1] += first[v];
    of_vertex.resize(first.back());
    std::vector<uint32_t> fill(first.begin(), first.end() - 1);
    for (uint32_t t = 0; t < triangles.size(); ++t)
      for (uint32_t v : triangles[t]) of_vertex[fill[v]++] = t;
    begin.assign(triangles.size() + 1, 0);
    for (uint32_t t = 0; t < triangles.size(); ++t) {
      for (uint32_t v : triangles[t])
        for (uint32_t r = first[v]; r < first[v + 1]; ++r)
          if (of_vertex[r] != t) around.push_back(of_vertex[r]);
      // An edge's neighbour shares two vertices: once is enough.
      std::sort(around.begin() + begin[t], around.end());
      around.erase(std::unique(around.begin() + begin[t], around.end()), around.end());
      begin[t + 1] = uint32_t(around.size());
    }
  }
};

struct Carried {
  std::vector<double> distances;  // the asset's units
  size_t rounds = 0, walk_steps = 0;
  bool settled = false;  // no offer was taken in the last round (else it stopped after kMaxRounds)
};
constexpr size_t kMaxRounds = 32;

/// Distances at `points` without a search: each point takes the nearest of its brick's corners' nearest triangles,
/// then walks from triangle to a triangle sharing a vertex while that is nearer, and points every 4 voxels apart
/// offer each other their triangles (then walk again) until none changes. Every value is a distance to a real
/// triangle, so never below the exact one; how far above is what this measures.
/// What carry_points does after taking the corners' triangles: walk over the surface, take the neighbours' offers.
struct CarrySteps {
  bool walk = true, offers = true;
  std::string name() const { return walk ? (offers ? "offers" : "walk") : (offers ? "offers-unwalked" : "corners"); }
};

Carried carry_points(const Search& s, const Rings* rings, const std::vector<uint64_t>& points,
                     const std::vector<Corner>& lattice, unsigned threads, CarrySteps last) {
  std::unordered_map<uint64_t, uint32_t> index;
  for (uint32_t n = 0; n < points.size(); ++n) index.emplace(points[n], n);
  std::vector<uint32_t> triangle(points.size());
  std::vector<double> d2(points.size());
  std::atomic<size_t> steps{0};
  auto walk = [&](const Vec3& p, uint32_t& t, double& best) {
    size_t taken = 0;
    for (bool moved = true; moved;) {
      moved = false;
      const uint32_t from = t;
      for (uint32_t r = rings->begin[from]; r < rings->begin[from + 1]; ++r) {
        const auto& c = s.corners[rings->around[r]];
        const double e = distance2(closest_on_triangle(p, c[0], c[1], c[2]), p);
        if (e < best) best = e, t = rings->around[r], moved = true;
      }
      taken += moved;
    }
    steps += taken;
  };
  parallel(points.size(), threads, [&](size_t n) {
    const auto v = voxel_of(points[n]);
    const Vec3 p = s.at(v[0], v[1], v[2]);
    auto [best, t] = nearest_corner_triangle(s, lattice, p, brick_of(s.vm, v));
    if (last.walk) walk(p, t, best);
    triangle[n] = t, d2[n] = best;
  });
  // Each point's neighbours 4 voxels away along the axes, kNone where that is not a point of `points`: outside the
  // flagged bricks, a brick corner, or past the grid's last voxel (a point clamped to it has uneven neighbours).
  constexpr uint32_t kNone = ~0u;
  std::vector<std::array<uint32_t, 6>> beside(points.size());
  parallel(points.size(), threads, [&](size_t n) {
    const auto c = voxel_of(points[n]);
    for (int a = 0; a < 3; ++a)
      for (int side = 0; side < 2; ++side) {
        auto m = c;
        m[a] += side ? 4 : -4;
        const auto found = m[a] < 0 ? index.end() : index.find(key_of(m));
        beside[n][2 * a + side] = found == index.end() ? kNone : found->second;
      }
  });
  // Rounds of offers; after the first only points with a neighbour that changed in the round before.
  Carried out;
  std::vector<uint8_t> changed(points.size(), 1), changed_now(points.size());
  out.settled = !last.offers;
  while (!out.settled && out.rounds < kMaxRounds) {
    const std::vector<uint32_t> offered = triangle;
    std::fill(changed_now.begin(), changed_now.end(), 0);
    std::atomic<bool> lowered{false};
    parallel(points.size(), threads, [&](size_t n) {
      bool news = false;
      for (uint32_t m : beside[n]) news |= m != kNone && changed[m];
      if (!news) return;
      const auto c = voxel_of(points[n]);
      const Vec3 p = s.at(c[0], c[1], c[2]);
      bool took = false;
      for (uint32_t m : beside[n]) {
        if (m == kNone || !changed[m] || offered[m] == triangle[n]) continue;
        const uint32_t f = offered[m];
        const double e = distance2(closest_on_triangle(p, s.corners[f][0], s.corners[f][1], s.corners[f][2]), p);
        if (e < d2[n]) d2[n] = e, triangle[n] = f, took = true;
      }
      if (took) {
        if (last.walk) walk(p, triangle[n], d2[n]);
        changed_now[n] = 1;
        lowered = true;
      }
    });
    changed.swap(changed_now);
    ++out.rounds;
    out.settled = !lowered;
  }
  out.distances.resize(points.size());
  for (size_t n = 0; n < points.size(); ++n) out.distances[n] = std::sqrt(d2[n]);
  out.walk_steps = steps;
  return out;
}

struct Flags {
  std::vector<uint8_t> of_brick;  ///< by brick table index: 1 near, 2 ridge (3 both)
  size_t coarse = 0, near = 0, ridge = 0, flagged = 0;
};

/// The coarse bricks with a corner within `near` voxels of the surface, and those whose corners' directions to
/// their nearest surface points differ by more than `ridge` degrees.
Flags flag_bricks(const Voxelmap& vm, const std::vector<Corner>& lattice, double near, double ridge) {
  const auto bd = vm.brick_dims();
  const double cos_ridge = std::cos(ridge * M_PI / 180);
  Flags flags;
  flags.of_brick.assign(vm.bricks.size(), 0);
  for (uint32_t bk = 0; bk < bd[2]; ++bk)
    for (uint32_t bj = 0; bj < bd[1]; ++bj)
      for (uint32_t bi = 0; bi < bd[0]; ++bi) {
        const size_t n = vm.brick_index(bi, bj, bk);
        if (vm.bricks[n] >= 0) continue;
        ++flags.coarse;
        const Corner* c[8];
        for (int q = 0; q < 8; ++q) c[q] = &lattice[vm.lattice_index(bi + (q & 1), bj + (q >> 1 & 1), bk + (q >> 2))];
        bool is_near = false, is_ridge = false;
        for (int q = 0; q < 8; ++q) is_near |= c[q]->distance < near * vm.voxel_size;
        for (int q = 0; q < 8 && !is_ridge; ++q)
          for (int r = q + 1; r < 8; ++r) is_ridge |= dot(c[q]->direction, c[r]->direction) < cos_ridge;
        flags.of_brick[n] = uint8_t((is_near ? 1 : 0) | (is_ridge ? 2 : 0));
        flags.near += is_near, flags.ridge += is_ridge, flags.flagged += flags.of_brick[n] != 0;
      }
  return flags;
}

/// The points every `step` voxels in the bricks flagged with a bit of `mask` (not their corners, each once), as
/// keys (key_of).
std::vector<uint64_t> points_every(const Voxelmap& vm, const Flags& flags, int step, uint8_t mask) {
  const auto bd = vm.brick_dims();
  std::unordered_set<uint64_t> unique;
  for (uint32_t bk = 0; bk < bd[2]; ++bk)
    for (uint32_t bj = 0; bj < bd[1]; ++bj)
      for (uint32_t bi = 0; bi < bd[0]; ++bi) {
        if (!(flags.of_brick[vm.brick_index(bi, bj, bk)] & mask)) continue;
        for (int z = 0; z <= 8; z += step)
          for (int y = 0; y <= 8; y += step)
            for (int x = 0; x <= 8; x += step) {
              if (x % 8 == 0 && y % 8 == 0 && z % 8 == 0) continue;  // a corner
              unique.insert(key_of({std::min<int64_t>(bi * 8 + uint32_t(x), vm.dims[0] - 1),
                                    std::min<int64_t>(bj * 8 + uint32_t(y), vm.dims[1] - 1),
                                    std::min<int64_t>(bk * 8 + uint32_t(z), vm.dims[2] - 1)}));
            }
      }
  std::vector<uint64_t> points(unique.begin(), unique.end());
  std::sort(points.begin(), points.end());
  return points;
}

struct Settings {
  std::string asset_path, mesh_path, json_path;
  double near = 16, ridge = 45, slack = 0.01;
  unsigned threads = 2;
  bool carry = false;
  CarrySteps carry_steps;
  uint64_t max_memory_mib = voxfmt::ReadOptions::kDefaultReadMemoryBytes >> 20;
};

void add_options(CLI::App& app, Settings& o) {
  app.add_option("asset", o.asset_path, "a baked asset")->required();
  app.add_option("mesh", o.mesh_path, "the mesh it was baked from")->required();
  app.add_option("--near", o.near, "flag a coarse brick with a corner within this many voxels of the surface (16)");
  app.add_option("--ridge", o.ridge,
                 "flag a coarse brick whose corners' nearest directions differ by more (45 degrees)");
  app.add_option("--slack", o.slack,
                 "the new points' searches may settle this much above the exact distance, relatively (0.01: the "
                 "issue's 1 %; 0 searches exactly)");
  app.add_flag("--carry", o.carry,
               "also find the every-4 points' distances without a search (corners' triangles carried, walked over "
               "the surface, offered between neighbours) and compare them with exact searches");
  app.add_option_function<std::string>(
         "--carry-steps",
         [&o](const std::string& name) {
           o.carry_steps = {name == "walk" || name == "offers", name == "offers" || name == "offers-unwalked"};
         },
         "how far --carry goes after the corners' triangles: corners (no further), walk (over the surface), "
         "offers-unwalked (neighbours' offers, no walk), offers (walk and offers; the default)")
      ->check(CLI::IsMember({"corners", "walk", "offers-unwalked", "offers"}));
  app.add_option("--threads", o.threads, "threads (2)")->check(CLI::Range(1u, 64u));
  app.add_option("--max-memory", o.max_memory_mib, "MiB the read may take")
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 30));
  app.add_option("--json", o.json_path, "write the figures here");
}

/// The figures as a table.
void print_table(const Settings& o, const Voxelmap& vm, const nlohmann::json& f) {
  std::printf("refined-lattice-cost: %s (%u x %u x %u voxels), %zu triangles, %u threads\n", o.asset_path.c_str(),
              vm.dims[0], vm.dims[1], vm.dims[2], f["triangles"].get<size_t>(), o.threads);
  std::printf("| step | count | s |\n|---|---|---|\n| hierarchy | %zu triangles | %.3f |\n",
              f["triangles"].get<size_t>(), f["hierarchy_s"].get<double>());
  std::printf("| corners (the bake has them) | %zu lattice points (%zu above their value) | %.3f |\n",
              f["lattice_points"].get<size_t>(), f["corners_above_lattice"].get<size_t>(),
              f["corners_s"].get<double>());
  std::printf("| flags | %zu of %zu coarse bricks (near %zu, ridge %zu) | |\n", f["flagged"].get<size_t>(),
              f["coarse_bricks"].get<size_t>(), f["near"].get<size_t>(), f["ridge"].get<size_t>());
  std::printf("| every 4 voxels in flagged bricks | %zu points | %.3f |\n", f["every4_points"].get<size_t>(),
              f["every4_s"].get<double>());
  std::printf("| every 2 voxels in ridge bricks | %zu points | %.3f |\n", f["every2_points"].get<size_t>(),
              f["every2_s"].get<double>());
  if (!f.contains("carried")) return;
  const nlohmann::json& c = f["carried"];
  std::printf("| every 4, exact searches | %zu points | %.3f |\n", f["every4_points"].get<size_t>(),
              c["exact_s"].get<double>());
  std::printf("| every 4, carried (no search; up to %s) | %zu rounds%s, %zu walk steps (adjacency %.3f s) | %.3f |\n",
              c["steps"].get<std::string>().c_str(), c["rounds"].get<size_t>(),
              c["settled"].get<bool>() ? "" : " (not settled)", c["walk_steps"].get<size_t>(),
              c["adjacency_s"].get<double>(), c["s"].get<double>());
  std::printf(
      "carried above exact, voxels: max %.3f, p99 %.3f; share above 0.01 / 0.1 / 0.5 / 1: %.3f %% / %.3f %% / "
      "%.3f %% / %.3f %%; lowest %.2g\n",
      c["max_over_voxels"].get<double>(), c["p99_over_voxels"].get<double>(), 100 * c["share_over_0_01"].get<double>(),
      100 * c["share_over_0_1"].get<double>(), 100 * c["share_over_0_5"].get<double>(),
      100 * c["share_over_1"].get<double>(), c["lowest_voxels"].get<double>());
}

/// carry_points at the every-4 points (the surface's adjacency built within its time) against exact searches: both
/// times, and how far above the exact distance. Returns the exact searches' excess over their bound (search_points).
double compare_carried(const Search& s, const voxfmt::bake::TriangleMesh& mesh, const std::vector<uint64_t>& points,
                       const std::vector<Corner>& lattice, unsigned threads, CarrySteps last, nlohmann::json& figures) {
  auto clock = std::chrono::steady_clock::now();
  std::optional<Rings> rings;
  if (last.walk) rings.emplace(mesh.triangles, mesh.vertices.size());
  const double rings_s = seconds_since(clock);
  const Carried carried = carry_points(s, rings ? &*rings : nullptr, points, lattice, threads, last);
  const double carry_s = rings_s + seconds_since(clock);
  std::vector<double> exact;
  const double excess = search_points(s, points, lattice, threads, 0.0, &exact);
  const double exact_s = seconds_since(clock);
  std::vector<double> over(points.size());
  double below = 0;
  for (size_t n = 0; n < points.size(); ++n) {
    over[n] = (carried.distances[n] - exact[n]) / s.vm.voxel_size;
    below = std::min(below, over[n]);
  }
  std::sort(over.begin(), over.end());
  auto share = [&](double v) {
    return double(over.end() - std::upper_bound(over.begin(), over.end(), v)) /
           double(std::max<size_t>(1, over.size()));
  };
  const double p99 = over.empty() ? 0 : over[size_t(std::ceil(0.99 * double(over.size() - 1)))];
  figures["carried"] = {{"steps", last.name()},
                        {"s", carry_s},
                        {"adjacency_s", rings_s},
                        {"exact_s", exact_s},
                        {"settled", carried.settled},
                        {"rounds", carried.rounds},
                        {"walk_steps", carried.walk_steps},
                        {"max_over_voxels", over.empty() ? 0 : over.back()},
                        {"p99_over_voxels", p99},
                        {"lowest_voxels", below},
                        {"share_over_0_01", share(0.01)},
                        {"share_over_0_1", share(0.1)},
                        {"share_over_0_5", share(0.5)},
                        {"share_over_1", share(1.0)}};
  return excess;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"What exact distances on a finer lattice in flagged coarse bricks would cost a bake (bench)"};
  Settings o;
  add_options(app, o);
  CLI11_PARSE(app, argc, argv);
  voxfmt::ReadOptions read;
  read.max_memory_bytes = o.max_memory_mib << 20;
  auto asset = voxfmt::read_asset(o.asset_path, nullptr, read);
  if (!asset) {
    std::cerr << "refined-lattice-cost: " << asset.error().describe() << "\n";
    return 2;
  }
  const Voxelmap& vm = asset->voxelmap;
  voxfmt::bake::TriangleMesh mesh;
  try {
    mesh = voxfmt::bake::import_mesh(o.mesh_path);
  } catch (const voxfmt::bake::BakeError& e) {
    std::cerr << "refined-lattice-cost: " << e.what() << "\n";
    return 2;
  }
  std::vector<std::array<Vec3, 3>> tris;
  tris.reserve(mesh.triangles.size());
  for (const auto& t : mesh.triangles) tris.push_back({mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]]});
  auto clock = std::chrono::steady_clock::now();
  const ClosestTriangle tree(tris);
  nlohmann::json figures = {{"asset", o.asset_path},    {"mesh", o.mesh_path},
                            {"threads", o.threads},     {"near_voxels", o.near},
                            {"ridge_degrees", o.ridge}, {"slack", o.slack},
                            {"triangles", tris.size()}, {"hierarchy_s", seconds_since(clock)}};
  const Search s{vm, tris, tree};
  size_t over = 0;
  const std::vector<Corner> lattice = find_corners(s, o.threads, over);
  figures["corners_s"] = seconds_since(clock);
  const Flags flags = flag_bricks(vm, lattice, o.near, o.ridge);
  const std::vector<uint64_t> every4 = points_every(vm, flags, 4, 3), every2 = points_every(vm, flags, 2, 2);
  seconds_since(clock);
  const double excess4 = search_points(s, every4, lattice, o.threads, o.slack);
  figures["every4_s"] = seconds_since(clock);
  const double excess2 = search_points(s, every2, lattice, o.threads, o.slack);
  figures["every2_s"] = seconds_since(clock);
  const double excess_exact =
      o.carry ? compare_carried(s, mesh, every4, lattice, o.threads, o.carry_steps, figures) : 0.0;
  figures.update({{"lattice_points", lattice.size()},
                  {"corners_above_lattice", over},
                  {"coarse_bricks", flags.coarse},
                  {"flagged", flags.flagged},
                  {"near", flags.near},
                  {"ridge", flags.ridge},
                  {"every4_points", every4.size()},
                  {"every2_points", every2.size()}});
  print_table(o, vm, figures);
  if (std::max({excess4, excess2, excess_exact}) > 1e-8) {
    std::fprintf(stderr, "refined-lattice-cost: a distance above its bound (relative excess %g, %g, %g)\n", excess4,
                 excess2, excess_exact);
    return 1;
  }
  if (!o.json_path.empty() && !(std::ofstream(o.json_path) << figures.dump(1) << "\n").flush()) {
    std::cerr << "refined-lattice-cost: cannot write " << o.json_path << "\n";
    return 1;
  }
  return 0;
}
