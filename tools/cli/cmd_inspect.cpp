// `voxfmt inspect FILE [--json]`: a readable summary of one asset.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <utility>

#include "commands.h"
#include "json_report.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/report.h"
#include "voxfmt/exports/exports.h"
#include "voxfmt/io.h"

namespace voxfmt::cli {

namespace {

struct Options {
  std::string file;
  bool json = false;
  ReadOptions read;
  std::string slice;  // AXIS=INDEX
  std::string png;
  std::string field = "layers";
  int zoom = 0;
  std::string ply;
  std::string vdb;
  std::string html;
  int level = -1;
  bool inward_normals = false;
};

std::string human_bytes(uint64_t bytes) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(1);
  if (bytes >= (1ull << 20))
    s << double(bytes) / (1 << 20) << " MiB";
  else if (bytes >= 1024)
    s << double(bytes) / 1024 << " KiB";
  else
    s << bytes << " B";
  return s.str();
}

std::string v3(const Vec3& v) {
  std::ostringstream s;
  s << std::setprecision(6) << "(" << v[0] << ", " << v[1] << ", " << v[2] << ")";
  return s.str();
}

void print_text(const std::string& file, const Asset& a, const AssetSummary& s, const std::vector<Issue>& warnings) {
  const Voxelmap& vm = a.voxelmap;
  const PointShell& ps = a.point_shell;
  std::ostream& o = std::cout;
  auto row = [&](const std::string& key) -> std::ostream& { return o << "  " << std::left << std::setw(20) << key; };
  o << terminal_safe(file) << "\n";
  row("format") << "voxfmt " << a.version.major << "." << a.version.minor << ", metres, right-handed, up "
                << terminal_safe(a.up_axis) << "\n";
  row("file size") << human_bytes(s.file_size) << "\n";
  row("memory (loaded)") << human_bytes(s.memory_bytes) << "\n";
  row("bounds") << v3(a.bounds_min) << " .. " << v3(a.bounds_max) << "\n";
  o << "voxelmap\n";
  row("dims") << vm.dims[0] << " x " << vm.dims[1] << " x " << vm.dims[2] << " (" << vm.voxel_count() << " voxels)\n";
  row("voxel size") << vm.voxel_size << " m\n";
  row("origin") << v3(vm.origin) << "\n";
  row("distance band") << "±" << vm.distance_band << " voxels, " << s.stored_distances << " distances stored\n";
  row("estimates") << (vm.estimates == Voxelmap::Estimates::Settled
                           ? "settled: never below the exact distance (spec 3.1, format 2.2)"
                           : "interpolated from the lattice (format 2.1 and older; voxfmt upgrade settles them)")
                   << "\n";
  row("layers") << s.layer_min << " .. " << s.layer_max << " (inside > 0)\n";
  o << "point shell\n";
  row("points") << ps.size() << " in " << ps.level_count() << " levels (tree depth "
                << (ps.level_count() ? ps.level_count() - 1 : 0) << ")\n";
  row("points per level");
  for (size_t l = 0; l < s.points_per_level.size(); ++l) o << (l ? ", " : "") << s.points_per_level[l];
  o << "\n";
  if (ps.point_spacing) row("point spacing") << *ps.point_spacing << " m\n";
  o << "mass properties (unit density)\n";
  row("volume") << a.mass.volume << " m^3\n";
  row("centre of mass") << v3(a.mass.center_of_mass) << "\n";
  row("inertia") << "[" << a.mass.inertia[0] << " " << a.mass.inertia[1] << " " << a.mass.inertia[2] << "; "
                 << a.mass.inertia[3] << " " << a.mass.inertia[4] << " " << a.mass.inertia[5] << "; "
                 << a.mass.inertia[6] << " " << a.mass.inertia[7] << " " << a.mass.inertia[8] << "] m^5\n";
  const Provenance& p = a.provenance;
  o << "provenance\n";
  // Every string below comes from the file as it is: terminal_safe() keeps a hostile one from driving the terminal.
  row("generator") << terminal_safe(p.generator) << " " << terminal_safe(p.generator_version) << "\n";
  if (!p.source_file.empty())
    row("source") << terminal_safe(p.source_file) << " (sha256 " << terminal_safe(p.source_sha256) << ")\n";
  if (!p.created_utc.empty()) row("created") << terminal_safe(p.created_utc) << "\n";
  row("build parameters") << terminal_safe(p.build_parameters_json) << "\n";
  row("build warnings") << p.build_warnings.size() << "\n";
  for (const BuildWarning& w : p.build_warnings)
    o << "    " << terminal_safe(w.code) << ": " << terminal_safe(w.message) << "\n";
  for (const Issue& w : warnings)
    o << "warning: " << code_name(w.code) << " " << terminal_safe(w.path) << ": " << terminal_safe(w.message) << "\n";
}

// The slice index and --level against the asset, before anything is written: a usage error writes no file (the
// exports check them too, but only once an earlier output has been written).
Status check_exports_fit(const Options& o, const Asset& asset) {
  if (!o.png.empty()) {
    const Result<exports::SliceSpec> spec = exports::parse_slice(o.slice);
    if (!spec) return spec.error();
    const auto& dims = asset.voxelmap.dims;
    const int64_t n = dims[size_t(spec->axis)];
    if (spec->index >= n)
      return Error{IssueCode::BadOption, std::string("--slice ") + "xyz"[spec->axis] + "=" +
                                             std::to_string(spec->index) + ": the index must be in 0.." +
                                             std::to_string(n - 1) + " (the grid is " + std::to_string(dims[0]) +
                                             " x " + std::to_string(dims[1]) + " x " + std::to_string(dims[2]) +
                                             " voxels)"};
  }
  const size_t levels = asset.point_shell.level_count();
  if (!o.ply.empty() && o.level >= 0 && size_t(o.level) >= levels)
    return Error{IssueCode::BadOption, "--level " + std::to_string(o.level) + ": the point-sphere tree has levels 0.." +
                                           std::to_string(int64_t(levels) - 1)};
  return Status::success();
}

// Writes the files asked for; returns a JSON description of each, or the first error.
Result<nlohmann::json> write_exports(const Options& o, const Asset& asset) {
  nlohmann::json exports = nlohmann::json::array();
  if (!o.png.empty()) {
    Result<exports::SliceSpec> spec = exports::parse_slice(o.slice);
    if (!spec) return spec.error();
    spec->distances = o.field == "distances";
    spec->zoom = o.zoom;
    const Result<exports::SliceInfo> s = exports::write_slice_png(asset, spec.value(), o.png);
    if (!s) return s.error();
    const char* axis = spec->axis == 0 ? "x" : spec->axis == 1 ? "y" : "z";
    exports.push_back({{"file", o.png},
                       {"kind", "slice"},
                       {"axis", axis},
                       {"index", spec->index},
                       {"field", o.field},
                       {"width", s->width},
                       {"height", s->height},
                       {"zoom", s->zoom},
                       {"columns", s->columns},
                       {"rows", s->rows},
                       {"surface_in_slice", s->has_surface}});
  }
  if (!o.ply.empty()) {
    const Result<exports::PlyInfo> p = exports::write_point_shell_ply(asset, o.level, o.inward_normals, o.ply);
    if (!p) return p.error();
    exports.push_back({{"file", o.ply},
                       {"kind", "point_shell"},
                       {"level", p->level},
                       {"levels", p->levels},
                       {"points", p->points},
                       {"normals", o.inward_normals ? "inward" : "outward"}});
  }
  if (!o.vdb.empty()) {
    const Result<exports::VdbInfo> v = exports::write_voxelmap_vdb(asset, o.vdb);
    if (!v) return v.error();
    exports.push_back({{"file", o.vdb},
                       {"kind", "vdb"},
                       {"grids", {"distance", "layers"}},
                       {"distance_voxels", v->distance_voxels},
                       {"layer_voxels", v->layer_voxels}});
  }
  return exports;
}

void print_export(const nlohmann::json& e) {
  if (e["kind"] == "slice")
    std::cout << terminal_safe(e["file"].get<std::string>()) << ": " << e["field"].get<std::string>() << " of slice "
              << e["axis"].get<std::string>() << " = " << e["index"] << ", " << e["columns"] << " x " << e["rows"]
              << " voxels at " << e["zoom"] << " px, " << e["width"] << " x " << e["height"] << " px"
              << (e["surface_in_slice"].get<bool>() ? "" : " (the surface does not cross this slice)") << "\n";
  else if (e["kind"] == "html")
    std::cout << terminal_safe(e["file"].get<std::string>()) << ": the asset's report card (" << std::fixed
              << std::setprecision(1) << double(e["bytes"].get<uint64_t>()) / (1 << 20) << " MB folder)\n";
  else if (e["kind"] == "vdb")
    std::cout << terminal_safe(e["file"].get<std::string>()) << ": OpenVDB grids \"distance\" (" << e["distance_voxels"]
              << " band voxels) and \"layers\" (" << e["layer_voxels"] << " voxels)\n";
  else
    std::cout << terminal_safe(e["file"].get<std::string>()) << ": point shell levels 0.." << e["level"] << " of 0.."
              << e["levels"].get<uint32_t>() - 1 << ", " << e["points"] << " points with "
              << e["normals"].get<std::string>() << " normals (binary PLY)\n";
}

// The options that write a picture or another format of the asset.
void add_export_options(CLI::App* cmd, Options& options) {
  auto* slice = cmd->add_option("--slice", options.slice, "Voxelmap slice to draw: AXIS=INDEX, e.g. z=40")
                    ->check(CLI::Validator(
                        [](std::string& text) {
                          const Result<exports::SliceSpec> spec = exports::parse_slice(text);
                          return spec ? std::string() : spec.error().message;
                        },
                        "AXIS=INDEX"));
  auto* png = cmd->add_option("--png", options.png,
                              "Write the --slice picture here (PNG: colour map inside red / outside blue, surface "
                              "contour, legend; (P*columns + 200) x (max(P*rows, 240) + 42) pixels)")
                  ->check(output_path());
  slice->needs(png);
  png->needs(slice);
  cmd->add_option("--field", options.field, "What the slice colours: layers (every voxel) or distances (the band)")
      ->capture_default_str()
      ->check(CLI::IsMember({"layers", "distances"}))
      ->needs(slice);
  cmd->add_option("--zoom", options.zoom,
                  "Pixels per voxel P of the slice picture (default: 900 / the longer side, within 1..16)")
      ->transform(whole_number())
      ->check(CLI::Range(1, 64))
      ->needs(slice);
  auto* ply = cmd->add_option("--ply", options.ply,
                              "Write the point shell with normals as binary PLY (MeshLab, Blender, CloudCompare)")
                  ->check(output_path());
  cmd->add_option("--level", options.level, "With --ply: only tree levels 0..L (a coarser shell; default: all)")
      ->transform(whole_number())
      ->needs(ply);
  cmd->add_flag("--inward-normals", options.inward_normals, "With --ply: keep the asset's inward normals")->needs(ply);
  cmd->add_option("--vdb", options.vdb,
                  "Write the voxelmap as OpenVDB grids: \"distance\" (level set of the stored band, metres) and "
                  "\"layers\" (int32), for Houdini, Blender or vdb_view")
      ->check(output_path());
  cmd->add_option("--html", options.html,
                  "Write the asset's report card (facts, validation, pictures, 3D view) as a folder with index.html "
                  "(the card `voxfmt report` shows)")
      ->check(output_path());
}

// Each file output apart from the asset and from the others: none may replace the asset or another output.
Status check_outputs(const Options& options) {
  const std::pair<const char*, const std::string*> outputs[] = {
      {"--png", &options.png}, {"--ply", &options.ply}, {"--vdb", &options.vdb}};
  std::error_code ec;
  for (size_t i = 0; i < std::size(outputs); ++i) {
    const std::string& path = *outputs[i].second;
    if (path.empty()) continue;
    if (Status usable = check_output_path(path, options.file); !usable) return usable;
    for (size_t j = 0; j < i; ++j)
      if (!outputs[j].second->empty() &&
          std::filesystem::weakly_canonical(std::filesystem::absolute(path, ec), ec) ==
              std::filesystem::weakly_canonical(std::filesystem::absolute(*outputs[j].second, ec), ec))
        return Error{IssueCode::BadOption,
                     std::string(outputs[j].first) + " and " + outputs[i].first + " name the same file " + path, path};
    // The card's folder is replaced whole: no other output may be it or lie in it.
    if (!options.html.empty()) {
      const auto card = std::filesystem::weakly_canonical(std::filesystem::absolute(options.html, ec), ec);
      const auto file = std::filesystem::weakly_canonical(std::filesystem::absolute(path, ec), ec);
      const auto [end, _] = std::mismatch(card.begin(), card.end(), file.begin(), file.end());
      if (end == card.end())
        return Error{IssueCode::BadOption, std::string(outputs[i].first) + " " + path + " is --html's folder or in it",
                     path};
    }
  }
  return Status::success();
}

int run(const Options& options) {
  if (Status usable = check_outputs(options); !usable)
    return report_error("inspect", usable.error(), options.json, options.file);
  for (const std::string* output : {&options.png, &options.ply, &options.vdb})
    if (!output->empty()) remove_dead_temporaries(*output);  // what a killed inspect left beside it
  const auto write_card = [&]() -> Result<nlohmann::json> {
    const Result<report::ReportInfo> info = report::write_asset_report(options.file, options.html, options.read);
    if (!info) return info.error();
    return nlohmann::json{{"file", info->index_html}, {"kind", "html"}, {"bytes", info->bytes}};
  };
  const bool more = !options.png.empty() || !options.ply.empty() || !options.vdb.empty();
  if (!options.html.empty() && !options.json && !more) {  // the card alone: the asset is read by the card only
    const Result<nlohmann::json> card = write_card();
    if (!card) return report_error("inspect", card.error(), options.json, options.file);
    print_export(card.value());
    return kExitOk;
  }
  std::vector<Issue> warnings;
  Result<Asset> asset = read_asset(options.file, &warnings, options.read);
  if (!asset) return report_error("inspect", asset.error(), options.json, options.file);
  if (Status fits = check_exports_fit(options, asset.value()); !fits)
    return report_error("inspect", fits.error(), options.json, options.file);
  nlohmann::json card;  // the report card's entry among the exports, where --html asks for one
  if (!options.html.empty()) {
    Result<nlohmann::json> written_card = write_card();
    if (!written_card) return report_error("inspect", written_card.error(), options.json, options.file);
    card = std::move(written_card.value());
  }
  Result<nlohmann::json> written = write_exports(options, asset.value());
  if (!written)
    return report_error("inspect", written.error(), options.json,
                        options.file);  // a slice or level outside, an unwritable file
  nlohmann::json& exports = written.value();
  if (!card.is_null()) exports.insert(exports.begin(), card);
  if (!exports.empty() && !options.json) {
    for (const nlohmann::json& e : exports) print_export(e);
    return kExitOk;
  }
  const AssetSummary summary = summarize_asset(options.file, asset.value());
  nlohmann::json out = nlohmann::json::parse(inspect_json(options.file, asset.value(), summary, warnings));
  if (!exports.empty()) out["exports"] = exports;
  if (options.json)
    std::cout << to_text(out) << "\n";
  else
    print_text(options.file, asset.value(), summary, warnings);
  return kExitOk;
}

}  // namespace

void add_inspect_command(CLI::App& app, int& exit_code) {
  auto options = std::make_shared<Options>();
  CLI::App* cmd = app.add_subcommand(
      "inspect",
      "Print a summary of an asset (grid, point shell, mass, provenance); draw a slice; export the point shell "
      "(PLY) or the voxelmap (OpenVDB)");
  cmd->add_option("file", options->file, "Asset file (.vox.h5)")->required();
  cmd->add_flag("--json", options->json, "Print the summary as JSON on stdout");
  add_read_budget_option(cmd, options->read);
  add_export_options(cmd, *options);
  cmd->footer(
      "\nExamples:\n"
      "  voxfmt inspect bunny.vox.h5                                  # what the asset holds\n"
      "  voxfmt inspect bunny.vox.h5 --slice z=150 --png slice.png    # a picture of the voxelmap\n"
      "  voxfmt inspect bunny.vox.h5 --ply shell.ply --vdb grids.vdb  # point shell and grids for other tools\n"
      "  voxfmt inspect bunny.vox.h5 --html bunny-card/               # the report card, open bunny-card/index.html\n");
  cmd->callback([options, &exit_code] { exit_code = run(*options); });
}

}  // namespace voxfmt::cli
