// The engine layouts of a loaded asset (loaders/engines) for voxfmt.warp and voxfmt.newton: NumPy arrays that own
// what the C++ library built (moved, not copied), and the .nvdb file's bytes.
#include <nanobind/stl/string.h>

#include <utility>
#include <vector>

#include "common.h"
#include "voxfmt/engines/layouts.h"

namespace voxfmt::python {

namespace {

/// A NumPy array of T over a vector's memory (of T, or bytes holding T: operator new aligns them for any T), the
/// vector moved into the array's owner.
template <class T, class Stored = T>
nb::ndarray<nb::numpy, T> owned(std::vector<Stored>&& values, std::initializer_list<size_t> shape) {
  auto* held = new std::vector<Stored>(std::move(values));
  nb::capsule owner(held, [](void* p) noexcept { delete static_cast<std::vector<Stored>*>(p); });
  return nb::ndarray<nb::numpy, T>(reinterpret_cast<T*>(held->data()), shape, owner);
}

engines::TextureFormat texture_format(const std::string& name) {
  if (name == "uint16") return engines::TextureFormat::Uint16;
  if (name == "uint8") return engines::TextureFormat::Uint8;
  if (name == "float32") return engines::TextureFormat::Float32;
  fail(IssueCode::BadOption, "texture_format: expected 'uint16', 'uint8' or 'float32', got '" + name + "'");
}

nb::dict texture_sdf(const Body& body, const std::string& format, double coarse_tolerance_voxels) {
  engines::TextureSdfOptions options;
  options.format = texture_format(format);
  options.coarse_tolerance_voxels = coarse_tolerance_voxels;
  Result<engines::TextureSdf> built = [&] {
    nb::gil_scoped_release release;
    return engines::texture_sdf(*body.object, options);
  }();
  if (!built) throw CodedError(built.error());
  engines::TextureSdf& t = built.value();
  const size_t bx = size_t(t.bricks[0]), by = size_t(t.bricks[1]), bz = size_t(t.bricks[2]);
  const size_t side = size_t(t.texture_side);
  nb::dict out;
  // Arrays [z][y][x], x fastest, as the C++ layout holds them.
  out["coarse"] = owned<float>(std::move(t.coarse), {bz + 1, by + 1, bx + 1});
  out["slots"] = owned<uint32_t>(std::move(t.slots), {bz, by, bx});
  if (t.format == engines::TextureFormat::Float32)
    out["texels"] = owned<float>(std::move(t.texels), {side, side, side});
  else if (t.format == engines::TextureFormat::Uint16)
    out["texels"] = owned<uint16_t>(std::move(t.texels), {side, side, side});
  else
    out["texels"] = owned<uint8_t>(std::move(t.texels), {side, side, side});
  out["lower"] = nb::make_tuple(t.lower[0], t.lower[1], t.lower[2]);
  out["cell"] = t.cell;
  out["bricks"] = nb::make_tuple(t.bricks[0], t.bricks[1], t.bricks[2]);
  out["blocks_per_side"] = t.blocks_per_side;
  out["value_min"] = t.value_min;
  out["value_range"] = t.value_range;
  out["value_bricks"] = t.value_bricks;
  out["coarse_stored"] = t.coarse_stored;
  out["max_quantisation_error"] = t.max_quantisation_error;
  out["format"] = format;
  return out;
}

nb::tuple nanovdb(const Body& body, double width_voxels, bool compress) {
  engines::NanoVdbOptions options;
  options.width_voxels = width_voxels;
  options.compress = compress;
  Result<engines::NanoVdbGrids> built = [&] {
    nb::gil_scoped_release release;
    return engines::nanovdb_grids(*body.object, options);
  }();
  if (!built) throw CodedError(built.error());
  const engines::NanoVdbGrids& g = built.value();
  nb::dict info;
  info["level_set_width"] = g.width;
  info["distance_leaves"] = g.distance_leaves;
  info["distance_active_voxels"] = g.distance_active_voxels;
  info["coarse_voxels"] = g.coarse_voxels;
  info["uncompressed_bytes"] = g.uncompressed_bytes;
  return nb::make_tuple(nb::bytes(g.file.data(), g.file.size()), info);
}

}  // namespace

void bind_engines(nb::module_& m) {
  using namespace nb::literals;
  m.def("_texture_sdf", &texture_sdf, "body"_a, "format"_a, "coarse_tolerance_voxels"_a,
        "The texture SDF layout of a body's voxelmap (Newton's): a dict of arrays and numbers.");
  m.def("_nanovdb", &nanovdb, "body"_a, "width_voxels"_a, "compress"_a,
        "The NanoVDB grids of a body's voxelmap as one .nvdb file's bytes, and what they hold.");
}

}  // namespace voxfmt::python
