// A small RGB raster with a built-in 5x7 bitmap font, written as PNG (libpng): inspect's slice pictures and the
// examples' scene pictures.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "voxfmt/result.h"

namespace voxfmt::exports {

struct Rgb {
  uint8_t r = 0, g = 0, b = 0;
};

class RasterImage {
 public:
  RasterImage(int width, int height, Rgb background);
  int width() const { return width_; }
  int height() const { return height_; }
  /// Pixels outside the image are ignored (drawing clips).
  void set(int x, int y, Rgb colour);
  Rgb get(int x, int y) const;
  void fill_rect(int x, int y, int w, int h, Rgb colour);
  /// Draws text with the built-in font (upper case, digits, - . , = + ( ) : / ? and space; lower case is drawn
  /// as upper case, anything else as '?'), each font pixel `scale` x `scale`. Returns the width drawn.
  int text(int x, int y, const std::string& text, int scale, Rgb colour);
  static int text_width(const std::string& text, int scale) {
    return int(text.size()) * 6 * scale - (text.empty() ? 0 : scale);
  }
  static int text_height(int scale) { return 7 * scale; }

  /// Writes 8-bit RGB PNG atomically; WRITE_FAILED naming the path on failure.
  Status write_png(const std::string& path) const;

 private:
  int width_, height_;
  std::vector<uint8_t> rgb_;
};

}  // namespace voxfmt::exports
