// libFuzzer target: arbitrary bytes as a mesh file of one format (the extension is a compile definition, one
// executable per format), baked at a small resolution the way `voxfmt build` bakes. The import parses in the
// isolated child (assimp's and CGAL's readers trust their input: a crash there is an IMPORT_FAILED result, not a
// finding); what is fuzzed is this project's code: the header check before the import, and on whatever mesh comes
// out, repair, the voxelmap's distances and layers, the point shell and tree, mass properties. A bake must fail
// with an error code or give an asset that passes full validation; anything else aborts, so the fuzzer keeps it.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "fuzz_input_file.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/io.h"

#ifndef VOXFMT_FUZZ_MESH_EXTENSION
#error "define VOXFMT_FUZZ_MESH_EXTENSION, e.g. \".obj\""
#endif

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = voxfmt::fuzz::write_input_file(data, size, "-mesh" VOXFMT_FUZZ_MESH_EXTENSION);
  if (path.empty()) return 0;
  voxfmt::bake::Settings settings;
  settings.voxelmap.resolution = 24;  // small grids keep each input in milliseconds
  settings.point_shell.points = 300;
  settings.threads = 1;
  settings.import.time_limit_s = 3;  // a hanging importer is stopped (IMPORT_FAILED) well before libFuzzer's timeout
  const voxfmt::Result<voxfmt::bake::Baked> baked = voxfmt::bake::bake_mesh(path, settings);
  if (!baked) return 0;  // refused with a code: what a broken mesh should get
  for (const voxfmt::Issue& issue : voxfmt::validate_asset(baked.value().asset, voxfmt::ValidationLevel::Full))
    if (issue.severity == voxfmt::Severity::Error) {
      std::fprintf(stderr, "bake produced an invalid asset: %s: %s\n", issue.path.c_str(), issue.message.c_str());
      std::abort();
    }
  return 0;
}
