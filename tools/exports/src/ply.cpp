// The point shell as binary PLY.
#include <cstring>
#include <string>

#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/exports/exports.h"

namespace voxfmt::exports {

Result<PlyInfo> write_point_shell_ply(const Asset& asset, int level, bool inward, const std::string& path) {
  const PointShell& ps = asset.point_shell;
  PlyInfo info;
  info.levels = uint32_t(ps.level_count());
  if (level < 0) level = int(info.levels) - 1;
  if (level >= int(info.levels))
    return Error{IssueCode::BadOption, "--level " + std::to_string(level) + ": the point-sphere tree has levels 0.." +
                                           std::to_string(info.levels - 1)};
  info.level = uint32_t(level);
  info.points = ps.level_offsets[size_t(level) + 1];
  std::string data = "ply\nformat binary_little_endian 1.0\n";
  data += "comment voxfmt point shell: tree levels 0.." + std::to_string(level) + " of 0.." +
          std::to_string(info.levels - 1) + ", " + std::to_string(info.points) + " of " + std::to_string(ps.size()) +
          " points, metres, normals " + (inward ? "inward (as stored)" : "outward (the asset stores inward normals)") +
          "\n";
  data += "element vertex " + std::to_string(info.points) + "\n";
  for (const char* p : {"x", "y", "z", "nx", "ny", "nz"}) data += std::string("property float ") + p + "\n";
  data += "end_header\n";
  const float sign = inward ? 1.0f : -1.0f;
  auto put = [&](float value) {  // little-endian on every platform
    uint32_t bits;
    std::memcpy(&bits, &value, 4);
    for (int b = 0; b < 4; ++b) data += char((bits >> (8 * b)) & 0xff);
  };
  data.reserve(data.size() + size_t(info.points) * 24);
  for (uint64_t i = 0; i < info.points; ++i) {
    for (int a = 0; a < 3; ++a) put(float(ps.points[i][size_t(a)]));
    for (int a = 0; a < 3; ++a) put(sign * ps.normals[i][size_t(a)]);
  }
  const Status written = write_file_atomically(path, data);
  if (!written) return written.error();
  return info;
}

}  // namespace voxfmt::exports
