#include "mesh_header.h"

#include <fstream>
#include <sstream>
#include <string>

#include "stages.h"

namespace voxfmt::bake {

namespace {

constexpr std::streamsize kHeaderBytes = 64 * 1024;  // more than any real header; a longer one is not checked

struct Declared {
  double min_bytes = 0;  // the fewest bytes that could hold what the header declares
  std::string what;      // "1000000000 vertices and 1 face"
  bool parsed = false;
};

// The smallest size of one scalar of a binary PLY property type; 0 for a name PLY does not define.
int ply_type_bytes(const std::string& type) {
  if (type == "char" || type == "uchar" || type == "int8" || type == "uint8") return 1;
  if (type == "short" || type == "ushort" || type == "int16" || type == "uint16") return 2;
  if (type == "int" || type == "uint" || type == "int32" || type == "uint32" || type == "float" || type == "float32")
    return 4;
  if (type == "double" || type == "float64") return 8;
  return 0;
}

// PLY: each element needs, per property, a number and a separator in ASCII, or the type's bytes in binary (a list,
// at least its count).
Declared ply_declared(std::istringstream& header) {
  Declared out;
  std::string line, format;
  double count = 0, element_bytes = 0;
  const auto close_element = [&] { out.min_bytes += count * element_bytes; };
  while (std::getline(header, line)) {
    std::istringstream words(line);
    std::string keyword, a, b;
    words >> keyword >> a >> b;
    if (keyword == "format") {
      format = a;
    } else if (keyword == "element") {
      close_element();
      std::istringstream number(b);
      if (!(number >> count) || count < 0) return {};
      element_bytes = 0;
      out.what += (out.what.empty() ? "" : ", ") + b + " '" + a + "'";
    } else if (keyword == "property") {
      const int bytes = ply_type_bytes(a == "list" ? b : a);
      if (bytes == 0) return {};
      element_bytes += format == "ascii" ? 2 : bytes;
    } else if (keyword == "end_header") {
      close_element();
      out.parsed = !format.empty();
      out.what += " elements";
      return out;
    }
  }
  return {};
}

// OFF (text): a vertex or a face needs at least a number and a separator. (Binary OFF, rare, is left to its reader.)
Declared off_declared(const std::string& header) {
  std::istringstream lines(header);
  std::string line, text;
  while (std::getline(lines, line)) text += line.substr(0, line.find('#')) + "\n";  // comments hold no tokens
  std::istringstream words(text);
  std::string keyword, token;
  words >> keyword;
  const bool has_dimension = keyword.find('n') != std::string::npos && keyword.find('n') < keyword.size() - 3;
  if (has_dimension) words >> token;
  const std::streampos counts_at = words.tellg();
  words >> token;
  if (token == "BINARY") return {};  // binary counts follow; rare enough that their reader judges them
  words.clear();
  words.seekg(counts_at);
  double vertices = 0, faces = 0;
  if (!(words >> vertices >> faces) || vertices < 0 || faces < 0) return {};
  std::ostringstream what;
  what.precision(15);
  what << vertices << (vertices == 1 ? " vertex" : " vertices") << " and " << faces
       << (faces == 1 ? " face" : " faces");
  return {2 * (vertices + faces), what.str(), true};
}

}  // namespace

void check_declared_counts(const std::string& path) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) return;  // the reader reports what cannot be opened
  const double file_bytes = double(in.tellg());
  in.seekg(0);
  std::string header(size_t(kHeaderBytes), '\0');
  in.read(header.data(), kHeaderBytes);
  header.resize(size_t(in.gcount()));
  Declared declared;
  size_t body_at = 0;
  if (header.rfind("ply", 0) == 0) {
    const size_t end = header.find("end_header");
    if (end == std::string::npos) return;
    body_at = header.find('\n', end);
    if (body_at != std::string::npos) ++body_at;  // the body starts after end_header's line
    std::istringstream lines(header.substr(0, end + 10));
    declared = ply_declared(lines);
  } else {
    std::istringstream first(header);
    std::string keyword;
    first >> keyword;
    if (keyword.size() < 3 || keyword.compare(keyword.size() - 3, 3, "OFF") != 0) return;
    declared = off_declared(header);
  }
  if (!declared.parsed || body_at == std::string::npos) return;  // npos: end_header ends the file
  const double body_bytes = file_bytes - double(body_at);
  if (declared.min_bytes <= body_bytes + 1)  // + 1: the last number needs no separator after it
    return;
  std::ostringstream message;
  message.precision(15);
  message << path << ": cannot read mesh: its header declares " << declared.what << ", which need at least "
          << declared.min_bytes << " bytes, but the file holds " << body_bytes
          << (body_at > 0 ? " bytes after its header" : " bytes") << " (a damaged or hostile file?)";
  throw BakeError(IssueCode::ImportFailed, message.str());
}

}  // namespace voxfmt::bake
