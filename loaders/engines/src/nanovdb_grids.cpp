// NanoVDB grids from the runtime's field, with NanoVDB's own header-only builder (no OpenVDB library, so the Python
// package builds them too): the level set's leaves are bricks of the asset, its tiles signed from the brick table.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <sstream>
#include <system_error>

#define NANOVDB_USE_ZIP
#include <nanovdb/NanoVDB.h>
#include <nanovdb/util/GridBuilder.h>
#include <nanovdb/util/GridChecksum.h>
#include <nanovdb/util/IO.h>
#include <zlib.h>

#include "field_samples.h"
#include "voxfmt/detail/cores.h"
#include "voxfmt/engines/layouts.h"
#include "voxfmt/version.h"

#include <nlohmann/json.hpp>

namespace voxfmt::engines {

namespace {

using detail::FieldSamples;
namespace core = runtime::core;
constexpr int kEdge = core::kEdge;

/// The grid's blind data: the metadata JSON, as NanoVDB's tools and Warp's feature arrays see it (bytes).
void attach_metadata(nanovdb::GridHandle<>& handle, const std::string& json) {
  if (json.empty()) return;
  nanovdb::GridData* data = reinterpret_cast<nanovdb::GridData*>(handle.data());
  auto* meta = const_cast<nanovdb::GridBlindMetaData*>(data->blindMetaData(0));
  meta->mElementCount = json.size();
  meta->mFlags = 0;
  meta->mSemantic = nanovdb::GridBlindDataSemantic::Unknown;
  meta->mDataClass = nanovdb::GridBlindDataClass::Unknown;
  meta->mDataType = nanovdb::GridType::Unknown;
  std::memset(meta->mName, 0, sizeof(meta->mName));
  std::strncpy(meta->mName, "voxfmt", sizeof(meta->mName) - 1);
  std::memcpy(const_cast<char*>(meta->getBlindData<char>()), json.data(), json.size());
}

/// `size` bytes as one zlib stream at zlib's fastest level, compressed in slices side by side: each slice a raw
/// deflate stream of its own that ends on a byte boundary (a full flush), the slices concatenated between the zlib
/// header and the Adler-32 of the whole (adler32_combine), as pigz does. Any inflate reads it as one stream; the
/// slices only cost a few bytes each. zlib itself compresses on one thread.
std::vector<Bytef> zlib_stream(const uint8_t* data, size_t size) {
  constexpr size_t kSlice = size_t(4) << 20;
  const size_t slices = std::max<size_t>(1, (size + kSlice - 1) / kSlice);
  std::vector<std::vector<Bytef>> packed(slices);
  std::vector<uLong> checksums(slices);
  std::atomic<size_t> next{0};
  std::atomic<bool> failed{false};
  run_workers(std::min<unsigned>(usable_cores(), unsigned(slices)), [&](unsigned) {
    for (size_t n; (n = next++) < slices;) {
      const size_t begin = n * kSlice, length = std::min(kSlice, size - begin);
      z_stream z{};
      if (deflateInit2(&z, Z_BEST_SPEED, Z_DEFLATED, -15, 8, Z_DEFAULT_STRATEGY) != Z_OK) {
        failed = true;
        return;
      }
      packed[n].resize(deflateBound(&z, uLong(length)) + 16);
      z.next_in = const_cast<Bytef*>(data + begin);
      z.avail_in = uInt(length);
      z.next_out = packed[n].data();
      z.avail_out = uInt(packed[n].size());
      const int status = deflate(&z, n + 1 == slices ? Z_FINISH : Z_FULL_FLUSH);
      if (status != (n + 1 == slices ? Z_STREAM_END : Z_OK) || z.avail_in != 0) failed = true;
      packed[n].resize(packed[n].size() - z.avail_out);
      deflateEnd(&z);
      checksums[n] = adler32(adler32(0, nullptr, 0), data + begin, uInt(length));
    }
  });
  if (failed) throw std::runtime_error("zlib could not compress a grid");
  std::vector<Bytef> out{0x78, 0x01};  // zlib header: deflate, 32 KiB window, fastest level
  uLong checksum = checksums[0];
  for (size_t n = 0; n < slices; ++n) {
    out.insert(out.end(), packed[n].begin(), packed[n].end());
    if (n > 0) checksum = adler32_combine(checksum, checksums[n], z_off_t(std::min(kSlice, size - n * kSlice)));
  }
  for (int shift = 24; shift >= 0; shift -= 8) out.push_back(Bytef(checksum >> shift));
  return out;
}

/// A grid as NanoVDB's ZIP codec stores it: its compressed size, then one zlib stream (zlib_stream: NanoVDB's own
/// writer uses zlib's default level on one thread, several times slower for a file a few percent smaller).
uint64_t write_zip(std::ostream& os, const nanovdb::GridHandle<>& handle) {
  const std::vector<Bytef> packed = zlib_stream(handle.data(), handle.size());
  const uint64_t bytes = packed.size();
  os.write(reinterpret_cast<const char*>(&bytes), sizeof(bytes));
  os.write(reinterpret_cast<const char*>(packed.data()), std::streamsize(bytes));
  return sizeof(bytes) + bytes;
}

/// Whether a brick without codes holds a voxel nearer than `width` (voxels): none is below its least lattice
/// corner, nor the band's edge.
bool coarse_brick_reaches(const FieldSamples& field, int a, int b, int c, float width) {
  return std::max(field.least_corner(a, b, c), field.field().band_edge) < width;
}

/// Tiles take the sign of the brick they cover (a tile of an upper node, 128 voxels a side: of the brick nearest its
/// middle), instead of NanoVDB's flood fill from the leaves, which an open mesh's holes would mislead. The root has
/// no tiles: past the upper nodes is the background, +width (outside the grid, outside the object).
void sign_tiles(nanovdb::NanoGrid<float>& grid, const FieldSamples& field, float width) {
  auto sign_at = [&](const nanovdb::Coord& origin, int extent) {
    int brick[3];
    for (int a = 0; a < 3; ++a) {
      const int mid = std::clamp(origin[a] + extent / 2, 0, field.dims(a) - 1);
      brick[a] = mid / kEdge;
    }
    return field.brick(brick[0], brick[1], brick[2]) == core::kCoarseInside ? -width : width;
  };
  auto& tree = grid.tree();
  auto* lower = tree.getFirstNode<1>();
  for (uint32_t n = 0; n < tree.nodeCount(1); ++n) {
    auto* data = lower[n].data();
    for (uint32_t t = 0; t < 4096; ++t) {
      if (data->mChildMask.isOn(t)) continue;
      const nanovdb::Coord local(int((t >> 8) & 15) * 8, int((t >> 4) & 15) * 8, int(t & 15) * 8);
      data->setValue(t, sign_at(lower[n].origin() + local, 8));
    }
  }
  auto* upper = tree.getFirstNode<2>();
  for (uint32_t n = 0; n < tree.nodeCount(2); ++n) {
    auto* data = upper[n].data();
    for (uint32_t t = 0; t < 32768; ++t) {
      if (data->mChildMask.isOn(t)) continue;
      const nanovdb::Coord local(int((t >> 10) & 31) * 128, int((t >> 5) & 31) * 128, int(t & 31) * 128);
      data->setValue(t, sign_at(upper[n].origin() + local, 128));
    }
  }
}

nanovdb::GridHandle<> distance_grid(const runtime::CollisionObject& object, const FieldSamples& field, float width,
                                    NanoVdbGrids& info) {
  const std::string metadata = grid_metadata_json(object, "distance", info.width);
  const runtime::SparseVoxelmap& map = object.voxelmap();
  const double h = map.voxel_size();
  nanovdb::GridBuilder<float> builder(float(width * h), nanovdb::GridClass::LevelSet, metadata.size());
  builder.setStats(nanovdb::StatsMode::MinMax);  // bounding boxes and extrema: what tools (and HDDA) read
  auto access = builder.getAccessor();
  const core::Field& f = field.field();
  for (int c = 0; c < f.brick_dims[2]; ++c)
    for (int b = 0; b < f.brick_dims[1]; ++b)
      for (int a = 0; a < f.brick_dims[0]; ++a) {
        if (field.brick(a, b, c) < 0 && !coarse_brick_reaches(field, a, b, c, width)) continue;
        ++info.distance_leaves;
        float values[core::kBrickVoxels];
        field.brick_values(a, b, c, values);
        // Clamped a cell's diagonal beyond the width: a cell with a corner within the width then holds the runtime's
        // values at all its corners (a distance changes by at most √3 voxels across a cell), so a sample there is
        // the runtime's; clamped at the width itself, such a cell bent the field and moved its zero (a hole's cap,
        // where the field jumps, changed sign).
        const float clamp = width + float(std::sqrt(3.0));
        for (int z = 0, n = 0; z < kEdge; ++z)
          for (int y = 0; y < kEdge; ++y)
            for (int x = 0; x < kEdge; ++x, ++n) {
              const float v = std::clamp(values[n], -clamp, clamp);
              access.setValue(nanovdb::Coord(a * kEdge + x, b * kEdge + y, c * kEdge + z), float(double(v) * h));
            }
      }
  info.distance_active_voxels = info.distance_leaves * 512;
  const nanovdb::Vec3d origin(map.origin().x(), map.origin().y(), map.origin().z());
  nanovdb::GridHandle<> handle = builder.getHandle<>(h, origin, "distance");
  auto* grid = handle.grid<float>();
  // Tiles are inactive: changing their values leaves the statistics (of active values) as the builder made them.
  sign_tiles(*grid, field, float(width * h));
  attach_metadata(handle, metadata);
  return handle;
}

nanovdb::GridHandle<> coarse_grid(const runtime::CollisionObject& object, const FieldSamples& field,
                                  NanoVdbGrids& info) {
  const std::string metadata = grid_metadata_json(object, "coarse", info.width);
  const runtime::SparseVoxelmap& map = object.voxelmap();
  const double h = map.voxel_size();
  const core::Field& f = field.field();
  float largest = 0;
  const size_t points = size_t(f.lattice_dims[0]) * size_t(f.lattice_dims[1]) * size_t(f.lattice_dims[2]);
  for (size_t n = 0; n < points; ++n) largest = std::max(largest, float(f.lattice[n]) * f.lattice_step);
  nanovdb::GridBuilder<float> builder(float(largest * h), nanovdb::GridClass::Unknown, metadata.size());
  builder.setStats(nanovdb::StatsMode::MinMax);
  auto access = builder.getAccessor();
  // The engines' coarse grids have a point at every brick corner up to the grid's last voxel, rounded up.
  int count[3];
  for (int a = 0; a < 3; ++a) count[a] = std::max(1, (f.dims[a] - 1 + kEdge - 1) / kEdge) + 1;
  for (int c = 0; c < count[2]; ++c)
    for (int b = 0; b < count[1]; ++b)
      for (int a = 0; a < count[0]; ++a)
        access.setValue(nanovdb::Coord(a, b, c), float(double(field.lattice_corner(a, b, c)) * h));
  info.coarse_voxels = uint64_t(count[0]) * uint64_t(count[1]) * uint64_t(count[2]);
  const nanovdb::Vec3d origin(map.origin().x(), map.origin().y(), map.origin().z());
  nanovdb::GridHandle<> handle = builder.getHandle<>(h * kEdge, origin, "coarse");
  attach_metadata(handle, metadata);
  return handle;
}

}  // namespace

std::string grid_metadata_json(const runtime::CollisionObject& object, const std::string& grid, double width) {
  const Provenance& p = object.provenance();
  nlohmann::json parameters = nlohmann::json::parse(p.build_parameters_json, nullptr, false);
  if (parameters.is_discarded()) parameters = p.build_parameters_json;
  const double h = object.voxelmap().voxel_size();
  nlohmann::json meta = {
      {"format", "voxfmt"},
      {"grid", grid},
      {"meaning", grid == "distance"
                      ? "signed distance to the surface, negative inside, clamped to +-level_set_width"
                      : "unsigned distance at every 8th voxel (brick corners): beyond the level set's width, "
                        "the distance is this interpolated, at least the width, with the level set's sign"},
      {"units", "m"},
      {"voxel_size", grid == "distance" ? h : 8 * h},
      {"asset_voxel_size", h},
      {"distance_band_voxels", object.distance_band()},
      {"level_set_width", width},
      {"exporter", std::string("voxfmt ") + VOXFMT_VERSION_STRING},
      {"generator", p.generator + " " + p.generator_version},
      {"source_file", p.source_file},
      {"source_sha256", p.source_sha256},
      {"created_utc", p.created_utc},
      {"build_parameters", parameters},
  };
  std::string json = meta.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  // Padded with spaces to NanoVDB's 32-byte alignment: the blind data ends the grid, and the next grid of a file
  // (or of a buffer that Warp reads) must start aligned.
  json.resize((json.size() + NANOVDB_DATA_ALIGNMENT - 1) / NANOVDB_DATA_ALIGNMENT * NANOVDB_DATA_ALIGNMENT, ' ');
  return json;
}

namespace {

// What the options and the grid allow, before any work.
Status check_exportable(const runtime::SparseVoxelmap& map, const NanoVdbOptions& options) {
  if (!(options.width_voxels >= 0 && options.width_voxels <= 32767))  // NaN fails too
    return Error{IssueCode::BadOption,
                 "nanovdb_grids: the level set's width must be 0 (the default) or a number of "
                 "voxels up to 32767, got " +
                     std::to_string(options.width_voxels)};
  // NanoVDB's readers map index to world in float: a grid 1e16 m from its origin came out with a voxel of 0. Within
  // 2^20 voxels of it a voxel keeps 3 bits below its size.
  constexpr double kMaxVoxelsFromOrigin = double(1 << 20);
  for (int a = 0; a < 3; ++a) {
    const double far =
        std::max(std::abs(map.origin()[a]), std::abs(map.origin()[a] + map.dims()[size_t(a)] * map.voxel_size()));
    if (!(far / map.voxel_size() <= kMaxVoxelsFromOrigin)) {
      char voxels[32];
      std::snprintf(voxels, sizeof voxels, "%.3g", far / map.voxel_size());
      return Error{IssueCode::ValueOutOfRange, "nanovdb_grids: the grid reaches " + std::string(voxels) +
                                                   " voxels from the world origin on axis " + std::to_string(a) +
                                                   "; NanoVDB's float transform keeps at most 2^20 (bake the mesh "
                                                   "nearer its origin)"};
    }
  }
  return Status::success();
}

// The two grids side by side (the level set is most of the work; the coarse grid is a bounded share).
std::vector<nanovdb::GridHandle<>> build_grids(const runtime::CollisionObject& object, const FieldSamples& field,
                                               double width, NanoVdbGrids& info) {
  std::vector<nanovdb::GridHandle<>> handles(2);
  std::exception_ptr failure[2];
  run_workers(2, [&](unsigned grid) {
    try {
      handles[grid] = grid == 0 ? distance_grid(object, field, float(width), info) : coarse_grid(object, field, info);
    } catch (...) {
      failure[grid] = std::current_exception();
    }
  });
  for (const std::exception_ptr& e : failure)
    if (e) std::rethrow_exception(e);
  return handles;
}

// NanoVDB's writer, step by step, so that the first grid can say that another follows: Warp's load_next_grid()
// reads the next grid where grid_count says there is one. Each grid keeps index 0, as NanoVDB 32.4's tools (and
// any reader of one grid alone) expect of a grid that starts its buffer. Empty where the stream failed.
std::string write_grids(std::vector<nanovdb::GridHandle<>>& handles, bool compress, NanoVdbGrids& info) {
  const auto codec = compress ? nanovdb::io::Codec::ZIP : nanovdb::io::Codec::NONE;
  nanovdb::io::Segment segment(codec);
  for (const auto& handle : handles) segment.add(handle);
  for (size_t n = 0; n < handles.size(); ++n) {
    auto* grid = reinterpret_cast<nanovdb::NanoGrid<float>*>(handles[n].data());
    grid->data()->mGridCount = n == 0 ? uint32_t(handles.size()) : 1u;
    nanovdb::updateChecksum(*grid);
    info.uncompressed_bytes += handles[n].size();
  }
  std::ostringstream file(std::string(segment.memUsage(), '\0'), std::ios::binary | std::ios::ate);
  for (size_t n = 0; n < handles.size(); ++n)
    segment.meta[n].fileSize =
        compress ? write_zip(file, handles[n]) : nanovdb::io::Internal::write(file, handles[n], codec);
  file.seekp(0);
  segment.write(file);
  return file ? std::move(file).str() : std::string();
}

}  // namespace

Result<NanoVdbGrids> nanovdb_grids(const runtime::CollisionObject& object, const NanoVdbOptions& options) {
  if (!object.has_voxelmap())
    return Error{IssueCode::InvalidAsset, "nanovdb_grids: the object has no voxelmap (loaded point shell only)"};
  const runtime::SparseVoxelmap& map = object.voxelmap();
  if (Status exportable = check_exportable(map, options); !exportable) return exportable.error();
  const FieldSamples field(field_of(map));
  // By default the band the asset stores completely: every voxel nearer than this has its exact distance.
  const double width = options.width_voxels > 0 ? options.width_voxels : double(field.field().band_edge);
  NanoVdbGrids info;
  info.width = width * map.voxel_size();
  try {
    std::vector<nanovdb::GridHandle<>> handles = build_grids(object, field, width, info);
    info.file = write_grids(handles, options.compress, info);
    if (info.file.empty()) return Error{IssueCode::Internal, "nanovdb_grids: NanoVDB could not write the grids"};
  } catch (const std::bad_alloc&) {
    return Error{IssueCode::OutOfMemory, "nanovdb_grids: out of memory building the grids"};
  } catch (const std::system_error& e) {  // no thread to be had (EAGAIN) under a memory limit is memory too
    const bool memory =
        e.code() == std::errc::resource_unavailable_try_again || e.code() == std::errc::not_enough_memory;
    return Error{memory ? IssueCode::OutOfMemory : IssueCode::Internal,
                 std::string("nanovdb_grids: ") + (memory ? "out of memory building the grids: " : "") + e.what()};
  } catch (const std::exception& e) {
    // NanoVDB reports its own allocations' failures as runtime_error ("... malloc failed").
    if (std::strstr(e.what(), "malloc failed"))
      return Error{IssueCode::OutOfMemory, std::string("nanovdb_grids: out of memory building the grids: ") + e.what()};
    return Error{IssueCode::Internal, std::string("nanovdb_grids: NanoVDB failed: ") + e.what()};
  }
  return info;
}

}  // namespace voxfmt::engines
