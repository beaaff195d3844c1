// UTF-8, which the format requires of every string it stores (spec §1) and every message must be (Python decodes
// them): names from a file system or a file may hold any bytes.
#pragma once

#include <string>

namespace voxfmt {

/// Whether `text` is valid UTF-8 (RFC 3629: no overlong forms, no surrogates, nothing above U+10FFFF).
bool is_utf8(const std::string& text);
/// `text` with every byte that is not part of valid UTF-8 written as \xNN.
std::string utf8_escaped(const std::string& text);

}  // namespace voxfmt
