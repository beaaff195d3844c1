// The readers under test take paths: each fuzz input is written to one file per process, reused for every input.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <string>

namespace voxfmt::fuzz {

/// Writes `data` to /tmp/voxfmt-fuzz-<pid><suffix> and returns its path, or "" if it cannot be written.
inline std::string write_input_file(const uint8_t* data, size_t size, const char* suffix) {
  const std::string path = "/tmp/voxfmt-fuzz-" + std::to_string(::getpid()) + suffix;
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return "";
  const bool written = std::fwrite(data, 1, size, f) == size;
  return std::fclose(f) == 0 && written ? path : "";
}

}  // namespace voxfmt::fuzz
