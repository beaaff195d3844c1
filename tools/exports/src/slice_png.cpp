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
  SliceInfo info;
  info.columns = vm.dims[size_t(col_axis)];
  info.rows = vm.dims[size_t(row_axis)];
  const int zoom = spec.zoom > 0 ? spec.zoom : std::clamp(900 / int(std::max(info.columns, info.rows)), 1, 16);
  info.zoom = zoom;
  // The slice's voxels, read as one block: columns fastest.
  std::array<uint32_t, 3> first{0, 0, 0}, size = vm.dims;
  first[size_t(spec.axis)] = uint32_t(spec.index);
  size[size_t(spec.axis)] = 1;
  std::vector<float> distances(size_t(info.columns) * info.rows);
  std::vector<int16_t> layers(distances.size());
  vm.read_block(first, size, distances.data(), layers.data());
  // The block is x fastest, then y, then z; the slice's columns and rows are two of those in that order.
  auto voxel = [&](int64_t col, int64_t row) { return size_t(row * info.columns + col); };

  // Colour scale over the whole grid (so slices compare): inside 0..deepest layer, outside 0..farthest layer,
  // each half of the scale to its own end; distances over the band.
  const auto [lowest, highest] = vm.layer_range();
  const int max_inside = std::max(1, highest), max_outside = std::max(1, -lowest);
  const double band_depth = vm.distance_band * vm.voxel_size;
  const double depth_in = spec.distances ? band_depth : double(max_inside);
  const double depth_out = spec.distances ? band_depth : double(max_outside);
  auto scale = [&](double depth) { return depth >= 0 ? depth / depth_in : depth / depth_out; };  // -1..1
  // Penetration depth (inside > 0) of a voxel, NaN where the distance field has no value.
  auto depth = [&](size_t v) -> double {
    if (!spec.distances) return layers[v];
    return std::isnan(distances[v]) ? std::numeric_limits<double>::quiet_NaN() : -double(distances[v]);
  };

  const int map_w = int(info.columns) * zoom, map_h = int(info.rows) * zoom;
  const int margin = 10, title_h = RasterImage::text_height(2), map_x = margin, map_y = margin + title_h + 8;
  const int content_h = std::max(map_h, kSliceMinMapHeight);
  info.width = map_w + kSliceExtraWidth;
  info.height = content_h + kSliceExtraHeight;
  RasterImage image(info.width, info.height, kBackground);

  for (int64_t row = 0; row < info.rows; ++row)
    for (int64_t col = 0; col < info.columns; ++col) {
      const double value = depth(voxel(col, row));
      const Rgb colour = std::isnan(value) ? kNotStored : diverging(scale(value));
      image.fill_rect(map_x + int(col) * zoom, map_y + int(info.rows - 1 - row) * zoom, zoom, zoom, colour);
    }

  // The surface: where the stored distance, interpolated bilinearly between voxel centres, changes sign. Each
  // crossing marks the pixel of the pair closer to zero (a 1-pixel line).
  std::vector<double> field(size_t(map_w) * size_t(map_h), std::numeric_limits<double>::quiet_NaN());
  for (int py = 0; py < map_h; ++py)
    for (int px = 0; px < map_w; ++px) {
      const double u = (px + 0.5) / zoom - 0.5, w = (map_h - py - 0.5) / zoom - 0.5;  // voxel coordinates
      const int64_t c0 = std::clamp<int64_t>(int64_t(std::floor(u)), 0, info.columns - 1);
      const int64_t r0 = std::clamp<int64_t>(int64_t(std::floor(w)), 0, info.rows - 1);
      const int64_t c1 = std::min<int64_t>(c0 + 1, info.columns - 1), r1 = std::min<int64_t>(r0 + 1, info.rows - 1);
      const double fu = std::clamp(u - double(c0), 0.0, 1.0), fw = std::clamp(w - double(r0), 0.0, 1.0);
      const float d00 = distances[voxel(c0, r0)], d10 = distances[voxel(c1, r0)];
      const float d01 = distances[voxel(c0, r1)], d11 = distances[voxel(c1, r1)];
      if (std::isnan(d00) || std::isnan(d10) || std::isnan(d01) || std::isnan(d11)) continue;
      field[size_t(py) * size_t(map_w) + size_t(px)] =
          (1 - fw) * ((1 - fu) * d00 + fu * d10) + fw * ((1 - fu) * d01 + fu * d11);
    }
  for (int py = 0; py < map_h; ++py)
    for (int px = 0; px < map_w; ++px) {
      const double a = field[size_t(py) * size_t(map_w) + size_t(px)];
      if (std::isnan(a)) continue;
      for (const auto& [nx, ny] : {std::pair{px + 1, py}, std::pair{px, py + 1}}) {
        if (nx >= map_w || ny >= map_h) continue;
        const double b = field[size_t(ny) * size_t(map_w) + size_t(nx)];
        if (std::isnan(b) || (a < 0) == (b < 0)) continue;
        info.has_surface = true;
        if (std::abs(a) <= std::abs(b))
          image.set(map_x + px, map_y + py, kContour);
        else
          image.set(map_x + nx, map_y + ny, kContour);
      }
    }

  // Title.
  char title[160];
  const double position = vm.origin[size_t(spec.axis)] + vm.voxel_size * double(spec.index);
  std::snprintf(title, sizeof title, "%s = %lld OF 0..%u (%.4g M), %s RIGHT, %s UP", kAxisNames[spec.axis],
                static_cast<long long>(spec.index), n - 1, position, kAxisNames[col_axis], kAxisNames[row_axis]);
  const int title_scale = RasterImage::text_width(title, 2) <= info.width - 2 * margin ? 2 : 1;
  image.text(map_x, margin + (title_scale == 1 ? 4 : 0), title, title_scale, kInk);

  // Legend: a colour bar from +max (top, inside) to -max (bottom, outside) with ticks, then the swatches.
  const int legend_x = map_x + map_w + 2 * margin, bar_w = 20;
  const int swatch_h = spec.distances ? 72 : 48;
  const int bar_top = map_y + RasterImage::text_height(2) * 2 + 14,
            bar_h = std::max(60, content_h - (bar_top - map_y) - swatch_h);
  image.text(legend_x, map_y, spec.distances ? "DISTANCE (M)" : "LAYER", 2, kInk);
  image.text(legend_x, map_y + RasterImage::text_height(2) + 6, spec.distances ? "(INSIDE < 0)" : "(INSIDE > 0)", 2,
             kInk);
  for (int y = 0; y < bar_h; ++y) {
    const double t = 1.0 - 2.0 * (y + 0.5) / bar_h;
    image.fill_rect(legend_x, bar_top + y, bar_w, 1, diverging(t));
  }
  const bool integers = !spec.distances;
  for (const double end : {depth_in, -depth_out}) {  // the inside half, then the outside half
    const double step = tick_step(std::abs(end), 3, integers);
    const int64_t ticks = int64_t(std::floor(std::abs(end) / step + 1e-9));
    for (int64_t tick = end > 0 ? 0 : 1; tick <= ticks; ++tick) {
      const double v = (end > 0 ? 1 : -1) * double(tick) * step;
      const int y = bar_top + int(std::lround((1.0 - scale(v)) / 2.0 * (bar_h - 1)));
      image.fill_rect(legend_x, y, bar_w, 1, kInk);  // across the bar: a stub beside a label reads as a minus
      // The label shows the stored quantity: the layer, or the signed distance d = -depth.
      const std::string label = number_label(spec.distances ? -v : v, integers);
      image.text(legend_x + bar_w + 6, y - RasterImage::text_height(2) / 2, label, 2, kInk);
    }
  }
  int swatch_y = bar_top + bar_h + 12;
  image.fill_rect(legend_x, swatch_y + 6, bar_w, 2, kContour);
  image.text(legend_x + bar_w + 8, swatch_y, "SURFACE", 2, kInk);
  if (spec.distances) {
    swatch_y += 24;
    image.fill_rect(legend_x, swatch_y, bar_w, 14, kNotStored);
    image.text(legend_x + bar_w + 8, swatch_y, "NOT STORED", 2, kInk);
  }

  const Status written = image.write_png(path);
  if (!written) return written.error();
  return info;
}

}  // namespace voxfmt::exports
