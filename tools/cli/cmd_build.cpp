// `voxfmt build MESH -o OUT`: bake one mesh into an asset.
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <future>
#include <iomanip>
#include <iostream>

#include "bake.h"
#include "bake_options.h"
#include "commands.h"
#include "json_report.h"
#include "voxfmt/io.h"
#include "voxfmt/validate.h"

namespace voxfmt::cli {

namespace {

struct Options {
  std::string mesh;
  std::string output;
  BakeSettings bake;
  bool json = false;
  bool quiet = false;
};

uint64_t peak_memory_bytes() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return uint64_t(usage.ru_maxrss) * 1024;  // Linux reports KiB
}

// The spec's semantic rules, checked before anything is written: an asset `validate --level full` would reject
// is a bake bug, reported as such instead of being written.
void verify(const std::string& mesh, const Asset& asset, bake::BuildReport& report) {
  const auto start = std::chrono::steady_clock::now();
  for (const Issue& issue : validate_asset(asset, ValidationLevel::Full))
    if (issue.severity == Severity::Error)
      throw bake::BakeError("INVALID_ASSET", mesh + ": the baked asset breaks spec rule " + code_name(issue.code) + " at " +
                                                 issue.path + ": " + issue.message +
                                                 " (a bake bug: please report it; --no-verify writes the asset anyway)");
  report.timings.push_back({"verify", std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count()});
}

int run(const Options& o) {
  const bool show_progress = !o.quiet && !o.json && isatty(STDERR_FILENO);
  const auto start = std::chrono::steady_clock::now();
  bake::BuildReport report;
  int bake_stages = 0;  // the bake's own stages; "write" comes after them
  auto progress = [&](int index, int count, const std::string& stage) {
    bake_stages = std::max(bake_stages, count);
    if (!show_progress) return;
    const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::cerr << "\r\033[K[" << index << "/" << count + 1 << "] " << stage << "  (" << std::fixed << std::setprecision(1)
              << t << " s)" << std::flush;
  };
  // The one way a failed bake is reported: a code and a message naming the input, on stderr and in --json.
  auto fail = [&](const std::string& code, const std::string& message) {
    if (show_progress) std::cerr << "\r\033[K";
    if (o.json)
      std::cout << to_text(nlohmann::json{{"status", "error"}, {"input", o.mesh}, {"code", code}, {"message", message}}) << "\n";
    std::cerr << "voxfmt build: error: " << code << ": " << message << "\n";
    return code == "BAD_OPTION" ? kExitUsageOrIo : kExitInvalid;
  };
  try {
    Asset asset = bake::build_asset(o.mesh, o.bake.build, report, progress);
    progress(bake_stages + 1, bake_stages, o.bake.verify ? "verify + write" : "write");
    const auto write_start = std::chrono::steady_clock::now();
    // Verify on one thread while the file is written (its compression takes the others); the file replaces
    // OUT only once verify has passed. The future's destructor waits for it on every path.
    std::future<void> verified;
    if (o.bake.verify) verified = std::async(std::launch::async, [&] { verify(o.mesh, asset, report); });
    std::exception_ptr verify_error;
    auto wait_for_verify = [&] {
      if (!verified.valid()) return;
      try {
        verified.get();
      } catch (...) {
        verify_error = std::current_exception();
      }
    };
    WriteOptions write_options;
    write_options.deflate_level = o.bake.deflate;
    write_options.before_commit = [&]() -> Status {
      wait_for_verify();
      if (verify_error) return Error{IssueCode::WriteFailed, "verify failed"};
      return Status::success();
    };
    const Status written = write_asset(o.output, asset, write_options);
    wait_for_verify();
    if (verify_error) std::rethrow_exception(verify_error);  // outranks the write failure it caused
    if (!written) throw bake::BakeError("WRITE_FAILED", written.error().message);
    report.timings.push_back({"write", std::chrono::duration<double>(std::chrono::steady_clock::now() - write_start).count()});
    if (show_progress) std::cerr << "\r\033[K";

    const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::error_code ec;
    const uint64_t file_size = std::filesystem::file_size(o.output, ec);
    const PointShell& ps = asset.point_shell;
    if (o.json) {
      nlohmann::json timings = nlohmann::json::object();
      for (const auto& t : report.timings) timings[t.stage] = t.seconds;
      nlohmann::json warnings = nlohmann::json::array();
      for (const auto& w : report.repair.warnings) warnings.push_back({{"code", w.code}, {"message", w.message}});
      const Voxelmap& vm = asset.voxelmap;
      std::cout << to_text(nlohmann::json{{"status", "ok"},
                                  {"input", o.mesh},
                                  {"output", o.output},
                                  {"source_sha256", asset.provenance.source_sha256},
                                  {"input_vertices", report.input_vertices},
                                  {"input_triangles", report.input_triangles},
                                  {"closed", report.repair.closed},
                                  {"timings_s", timings},
                                  {"total_s", total},
                                  {"peak_memory_bytes", peak_memory_bytes()},
                                  {"file_size_bytes", file_size},
                                  {"voxelmap", {{"dims", vm.dims}, {"voxel_size", vm.voxel_size}, {"stored_distances", vm.stored_count()}}},
                                  {"pointshell", {{"points", ps.size()}, {"levels", ps.level_count()}, {"points_per_level", ps.points_per_level()}}},
                                  {"volume", asset.mass.volume},
                                  {"warnings", warnings}})
                << "\n";
    } else if (!o.quiet) {
      for (const auto& w : report.repair.warnings) std::cerr << "warning: " << w.code << ": " << w.message << "\n";
      const Voxelmap& vm = asset.voxelmap;
      std::cout << o.output << ": " << vm.dims[0] << "x" << vm.dims[1] << "x" << vm.dims[2] << " voxels of "
                << vm.voxel_size << " m, " << ps.size() << " points in " << ps.level_count() << " levels, "
                << file_size / 1024 << " KiB, " << std::fixed << std::setprecision(2) << total << " s\n";
    }
    return kExitOk;
  } catch (const bake::BakeError& e) {
    return fail(e.code(), e.what());
  } catch (const std::bad_alloc&) {
    return fail("OUT_OF_MEMORY", o.mesh + ": out of memory (try a coarser --resolution or --voxel-size)");
  } catch (const std::exception& e) {  // library failures (CGAL, TBB) still get a clean message
    return fail("INTERNAL", o.mesh + ": " + e.what());
  }
}

}  // namespace

void add_build_command(CLI::App& app, int& exit_code) {
  auto o = std::make_shared<Options>();
  CLI::App* cmd = app.add_subcommand("build", "Bake a mesh (any format assimp reads) into a voxfmt asset");
  cmd->add_option("mesh", o->mesh, "Input mesh file (OBJ, PLY, STL, OFF, glTF/GLB, FBX, DAE, ...)")->required();
  cmd->add_option("-o,--output", o->output, "Output asset file (.vox.h5); written atomically")->required();
  add_bake_options(*cmd, o->bake);
  cmd->add_flag("--json", o->json, "Print a JSON summary (timings, peak memory, sizes, warnings) on stdout");
  cmd->add_flag("-q,--quiet", o->quiet, "No progress, warnings or summary");
  cmd->callback([o, &exit_code] { exit_code = run(*o); });
}

}  // namespace voxfmt::cli
