// What a read will cost, decided from a file's metadata before any of its data is decoded (spec §1, "Limits").
// A small file can declare gigabytes: chunks never written read as the fill value, and deflate inflates a
// thousandfold. So the declared shapes, chunk shapes and element sizes alone decide whether the read goes on:
// the format's limits (a damaged or hostile file: VALUE_OUT_OF_RANGE) and the reader's budget (a file too big
// for this reader: OUT_OF_MEMORY, with the figure). Nothing here depends on the machine, so a file's verdict
// is the same everywhere.
#include <algorithm>
#include <cstdio>

#include "load.h"

namespace voxfmt::detail {

namespace {

constexpr uint64_t kMiB = uint64_t(1) << 20;
/// Spec §1: a file may declare at most this many bytes of data per byte it stores, plus kDeclaredSlack (deflate's
/// own ratio is at most 1032; voxfmt's 2.0 files declare about 2x their size, its 1.x files up to ~200x).
constexpr uint64_t kDeclaredPerStored = 1024;
constexpr uint64_t kDeclaredSlack = 64 * kMiB;
/// What a read may decode, as a multiple of its memory budget (a 1.x grid is decoded a slab at a time and
/// converted, so it decodes more than it holds).
constexpr uint64_t kWorkPerBudget = 4;
/// HDF5's own allowance besides the data: open objects, its caches, a chunk being decoded and its filter buffer.
constexpr uint64_t kLibraryBytes = 16 * kMiB;

std::string mib(uint64_t bytes) {
  char text[32];
  if (bytes < kMiB)
    std::snprintf(text, sizeof text, "%.1f KiB", double(bytes) / 1024.0);
  else
    std::snprintf(text, sizeof text, "%.1f MiB", double(bytes) / double(kMiB));
  return text;
}

uint64_t saturating_add(uint64_t a, uint64_t b) { return a > UINT64_MAX - b ? UINT64_MAX : a + b; }
uint64_t saturating_mul(uint64_t a, uint64_t b) { return b != 0 && a > UINT64_MAX / b ? UINT64_MAX : a * b; }

struct Dataset {
  const char* name;
  size_t element_bytes;  // as held in memory (the format's dtype)
  bool held;             // kept whole in memory (else streamed: a 1.x grid)
};

constexpr Dataset kBrickDatasets[] = {{"bricks", 4, true}, {"brick_values", 2, true}, {"lattice", 4, true}};
constexpr Dataset kDenseDatasets[] = {{"layers", 2, false}, {"distances", 4, false}};
constexpr Dataset kShellDatasets[] = {{"points", 8, true},       {"normals", 4, true},     {"sphere_centers", 8, true},
                                      {"sphere_radii", 8, true}, {"child_begin", 4, true}, {"child_count", 4, true},
                                      {"level_offsets", 4, true}};

// What the datasets declare, summed as they are visited (saturating: a hostile file may declare anything).
struct ReadTally {
  uint64_t declared = 0;  // bytes the datasets declare in the file's types
  uint64_t held = 0;      // bytes the read keeps in memory
  uint64_t work = 0;      // bytes the read decodes
  uint64_t chunks = 0, largest_chunk = 0;
  uint64_t streamed_cache = 0;  // chunk caches of the streamed 1.x grids, together
  uint64_t dense_cache = 0;     // the largest one
  uint64_t most_chunks = 0;
  std::string most_chunked;  // the dataset split into the most chunks: the one a message names
  std::vector<uint64_t> dense_shape;
  bool refused = false;

  void add(h5::Reader& r, const std::string& path, const h5::Layout& l, const Dataset& dataset) {
    const uint64_t elements = l.elements();
    const uint64_t bytes = saturating_mul(elements, l.element_bytes);
    const uint64_t chunk_bytes = l.chunk_bytes();
    if (chunk_bytes > h5::kMaxChunkBytes) {
      r.report(IssueCode::ValueOutOfRange, path,
               "chunks of " + mib(chunk_bytes) + " each, more than the format's " + mib(h5::kMaxChunkBytes) +
                   " (a chunk is decoded whole: one would hold the read up for its whole size)");
      refused = true;
    }
    declared = saturating_add(declared, bytes);
    chunks = saturating_add(chunks, l.chunk_count());
    if (l.chunk_count() > most_chunks) {
      most_chunks = l.chunk_count();
      most_chunked = path;
    }
    largest_chunk = std::max(largest_chunk, chunk_bytes);
    work = saturating_add(work, bytes);
    if (dataset.held) {
      held = saturating_add(held, saturating_mul(elements, dataset.element_bytes));
    } else if (l.shape.size() == 3) {
      // A 1.x grid, read 9 z layers at a time: two bands of chunks cached (each decoded once), a slab held.
      const uint64_t plane = saturating_mul(l.shape[1], l.shape[2]);
      const uint64_t band = l.chunk.size() == 3 ? saturating_mul(plane, l.chunk[0] * l.element_bytes) : 0;
      dense_cache = std::max(dense_cache, saturating_mul(band, 2));
      streamed_cache = saturating_add(streamed_cache, saturating_mul(band, 2));
      held = saturating_add(held, saturating_mul(plane, 9 * dataset.element_bytes));
      dense_shape = l.shape;
    }
  }

