// Stage 1: any mesh format assimp reads -> one triangle soup in the file's frame (times unit_scale), in double
// precision for triangle meshes in OFF, OBJ and PLY.
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/IO/polygon_soup_io.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <assimp/DefaultLogger.hpp>
#include <assimp/Importer.hpp>
#include <assimp/LogStream.hpp>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "mesh_header.h"
#include "stages.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/isolated_call.h"
#include "voxfmt/io.h"

#if !defined(_WIN32)
#include <unistd.h>
#endif

namespace voxfmt::bake {

namespace {

void append_node(const aiScene& scene, const aiNode& node, const aiMatrix4x4& parent, TriangleMesh& out, double scale,
                 const std::string& path) {
  const aiMatrix4x4 transform = parent * node.mTransformation;
  for (unsigned m = 0; m < node.mNumMeshes; ++m) {
    const aiMesh& mesh = *scene.mMeshes[node.mMeshes[m]];
    const uint32_t base = uint32_t(out.vertices.size());
    for (unsigned v = 0; v < mesh.mNumVertices; ++v) {
      const aiVector3D p = transform * mesh.mVertices[v];
      const Vec3 q = {double(p.x) * scale, double(p.y) * scale, double(p.z) * scale};
      if (!std::isfinite(q[0]) || !std::isfinite(q[1]) || !std::isfinite(q[2]))
        throw BakeError(IssueCode::NonFiniteCoordinates, path + ": vertex " + std::to_string(v) + " of mesh '" +
                                                             mesh.mName.C_Str() + "' has a non-finite coordinate");
      out.vertices.push_back(q);
    }
    for (unsigned f = 0; f < mesh.mNumFaces; ++f) {
      const aiFace& face = mesh.mFaces[f];
      if (face.mNumIndices != 3) continue;  // points and lines carry no surface
      // Some readers (PLY's) pass a face's index on unchecked: past the vertices, the bake would read past them.
      for (unsigned i = 0; i < 3; ++i)
        if (face.mIndices[i] >= mesh.mNumVertices)
          throw BakeError(IssueCode::ImportFailed, path + ": cannot read mesh: face " + std::to_string(f) +
                                                       " of mesh '" + mesh.mName.C_Str() + "' names vertex " +
                                                       std::to_string(face.mIndices[i]) + " of " +
                                                       std::to_string(mesh.mNumVertices) + " (a corrupt file)");
      out.triangles.push_back({base + face.mIndices[0], base + face.mIndices[1], base + face.mIndices[2]});
    }
  }
  for (unsigned c = 0; c < node.mNumChildren; ++c) append_node(scene, *node.mChildren[c], transform, out, scale, path);
}

std::string lowercase(std::string text) {
  std::transform(text.begin(), text.end(), text.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return text;
}

// assimp (Debian's build) stores coordinates as 32-bit floats: a mesh 2 km from its origin would lose 0.1 mm.
// CGAL's readers of the text formats OFF, OBJ and PLY keep doubles, so triangle meshes in those formats are
// read with them. Anything else — polygons (assimp triangulates concave ones correctly), a file CGAL's reader
// refuses or that holds no face, other formats — goes to assimp, which names the problem.
bool read_triangles_in_double(const std::string& path, double scale, TriangleMesh& out) {
  const std::string extension = lowercase(std::filesystem::path(path).extension().string());  // PART.OBJ too
  if (extension != ".off" && extension != ".obj" && extension != ".ply") return false;
  using Point = CGAL::Exact_predicates_inexact_constructions_kernel::Point_3;
  std::vector<Point> points;
  std::vector<std::vector<std::size_t>> polygons;
  try {
    if (!CGAL::IO::read_polygon_soup(path, points, polygons, CGAL::parameters::verbose(false))) return false;
  } catch (...) {
    return false;
  }
  if (polygons.empty() || points.size() > UINT32_MAX) return false;
  for (const auto& polygon : polygons) {
    if (polygon.size() != 3) return false;
    for (std::size_t v : polygon)
      if (v >= points.size()) return false;
  }
  out.vertices.reserve(points.size());
  for (std::size_t v = 0; v < points.size(); ++v) {
    const Vec3 q = {points[v].x() * scale, points[v].y() * scale, points[v].z() * scale};
    if (!std::isfinite(q[0]) || !std::isfinite(q[1]) || !std::isfinite(q[2]))
      throw BakeError(IssueCode::NonFiniteCoordinates,
                      path + ": vertex " + std::to_string(v) + " has a non-finite coordinate");
    out.vertices.push_back(q);
  }
  out.triangles.reserve(polygons.size());
  for (const auto& polygon : polygons)
    out.triangles.push_back({uint32_t(polygon[0]), uint32_t(polygon[1]), uint32_t(polygon[2])});
  return true;
}

}  // namespace

bool is_mesh_file_name(const std::string& path) {
  static const std::vector<std::string> extensions = [] {
    std::string list;  // "*.3d;*.3ds;...;*.mesh.xml;..."
    Assimp::Importer().GetExtensionList(list);
    const std::vector<std::string> excluded = {".bvh", ".md5anim", ".md5camera", ".xml", ".raw"};
    std::vector<std::string> out;
    size_t start = 0;
    while (start < list.size()) {
      size_t end = list.find(';', start);
      if (end == std::string::npos) end = list.size();
      std::string pattern = lowercase(list.substr(start, end - start));
      if (pattern.rfind("*", 0) == 0) pattern.erase(0, 1);
      if (!pattern.empty() && std::find(excluded.begin(), excluded.end(), pattern) == excluded.end())
        out.push_back(pattern);
      start = end + 1;
    }
    return out;
  }();
  const std::string name = lowercase(std::filesystem::path(path).filename().string());
  for (const std::string& extension : extensions)
    if (name.size() > extension.size() &&
        name.compare(name.size() - extension.size(), extension.size(), extension) == 0)
      return true;
  return false;
}

namespace {

// Some of assimp's readers report a corrupt file only to its log and read on: an OFF face naming a vertex the file
// does not have gets the last vertex instead, a mesh nobody drew. During a read, the first logged error or warning
// that a vertex or face index is out of range is kept, and refuses the file. (Other indices out of range, a
// material's or a clip's, leave the geometry whole: those files still read.)
class CorruptGeometry : public Assimp::LogStream {
 public:
  explicit CorruptGeometry(std::string& first) : first_(first) {}
  void write(const char* message) override {
    if (!first_.empty() || !message) return;
    const std::string lower = lowercase(message);
    const auto has = [&lower](const char* words) { return lower.find(words) != std::string::npos; };
    if (!has("out of range") || !has("index") || !(has("vertex") || has("face"))) return;
    std::string text = message;  // "Error, T0: OFF: Vertex index is out of range\n": the message alone
    if (const size_t colon = text.find(": "); colon != std::string::npos && text.find(", T") < colon)
      text.erase(0, colon + 2);
    while (!text.empty() && (text.back() == '\n' || text.back() == '\r')) text.pop_back();
    first_ = text;
  }

