// UTF-8, which the format requires of every string it stores (spec §1) and every message must be (Python decodes
// them): names from a file system or a file may hold any bytes. And hex, for bytes that text cannot carry.
#pragma once

#include <string>
#include <string_view>

namespace voxfmt {

/// Whether `text` is valid UTF-8 (RFC 3629: no overlong forms, no surrogates, nothing above U+10FFFF).
bool is_utf8(const std::string& text);
/// `text` with every byte that is not part of valid UTF-8 written as \xNN.
std::string utf8_escaped(const std::string& text);
/// `text` as utf8_escaped writes it, with control characters (C0, DEL, C1) escaped as \xNN too: for text from a
/// file shown on a terminal, where an escape sequence could clear the screen or forge a line.
std::string terminal_safe(const std::string& text);
/// The one message for STRING_NOT_UTF8, whether a reader found the bytes in a file or a writer was given them.
std::string not_utf8_message(const std::string& text);
/// `bytes` as lowercase hex, two digits a byte (a digest, a path's exact bytes in JSON).
std::string lowercase_hex(std::string_view bytes);

}  // namespace voxfmt