  template <size_t N>
  void add_group(h5::Reader& r, const char* group, const Dataset (&datasets)[N]) {
    h5::Handle g(H5Gopen2(r.file(), group, H5P_DEFAULT), H5Gclose);
    if (!g.valid()) {
      H5Eclear2(H5E_DEFAULT);
      return;  // the read reports a missing group
    }
    for (const Dataset& dataset : datasets) {
      std::optional<h5::Layout> l = r.layout(g.get(), dataset.name);
      if (l) add(r, std::string(group) + "/" + dataset.name, *l, dataset);  // else the read reports it
    }
  }

  // A 1.x grid becomes a brick table and a lattice (4 bytes per brick and lattice point) plus its value bricks.
  void add_converted_grid() {
    if (dense_shape.size() != 3) return;
    uint64_t bricks = 1, lattice = 1;
    for (uint64_t d : dense_shape) {
      bricks = saturating_mul(bricks, (d + 7) / 8);
      lattice = saturating_mul(lattice, (d + 7) / 8 + 1);
    }
    held = saturating_add(held, saturating_mul(saturating_add(bricks, lattice), 4));
  }
};

// The format's limits: false (and reported) where the file breaks one.
bool within_format_limits(h5::Reader& r, const ReadTally& t, uint64_t file_bytes) {
  if (t.refused) return false;
  if (t.chunks > h5::kMaxChunksPerFile) {
    r.report(IssueCode::ValueOutOfRange, t.most_chunked,
             "the datasets are split into " + std::to_string(t.chunks) + " chunks (this one " +
                 std::to_string(t.most_chunks) + "), more than the format's " + std::to_string(h5::kMaxChunksPerFile) +
                 " per file: chunks this small cost more to find than to read");
    return false;
  }
  const uint64_t allowed = saturating_add(saturating_mul(file_bytes, kDeclaredPerStored), kDeclaredSlack);
  if (t.declared > allowed) {
    r.report(IssueCode::ValueOutOfRange, "/",
             "the datasets declare " + mib(t.declared) + " in a file of " + mib(file_bytes) +
                 ", more than the format allows (" + std::to_string(kDeclaredPerStored) +
                 " bytes per stored byte + 64 MiB): chunks that were never written, or a decompression bomb");
    return false;
  }
  return true;
}

// The reader's budget: the bytes the read needs, or nothing (reported) where it is beyond the budget.
std::optional<uint64_t> within_budget(h5::Reader& r, const ReadTally& t, uint64_t budget) {
  const uint64_t need = saturating_add(saturating_add(t.held, t.streamed_cache),
                                       saturating_add(saturating_mul(t.largest_chunk, 2), kLibraryBytes));
  const std::string larger =
      " (nothing was read; a larger budget reads it: --max-memory MiB, max_memory_mib=, "
      "ReadOptions::max_memory_bytes)";
  if (need > budget) {
    r.report(IssueCode::OutOfMemory, "/",
             "reading this file needs " + mib(need) + ", more than the read budget of " + mib(budget) + larger);
    return std::nullopt;
  }
  if (t.work > saturating_mul(budget, kWorkPerBudget)) {
    r.report(IssueCode::OutOfMemory, "/",
             "reading this file decodes " + mib(t.work) + ", more than " + std::to_string(kWorkPerBudget) +
                 " times the read budget of " + mib(budget) + larger);
    return std::nullopt;
  }
  return need;
}

}  // namespace

std::optional<DenseReadBudget> check_read_cost(h5::Reader& r, const FormatVersion& version, uint64_t file_bytes,
                                               const ReadOptions& options) {
  ReadTally tally;
  if (version.major == 1)
    tally.add_group(r, "/voxelmap", kDenseDatasets);
  else
    tally.add_group(r, "/voxelmap", kBrickDatasets);
  tally.add_group(r, "/pointshell", kShellDatasets);
  tally.add_converted_grid();
  if (!within_format_limits(r, tally, file_bytes)) return std::nullopt;
  const std::optional<uint64_t> need = within_budget(r, tally, options.max_memory_bytes);
  if (!need) return std::nullopt;
  DenseReadBudget dense;
  dense.chunk_cache_bytes = tally.dense_cache;
  dense.value_brick_bytes = options.max_memory_bytes - *need;
  return dense;
}

}  // namespace voxfmt::detail
