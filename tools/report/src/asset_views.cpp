#include "asset_views.h"

#include <openssl/evp.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "voxfmt/exports/exports.h"

namespace voxfmt::report {

namespace {

using exports::RasterImage;
using exports::Rgb;

// ---- encoding of the 3D view's arrays: zlib-deflated (the page inflates them with DecompressionStream) and
// base64 (the only way bytes reach a page opened from file:// without fetch).
std::string deflate_base64(const std::vector<uint8_t>& bytes) {
  uLongf packed_size = compressBound(uLong(bytes.size()));
  std::vector<uint8_t> packed(packed_size);
  if (compress2(packed.data(), &packed_size, bytes.data(), uLong(bytes.size()), 9) != Z_OK) return {};
  std::string text(4 * ((packed_size + 2) / 3) + 1, '\0');
  const int n = EVP_EncodeBlock(reinterpret_cast<unsigned char*>(text.data()), packed.data(), int(packed_size));
  text.resize(size_t(std::max(n, 0)));
  return text;
}

// A signed axis of the asset: which coordinate, and +1 or -1.
struct Axis {
  int index;
  double sign;
  Axis operator-() const { return {index, -sign}; }
  double of(const Vec3& q) const { return sign * q[size_t(index)]; }
};

// How a person looks at the asset from the front, its up axis (+X ... -Z) pointing up the picture: right x up =
// toward (the viewer), right-handed. Y up looks along -Z, Z up along +Y, X up along +Z; an up axis that points
// down a coordinate turns the picture half round (right and up both flip), so the object stands the right way up.
struct ViewFrame {
  Axis right, up, toward;
};

ViewFrame front_frame(const std::string& up_axis) {
  const double sign = !up_axis.empty() && up_axis[0] == '-' ? -1.0 : 1.0;
  ViewFrame f{{0, 1.0}, {1, 1.0}, {2, 1.0}};  // +Y
  if (up_axis.find('Z') != std::string::npos) f = {{0, 1.0}, {2, 1.0}, {1, -1.0}};
  if (up_axis.find('X') != std::string::npos) f = {{1, 1.0}, {0, 1.0}, {2, -1.0}};
  f.right.sign *= sign;
  f.up.sign *= sign;
  return f;
}

// One orthographic view of the point shell: each point a small disc, lit by its outward normal (headlight from
// the viewer plus a little from the asset's up), nearest point wins.
void draw_view(RasterImage& image, int x0, int size, const Asset& asset, const ViewFrame& view, const Axis& world_up) {
  const PointShell& shell = asset.point_shell;
  const Vec3& lo = asset.bounds_min;
  const Vec3& hi = asset.bounds_max;
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-12});
  const double scale = (size - 8) / extent;
  const Vec3 mid{0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])};
  const double cx = view.right.of(mid), cy = view.up.of(mid);
  std::vector<float> depth(size_t(size) * size, -std::numeric_limits<float>::infinity());
  // Splat radius: points cover the surface at this scale (spacing ~ sqrt(area / n), area ~ 2 extent^2).
  const double spacing = extent * std::sqrt(2.0 / std::max<size_t>(shell.size(), 1));
  const int radius = std::clamp(int(std::ceil(0.6 * spacing * scale)), 1, 4);
  for (size_t p = 0; p < shell.size(); ++p) {
    const Vec3& q = shell.points[p];
    // Outward normal = -inward.
    const Vec3 outward{-double(shell.normals[p][0]), -double(shell.normals[p][1]), -double(shell.normals[p][2])};
    const double toward = view.toward.of(q);
    const int px = x0 + size / 2 + int(std::lround((view.right.of(q) - cx) * scale));
    const int py = size / 2 - int(std::lround((view.up.of(q) - cy) * scale));
    const double facing = view.toward.of(outward), above = world_up.of(outward);
    const double light = std::clamp(0.25 + 0.6 * std::max(facing, 0.0) + 0.15 * std::max(above, 0.0), 0.0, 1.0);
    const Rgb colour{uint8_t(60 + 150 * light), uint8_t(90 + 140 * light), uint8_t(120 + 125 * light)};
    for (int dy = -radius; dy <= radius; ++dy)
      for (int dx = -radius; dx <= radius; ++dx) {
        if (dx * dx + dy * dy > radius * radius) continue;
        const int x = px + dx, y = py + dy;
        if (x < x0 || x >= x0 + size || y < 0 || y >= size) continue;
        float& d = depth[size_t(y) * size + size_t(x - x0)];
        if (toward <= d) continue;
        d = float(toward);
        image.set(x, y, colour);
      }
  }
}

}  // namespace

