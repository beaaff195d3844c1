// Shared helpers of the libvoxfmt tests.
#pragma once

#include <string>

#include "voxfmt/asset.h"

namespace voxfmt::test {

/// A small asset with every field, optional ones included, set to distinctive values.
Asset make_full_asset();

/// A fresh scratch directory for one test (removed at process exit is not needed: it lives under the
/// build tree's temp dir).
std::string scratch_dir(const std::string& test_name);

}  // namespace voxfmt::test
