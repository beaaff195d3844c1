// libFuzzer target: arbitrary bytes as a `voxfmt batch` manifest (JSON lines), read the way a resumed batch reads it.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <stdexcept>
#include <string>

#include "batch_manifest.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const std::string path = "/tmp/voxfmt-fuzz-manifest-" + std::to_string(::getpid()) + ".jsonl";
  if (FILE* f = std::fopen(path.c_str(), "wb")) {
    std::fwrite(data, 1, size, f);
    std::fclose(f);
  } else {
    return 0;
  }
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
