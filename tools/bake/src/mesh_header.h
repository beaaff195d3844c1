// A mesh file's header promises counts that its readers believe: they reserve memory for them, and CGAL's OFF
// reader computes an int from them that overflows beyond ~1e9. The promise is checked against the file's size first.
#pragma once

#include <string>

namespace voxfmt::bake {

/// Throws IMPORT_FAILED when an OFF or PLY header (found by its first bytes, whatever the file's name) declares
/// more vertices, faces or other elements than the rest of the file could hold at its smallest encoding. Files of
/// other formats, and headers it cannot parse, pass: their reader judges them.
void check_declared_counts(const std::string& path);

}  // namespace voxfmt::bake