Status write_views_png(const Asset& asset, int size, const std::string& path) {
  // Front; side (the viewer at the front's right); top (the viewer above, the front's side at the bottom).
  const ViewFrame front = front_frame(asset.up_axis);
  const ViewFrame side{-front.toward, front.up, front.right};
  const ViewFrame top{front.right, -front.toward, front.up};
  RasterImage image(3 * size, size, Rgb{255, 255, 255});
  draw_view(image, 0, size, asset, front, front.up);
  draw_view(image, size, size, asset, side, front.up);
  draw_view(image, 2 * size, size, asset, top, front.up);
  return image.write_png(path);
}

Status write_mid_slice_png(const Asset& asset, int size, const std::string& path) {
  const Voxelmap& vm = asset.voxelmap;
  const ViewFrame front = front_frame(asset.up_axis);  // the slice faces the front view's viewer, drawn as it is
  const size_t axis = size_t(front.toward.index), col = size_t(front.right.index), row = size_t(front.up.index);
  const uint32_t columns = vm.dims[col], rows = vm.dims[row];
  std::array<uint32_t, 3> first{0, 0, 0}, extent = vm.dims;
  first[axis] = vm.dims[axis] / 2;
  extent[axis] = 1;
  std::vector<int16_t> layers(size_t(columns) * rows);
  vm.read_block(first, extent, nullptr, layers.data());
  const auto [lowest, highest] = vm.layer_range();
  const double scale = double(size) / std::max(columns, rows);
  const int width = std::max(1, int(std::lround(columns * scale))),
            height = std::max(1, int(std::lround(rows * scale)));
  RasterImage image(width, height, Rgb{255, 255, 255});
  // Column c from the picture's left and row r from its bottom, as the block holds them (x fastest).
  auto layer_at = [&](int64_t c, int64_t r) {
    c = std::clamp<int64_t>(c, 0, columns - 1);
    r = std::clamp<int64_t>(r, 0, rows - 1);
    std::array<size_t, 3> at{0, 0, 0};
    at[col] = size_t(front.right.sign > 0 ? c : columns - 1 - c);
    at[row] = size_t(front.up.sign > 0 ? r : rows - 1 - r);
    return int(layers[(at[2] * extent[1] + at[1]) * extent[0] + at[0]]);
  };
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const int64_t c = int64_t(x / scale), r = int64_t(rows) - 1 - int64_t(y / scale);  // rows go up
      const int layer = layer_at(c, r);
      // The surface: the voxel's sign differs from a neighbour's (layer >= 1 is inside).
      const bool inside = layer >= 1;
      bool surface = false;
      for (const auto& [dc, dr] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}})
        surface = surface || ((layer_at(c + dc, r + dr) >= 1) != inside);
      Rgb colour;
      if (surface && inside)
        colour = Rgb{20, 20, 20};
      else if (inside) {
        const double t = std::min(1.0, double(layer) / std::max(1, highest));
        colour = Rgb{uint8_t(240 - 60 * t), uint8_t(150 - 110 * t), uint8_t(140 - 100 * t)};
      } else {
        const double t = std::min(1.0, double(-layer) / std::max(1, -lowest));
        colour = Rgb{uint8_t(200 - 150 * t), uint8_t(220 - 120 * t), uint8_t(250 - 60 * t)};
      }
      image.set(x, y, colour);
    }
  return image.write_png(path);
}

