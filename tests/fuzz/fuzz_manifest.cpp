// libFuzzer target: arbitrary bytes as a `voxfmt batch` manifest (JSON lines), read the way a resumed batch reads it.
#include <cstdint>
#include <stdexcept>
#include <string>

#include "batch_manifest.h"
#include "fuzz_input_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = voxfmt::fuzz::write_input_file(data, size, "-manifest.jsonl");
  if (path.empty()) return 0;
  try {
    voxfmt::cli::Manifest manifest(path);  // reads, drops torn lines, rewrites atomically
    if (const nlohmann::json* record = manifest.last("out.vox.h5")) {
      (void)voxfmt::cli::text_field(*record, "code");
      (void)voxfmt::cli::integer_field(*record, "size");
    }
  } catch (const std::runtime_error&) {  // the documented error of a manifest that cannot be used
  }
  return 0;
}