 private:
  std::string& first_;
};

// Listens to assimp's log for the life of a read: on the logger a host application installed, else on one of its
// own, removed again at the end. Assimp has one logger per process, so reads in one process take turns (an
// isolated read is alone in its child).
class CorruptGeometryLog {
 public:
  explicit CorruptGeometryLog(std::string& first) : turn_(mutex()) {
    own_ = Assimp::DefaultLogger::isNullLogger();
    if (own_) Assimp::DefaultLogger::create(nullptr, Assimp::Logger::NORMAL, 0);
    stream_ = new CorruptGeometry(first);
    Assimp::DefaultLogger::get()->attachStream(stream_, kSeverities);  // the logger owns it while attached
  }
  ~CorruptGeometryLog() {
    if (own_)
      Assimp::DefaultLogger::kill();  // deletes the stream
    else if (Assimp::DefaultLogger::get()->detachStream(stream_, kSeverities))
      delete stream_;  // detached: ours again
  }
  CorruptGeometryLog(const CorruptGeometryLog&) = delete;
  CorruptGeometryLog& operator=(const CorruptGeometryLog&) = delete;

 private:
  static constexpr unsigned kSeverities = Assimp::Logger::Warn | Assimp::Logger::Err;
  static std::mutex& mutex() {
    static std::mutex m;
    return m;
  }
  std::lock_guard<std::mutex> turn_;
  bool own_ = false;
  CorruptGeometry* stream_ = nullptr;
};

// The next line of an ASCII OFF file with something before its comment, without the comment; false at the end.
bool off_line(std::istream& in, std::string& line) {
  while (std::getline(in, line)) {
    line.resize(std::min(line.size(), line.find('#')));
    if (line.find_first_not_of(" \t\r") != std::string::npos) return true;
  }
  return false;
}

std::vector<std::string> words_of(const std::string& line) {
  std::istringstream split(line);
  std::vector<std::string> words;
  for (std::string word; split >> word;) words.push_back(word);
  return words;
}

// assimp's OFF reader takes a negative face index ("-1") for vertex 0 and reads on, with nothing in its log: the face
// joins the wrong vertex; CGAL's converts it to an unsigned integer, which is undefined. So an OFF file is looked
// through for a negative index before either reads it: the first one, if any. Vertex lines are only counted, and a
// face line is split only where it holds a '-'.
std::optional<std::string> off_negative_index(const std::string& path) {
  std::ifstream in(path);
  std::string line;
  if (!off_line(in, line)) return std::nullopt;
  std::vector<std::string> words = words_of(line);
  const std::string header = words[0];
  if (header.size() < 3 || header.compare(header.size() - 3, 3, "OFF") != 0) return std::nullopt;
  for (const std::string& word : words)
    if (word == "BINARY") return std::nullopt;  // binary OFF: its indices are read as integers, not text
  // After the keyword (and an nOFF's dimension) come the counts, on its line or the next.
  const size_t first_count = std::min(words.size(), size_t(1 + (header.find('n') != std::string::npos)));
  std::vector<std::string> counts(words.begin() + std::ptrdiff_t(first_count), words.end());
  if (counts.empty() && off_line(in, line)) counts = words_of(line);
  uint64_t vertices = 0, faces = 0;
  try {
    if (counts.size() < 2) return std::nullopt;
    vertices = std::stoull(counts[0]);
    faces = std::stoull(counts[1]);
  } catch (...) {
    return std::nullopt;  // assimp names what is wrong with the header
  }
  for (uint64_t v = 0; v < vertices; ++v)
    if (!off_line(in, line)) return std::nullopt;
  for (uint64_t f = 0; f < faces && off_line(in, line); ++f) {
    if (line.find('-') == std::string::npos) continue;
    words = words_of(line);
    for (size_t i = 1; i < words.size(); ++i)
      if (words[i][0] == '-' && i <= std::strtoull(words[0].c_str(), nullptr, 10))
        return "face " + std::to_string(f) + " names vertex " + words[i];
  }
  return std::nullopt;
}

// The parse itself: CGAL's readers, then assimp.
TriangleMesh import_in_process(const std::string& path, const ImportSettings& options) {
  TriangleMesh mesh;
  if (lowercase(std::filesystem::path(path).extension().string()) == ".off")
    if (const std::optional<std::string> negative = off_negative_index(path))
      throw BakeError(IssueCode::ImportFailed, path + ": cannot read mesh: " + *negative + " (a corrupt file)");
  if (read_triangles_in_double(path, options.unit_scale, mesh)) return mesh;

  std::string corrupt;
  const CorruptGeometryLog log(corrupt);
  Assimp::Importer importer;
  const std::string extension = std::filesystem::path(path).extension().string();
  if (extension.empty() || !importer.IsExtensionSupported(extension))
    throw BakeError(IssueCode::UnsupportedFormat,
                    path + ": file type '" + extension + "' is not a mesh format assimp reads (see `assimp listext`)");
  // Split polygons into triangles; points and lines are skipped by append_node, which also applies the node
  // transforms.
  const aiScene* scene = importer.ReadFile(path, aiProcess_Triangulate);
  if (!scene || !scene->mRootNode) {
    const std::string reason = importer.GetErrorString();
    // Some importers refuse a file with nothing in it instead of returning an empty scene.
    const std::string lower = lowercase(reason);
    const bool empty =
        lower.find("no valid faces") != std::string::npos || lower.find("no meshes") != std::string::npos;
    throw BakeError(empty ? IssueCode::EmptyScene : IssueCode::ImportFailed,
                    path + (empty ? ": the scene contains no triangles (" : ": cannot read mesh (") + reason + ")");
  }
  if (!corrupt.empty())
    throw BakeError(IssueCode::ImportFailed, path + ": cannot read mesh: " + corrupt + " (a corrupt file)");

  append_node(*scene, *scene->mRootNode, aiMatrix4x4(), mesh, options.unit_scale, path);
  if (mesh.triangles.empty()) throw BakeError(IssueCode::EmptyScene, path + ": the scene contains no triangles");
  return mesh;
}

#if !defined(_WIN32)
// What an isolated import sends back: the mesh, or the error it ended with.
struct ImportOutcome {
  bool failed = false;
  IssueCode code = IssueCode::Internal;
  std::string message;
  TriangleMesh mesh;
};

// What one isolated import may take, in proportion to its file.
struct ImportLimits {
  uint64_t input_bytes = 0;  // the file's, and for a .gltf its folder's (its buffers and textures lie there)
  double seconds = 0;        // ~1 s per 50 MB beyond 30 s, unless the caller sets it
  // A parser that believes a header announcing 2e9 vertices in a 300-byte file allocates until the time limit (~1 GB
  // a second). No mesh format holds a triangle in fewer than a few bytes, nor needs more than ~100 bytes of memory
  // for it, even compressed (3MF, FBX, zipped COLLADA).
  double bytes = 0;
};

ImportLimits import_limits(const std::string& path, const ImportSettings& options) {
  namespace fs = std::filesystem;
  std::error_code ec;
  ImportLimits limits;
  limits.input_bytes = fs::file_size(path, ec);
  if (ec) limits.input_bytes = 0;
  const fs::path folder = fs::path(path).has_parent_path() ? fs::path(path).parent_path() : fs::path(".");
  if (lowercase(fs::path(path).extension().string()) == ".gltf")
    for (auto it = fs::directory_iterator(folder, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
      std::error_code unreadable;
      const uintmax_t size = it->is_regular_file(unreadable) ? it->file_size(unreadable) : 0;
      if (!unreadable && it->path().filename() != fs::path(path).filename()) limits.input_bytes += size;
    }
  limits.seconds = options.time_limit_s > 0 ? options.time_limit_s : 30.0 + double(limits.input_bytes) / 5e6;
  limits.bytes = 1024.0 * 1024 * 1024 + 256.0 * double(limits.input_bytes);
  return limits;
}

// The error of an import that did not finish in its child.
[[noreturn]] void throw_failed_import(const detail::ChildOutcome& outcome, const std::string& path,
                                      const ImportLimits& limits) {
  switch (outcome.kind) {
    case detail::ChildOutcome::CannotStart:
      throw BakeError(IssueCode::Internal, path + ": cannot import the mesh in isolation: " + outcome.detail);
    case detail::ChildOutcome::Died:
      throw BakeError(IssueCode::ImportFailed, path + ": cannot read mesh: the importer died of signal " +
                                                   std::to_string(outcome.signal) + " (" + strsignal(outcome.signal) +
                                                   ") on it (a malformed file; read in isolation)");
    case detail::ChildOutcome::TimedOut:
      throw BakeError(IssueCode::ImportFailed, path + ": cannot read mesh: the importer did not finish within " +
                                                   std::to_string(int(limits.seconds)) +
                                                   " s (a malformed file; stopped)");
    case detail::ChildOutcome::OutOfMemory:
      if (outcome.over_limit)
        throw BakeError(IssueCode::ImportFailed,
                        path + ": cannot read mesh: the importer needed more than " +
                            std::to_string(int64_t(limits.bytes / 1048576)) + " MiB for " +
                            std::to_string(limits.input_bytes) +
                            " bytes of input (a header that declares more than the file holds?); stopped");
      throw BakeError(IssueCode::OutOfMemory, path + ": out of memory receiving the imported mesh");
    default:
      throw BakeError(IssueCode::ImportFailed,
                      path + ": cannot read mesh: the isolated import failed (out of memory, or malformed data)");
  }
}

// assimp's importers trust their input (Debian's build aborts in an assertion on an OFF file that announces more
// vertices than it holds; its history of CVEs is long), so, as for assets (voxfmt/detail/isolated_call.h), the
// parse runs in a child process: a crash, a hang or memory out of proportion there is IMPORT_FAILED, not the end
// of `voxfmt build`.
TriangleMesh import_isolated(const std::string& path, const ImportSettings& options) {
  const ImportLimits limits = import_limits(path, options);
  ImportOutcome result;
  // A parse of a local file never sleeps: a child asleep for kAsleepS without CPU holds a lock inherited from another
  // thread at the fork (clang's ASan allocator has no fork handler), which says nothing about the file: once more.
  constexpr double kAsleepS = 5.0;
  auto attempt = [&] {
    return detail::run_isolated(
        detail::Watchdog{limits.seconds, 0, nullptr, kAsleepS, limits.bytes}, result,
        [&] {
          ImportOutcome r;
          try {
            r.mesh = import_in_process(path, options);
          } catch (const BakeError& e) {
            r = {true, e.code(), e.what(), {}};
          } catch (const std::bad_alloc&) {
            r = {true, IssueCode::OutOfMemory, path + ": out of memory reading the mesh", {}};
          } catch (const std::exception& e) {
            r = {true, IssueCode::ImportFailed, path + ": cannot read mesh (" + e.what() + ")", {}};
          }
          return r;
        },
        [](auto& w, auto& r) {
          w.pod(r.failed);
          w.pod(r.code);
          w.text(r.message);
          w.array(r.mesh.vertices);
          w.array(r.mesh.triangles);
        });
  };
  detail::ChildOutcome outcome = attempt();
  if (outcome.kind == detail::ChildOutcome::TimedOut && outcome.asleep) outcome = attempt();
  if (outcome.kind != detail::ChildOutcome::Finished) throw_failed_import(outcome, path, limits);
  if (result.failed) throw BakeError(result.code, result.message);
  return std::move(result.mesh);
}
#endif

}  // namespace

TriangleMesh import_mesh(const std::string& path, const ImportSettings& options) {
  std::error_code ec;
  if (const std::string kind = not_a_regular_file(path); !kind.empty())
    throw BakeError(IssueCode::InputNotFound, path + ": " + kind);
  if (!std::filesystem::exists(path, ec)) throw BakeError(IssueCode::InputNotFound, path + ": no such file");
#if !defined(_WIN32)
  if (::access(path.c_str(), R_OK) != 0)  // the file's permissions, not its content: no importer's fault
    throw BakeError(IssueCode::InputNotFound, path + ": cannot read it: " + std::strerror(errno));
#endif
  if (!(options.unit_scale > 0) || !std::isfinite(options.unit_scale))
    throw BakeError(IssueCode::BadOption, "unit scale must be a finite number > 0");
  check_declared_counts(path);
#if !defined(_WIN32)
  if (read_isolation()) return import_isolated(path, options);
#endif
  return import_in_process(path, options);
}

}  // namespace voxfmt::bake
