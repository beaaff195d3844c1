// File paths in JSON records (batch manifests, the reports that read them): JSON holds UTF-8 text only, while a
// path on Linux may hold any bytes. Written once here so that every reader of a record gets the same file back.
#pragma once

#include <nlohmann/json.hpp>

#include <string>

#include "voxfmt/detail/utf8.h"

namespace voxfmt {

/// Stores `path` under `key`: as it is where it is UTF-8; else escaped (\xNN) for people to read, with its exact
/// bytes in hex under "<key>_hex" for programs.
inline void set_path(nlohmann::json& record, const std::string& key, const std::string& path) {
  record[key] = utf8_escaped(path);
  record.erase(key + "_hex");
  if (is_utf8(path)) return;
  record[key + "_hex"] = lowercase_hex(path);
}

/// The path set_path stored under `key` (its exact bytes where "<key>_hex" holds them); "" where there is none.
inline std::string path_of(const nlohmann::json& record, const std::string& key) {
  const auto value = [&](const std::string& name) {
    const auto it = record.find(name);
    return it != record.end() && it->is_string() ? it->get<std::string>() : std::string();
  };
  const std::string hex = value(key + "_hex");
  std::string bytes;
  const auto nibble = [](char c) { return c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1; };
  for (size_t i = 0; i + 1 < hex.size() && hex.size() % 2 == 0; i += 2) {
    const int high = nibble(hex[i]), low = nibble(hex[i + 1]);
    if (high < 0 || low < 0) return value(key);  // damaged: the text is the best we have
    bytes += char(high * 16 + low);
  }
  return bytes.empty() ? value(key) : bytes;
}

}  // namespace voxfmt