namespace {

// The point shell for the viewer: whole levels from the root while they fit in max_points (the root always).
nlohmann::json shell_data(const PointShell& shell, const Vec3& lo, const Vec3& hi, size_t max_points) {
  size_t levels = std::min<size_t>(1, shell.level_count());
  while (levels < shell.level_count() && shell.level_offsets[levels + 1] <= max_points) ++levels;
  const size_t n = levels ? shell.level_offsets[levels] : 0;
  // Coordinates in 12 bits of the bounds (1/4096 of the object: finer than any view of it), as two byte planes
  // (low bytes, then high nibbles) because deflate packs planes far better than interleaved words.
  std::vector<uint8_t> bytes(n * 9);
  for (size_t p = 0; p < n; ++p) {
    for (size_t a = 0; a < 3; ++a) {
      const double span = std::max(hi[a] - lo[a], 1e-12);
      const auto q = uint16_t(std::lround(std::clamp((shell.points[p][a] - lo[a]) / span, 0.0, 1.0) * 4095.0));
      bytes[3 * p + a] = uint8_t(q & 0xff);
      bytes[3 * n + 3 * p + a] = uint8_t(q >> 8);
      // Outward normals, as viewers expect (the asset's are inward).
      const double inward = std::clamp(double(shell.normals[p][a]), -1.0, 1.0);
      bytes[6 * n + 3 * p + a] = uint8_t(int8_t(std::lround(-127.0 * inward)));
    }
  }
  std::vector<uint32_t> offsets(shell.level_offsets.begin(), shell.level_offsets.begin() + std::ptrdiff_t(levels + 1));
  return {{"points", n},
          {"levels_shown", levels},
          {"levels", shell.level_count()},
          {"total_points", shell.size()},
          {"level_offsets", offsets},
          {"encoding",
           "12-bit xyz over the bounds as low bytes (3n) then high bytes (3n), then int8 outward normals xyz "
           "(3n); zlib; base64"},
          {"data", deflate_base64(bytes)}};
}

nlohmann::json field_data(const Voxelmap& vm, uint32_t max_grid) {
  // Distance grid: every step-th voxel's signed distance (stored or estimate), in 1/16 of a grid cell, clamped
  // to +-127 (8 cells): enough for the surface and the slicing plane.
  const uint32_t longest = std::max({vm.dims[0], vm.dims[1], vm.dims[2], 1u});
  const uint32_t step = std::max(1u, (longest + max_grid - 1) / max_grid);
  std::array<uint32_t, 3> g{};
  for (size_t a = 0; a < 3; ++a) g[a] = std::max(1u, (vm.dims[a] + step - 1) / step);
  const double cell = vm.voxel_size * step, quantum = cell / 16.0;
  const size_t cells = size_t(g[0]) * g[1] * g[2];
  std::vector<uint8_t> field(cells);
  size_t v = 0;
  for (uint32_t k = 0; k < g[2]; ++k)
    for (uint32_t j = 0; j < g[1]; ++j)
      for (uint32_t i = 0; i < g[0]; ++i) {
        const double d = vm.voxel(i * step, j * step, k * step).distance;
        field[v++] = uint8_t(int8_t(std::lround(std::clamp(d / quantum, -127.0, 127.0))));
      }
  const Vec3& o = vm.origin;
  return {{"dims", g},
          {"origin", {o[0], o[1], o[2]}},
          {"cell", cell},
          {"quantum", quantum},
          {"step_voxels", step},
          {"encoding", "int8 signed distance / quantum (negative inside), x fastest; zlib; base64"},
          {"data", deflate_base64(field)}};
}

}  // namespace

nlohmann::json scene_data(const Asset& asset, size_t max_points, uint32_t max_grid) {
  nlohmann::json data;
  const Vec3& lo = asset.bounds_min;
  const Vec3& hi = asset.bounds_max;
  data["bounds"] = {{lo[0], lo[1], lo[2]}, {hi[0], hi[1], hi[2]}};
  data["up_axis"] = asset.up_axis;
  // The front view's frame, so that the 3D view's camera stands as the pictures do: [axis, sign] each.
  const ViewFrame front = front_frame(asset.up_axis);
  const auto axis = [](const Axis& a) { return nlohmann::json::array({a.index, a.sign}); };
  data["view"] = {{"right", axis(front.right)}, {"up", axis(front.up)}, {"toward", axis(front.toward)}};
  data["shell"] = shell_data(asset.point_shell, lo, hi, max_points);
  data["field"] = field_data(asset.voxelmap, max_grid);
  return data;
}

}  // namespace voxfmt::report
