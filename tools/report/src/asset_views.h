// What the report draws and ships of one asset: three views of the point shell and the mid slice of the
// voxelmap as PNG (drawn here, no GPU), and the 3D view's data (a point shell and a coarse distance grid).
#pragma once

#include <nlohmann/json.hpp>

#include <string>

#include "voxfmt/asset.h"
#include "voxfmt/result.h"

namespace voxfmt::report {

/// Front, side and top views side by side, each `size` x `size` pixels.
Status write_views_png(const Asset& asset, int size, const std::string& path);
/// The middle slice facing the front view: inside red (darker deeper), outside blue, the surface black; the
/// longer side `size` pixels.
Status write_mid_slice_png(const Asset& asset, int size, const std::string& path);
/// The 3D view's arrays: whole point-shell levels up to `max_points` points, and every voxel of a grid at most
/// `max_grid` cells on its longest side; compressed and base64-encoded, described in their "encoding" keys.
nlohmann::json scene_data(const Asset& asset, size_t max_points, uint32_t max_grid);

}  // namespace voxfmt::report
