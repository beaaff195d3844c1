// The voxelmap as OpenVDB grids, for tools that read .vdb (Houdini, Blender, vdb_view, OpenVDB's own tools).
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/exports/exports.h"

#include <openvdb/io/Archive.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/SignedFloodFill.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <vector>

namespace voxfmt::exports {

namespace {

// The band as a narrow-band level set (the inactive inside given its negative sign by the signed flood fill) and
// the layers: a voxel per voxel of the value bricks; a coarse brick, whose voxels the lattice interpolates, is one
// tile of OpenVDB's 8^3 leaf size (its bricks are aligned the same way) holding its middle voxel's layer.
void fill_grids(const Voxelmap& vm, float background, openvdb::FloatGrid& distance, openvdb::Int32Grid& layers,
                VdbInfo& info) {
  openvdb::FloatGrid::Accessor access = distance.getAccessor();
  openvdb::Int32Grid::Accessor layer_access = layers.getAccessor();
  const auto bd = vm.brick_dims();
  constexpr uint32_t E = Voxelmap::kBrickEdge;
  size_t n = 0;
  for (uint32_t bk = 0; bk < bd[2]; ++bk)
    for (uint32_t bj = 0; bj < bd[1]; ++bj)
      for (uint32_t bi = 0; bi < bd[0]; ++bi, ++n) {
        const uint32_t i0 = bi * E, j0 = bj * E, k0 = bk * E;
        const uint32_t i1 = std::min(i0 + E, vm.dims[0]), j1 = std::min(j0 + E, vm.dims[1]),
                       k1 = std::min(k0 + E, vm.dims[2]);
        if (vm.bricks[n] < 0) {
          const uint32_t mi = std::min(i0 + E / 2, vm.dims[0] - 1), mj = std::min(j0 + E / 2, vm.dims[1] - 1),
                         mk = std::min(k0 + E / 2, vm.dims[2] - 1);
          layers.tree().addTile(1, openvdb::Coord(int(i0), int(j0), int(k0)), vm.layer(mi, mj, mk), true);
          info.layer_voxels += size_t(i1 - i0) * (j1 - j0) * (k1 - k0);
          continue;
        }
        for (uint32_t k = k0; k < k1; ++k)
          for (uint32_t j = j0; j < j1; ++j)
            for (uint32_t i = i0; i < i1; ++i) {
              const openvdb::Coord xyz{int(i), int(j), int(k)};
              const VoxelValue v = vm.voxel(i, j, k);
              layer_access.setValue(xyz, vm.layer(i, j, k));
              ++info.layer_voxels;
              if (!v.stored) continue;
              access.setValue(xyz, std::clamp(float(v.distance), -background, background));
              ++info.distance_voxels;
            }
      }
  openvdb::tools::signedFloodFill(distance.tree());
}

}  // namespace

// What openvdb::io::File writes (a seekable archive: grid offsets, so readers load grids lazily), into any
// std::ostream: Archive's own write, which only its subclasses may call.
class SeekableArchive : public openvdb::io::Archive {
 public:
  void write_to(std::ostream& out, const openvdb::GridCPtrVec& grids) const {
    openvdb::io::Archive::write(out, grids, /*seekable=*/true);
  }
};

Result<VdbInfo> write_voxelmap_vdb(const Asset& asset, const std::string& path) {
  openvdb::initialize();
  const Voxelmap& vm = asset.voxelmap;
  openvdb::math::Transform::Ptr transform = openvdb::math::Transform::createLinearTransform(vm.voxel_size);
  transform->postTranslate(openvdb::Vec3d(vm.origin[0], vm.origin[1], vm.origin[2]));
  VdbInfo info;
  const float background = float(vm.distance_band * vm.voxel_size);
  openvdb::FloatGrid::Ptr distance = openvdb::FloatGrid::create(background);
  openvdb::Int32Grid::Ptr layers = openvdb::Int32Grid::create(0);
  fill_grids(vm, background, *distance, *layers, info);
  distance->setName("distance");
  distance->setGridClass(openvdb::GRID_LEVEL_SET);
  distance->setTransform(transform);
  layers->setName("layers");
  layers->setTransform(transform->copy());
  openvdb::GridPtrVec grids{distance, layers};
  for (const auto& grid : grids) {
    grid->insertMeta("voxfmt_source", openvdb::StringMetadata(asset.provenance.source_file));
    grid->insertMeta("voxfmt_distance_band_voxels", openvdb::DoubleMetadata(vm.distance_band));
  }
  AtomicWrite steps;
  steps.write = [&](const std::string& temp) -> Status {
    // Into a stream we own and check: openvdb::io::File does not report a write its ofstream failed (a full disk,
    // a file-size limit), and a cut-short file would pass for a written one.
    std::ofstream out(temp, std::ios::binary);
    errno = 0;
    try {
      SeekableArchive().write_to(out, openvdb::GridCPtrVec(grids.begin(), grids.end()));
    } catch (const std::exception& e) {
      return Error{IssueCode::WriteFailed, path + ": cannot write the VDB file (" + e.what() + ")", path};
    }
    out.close();
    if (!out)
      return Error{IssueCode::WriteFailed,
                   path + ": cannot write the VDB file (" + (errno ? std::strerror(errno) : "the stream failed") + ")",
                   path};
    return Status::success();
  };
  const Status written = write_file_atomically(path, steps);
  if (!written) return written.error();
  return info;
}

}  // namespace voxfmt::exports
