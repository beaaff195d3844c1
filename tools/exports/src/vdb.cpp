// The voxelmap as OpenVDB grids, for tools that read .vdb (Houdini, Blender, vdb_view, OpenVDB's own tools).
#include "voxfmt/atomic_file.h"
#include "voxfmt/exports/exports.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/Dense.h>
#include <openvdb/tools/SignedFloodFill.h>

#include <algorithm>
#include <vector>

namespace voxfmt::exports {

Result<VdbInfo> write_voxelmap_vdb(const Asset& asset, const std::string& path) {
  openvdb::initialize();
  const Voxelmap& vm = asset.voxelmap;
  openvdb::math::Transform::Ptr transform = openvdb::math::Transform::createLinearTransform(vm.voxel_size);
  transform->postTranslate(openvdb::Vec3d(vm.origin[0], vm.origin[1], vm.origin[2]));
  const int W = int(vm.dims[0]), H = int(vm.dims[1]), D = int(vm.dims[2]);
  VdbInfo info;

  // The band as a narrow-band level set; the signed flood fill gives the inactive inside its negative sign.
  const float background = float(vm.distance_band * vm.voxel_size);
  openvdb::FloatGrid::Ptr distance = openvdb::FloatGrid::create(background);
  {
    openvdb::FloatGrid::Accessor access = distance->getAccessor();
    for (int k = 0; k < D; ++k)
      for (int j = 0; j < H; ++j)
        for (int i = 0; i < W; ++i) {
          const float d = vm.distances[vm.linear_index(uint32_t(i), uint32_t(j), uint32_t(k))];
          if (!Voxelmap::is_stored(d)) continue;
          access.setValue(openvdb::Coord(i, j, k), std::clamp(d, -background, background));
          ++info.distance_voxels;
        }
  }
  openvdb::tools::signedFloodFill(distance->tree());
  distance->setName("distance");
  distance->setGridClass(openvdb::GRID_LEVEL_SET);
  distance->setTransform(transform);

  // Layers: x fastest like the asset, so the dense copy needs no reordering (only widening to int32).
  std::vector<int32_t> wide(vm.layers.begin(), vm.layers.end());
  openvdb::Int32Grid::Ptr layers = openvdb::Int32Grid::create(0);
  {
    openvdb::tools::Dense<int32_t, openvdb::tools::LayoutXYZ> dense(
        openvdb::CoordBBox(openvdb::Coord(0, 0, 0), openvdb::Coord(W - 1, H - 1, D - 1)), wide.data());
    openvdb::tools::copyFromDense(dense, *layers, /*tolerance=*/0);
  }
  info.layer_voxels = vm.voxel_count();
  layers->setName("layers");
  layers->setTransform(transform->copy());

  openvdb::GridPtrVec grids{distance, layers};
  for (const auto& grid : grids) {
    grid->insertMeta("voxfmt_source", openvdb::StringMetadata(asset.provenance.source_file));
    grid->insertMeta("voxfmt_distance_band_voxels", openvdb::DoubleMetadata(vm.distance_band));
  }
  AtomicWrite steps;
  steps.write = [&](const std::string& temp) -> Status {
    try {
      openvdb::io::File file(temp);
      file.write(grids);
      file.close();
    } catch (const std::exception& e) {
      return Error{IssueCode::WriteFailed, path + ": cannot write the VDB file (" + e.what() + ")", path};
    }
    return Status::success();
  };
  const Status written = write_file_atomically(path, steps);
  if (!written) return written.error();
  return info;
}

}  // namespace voxfmt::exports
