// One environment of the batch on a block of lanes, walked level by level as the runtime's LevelTraversal walks
// (node order within a level): each lane examines one node of a tile (visit_node), a scan over the lanes places
// the tile's contacts and the ranges of the nodes it opens, and one lane adds the tile's wrench in node order. So
// the contacts, their order and the wrench's sums are the runtime's, bit for bit.
//
// Written once over a Block's lanes and barriers: block.each(phase) runs phase(lane) on every lane, then waits for
// all. CUDA runs it on a thread block (loaders/gpu/src/kernels.cu); the CPU tests on EmulatedBlock, whose lanes
// run one after another. Within a phase a lane reads only what earlier phases wrote (or its own slot) and writes
// only its own slots, or the same value as every other writer: then the two agree. State that lives across phases
// is in BlockState (shared memory on a GPU), never in a lane's locals.
#pragma once

#include "batch.h"

namespace voxfmt::runtime::core {

// The lanes of a block; another count only to measure one (scripts/gpu-check.sh builds several).
#ifndef VOXFMT_BLOCK_LANES
#define VOXFMT_BLOCK_LANES 128
#endif
constexpr int kBlockLanes = VOXFMT_BLOCK_LANES;
static_assert(kBlockLanes >= 32 && kBlockLanes <= 256 && (kBlockLanes & (kBlockLanes - 1)) == 0,
              "whole warps, a power of two, a lane index in a byte");

/// The children of a node the walk opened: the next level's nodes first .. first + count - 1, the bounds the
/// parent carries to them, and where they start among the level's nodes.
struct OpenRange {
  uint32_t first, count;
  float bound, point_bound;
  uint32_t start;
};

/// A block's frontier: two halves of `capacity` ranges each (the level walked and the next), in memory the caller
/// gives each block. A level that opens more nodes than `capacity` ends the environment with kEnvFrontierFull.
struct Frontier {
  OpenRange* ranges;
  uint32_t capacity;
};

/// The most nodes of one level that have children, over `shells`: the frontier capacity a walk never exceeds.
inline uint32_t frontier_capacity(const Shell* const* shells, size_t count) {
  uint32_t widest = 1;
  for (size_t s = 0; s < count; ++s) {
    // Breadth first, node n is a level's first when it is its previous level's first node's first child.
    const Shell& shell = *shells[s];
    uint32_t begin = 0, end = shell.count > 0 ? 1 : 0;
    while (begin < end) {
      uint32_t parents = 0, next_end = end;
      for (uint32_t n = begin; n < end; ++n)
        if (shell.nodes[n].child_count > 0) {
          ++parents;
          next_end = shell.nodes[n].first_child + shell.nodes[n].child_count;
        }
      widest = parents > widest ? parents : widest;
      begin = end;
      end = next_end;
    }
  }
  return widest;
}

/// What one lane found at its node of a tile.
struct LaneFind {
  ContactValues contact;  ///< where `hit`
  OpenRange children;     ///< where `opens` (start not yet placed)
  uint32_t node;
  uint32_t hit, opens;  ///< 0 or 1
};

/// A block's state across phases: the environment's query and reductions, the level walked, the tile's lanes.
struct BlockState {
  EnvQuery query;
  EnvResult result;
  ContactArrays out;
  double force[3], torque[3];
  uint32_t half;      ///< which half of the frontier holds the level walked
  uint32_t parents;   ///< ranges of the level walked
  uint32_t children;  ///< its nodes
  uint32_t next_parents, next_children;
  uint32_t frontier_full;
  LaneFind lane[kBlockLanes];
  uint8_t hit_lane[kBlockLanes];  ///< the tile's lanes that hit, in lane order
  /// Inclusive sums over the lanes of (hits, opened nodes, their children), two buffers a scan alternates.
  uint32_t sums[2][3][kBlockLanes];
};

/// The range among the level's `parents` whose children hold the level's `child`-th node.
VOXFMT_HD uint32_t range_of(const OpenRange* ranges, uint32_t parents, uint32_t child) {
  uint32_t low = 0, high = parents;  // ranges[low].start <= child < ranges[high].start
  while (high - low > 1) {
    const uint32_t middle = (low + high) / 2;
    if (ranges[middle].start <= child)
      low = middle;
    else
      high = middle;
  }
  return low;
}

/// Inclusive sums over the lanes of s.sums[0][c][*] for the three counters: returns which buffer holds them.
#if defined(__CUDACC__)
#pragma nv_exec_check_disable
#endif
template <class Block>
VOXFMT_HD int sum_lanes(const Block& block, BlockState& s) {
  int from = 0;
  for (int step = 1; step < kBlockLanes; step *= 2) {
    block.each([&](int lane) {
      for (int c = 0; c < 3; ++c) {
        uint32_t v = s.sums[from][c][lane];
        if (lane >= step) v += s.sums[from][c][lane - step];
        s.sums[1 - from][c][lane] = v;
      }
    });
    from = 1 - from;
  }
  return from;
}

/// Sets environment `e` up (one lane): its query, its outputs, the root as the first level.
template <class T>
VOXFMT_HD void begin_environment(BlockState& s, const BatchInputs<T>& in, const BatchOutputs& out, size_t e,
                                 const Frontier& frontier) {
  s.result = EnvResult{};
  for (int k = 0; k < 3; ++k) s.force[k] = s.torque[k] = 0;
  s.half = 0;
  s.parents = s.children = s.next_parents = s.next_children = s.frontier_full = 0;
  int32_t pair = 0;
  RigidPose pa, pb;
  if (!environment_of(in, e, pair, pa, pb, s.result)) return;
  s.query = env_query(in.bodies[in.pair_a[pair]], pa, in.bodies[in.pair_b[pair]], pb, in.proximity, in.stiffness,
                      in.gradient_normals);
  s.out = environment_contacts(out, e);
  if (!s.query.runs || s.query.shell->count == 0) return;
  const float infinity = __builtin_huge_valf();
  frontier.ranges[0] = {0, 1, -infinity, -infinity, 0};  // the root, as the child of no parent
  s.parents = s.children = 1;
}

/// Lane `lane`'s node of the tile from `base`: examined, and its three counters for the scan.
VOXFMT_HD void examine_lane(BlockState& s, const OpenRange* ranges, uint32_t base, int lane) {
  LaneFind& l = s.lane[lane];
  l.hit = l.opens = 0;
  const uint32_t child = base + uint32_t(lane);
  if (child < s.children) {
    const OpenRange& parent = ranges[range_of(ranges, s.parents, child)];
    l.node = parent.first + (child - parent.start);
    NodeVisit v;
    const Shell& shell = *s.query.shell;
    if (visit_node(*s.query.field, shell, s.query.frame, l.node, parent.bound, parent.point_bound, v) && v.in_reach) {
      if (v.hit) {
        l.hit = 1;
        contact_values(s.query, l.node, v.distance, &v.gradient, l.contact);
      }
      const Node& n = shell.nodes[l.node];
      if (n.child_count > 0) {
        l.opens = 1;
        l.children = {n.first_child, n.child_count, v.bound, v.point_bound, 0};
      }
    }
  }
  s.sums[0][0][lane] = l.hit;
  s.sums[0][1][lane] = l.opens;
  s.sums[0][2][lane] = l.opens ? l.children.count : 0;
}

/// Lane `lane`'s finds in place: its contact at the environment's next free slots, its children's range at the
/// next level's (the tile's sums in s.sums[sums]).
VOXFMT_HD void place_lane(BlockState& s, OpenRange* next, uint32_t capacity, int sums, int lane) {
  const LaneFind& l = s.lane[lane];
  if (l.hit) {
    s.hit_lane[s.sums[sums][0][lane] - 1] = uint8_t(lane);
    const uint32_t i = s.result.count + s.sums[sums][0][lane] - 1;
    if (i < s.out.capacity) write_contact(s.out, i, l.contact, l.node, s.query.point_of_b);
  }
  if (l.opens) {
    const uint32_t j = s.next_parents + s.sums[sums][1][lane] - 1;
    if (j < capacity) {
      OpenRange r = l.children;
      r.start = s.next_children + s.sums[sums][2][lane] - r.count;
      next[j] = r;
    } else {
      s.frontier_full = 1;  // every writer writes 1
    }
  }
}

/// The tile's reductions, by one lane in node order (the runtime's order of sums): over its hits only, the sums in
/// registers (in shared memory each addition would wait for the last one's store).
VOXFMT_HD void add_tile(BlockState& s, int sums) {
  const uint32_t hits = s.sums[sums][0][kBlockLanes - 1];
  double force[3] = {s.force[0], s.force[1], s.force[2]}, torque[3] = {s.torque[0], s.torque[1], s.torque[2]};
  EnvResult result = s.result;
  for (uint32_t h = 0; h < hits; ++h) add_contact(s.lane[s.hit_lane[h]].contact, result, force, torque);
  for (int k = 0; k < 3; ++k) {
    s.force[k] = force[k];
    s.torque[k] = torque[k];
  }
  s.result.max_depth = result.max_depth;
  const uint32_t room = s.result.count < s.out.capacity ? s.out.capacity - s.result.count : 0;
  s.result.overflow += hits > room ? hits - room : 0;
  s.result.count += hits;
  s.next_parents += s.sums[sums][1][kBlockLanes - 1];
  s.next_children += s.sums[sums][2][kBlockLanes - 1];
}

/// The next level becomes the one walked (one lane).
VOXFMT_HD void next_level(BlockState& s) {
  s.half = 1 - s.half;
  s.parents = s.next_parents;
  s.children = s.next_children;
  s.next_parents = s.next_children = 0;
  if (s.frontier_full) {
    s.children = 0;
    s.result = EnvResult{};
    s.result.error = kEnvFrontierFull;
  }
}

/// Environment `e` of a batch on `block`, start to end; `s` is the block's, `frontier` its memory.
#if defined(__CUDACC__)
#pragma nv_exec_check_disable
#endif
template <class Block, class T>
VOXFMT_HD void run_environment_block(const Block& block, BlockState& s, const BatchInputs<T>& in,
                                     const BatchOutputs& out, size_t e, const Frontier& frontier) {
  block.each([&](int lane) {
    if (lane == 0) begin_environment(s, in, out, e, frontier);
  });
  // s.children and s.half change only in next_level's phase: every lane reads the same values here.
  while (s.children > 0) {
    const uint32_t children = s.children;
    const OpenRange* ranges = frontier.ranges + size_t(s.half) * frontier.capacity;
    OpenRange* next = frontier.ranges + size_t(1 - s.half) * frontier.capacity;
    for (uint32_t base = 0; base < children; base += kBlockLanes) {
      block.each([&](int lane) { examine_lane(s, ranges, base, lane); });
      const int sums = sum_lanes(block, s);
      block.each([&](int lane) { place_lane(s, next, frontier.capacity, sums, lane); });
      const bool last_tile = base + kBlockLanes >= children;
      block.each([&](int lane) {
        if (lane != 0) return;
        add_tile(s, sums);
        if (last_tile) next_level(s);
      });
    }
  }
  block.each([&](int lane) {
    if (lane != 0) return;
    if (s.result.error == 0)
      for (int k = 0; k < 3; ++k) {
        s.result.force[k] = float(s.force[k]);
        s.result.torque[k] = float(s.torque[k]);
      }
    write_result(out, e, s.result);
  });
}

#if !defined(__CUDACC__)
/// A block for the CPU: its lanes run one after another, each phase to its end before the next begins; in
/// `reverse`, from the last lane to the first (a phase whose lanes read each other's writes then answers
/// differently, as it would on a GPU).
struct EmulatedBlock {
  bool reverse = false;
  template <class Phase>
  void each(Phase&& phase) const {
    for (int n = 0; n < kBlockLanes; ++n) phase(reverse ? kBlockLanes - 1 - n : n);
  }
};
#endif

}  // namespace voxfmt::runtime::core
