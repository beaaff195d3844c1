// Shared helpers of the libvoxfmt tests.
#pragma once

#include <string>

#include "voxfmt/asset.h"
#include "voxfmt/io.h"

namespace voxfmt::test {

/// A small asset with every field, optional ones included, set to distinctive values.
Asset make_full_asset();
/// Write options for make_full_asset(): its numbers are arbitrary (only their structure is right), so only
/// the structural rules are checked.
inline WriteOptions structural() {
  WriteOptions options;
  options.validation = ValidationLevel::Quick;
  return options;
}
/// Read options for the same: the structural rules only.
inline ReadOptions structural_read() {
  ReadOptions options;
  options.level = ValidationLevel::Quick;
  return options;
}

/// A fresh scratch directory for one test (removed at process exit is not needed: it lives under the
/// build tree's temp dir).
std::string scratch_dir(const std::string& test_name);

}  // namespace voxfmt::test
