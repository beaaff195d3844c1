#include "voxfmt/exports/exports.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <vector>

namespace voxfmt::exports {

namespace {

const char* kAxisNames[3] = {"x", "y", "z"};

// Diverging colour map: t in [-1, 1], -1 outside (blue), 0 the surface (near white), +1 deep inside (red).
Rgb diverging(double t) {
  t = std::clamp(t, -1.0, 1.0);
  const Rgb outside{40, 90, 180}, middle{245, 245, 245}, inside{190, 30, 40};
  const Rgb& end = t < 0 ? outside : inside;
  const double a = std::abs(t);
  auto mix = [&](uint8_t m, uint8_t e) { return uint8_t(std::lround(m + (double(e) - m) * a)); };
  return {mix(middle.r, end.r), mix(middle.g, end.g), mix(middle.b, end.b)};
}

const Rgb kNotStored{150, 150, 150}, kContour{0, 0, 0}, kBackground{255, 255, 255}, kInk{30, 30, 30};

// A round tick step giving at most `max_ticks` intervals over `span`: 1, 2 or 5 times a power of ten.
double tick_step(double span, int max_ticks, bool integers) {
  const double raw = span / max_ticks;
  double step = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (m * step >= raw) {
      step *= m;
      break;
    }
  return integers ? std::max(1.0, std::round(step)) : step;
}

std::string number_label(double value, bool integers) {
  if (integers) return std::to_string(int64_t(std::llround(value)));
  if (std::abs(value) < 1e-12) return "0";
  char text[32];
  std::snprintf(text, sizeof text, "%.3g", value);
  return text;
}

}  // namespace

Result<SliceSpec> parse_slice(const std::string& text) {
  const size_t eq = text.find('=');
  SliceSpec spec;
  const std::string axis = eq == std::string::npos ? "" : text.substr(0, eq);
  const std::string index = eq == std::string::npos ? "" : text.substr(eq + 1);
  if (axis.size() != 1 || std::string("xyzXYZ").find(axis[0]) == std::string::npos)
    return Error{IssueCode::BadOption, "'" + text + "': expected AXIS=INDEX with AXIS x, y or z (e.g. z=40)"};
  if (index.empty() || index.size() > 9 || index.find_first_not_of("0123456789") != std::string::npos)
    return Error{IssueCode::BadOption, "'" + text + "': the index must be a voxel index >= 0 (e.g. z=40)"};
  spec.axis = std::tolower(static_cast<unsigned char>(axis[0])) - 'x';
  spec.index = std::stoll(index);
  return spec;
}

namespace {

// A slice's voxels, read as one block: columns fastest; rows go up.
struct SliceVoxels {
  int64_t columns = 0, rows = 0;
  std::vector<float> distances;
  std::vector<int16_t> layers;
  size_t at(int64_t col, int64_t row) const { return size_t(row * columns + col); }
};

SliceVoxels read_slice(const Voxelmap& vm, const SliceSpec& spec, int col_axis, int row_axis) {
  SliceVoxels s;
  s.columns = vm.dims[size_t(col_axis)];
  s.rows = vm.dims[size_t(row_axis)];
  std::array<uint32_t, 3> first{0, 0, 0}, size = vm.dims;
  first[size_t(spec.axis)] = uint32_t(spec.index);
  size[size_t(spec.axis)] = 1;
  s.distances.resize(size_t(s.columns * s.rows));
  s.layers.resize(s.distances.size());
  // The block is x fastest, then y, then z; the slice's columns and rows are two of those in that order.
  vm.read_block(first, size, s.distances.data(), s.layers.data());
  return s;
}

// The colour scale over the whole grid (so slices compare): inside 0..deepest layer, outside 0..farthest layer,
// each half of the scale to its own end; distances over the band.
struct SliceScale {
  bool distances = false;
  double depth_in = 1, depth_out = 1;
  SliceScale(const Voxelmap& vm, bool show_distances) : distances(show_distances) {
    const auto [lowest, highest] = vm.layer_range();
    const double band_depth = vm.distance_band * vm.voxel_size;
    depth_in = distances ? band_depth : double(std::max(1, highest));
    depth_out = distances ? band_depth : double(std::max(1, -lowest));
  }
  double operator()(double depth) const { return depth >= 0 ? depth / depth_in : depth / depth_out; }  // -1..1
  // Penetration depth (inside > 0) of voxel `v`, NaN where the distance field has no value.
  double depth(const SliceVoxels& s, size_t v) const {
    if (!distances) return s.layers[v];
    return std::isnan(s.distances[v]) ? std::numeric_limits<double>::quiet_NaN() : -double(s.distances[v]);
  }
};

struct MapPlace {
  int x, y, zoom, width, height;
};

// The surface: where the stored distance, interpolated bilinearly between voxel centres, changes sign. Each crossing
// marks the pixel of the pair closer to zero (a 1-pixel line). Returns whether there is one.
bool draw_surface(const SliceVoxels& s, const MapPlace& map, RasterImage& image) {
  const int map_w = map.width, map_h = map.height, zoom = map.zoom;
  std::vector<double> field(size_t(map_w) * size_t(map_h), std::numeric_limits<double>::quiet_NaN());
  for (int py = 0; py < map_h; ++py)
    for (int px = 0; px < map_w; ++px) {
      const double u = (px + 0.5) / zoom - 0.5, w = (map_h - py - 0.5) / zoom - 0.5;  // voxel coordinates
      const int64_t c0 = std::clamp<int64_t>(int64_t(std::floor(u)), 0, s.columns - 1);
      const int64_t r0 = std::clamp<int64_t>(int64_t(std::floor(w)), 0, s.rows - 1);
      const int64_t c1 = std::min<int64_t>(c0 + 1, s.columns - 1), r1 = std::min<int64_t>(r0 + 1, s.rows - 1);
      const double fu = std::clamp(u - double(c0), 0.0, 1.0), fw = std::clamp(w - double(r0), 0.0, 1.0);
      const float d00 = s.distances[s.at(c0, r0)], d10 = s.distances[s.at(c1, r0)];
      const float d01 = s.distances[s.at(c0, r1)], d11 = s.distances[s.at(c1, r1)];
      if (std::isnan(d00) || std::isnan(d10) || std::isnan(d01) || std::isnan(d11)) continue;
      field[size_t(py) * size_t(map_w) + size_t(px)] =
          (1 - fw) * ((1 - fu) * d00 + fu * d10) + fw * ((1 - fu) * d01 + fu * d11);
    }
  bool any = false;
  for (int py = 0; py < map_h; ++py)
    for (int px = 0; px < map_w; ++px) {
      const double a = field[size_t(py) * size_t(map_w) + size_t(px)];
      if (std::isnan(a)) continue;
      for (const auto& [nx, ny] : {std::pair{px + 1, py}, std::pair{px, py + 1}}) {
        if (nx >= map_w || ny >= map_h) continue;
        const double b = field[size_t(ny) * size_t(map_w) + size_t(nx)];
        if (std::isnan(b) || (a < 0) == (b < 0)) continue;
        any = true;
        if (std::abs(a) <= std::abs(b))
          image.set(map.x + px, map.y + py, kContour);
        else
          image.set(map.x + nx, map.y + ny, kContour);
      }
    }
  return any;
}

// The legend at (x, y): a colour bar from +max (top, inside) to -max (bottom, outside) with ticks, then the
// swatches, within `height`.
void draw_legend(const SliceScale& scale, int x, int y, int height, RasterImage& image) {
  const int bar_w = 20;
  const int swatch_h = scale.distances ? 72 : 48;
  const int bar_top = y + RasterImage::text_height(2) * 2 + 14, bar_h = std::max(60, height - (bar_top - y) - swatch_h);
  image.text(x, y, scale.distances ? "DISTANCE (M)" : "LAYER", 2, kInk);
  image.text(x, y + RasterImage::text_height(2) + 6, scale.distances ? "(INSIDE < 0)" : "(INSIDE > 0)", 2, kInk);
  for (int row = 0; row < bar_h; ++row)
    image.fill_rect(x, bar_top + row, bar_w, 1, diverging(1.0 - 2.0 * (row + 0.5) / bar_h));
  const bool integers = !scale.distances;
  for (const double end : {scale.depth_in, -scale.depth_out}) {  // the inside half, then the outside half
    const double step = tick_step(std::abs(end), 3, integers);
    const int64_t ticks = int64_t(std::floor(std::abs(end) / step + 1e-9));
    for (int64_t tick = end > 0 ? 0 : 1; tick <= ticks; ++tick) {
      const double v = (end > 0 ? 1 : -1) * double(tick) * step;
      const int tick_y = bar_top + int(std::lround((1.0 - scale(v)) / 2.0 * (bar_h - 1)));
      image.fill_rect(x, tick_y, bar_w, 1, kInk);  // across the bar: a stub beside a label reads as a minus
      // The label shows the stored quantity: the layer, or the signed distance d = -depth.
      const std::string label = number_label(scale.distances ? -v : v, integers);
      image.text(x + bar_w + 6, tick_y - RasterImage::text_height(2) / 2, label, 2, kInk);
    }
  }
  int swatch_y = bar_top + bar_h + 12;
  image.fill_rect(x, swatch_y + 6, bar_w, 2, kContour);
  image.text(x + bar_w + 8, swatch_y, "SURFACE", 2, kInk);
  if (scale.distances) {
    swatch_y += 24;
    image.fill_rect(x, swatch_y, bar_w, 14, kNotStored);
    image.text(x + bar_w + 8, swatch_y, "NOT STORED", 2, kInk);
  }
}

}  // namespace

Result<SliceInfo> write_slice_png(const Asset& asset, const SliceSpec& spec, const std::string& path) {
  const Voxelmap& vm = asset.voxelmap;
  const uint32_t n = vm.dims[size_t(spec.axis)];
  if (spec.index < 0 || spec.index >= int64_t(n))
    return Error{IssueCode::BadOption, "--slice " + std::string(kAxisNames[spec.axis]) + "=" +
                                           std::to_string(spec.index) + ": the index must be in 0.." +
                                           std::to_string(n - 1) + " (the grid is " + std::to_string(vm.dims[0]) +
                                           " x " + std::to_string(vm.dims[1]) + " x " + std::to_string(vm.dims[2]) +
                                           " voxels)"};
  // Columns and rows of the slice: z -> (x, y), y -> (x, z), x -> (y, z); rows go up.
  const int col_axis = spec.axis == 0 ? 1 : 0, row_axis = spec.axis == 2 ? 1 : 2;
  const SliceVoxels slice = read_slice(vm, spec, col_axis, row_axis);
  const SliceScale scale(vm, spec.distances);
  SliceInfo info;
  info.columns = uint32_t(slice.columns);
  info.rows = uint32_t(slice.rows);
  info.zoom = spec.zoom > 0 ? spec.zoom : std::clamp(900 / int(std::max(info.columns, info.rows)), 1, 16);
  const int margin = 10, title_h = RasterImage::text_height(2);
  const MapPlace map{margin, margin + title_h + 8, info.zoom, int(info.columns) * info.zoom,
                     int(info.rows) * info.zoom};
  const int content_h = std::max(map.height, kSliceMinMapHeight);
  info.width = map.width + kSliceExtraWidth;
  info.height = content_h + kSliceExtraHeight;
  RasterImage image(info.width, info.height, kBackground);
  for (int64_t row = 0; row < slice.rows; ++row)
    for (int64_t col = 0; col < slice.columns; ++col) {
      const double value = scale.depth(slice, slice.at(col, row));
      const Rgb colour = std::isnan(value) ? kNotStored : diverging(scale(value));
      image.fill_rect(map.x + int(col) * map.zoom, map.y + int(slice.rows - 1 - row) * map.zoom, map.zoom, map.zoom,
                      colour);
    }
  info.has_surface = draw_surface(slice, map, image);
  char title[160];
  const double position = vm.origin[size_t(spec.axis)] + vm.voxel_size * double(spec.index);
  std::snprintf(title, sizeof title, "%s = %lld OF 0..%u (%.4g M), %s RIGHT, %s UP", kAxisNames[spec.axis],
                static_cast<long long>(spec.index), n - 1, position, kAxisNames[col_axis], kAxisNames[row_axis]);
  const int title_scale = RasterImage::text_width(title, 2) <= info.width - 2 * margin ? 2 : 1;
  image.text(map.x, margin + (title_scale == 1 ? 4 : 0), title, title_scale, kInk);
  draw_legend(scale, map.x + map.width + 2 * margin, map.y, content_h, image);
  const Status written = image.write_png(path);
  if (!written) return written.error();
  return info;
}

}  // namespace voxfmt::exports
