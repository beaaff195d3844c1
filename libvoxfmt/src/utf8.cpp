#include "voxfmt/detail/utf8.h"

#include <cstdint>
#include <cstdio>

namespace voxfmt {

namespace {
// Length of the UTF-8 sequence starting at s[i] (1-4), or 0 if it is not a valid one (RFC 3629: no overlong
// forms, no surrogates, nothing above U+10FFFF).
size_t utf8_sequence(const std::string& s, size_t i) {
  const auto byte = [&](size_t k) { return i + k < s.size() ? uint8_t(s[i + k]) : uint8_t(0); };
  const auto tail = [&](size_t k) { return (byte(k) & 0xC0) == 0x80; };
  const uint8_t b = byte(0);
  if (b < 0x80) return 1;
  if (b >= 0xC2 && b <= 0xDF) return tail(1) ? 2 : 0;
  if (b >= 0xE0 && b <= 0xEF) {
    const uint8_t lo = b == 0xE0 ? 0xA0 : 0x80, hi = b == 0xED ? 0x9F : 0xBF;
    return byte(1) >= lo && byte(1) <= hi && tail(2) ? 3 : 0;
  }
  if (b >= 0xF0 && b <= 0xF4) {
    const uint8_t lo = b == 0xF0 ? 0x90 : 0x80, hi = b == 0xF4 ? 0x8F : 0xBF;
    return byte(1) >= lo && byte(1) <= hi && tail(2) && tail(3) ? 4 : 0;
  }
  return 0;
}

void append_hex(std::string& out, uint8_t byte) {
  char hex[8];
  std::snprintf(hex, sizeof hex, "\\x%02X", unsigned(byte));
  out += hex;
}
}  // namespace

bool is_utf8(const std::string& text) {
  for (size_t i = 0; i < text.size();) {
    const size_t n = utf8_sequence(text, i);
    if (n == 0) return false;
    i += n;
  }
  return true;
}

std::string utf8_escaped(const std::string& text) {
  if (is_utf8(text)) return text;
  std::string out;
  for (size_t i = 0; i < text.size();) {
    const size_t n = utf8_sequence(text, i);
    if (n > 0) {
      out.append(text, i, n);
      i += n;
      continue;
    }
    append_hex(out, uint8_t(text[i]));
    ++i;
  }
  return out;
}

std::string terminal_safe(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (size_t i = 0; i < text.size();) {
    const size_t n = utf8_sequence(text, i);
    const uint8_t lead = uint8_t(text[i]);
    // C0 and DEL, and C1 (U+0080..U+009F, two bytes from 0xC2): a terminal acts on them (CSI, OSC, a bare CR).
    const bool control = n == 1 ? lead < 0x20 || lead == 0x7F : n == 2 && lead == 0xC2 && uint8_t(text[i + 1]) <= 0x9F;
    if (n == 0 || control) {
      const size_t bytes = n == 0 ? 1 : n;
      for (size_t k = 0; k < bytes; ++k) append_hex(out, uint8_t(text[i + k]));
      i += bytes;
      continue;
    }
    out.append(text, i, n);
    i += n;
  }
  return out;
}

std::string not_utf8_message(const std::string& text) {
  return "string is not valid UTF-8: '" + utf8_escaped(text) + "'";
}

std::string lowercase_hex(std::string_view bytes) {
  static constexpr char digits[] = "0123456789abcdef";
  std::string out;
  out.reserve(2 * bytes.size());
  for (const unsigned char c : bytes) out += {digits[c >> 4], digits[c & 15]};
  return out;
}

}  // namespace voxfmt
