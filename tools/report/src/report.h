// voxfmt report: a baked library (a `voxfmt batch` output folder) or one asset as a self-contained HTML
// report folder — index.html, the page's script and style, three.js with its licence, the library's data as a
// script, and per asset its pictures and a compressed point shell and distance grid for the 3D view. Everything
// loads from file:// with no server and no network (scripts, not fetch: browsers refuse file:// fetches).
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <ios>
#include <istream>
#include <map>
#include <streambuf>
#include <string>

#include <nlohmann/json.hpp>

#include "voxfmt/detail/json_path.h"
#include "voxfmt/io.h"
#include "voxfmt/result.h"

namespace voxfmt::report {

struct LibraryReportOptions {
  std::string library;           ///< folder holding manifest.jsonl and the assets, or only assets (*.vox.h5 below it)
  std::string out;               ///< report folder (default LIBRARY/report); replaced only when empty or a report
  std::string manifest;          ///< the manifest to read ("" = LIBRARY/manifest.jsonl and manifest.shard-I-of-N.jsonl)
  std::string against;           ///< another baked library to compare with ("" = none)
  double size_threshold = 0.10;  ///< relative growth or shrinkage of a file that the comparison lists
  double time_threshold = 0.25;  ///< relative slow-down of a bake that the comparison lists
  int threads = 0;               ///< 0 = every core
  bool pictures = true;          ///< thumbnails, slices and 3D data of each readable asset
  ReadOptions read;              ///< budget of each asset read
  /// Called now and then from the worker threads (one at a time) with the assets read so far and their number.
  std::function<void(size_t done, size_t total)> progress;
};

struct ReportInfo {
  std::string index_html;  ///< path of the written page
  size_t meshes = 0, built = 0, up_to_date = 0, failed = 0;
  size_t unreadable_assets = 0;  ///< built per the manifest, but the asset cannot be read now (its card says why)
  size_t skipped_lines = 0;      ///< manifest lines that are not JSON records
  uint64_t bytes = 0;            ///< size of the report folder
};

/// Writes the report of a library: a batch's (its manifest), or a folder of assets with no manifest (each *.vox.h5
/// below it, as built). FILE_NOT_FOUND when LIBRARY (or AGAINST) has neither, BAD_OPTION
/// when OUT exists and is neither empty nor a previous report holding only what a report writes, WRITE_FAILED when
/// it cannot be written. A damaged asset or a damaged manifest line never fails the report: the asset's card carries
/// the coded error.
Result<ReportInfo> write_library_report(const LibraryReportOptions& options);

/// Whether a report could be written into `out`: BAD_OPTION where it is a file system's root, or a folder that
/// holds anything a report does not write or is no previous report (its data.js says so): never replaced. Cheap:
/// `batch --report` checks before its bakes.
Status check_report_folder(const std::string& out);

/// The same page for one asset (`voxfmt inspect ASSET --html OUT`), its card open. Fails like read_asset when
/// the asset cannot be read, WRITE_FAILED when OUT cannot be written.
Result<ReportInfo> write_asset_report(const std::string& asset, const std::string& out, const ReadOptions& read);

/// The longest manifest record read (a record is a mesh's paths, settings, figures and warnings: a few KiB).
constexpr size_t kMaxManifestRecordBytes = size_t(1) << 20;

/// The next line of a manifest into `line`, false at the end. A line longer than kMaxManifestRecordBytes is read
/// past, not kept (`line` comes back empty and `too_long` set): a hostile or broken record costs no memory.
inline bool read_manifest_line(std::istream& in, std::string& line, bool& too_long) {
  line.clear();
  too_long = false;
  std::streambuf* buffer = in.rdbuf();  // byte by byte from the buffer: no stream sentry per byte
  using Traits = std::char_traits<char>;
  bool any = false;
  for (Traits::int_type c = buffer ? buffer->sbumpc() : Traits::eof(); c != Traits::eof(); c = buffer->sbumpc()) {
    any = true;
    if (c == '\n') {
      if (too_long) line.clear();
      return true;
    }
    if (line.size() < kMaxManifestRecordBytes)
      line.push_back(Traits::to_char_type(c));
    else
      too_long = true;
  }
  in.setstate(std::ios::eofbit);
  if (too_long) line.clear();
  return any;
}

/// `folder` ("" for the working directory) however it was typed ("out", "./out/", a link to it): absolute from the
/// working directory, its links resolved (lexically normal where the file system cannot say).
inline std::string resolved_folder(const std::string& folder) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path absolute = fs::absolute(folder.empty() ? fs::path(".") : fs::path(folder), ec);
  const fs::path canonical = ec ? fs::path() : fs::weakly_canonical(absolute, ec);
  return (ec ? (absolute.empty() ? fs::path(folder) : absolute).lexically_normal() : canonical).string();
}

/// The one name of a record's output however its folder was typed ("out/a.vox.h5", "./out/a.vox.h5",
/// "/abs/out/a.vox.h5", a link to the folder): resolved_folder of its folder, then the file's own name (a file
/// that is itself a link keeps its name: two links are two outputs). A batch and a report key their records by
/// it, so a library batched twice with its folder spelled two ways, from one working directory, has one record a
/// mesh. `folders` caches the resolved folders (a manifest's records share a few: one resolution each, not one per
/// record).
inline std::string manifest_output_key(const std::string& output,
                                       std::map<std::string, std::string>* folders = nullptr) {
  const std::filesystem::path path(output);
  const std::string folder = path.parent_path().string();
  std::string resolved;
  if (folders && folders->count(folder)) {
    resolved = folders->at(folder);
  } else {
    resolved = resolved_folder(folder);
    if (folders) (*folders)[folder] = resolved;
  }
  return (std::filesystem::path(resolved) / path.filename()).string();
}

/// A record's `output` is a path from the working directory of the batch that wrote it; `output_from_manifest`
/// (0.4) is the same file's path from the manifest's folder, which means that file from any working directory and
/// after the library moves. Stamped when a record is written to the manifest at `manifest` (the file itself, not a
/// link to it).
inline void stamp_output_from_manifest(nlohmann::json& record, const std::string& manifest) {
  const std::string output = path_of(record, "output");
  if (output.empty()) return;
  const std::filesystem::path relative =
      std::filesystem::path(manifest_output_key(output))
          .lexically_relative(resolved_folder(std::filesystem::path(manifest).parent_path().string()));
  if (!relative.empty()) set_path(record, "output_from_manifest", relative.string());
}

/// A record read from the manifest at `manifest`: its `output` made the asset's path (absolute), from
/// `output_from_manifest` where the record has one (older records keep theirs). From the manifest's folder with its
/// links resolved, as the stamp was taken: lexically, a ".." after a linked folder goes elsewhere.
inline void locate_output(nlohmann::json& record, const std::string& manifest) {
  const std::string relative = path_of(record, "output_from_manifest");
  if (relative.empty()) return;
  const std::filesystem::path folder = resolved_folder(std::filesystem::path(manifest).parent_path().string());
  set_path(record, "output", (folder / relative).lexically_normal().string());
}

}  // namespace voxfmt::report
