// libFuzzer target: arbitrary bytes as an asset file, through everything a user runs on one — open, quick and full
// validation, loading into the runtime, one query. HDF5 parses in the isolated child (a crash there is a
// READ_FAILED finding, not a fuzzer finding); what is fuzzed is this project's code around it: the reader's checks,
// the child's wire format, the validator, the runtime's conversion and query.
#include <cstdint>
#include <string>

#include "fuzz_input_file.h"
#include "voxfmt/io.h"
#include "voxfmt/runtime/collision_object.h"
#include "voxfmt/runtime/query.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = voxfmt::fuzz::write_input_file(data, size, "-asset.vox.h5");
  if (path.empty()) return 0;
  (void)voxfmt::validate_file(path, voxfmt::ValidationLevel::Full);
  voxfmt::Result<voxfmt::Asset> asset = voxfmt::read_asset(path);
  if (!asset) return 0;
  auto loaded = voxfmt::runtime::CollisionObject::from_asset(asset.value());
  if (!loaded) return 0;
  const voxfmt::runtime::CollisionObject& object = *loaded.value();
  voxfmt::runtime::ContactSet contacts;
  voxfmt::runtime::Pose shifted;
  shifted.translation.x() = 0.25 * (object.bounds_max() - object.bounds_min()).x();
  voxfmt::runtime::query_contacts(object, voxfmt::runtime::Pose{}, object, shifted, {}, contacts);
  return 0;
}
