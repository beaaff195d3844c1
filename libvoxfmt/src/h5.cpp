#include "h5.h"

#include <libdeflate.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>
#include <new>
#include <sstream>

#include <unistd.h>

#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/cores.h"

namespace voxfmt::h5 {

void silence_hdf5_errors() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }

namespace {
herr_t collect_innermost(unsigned n, const H5E_error2_t* err, void* client) {
  auto* out = static_cast<std::string*>(client);
  if (n == 0 && err->desc && *err->desc) *out = err->desc;  // walking upward: entry 0 is the innermost
  return 0;
}

std::string dims_to_string(const std::vector<uint64_t>& dims) {
  if (dims.empty()) return "scalar";
  std::ostringstream s;
  s << '[';
  for (size_t i = 0; i < dims.size(); ++i) s << (i ? ", " : "") << dims[i];
  s << ']';
  return s.str();
}

std::string shape_to_string(const Shape& shape) {
  if (shape.empty()) return "scalar";
  std::ostringstream s;
  s << '[';
  for (size_t i = 0; i < shape.size(); ++i) {
    s << (i ? ", " : "");
    if (shape[i] < 0)
      s << 'n';
    else
      s << shape[i];
  }
  s << ']';
  return s.str();
}

std::string describe_type(hid_t type) {
  H5T_class_t cls = H5Tget_class(type);
  size_t size = H5Tget_size(type);
  std::ostringstream s;
  switch (cls) {
    case H5T_INTEGER:
      s << (H5Tget_sign(type) == H5T_SGN_NONE ? "unsigned " : "signed ") << size * 8 << "-bit integer";
      break;
    case H5T_FLOAT:
      s << size * 8 << "-bit float";
      break;
    case H5T_STRING:
      s << "string";
      break;
    case H5T_COMPOUND:
      s << "compound";
      break;
    case H5T_ARRAY:
      s << "array type";
      break;
    case H5T_VLEN:
      s << "variable-length sequence";
      break;
    case H5T_ENUM:
      s << "enum";
      break;
    default:
      s << "HDF5 type class " << int(cls);
      break;
  }
  return s.str();
}
}  // namespace

namespace {
herr_t find_failed_allocation(unsigned, const H5E_error2_t* err, void* client) {
  if (err->maj_num == H5E_RESOURCE && (err->min_num == H5E_NOSPACE || err->min_num == H5E_CANTALLOC))
    *static_cast<bool*>(client) = true;
  return 0;
}
}  // namespace

Hdf5Failure last_hdf5_failure() {
  Hdf5Failure failure;
  H5Ewalk2(H5E_DEFAULT, H5E_WALK_UPWARD, find_failed_allocation, &failure.out_of_memory);
  failure.reason = last_hdf5_reason();
  return failure;
}

std::mutex& process_mutex() {
  static std::mutex mutex;
  return mutex;
}

std::string last_hdf5_reason() {
  std::string reason;
  H5Ewalk2(H5E_DEFAULT, H5E_WALK_UPWARD, collect_innermost, &reason);
  H5Eclear2(H5E_DEFAULT);
  return reason.empty() ? "unknown HDF5 error" : reason;
}

std::string join_path(const std::string& group_path, const std::string& name) {
  if (group_path.empty() || group_path == "/") return "/" + name;
  return group_path + "/" + name;
}

uint64_t Layout::elements() const {
  uint64_t n = 1;
  for (uint64_t d : shape) n = d != 0 && n > (uint64_t(1) << 62) / d ? uint64_t(1) << 63 : n * d;
  return n;
}

uint64_t Layout::chunk_count() const {
  if (chunk.empty()) return 0;
  uint64_t n = 1;
  for (size_t a = 0; a < shape.size() && a < chunk.size(); ++a) {
    const uint64_t along = chunk[a] == 0 ? 0 : (shape[a] + chunk[a] - 1) / chunk[a];
    n = along != 0 && n > (uint64_t(1) << 62) / along ? uint64_t(1) << 63 : n * along;
  }
  return n;
}

uint64_t Layout::chunk_bytes() const {
  uint64_t n = element_bytes;
  for (uint64_t c : chunk) n = c != 0 && n > (uint64_t(1) << 62) / c ? uint64_t(1) << 63 : n * c;
  return chunk.empty() ? 0 : n;
}

// ---------------------------------------------------------------- Reader

void Reader::report(IssueCode code, const std::string& path, const std::string& message) {
  issues_.push_back(Issue{code, severity_of(code), utf8_escaped(path), utf8_escaped(message)});
}

bool Reader::open() {
  silence_hdf5_errors();
  // Only a regular file: fopen opens a folder (whose read then fails deep in HDF5) and waits forever on a FIFO.
  if (const std::string kind = not_a_regular_file(file_); !kind.empty()) {
    report(IssueCode::FileNotFound, "/", "cannot open file: it " + kind);
    return false;
  }
  if (FILE* f = std::fopen(file_.c_str(), "rb")) {
    std::fclose(f);
  } else {
    report(IssueCode::FileNotFound, "/", std::string("cannot open file: ") + std::strerror(errno));
    return false;
  }
  htri_t is_hdf5 = H5Fis_hdf5(file_.c_str());
  if (is_hdf5 <= 0) {
    std::string reason = is_hdf5 < 0 ? last_hdf5_reason() : "no HDF5 signature found";
    report(IssueCode::NotHdf5, "/", "not an HDF5 file (" + reason + ")");
    return false;
  }
  hid_t id = H5Fopen(file_.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (id < 0) {
    report(IssueCode::NotHdf5, "/", "HDF5 cannot open the file (" + last_hdf5_reason() + ")");
    return false;
  }
  file_handle_ = Handle(id, H5Fclose);
  return true;
}

bool Reader::stays_in_file() {
  // An asset is one file (spec §1): a link that leaves it (external, or user-defined) would open and read whatever
  // file it names, reached directly or through a soft link. Every link of the file is looked at once, before any
  // object is opened (an asset has a few dozen; past kMaxLinks the file is no asset).
  struct LinkVisit {
    std::string leaving;
    size_t count = 0;
  } visit;
  constexpr size_t kMaxLinks = 100000;
  const herr_t visited = H5Lvisit(
      file(), H5_INDEX_NAME, H5_ITER_NATIVE,
      [](hid_t, const char* name, const H5L_info_t* info, void* data) -> herr_t {
        auto& v = *static_cast<LinkVisit*>(data);
        if (info->type != H5L_TYPE_HARD && info->type != H5L_TYPE_SOFT) {
          v.leaving = name;
          return 1;
        }
        return ++v.count > kMaxLinks ? 1 : 0;
      },
      &visit);
  if (visited < 0) {  // a damaged object header or group: nothing in it can be trusted
    report(IssueCode::ReadFailed, "/", "cannot walk the file's links (" + last_hdf5_reason() + ")");
    return false;
  }
  if (!visit.leaving.empty()) {
    report(IssueCode::ReadFailed, "/" + visit.leaving, "is a link to another file; an asset holds its objects itself");
    return false;
  }
  if (visit.count > kMaxLinks) {
    report(IssueCode::ValueOutOfRange, "/", "holds more than " + std::to_string(kMaxLinks) + " links: not an asset");
    return false;
  }
  return true;
}

bool Reader::has_member(hid_t parent, const std::string& name) {
  htri_t exists = H5Lexists(parent, name.c_str(), H5P_DEFAULT);
  if (exists < 0) H5Eclear2(H5E_DEFAULT);
  return exists > 0;
}

bool Reader::has_attribute(hid_t object, const std::string& name) {
  htri_t exists = H5Aexists(object, name.c_str());
  if (exists < 0) H5Eclear2(H5E_DEFAULT);
  return exists > 0;
}

std::optional<Handle> Reader::open_member(hid_t parent, const std::string& parent_path, const std::string& name,
                                          bool want_group) {
  const std::string path = join_path(parent_path, name);
  const char* kind = want_group ? "group" : "dataset";
  if (!has_member(parent, name)) {
    report(IssueCode::MissingObject, path, std::string("required ") + kind + " is missing");
    return std::nullopt;
  }
  hid_t obj = H5Oopen(parent, name.c_str(), H5P_DEFAULT);
  if (obj < 0) {
    report(IssueCode::ReadFailed, path, "cannot open object (" + last_hdf5_reason() + ")");
    return std::nullopt;
  }
  if (H5Iget_type(obj) != (want_group ? H5I_GROUP : H5I_DATASET)) {
    H5Oclose(obj);
    report(IssueCode::WrongKind, path, std::string("expected a ") + kind + ", found another kind of object");
    return std::nullopt;
  }
  return Handle(obj, H5Oclose);
}

std::optional<Handle> Reader::group(hid_t parent, const std::string& parent_path, const std::string& name) {
  return open_member(parent, parent_path, name, true);
}

std::optional<Handle> Reader::open_attribute(hid_t object, const std::string& object_path, const std::string& name,
                                             std::string& path) {
  path = object_path + (object_path == "/" ? "" : "/") + "@" + name;
  if (!has_attribute(object, name)) {
    report(IssueCode::MissingObject, path, "required attribute is missing");
    return std::nullopt;
  }
  Handle attr(H5Aopen(object, name.c_str(), H5P_DEFAULT), H5Aclose);
  if (!attr.valid()) {
    report(IssueCode::ReadFailed, path, "cannot open attribute (" + last_hdf5_reason() + ")");
    return std::nullopt;
  }
  return attr;
}

bool Reader::check_type(hid_t type, H5T_class_t cls, size_t size, bool is_signed, const char* name,
                        const std::string& path) {
  bool ok = H5Tget_class(type) == cls && H5Tget_size(type) == size;
  if (ok && cls == H5T_INTEGER) ok = (H5Tget_sign(type) != H5T_SGN_NONE) == is_signed;
  if (!ok) {
    report(IssueCode::WrongDtype, path,
           std::string("dtype is ") + describe_type(type) + ", expected " + name + " (little-endian)");
  }
  return ok;
}

bool Reader::check_shape(hid_t space, const Shape& expected, const std::string& path, std::vector<uint64_t>& actual) {
  H5S_class_t space_class = H5Sget_simple_extent_type(space);
  actual.clear();
  if (space_class == H5S_SIMPLE) {
    int rank = H5Sget_simple_extent_ndims(space);
    std::vector<hsize_t> dims(rank > 0 ? rank : 0);
    if (rank > 0) H5Sget_simple_extent_dims(space, dims.data(), nullptr);
    actual.assign(dims.begin(), dims.end());
  } else if (space_class != H5S_SCALAR) {
    report(IssueCode::WrongShape, path, "has an empty (null) dataspace, expected " + shape_to_string(expected));
    return false;
  }
  bool ok = actual.size() == expected.size();
  for (size_t i = 0; ok && i < expected.size(); ++i) ok = expected[i] < 0 || uint64_t(expected[i]) == actual[i];
  if (!ok)
    report(IssueCode::WrongShape, path,
           "shape is " + dims_to_string(actual) + ", expected " + shape_to_string(expected));
  return ok;
}

std::optional<std::string> Reader::string_attribute(hid_t object, const std::string& object_path,
                                                    const std::string& name) {
  std::string path;
  std::optional<Handle> opened = open_attribute(object, object_path, name, path);
  if (!opened) return std::nullopt;
  const Handle& attr = *opened;
  Handle type(H5Aget_type(attr.get()), H5Tclose);
  if (H5Tget_class(type.get()) != H5T_STRING) {
    report(IssueCode::WrongDtype, path, "dtype is " + describe_type(type.get()) + ", expected a string");
    return std::nullopt;
  }
  Handle space(H5Aget_space(attr.get()), H5Sclose);
  std::vector<uint64_t> actual;
  if (!check_shape(space.get(), {}, path, actual)) return std::nullopt;

  if (H5Tis_variable_str(type.get()) > 0) {
    // Files written before 2026-11 hold variable-length strings, whose bytes live in HDF5's global heap (whose
    // reader trusts the file: isolated_read.cpp).
    Handle memtype(H5Tcopy(H5T_C_S1), H5Tclose);
    H5Tset_size(memtype.get(), H5T_VARIABLE);
    H5Tset_cset(memtype.get(), H5Tget_cset(type.get()));
    char* buffer = nullptr;
    if (H5Aread(attr.get(), memtype.get(), &buffer) < 0) {
      report(IssueCode::ReadFailed, path, "cannot read attribute (" + last_hdf5_reason() + ")");
      return std::nullopt;
    }
    std::string value = buffer ? buffer : "";
    if (buffer) H5free_memory(buffer);
    return checked_text(std::move(value), path);
  }
  size_t size = H5Tget_size(type.get());
  if (size == 0 || size > kMaxStringBytes + 1) {
    report(IssueCode::ValueOutOfRange, path,
           "fixed-length string of " + std::to_string(size) + " bytes, outside the format's limit of 1.." +
               std::to_string(kMaxStringBytes + 1) + " (with its terminating null)");
    return std::nullopt;
  }
  Handle memtype(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(memtype.get(), size);
  H5Tset_strpad(memtype.get(), H5T_STR_NULLPAD);
  H5Tset_cset(memtype.get(), H5Tget_cset(type.get()));  // HDF5 has no ASCII<->UTF-8 conversion
  std::string buffer(size, '\0');
  if (H5Aread(attr.get(), memtype.get(), buffer.data()) < 0) {
    report(IssueCode::ReadFailed, path, "cannot read attribute (" + last_hdf5_reason() + ")");
    return std::nullopt;
  }
  buffer.resize(std::strlen(buffer.c_str()));
  if (H5Tget_strpad(type.get()) == H5T_STR_SPACEPAD)
    while (!buffer.empty() && buffer.back() == ' ') buffer.pop_back();
  return checked_text(std::move(buffer), path);
}

std::optional<std::string> Reader::checked_text(std::string bytes, const std::string& path) {
  // Within the limit whatever the storage (a null-padded fixed string may fill its type with no null: 60,001
  // bytes of text in a type of 60,001).
  if (bytes.size() > kMaxStringBytes) {
    report(IssueCode::ValueOutOfRange, path,
           "string of " + std::to_string(bytes.size()) + " bytes, more than the format's limit of " +
               std::to_string(kMaxStringBytes));
    return std::nullopt;
  }
  // Bytes from the file become text only once they are known to be UTF-8 (spec §1): every consumer, Python's
  // str among them, can then take them as they are.
  if (is_utf8(bytes)) return bytes;
  report(IssueCode::StringNotUtf8, path, not_utf8_message(bytes));
  return std::nullopt;
}

template <class T>
std::optional<std::vector<T>> Reader::numeric_attribute(hid_t object, const std::string& object_path,
                                                        const std::string& name, const Shape& shape) {
  std::string path;
  std::optional<Handle> opened = open_attribute(object, object_path, name, path);
  if (!opened) return std::nullopt;
  const Handle& attr = *opened;
  Handle type(H5Aget_type(attr.get()), H5Tclose);
  using Traits = TypeTraits<T>;
  if (!check_type(type.get(), Traits::kClass, sizeof(T), Traits::kSigned, Traits::kName, path)) return std::nullopt;
  Handle space(H5Aget_space(attr.get()), H5Sclose);
  std::vector<uint64_t> actual;
  if (!check_shape(space.get(), shape, path, actual)) return std::nullopt;
  size_t count = 1;
  for (uint64_t d : actual) count *= d;
  std::vector<T> values(count);
  if (H5Aread(attr.get(), Traits::memory_type(), values.data()) < 0) {
    report(IssueCode::ReadFailed, path, "cannot read attribute (" + last_hdf5_reason() + ")");
    return std::nullopt;
  }
  return values;
}

bool Reader::check_storage(hid_t dset, const std::vector<uint64_t>& dims, const std::string& path) {
  // Before any data is decoded (spec §1): only the filters the spec names run (HDF5's decoders are where damaged
  // files do harm), and a chunk grid is small enough that walking it cannot take hours.
  Handle plist(H5Dget_create_plist(dset), H5Pclose);
  if (!plist.valid()) {
    report(IssueCode::ReadFailed, path, "cannot read the dataset's storage properties (" + last_hdf5_reason() + ")");
    return false;
  }
  if (H5Pget_external_count(plist.get()) != 0 || H5Pget_layout(plist.get()) == H5D_VIRTUAL) {
    report(IssueCode::ReadFailed, path, "keeps its data in other files; an asset holds its data itself");
    return false;
  }
  const int filters = H5Pget_nfilters(plist.get());
  for (int i = 0; i < filters; ++i) {
    unsigned flags = 0;
    size_t values = 0;
    char name[64] = {0};
    const H5Z_filter_t id =
        H5Pget_filter2(plist.get(), unsigned(i), &flags, &values, nullptr, sizeof name, name, nullptr);
    if (id != H5Z_FILTER_DEFLATE && id != H5Z_FILTER_SHUFFLE && id != H5Z_FILTER_FLETCHER32) {
      report(IssueCode::ReadFailed, path,
             "uses HDF5 filter " + std::to_string(int(id)) + (name[0] ? std::string(" (") + name + ")" : "") +
                 "; the format allows only deflate, shuffle and fletcher32");
      return false;
    }
  }
  if (H5Pget_layout(plist.get()) == H5D_CHUNKED && !dims.empty()) {
    std::vector<hsize_t> chunk(dims.size());
    if (H5Pget_chunk(plist.get(), int(chunk.size()), chunk.data()) != int(dims.size()) ||
        std::find(chunk.begin(), chunk.end(), hsize_t(0)) != chunk.end()) {
      report(IssueCode::ReadFailed, path, "chunk shape does not match the dataset's rank, or has a zero extent");
      return false;
    }
  }
  return true;
}

std::optional<Layout> Reader::layout(hid_t group, const std::string& name) {
  if (!has_member(group, name)) return std::nullopt;
  Handle dset(H5Dopen2(group, name.c_str(), H5P_DEFAULT), H5Dclose);
  if (!dset.valid()) {
    H5Eclear2(H5E_DEFAULT);
    return std::nullopt;
  }
  Handle type(H5Dget_type(dset.get()), H5Tclose);
  Handle space(H5Dget_space(dset.get()), H5Sclose);
  Handle plist(H5Dget_create_plist(dset.get()), H5Pclose);
  if (!type.valid() || !space.valid() || !plist.valid()) {
    H5Eclear2(H5E_DEFAULT);
    return std::nullopt;
  }
  Layout layout;
  layout.element_bytes = H5Tget_size(type.get());
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank < 0 || rank > 32) return std::nullopt;
  std::vector<hsize_t> dims(static_cast<size_t>(rank)), chunk(static_cast<size_t>(rank));
  if (rank > 0) H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
  layout.shape.assign(dims.begin(), dims.end());
  if (H5Pget_layout(plist.get()) == H5D_CHUNKED && rank > 0) {
    if (H5Pget_chunk(plist.get(), rank, chunk.data()) != rank) return std::nullopt;
    layout.chunk.assign(chunk.begin(), chunk.end());
  }
  return layout;
}

template <class T>
std::optional<OpenDataset> Reader::open_dataset(hid_t group, const std::string& group_path, const std::string& name,
                                                const Shape& shape, uint64_t chunk_cache_bytes) {
  OpenDataset result;
  result.path = join_path(group_path, name);
  const std::string& path = result.path;
  if (!open_member(group, group_path, name, false)) return std::nullopt;  // reports what is missing or wrong
  Handle access(H5Pcreate(H5P_DATASET_ACCESS), H5Pclose);
  if (chunk_cache_bytes > 0)  // slots: a prime well above the chunks it holds (HDF5's advice)
    H5Pset_chunk_cache(access.get(), 100003, size_t(chunk_cache_bytes), 1.0);
  result.handle = Handle(H5Dopen2(group, name.c_str(), access.get()), H5Dclose);
  if (!result.handle.valid()) {
    report(IssueCode::ReadFailed, path, "cannot open dataset (" + last_hdf5_reason() + ")");
    return std::nullopt;
  }
  Handle type(H5Dget_type(result.handle.get()), H5Tclose);
  using Traits = TypeTraits<T>;
  if (!check_type(type.get(), Traits::kClass, sizeof(T), Traits::kSigned, Traits::kName, path)) return std::nullopt;
  Handle space(H5Dget_space(result.handle.get()), H5Sclose);
  if (!check_shape(space.get(), shape, path, result.shape)) return std::nullopt;
  uint64_t count = 1;
  for (uint64_t d : result.shape) {
    count *= d;
    if (count > kMaxElements) break;
  }
  if (count > kMaxElements) {
    report(IssueCode::ValueOutOfRange, path, "dataset has more than 2^31 elements (the format's limit)");
    return std::nullopt;
  }
  if (!check_storage(result.handle.get(), result.shape, path)) return std::nullopt;
  if (std::optional<Layout> l = layout(group, name)) result.chunk = l->chunk;
  return result;
}

namespace {
// The pieces one read is cut into: boxes aligned to the chunk grid (to rows where there are no chunks), each at
// most kElementsPerPiece elements (or one chunk, if larger) and kChunksPerPiece chunks. The last dimensions are
// taken whole while the piece stays within both limits, the next one partly, the ones before one chunk deep.
std::vector<uint64_t> piece_shape(const std::vector<uint64_t>& extent, const std::vector<uint64_t>& chunk) {
  const size_t rank = extent.size();
  const bool chunked = chunk.size() == rank;
  const std::vector<uint64_t> unit = chunked ? chunk : std::vector<uint64_t>(rank, 1);
  std::vector<uint64_t> piece(unit);
  // outer[a]: elements of one unit along every axis before a.
  std::vector<uint64_t> outer(rank + 1, 1);
  for (size_t a = 0; a < rank; ++a) outer[a + 1] = outer[a] * unit[a];
  const uint64_t max_elements = std::max(kElementsPerPiece, outer[rank]);
  const uint64_t max_chunks = chunked ? kChunksPerPiece : UINT64_MAX;
  uint64_t inner = 1, chunks = 1;  // elements and chunks of the piece along the axes after a
  for (size_t a = rank; a-- > 0;) {
    const uint64_t along = (extent[a] + unit[a] - 1) / unit[a];
    const uint64_t fit =
        std::max<uint64_t>(1, std::min(max_elements / (inner * unit[a] * outer[a]), max_chunks / chunks));
    if (fit < along) {  // this axis is cut; the ones before it take one unit each
      piece[a] = fit * unit[a];
      break;
    }
    piece[a] = extent[a];
    inner *= extent[a];
    chunks *= along;
  }
  return piece;
}
}  // namespace

template <class T>
bool Reader::read_rows(const OpenDataset& d, uint64_t first, uint64_t count, T* out) {
  if (count == 0) return true;
  if (d.shape.empty()) {  // scalar
    if (H5Dread(d.handle.get(), TypeTraits<T>::memory_type(), H5S_ALL, H5S_ALL, H5P_DEFAULT, out) < 0) {
      report(IssueCode::ReadFailed, d.path, "cannot read dataset (" + last_hdf5_reason() + ")");
      return false;
    }
    return true;
  }
  const size_t rank = d.shape.size();
  std::vector<uint64_t> extent(d.shape);
  extent[0] = count;  // the rows asked for; the box grid starts at `first`, aligned to the chunk grid
  std::vector<uint64_t> piece = piece_shape(d.shape, d.chunk);
  Handle file_space(H5Dget_space(d.handle.get()), H5Sclose);
  std::vector<hsize_t> memory_extent(extent.begin(), extent.end());
  Handle memory_space(H5Screate_simple(int(rank), memory_extent.data(), nullptr), H5Sclose);
  // Box corners: along the rows from the chunk boundary at or below `first`, elsewhere from 0.
  std::vector<uint64_t> corner(rank, 0);
  const uint64_t row_unit = d.chunk.size() == rank ? d.chunk[0] : 1;
  const uint64_t row_origin = first / row_unit * row_unit;
  corner[0] = row_origin;
  std::vector<hsize_t> file_start(rank), memory_start(rank), size(rank);
  while (true) {
    bool empty = false;
    for (size_t a = 0; a < rank; ++a) {
      const uint64_t lo = a == 0 ? std::max(corner[0], first) : corner[a];
      const uint64_t end =
          a == 0 ? std::min(corner[0] + piece[0], first + count) : std::min(corner[a] + piece[a], d.shape[a]);
      empty |= end <= lo;
      file_start[a] = lo;
      memory_start[a] = a == 0 ? lo - first : lo;
      size[a] = end > lo ? end - lo : 0;
    }
    if (!empty) {
      if (H5Sselect_hyperslab(file_space.get(), H5S_SELECT_SET, file_start.data(), nullptr, size.data(), nullptr) < 0 ||
          H5Sselect_hyperslab(memory_space.get(), H5S_SELECT_SET, memory_start.data(), nullptr, size.data(), nullptr) <
              0 ||
          H5Dread(d.handle.get(), TypeTraits<T>::memory_type(), memory_space.get(), file_space.get(), H5P_DEFAULT,
                  out) < 0) {
        report(IssueCode::ReadFailed, d.path, "cannot read dataset (" + last_hdf5_reason() + ")");
        return false;
      }
      progress();
    }
    // The next box: the last axis fastest.
    size_t a = rank;
    while (a-- > 0) {
      corner[a] += piece[a];
      const uint64_t end = a == 0 ? first + count : d.shape[a];
      if (corner[a] < end) break;
      corner[a] = a == 0 ? row_origin : 0;
    }
    if (a == size_t(-1)) break;
  }
  return true;
}

namespace {
bool host_is_little_endian() {
  const uint16_t probe = 1;
  unsigned char first = 0;
  std::memcpy(&first, &probe, 1);
  return first == 1;
}

// Compressed bytes read from the file before they are inflated together: a bound on the memory a read adds.
constexpr uint64_t kRawBytesPerBatch = uint64_t(16) << 20;

// A chunked dataset as three axes (the first ones of extent 1 where the rank is lower; the last is the fastest),
// with the value of chunks never written. The reader and the writer walk chunks, rows and byte planes through it.
template <class T>
struct ChunkGrid {
  size_t rank = 0;
  uint64_t dims[3] = {1, 1, 1}, chunk[3] = {1, 1, 1}, grid[3] = {1, 1, 1};
  uint64_t count = 1, elements = 1;  // chunks; elements a chunk
  T fill{};

  // False where the shape is beyond the spec's limits; checked axis by axis, so that no product overflows
  // whatever a file declares.
  template <class Extent>
  bool set_shape(size_t dataset_rank, const Extent* dataset_dims, const Extent* chunk_dims) {
    if (dataset_rank == 0 || dataset_rank > 3) return false;
    rank = dataset_rank;
    for (size_t a = 0; a < rank; ++a) {
      dims[3 - rank + a] = dataset_dims[a];
      chunk[3 - rank + a] = chunk_dims[a];
    }
    for (int a = 0; a < 3; ++a) {
      if (chunk[a] == 0 || chunk[a] > kMaxChunkBytes || dims[a] > kMaxElements) return false;
      grid[a] = (dims[a] + chunk[a] - 1) / chunk[a];
      count *= grid[a];
      elements *= chunk[a];
      if (bytes() > kMaxChunkBytes || count > kMaxChunksPerFile) return false;
    }
    return true;
  }
  uint64_t bytes() const { return elements * sizeof(T); }
  void corner(uint64_t c, uint64_t (&at)[3]) const {
    at[0] = c / (grid[1] * grid[2]) * chunk[0];
    at[1] = c / grid[2] % grid[1] * chunk[1];
    at[2] = c % grid[2] * chunk[2];
  }
  // The chunk's corner as HDF5 names it: `rank` coordinates.
  void offset(uint64_t c, hsize_t (&out)[3]) const {
    uint64_t at[3];
    corner(c, at);
    for (size_t a = 0; a < rank; ++a) out[a] = at[3 - rank + a];
  }
  // Calls row(first element in the dataset, first element in the chunk, length) for every row of chunk c that
  // lies in the dataset: edge chunks are stored full-size, the part past the dataset is padding.
  template <class Row>
  void for_each_row(uint64_t c, Row&& row) const {
    uint64_t at[3];
    corner(c, at);
    const uint64_t n = std::min(chunk[2], dims[2] - at[2]);
    for (uint64_t a = 0; a < chunk[0] && at[0] + a < dims[0]; ++a)
      for (uint64_t b = 0; b < chunk[1] && at[1] + b < dims[1]; ++b)
        row(((at[0] + a) * dims[1] + at[1] + b) * dims[2] + at[2], (a * chunk[1] + b) * chunk[2], n);
  }
  // HDF5's shuffle filter: byte k of every element into plane k. Plane by plane, so the writes stay sequential.
  void shuffle(const T* block, unsigned char* planes) const {
    const unsigned char* bytes = reinterpret_cast<const unsigned char*>(block);
    for (size_t k = 0; k < sizeof(T); ++k)
      for (uint64_t e = 0; e < elements; ++e) planes[k * elements + e] = bytes[e * sizeof(T) + k];
  }
  void unshuffle(const unsigned char* planes, unsigned char* block) const {
    for (size_t k = 0; k < sizeof(T); ++k)
      for (uint64_t e = 0; e < elements; ++e) block[e * sizeof(T) + k] = planes[k * elements + e];
  }
};

// The chunk grid of a dataset stored as voxfmt writes it (shuffle then deflate, the native type, a defined fill
// value), else nothing.
template <class T>
std::optional<ChunkGrid<T>> shuffled_deflate_grid(const OpenDataset& d) {
  ChunkGrid<T> g;
  if (!host_is_little_endian() || d.chunk.size() != d.shape.size() ||
      !g.set_shape(d.shape.size(), d.shape.data(), d.chunk.data()))
    return std::nullopt;
  Handle plist(H5Dget_create_plist(d.handle.get()), H5Pclose);
  Handle type(H5Dget_type(d.handle.get()), H5Tclose);
  H5D_fill_value_t fill_status;
  H5D_fill_time_t fill_time;
  if (!plist.valid() || !type.valid() || H5Pget_nfilters(plist.get()) != 2 ||
      H5Tequal(type.get(), TypeTraits<T>::memory_type()) <= 0 ||
      H5Pget_filter2(plist.get(), 0, nullptr, nullptr, nullptr, 0, nullptr, nullptr) != H5Z_FILTER_SHUFFLE ||
      H5Pget_filter2(plist.get(), 1, nullptr, nullptr, nullptr, 0, nullptr, nullptr) != H5Z_FILTER_DEFLATE ||
      H5Pfill_value_defined(plist.get(), &fill_status) < 0 || fill_status == H5D_FILL_VALUE_UNDEFINED ||
      H5Pget_fill_time(plist.get(), &fill_time) < 0 || fill_time == H5D_FILL_TIME_NEVER ||
      H5Pget_fill_value(plist.get(), TypeTraits<T>::memory_type(), &g.fill) < 0) {
    H5Eclear2(H5E_DEFAULT);
    return std::nullopt;
  }
  return g;
}

// Reads the raw (still filtered) chunks [first, end) into `raw`; an empty one was never written.
template <class T>
bool read_raw_batch(hid_t dset, const ChunkGrid<T>& g, uint64_t first, uint64_t end,
                    std::vector<std::vector<unsigned char>>& raw) {
  // A deflate stream of n bytes is at most n plus 5 bytes a stored block of 64 KiB, plus the zlib wrapper.
  const uint64_t largest_stream = g.bytes() + 5 * (g.bytes() / 65535 + 1) + 16;
  raw.assign(size_t(end - first), {});
  for (uint64_t c = first; c < end; ++c) {
    hsize_t offset[3];
    g.offset(c, offset);
    unsigned mask = 0;
    uint32_t filters = 0;
    haddr_t address = HADDR_UNDEF;
    hsize_t size = 0;
    if (H5Dget_chunk_info_by_coord(dset, offset, &mask, &address, &size) < 0) return false;
    if (address == HADDR_UNDEF) continue;  // never written: the fill value
    if (mask != 0 || size == 0 || size > largest_stream) return false;
    std::vector<unsigned char>& bytes = raw[size_t(c - first)];
    bytes.resize(size_t(size));
    if (H5Dread_chunk(dset, H5P_DEFAULT, offset, &filters, bytes.data()) < 0 || filters != 0) return false;
  }
  return true;
}

// Runs `body(chunk, scratch)` for chunks [first, end) on up to 8 cores, each worker with its own scratch from
// `make_scratch()` (buffers, a (de)compressor); stops early once a call returns false or anything throws. True if
// every chunk's call returned true.
template <class MakeScratch, class Body>
bool for_each_chunk_in_parallel(uint64_t first, uint64_t end, MakeScratch&& make_scratch, Body&& body) {
  std::atomic<uint64_t> next{first};
  std::atomic<bool> failed{false};
  run_workers(std::min(8u, usable_cores()), [&](unsigned) {
    try {
      auto scratch = make_scratch();
      for (uint64_t c = next++; c < end && !failed; c = next++)
        if (!body(c, scratch)) failed = true;
    } catch (...) {  // bad_alloc: a worker thread must not let it escape
      failed = true;
    }
  });
  return !failed;
}

// Inflates, unshuffles and places chunks [first, end) into `out`, on every core; false if a stream does not
// inflate to exactly a chunk.
template <class T>
bool inflate_batch(const ChunkGrid<T>& g, const std::vector<std::vector<unsigned char>>& raw, uint64_t first,
                   uint64_t end, T* out) {
  struct Scratch {
    std::unique_ptr<libdeflate_decompressor, void (*)(libdeflate_decompressor*)> inflater;
    std::vector<unsigned char> shuffled, block;
  };
  auto make_scratch = [&] {
    Scratch s{{libdeflate_alloc_decompressor(), libdeflate_free_decompressor}, {}, {}};
    if (!s.inflater) throw std::bad_alloc();
    s.shuffled.resize(size_t(g.bytes()));
    s.block.resize(size_t(g.bytes()));
    return s;
  };
  return for_each_chunk_in_parallel(first, end, make_scratch, [&](uint64_t c, Scratch& s) {
    const std::vector<unsigned char>& stream = raw[size_t(c - first)];
    if (!stream.empty()) {
      if (libdeflate_zlib_decompress(s.inflater.get(), stream.data(), stream.size(), s.shuffled.data(),
                                     size_t(g.bytes()), nullptr) != LIBDEFLATE_SUCCESS)
        return false;
      g.unshuffle(s.shuffled.data(), s.block.data());
    }
    g.for_each_row(c, [&](uint64_t at, uint64_t from, uint64_t n) {
      if (stream.empty())
        std::fill(out + at, out + at + n, g.fill);
      else
        std::memcpy(out + at, s.block.data() + from * sizeof(T), size_t(n) * sizeof(T));
    });
    return true;
  });
}
}  // namespace

// HDF5 runs a dataset's filters on the calling thread, chunk after chunk, with zlib. A dataset stored as voxfmt
// writes it is read here by its raw chunks (HDF5 still finds and reads them) and inflated by libdeflate on all
// cores. Any other storage, and any chunk not as expected (a skipped filter, a size no deflate stream of it could
// have, a stream that does not inflate to exactly the chunk), returns false: the caller then reads through HDF5,
// which judges the file as it always has.
template <class T>
bool Reader::read_raw_chunks(const OpenDataset& d, T* out) {
  const std::optional<ChunkGrid<T>> g = shuffled_deflate_grid<T>(d);
  if (!g) return false;
  // Batches of as many chunks as one piece of read_rows may cover (the work between two progress reports), and
  // at most kRawBytesPerBatch of raw chunks read ahead.
  const uint64_t most = std::max<uint64_t>(1, std::min(kChunksPerPiece, kElementsPerPiece / g->elements));
  const uint64_t per_batch = std::max<uint64_t>(1, std::min(most, kRawBytesPerBatch / g->bytes()));
  std::vector<std::vector<unsigned char>> raw;
  for (uint64_t first = 0; first < g->count; first += per_batch) {
    const uint64_t end = std::min(g->count, first + per_batch);
    if (!read_raw_batch(d.handle.get(), *g, first, end, raw)) {
      H5Eclear2(H5E_DEFAULT);
      return false;
    }
    if (!inflate_batch(*g, raw, first, end, out)) return false;
    progress();
  }
  return true;
}

template <class T>
std::optional<std::vector<T>> Reader::dataset(hid_t group, const std::string& group_path, const std::string& name,
                                              const Shape& shape, std::vector<uint64_t>* shape_out) {
  std::optional<OpenDataset> d = open_dataset<T>(group, group_path, name, shape);
  if (!d) return std::nullopt;
  std::vector<T> values;
  try {
    values.resize(size_t(d->elements()));
  } catch (const std::bad_alloc&) {
    report(IssueCode::OutOfMemory, d->path, "not enough memory for " + std::to_string(d->elements()) + " elements");
    return std::nullopt;
  }
  if (!read_raw_chunks<T>(*d, values.data()) && !read_rows<T>(*d, 0, d->shape.empty() ? 1 : d->shape[0], values.data()))
    return std::nullopt;
  if (shape_out) *shape_out = d->shape;
  return values;
}

namespace {
herr_t collect_link_name(hid_t, const char* name, const H5L_info_t*, void* out) {
  static_cast<std::vector<std::string>*>(out)->emplace_back(name);
  return 0;
}
herr_t collect_attr_name(hid_t, const char* name, const H5A_info_t*, void* out) {
  static_cast<std::vector<std::string>*>(out)->emplace_back(name);
  return 0;
}
}  // namespace

std::vector<std::string> Reader::member_names(hid_t group) {
  std::vector<std::string> names;
  if (H5Literate(group, H5_INDEX_NAME, H5_ITER_INC, nullptr, collect_link_name, &names) < 0) H5Eclear2(H5E_DEFAULT);
  return names;
}

std::vector<std::string> Reader::attribute_names(hid_t object) {
  std::vector<std::string> names;
  if (H5Aiterate2(object, H5_INDEX_NAME, H5_ITER_INC, nullptr, collect_attr_name, &names) < 0) H5Eclear2(H5E_DEFAULT);
  return names;
}

// ---------------------------------------------------------------- Writer

bool Writer::fail(const std::string& what) {
  const Hdf5Failure failure = last_hdf5_failure();
  out_of_memory_ = failure.out_of_memory;
  failure_ = what + " (" + failure.reason + ")";
  return false;
}

std::optional<Handle> Writer::create_group(hid_t parent, const std::string& name) {
  hid_t id = H5Gcreate2(parent, name.c_str(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  if (id < 0) {
    fail("cannot create group " + name);
    return std::nullopt;
  }
  return Handle(id, H5Gclose);
}

bool Writer::string_attribute(hid_t object, const std::string& name, const std::string& value) {
  // Fixed-length (spec §1): stored inside the attribute itself, so a reader never needs HDF5's global heap.
  if (value.size() > kMaxStringBytes) {
    failure_ = "attribute " + name + " holds " + std::to_string(value.size()) + " bytes, more than the format's " +
               std::to_string(kMaxStringBytes);
    return false;
  }
  Handle type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type.get(), value.size() + 1);
  H5Tset_strpad(type.get(), H5T_STR_NULLTERM);
  H5Tset_cset(type.get(), H5T_CSET_UTF8);
  Handle space(H5Screate(H5S_SCALAR), H5Sclose);
  Handle attr(H5Acreate2(object, name.c_str(), type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
  if (!attr.valid()) return fail("cannot create attribute " + name);
  if (H5Awrite(attr.get(), type.get(), value.c_str()) < 0) return fail("cannot write attribute " + name);
  return true;
}

template <class T>
bool Writer::numeric_attribute(hid_t object, const std::string& name, const std::vector<uint64_t>& shape,
                               const T* data) {
  std::vector<hsize_t> dims(shape.begin(), shape.end());
  Handle space(shape.empty() ? H5Screate(H5S_SCALAR) : H5Screate_simple(int(dims.size()), dims.data(), nullptr),
               H5Sclose);
  Handle attr(H5Acreate2(object, name.c_str(), TypeTraits<T>::file_type(), space.get(), H5P_DEFAULT, H5P_DEFAULT),
              H5Aclose);
  if (!attr.valid()) return fail("cannot create attribute " + name);
  if (H5Awrite(attr.get(), TypeTraits<T>::memory_type(), data) < 0) return fail("cannot write attribute " + name);
  return true;
}

namespace {

// Compresses every chunk of a dataset into what HDF5's shuffle + deflate pipeline reads, on all cores, and writes
// the results with H5Dwrite_chunk (HDF5 itself filters chunks on one thread). libdeflate writes the zlib streams:
// the same format as zlib's, about twice as fast at the same level. Chunks whose every value is bitwise `*fill` are
// skipped.
template <class T>
bool write_chunks_in_parallel(hid_t dset, const ChunkGrid<T>& g, const T* data, int level, const T* fill,
                              WriteTicker* ticker) {
  std::vector<std::vector<unsigned char>> compressed(size_t(g.count));
  struct Scratch {
    std::unique_ptr<libdeflate_compressor, void (*)(libdeflate_compressor*)> compressor;
    std::vector<T> block;
    std::vector<unsigned char> shuffled;
  };
  auto make_scratch = [&] {
    Scratch s{{libdeflate_alloc_compressor(level), libdeflate_free_compressor}, {}, {}};
    if (!s.compressor) throw std::bad_alloc();
    s.block.resize(size_t(g.elements));
    s.shuffled.resize(size_t(g.bytes()));
    return s;
  };
  const bool compressed_all = for_each_chunk_in_parallel(0, g.count, make_scratch, [&](uint64_t c, Scratch& s) {
    std::fill(s.block.begin(), s.block.end(), g.fill);  // the padding of edge chunks
    uint64_t values = 0;
    g.for_each_row(c, [&](uint64_t at, uint64_t from, uint64_t n) {
      std::memcpy(s.block.data() + from, data + at, size_t(n) * sizeof(T));
      values += n;
    });
    if (ticker) ticker->add(values * sizeof(T));
    // Bitwise, so NaN fills compare equal. Such a chunk is not written: compressed[c] stays empty.
    if (fill &&
        std::all_of(s.block.begin(), s.block.end(), [&](const T& v) { return std::memcmp(&v, fill, sizeof(T)) == 0; }))
      return true;
    g.shuffle(s.block.data(), s.shuffled.data());
    std::vector<unsigned char>& stream = compressed[size_t(c)];
    const size_t bound = libdeflate_zlib_compress_bound(s.compressor.get(), s.shuffled.size());
    stream.resize(bound);
    const size_t size =
        libdeflate_zlib_compress(s.compressor.get(), s.shuffled.data(), s.shuffled.size(), stream.data(), bound);
    stream.resize(size);
    return size != 0;
  });
  if (!compressed_all) return false;
  for (uint64_t c = 0; c < g.count; ++c) {
    const std::vector<unsigned char>& stream = compressed[size_t(c)];
    if (stream.empty()) continue;
    hsize_t offset[3];
    g.offset(c, offset);
    if (H5Dwrite_chunk(dset, H5P_DEFAULT, 0, offset, stream.size(), stream.data()) < 0) return false;
  }
  return true;
}

}  // namespace

template <class T>
bool Writer::dataset(hid_t group, const std::string& name, const std::vector<uint64_t>& shape, const T* data,
                     int deflate_level, const std::vector<uint64_t>& chunk_shape, const T* fill) {
  std::vector<hsize_t> dims(shape.begin(), shape.end());
  Handle space(H5Screate_simple(int(dims.size()), dims.data(), nullptr), H5Sclose);
  Handle dcpl(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
  uint64_t count = 1;
  for (uint64_t d : shape) count *= d;
  const bool chunked = !chunk_shape.empty() && chunk_shape.size() == dims.size() && count > 0;
  std::vector<hsize_t> chunk(dims.size());
  if (chunked) {
    for (size_t i = 0; i < dims.size(); ++i)
      chunk[i] = std::max<hsize_t>(1, std::min<hsize_t>(dims[i], chunk_shape[i]));
    H5Pset_chunk(dcpl.get(), int(chunk.size()), chunk.data());
    if (fill && H5Pset_fill_value(dcpl.get(), TypeTraits<T>::memory_type(), fill) < 0)
      return fail("cannot set the fill value of dataset " + name);
    if (deflate_level > 0) {
      H5Pset_shuffle(dcpl.get());
      H5Pset_deflate(dcpl.get(), unsigned(std::min(deflate_level, 9)));
    }
  }
  Handle dset(
      H5Dcreate2(group, name.c_str(), TypeTraits<T>::file_type(), space.get(), H5P_DEFAULT, dcpl.get(), H5P_DEFAULT),
      H5Dclose);
  if (!dset.valid()) return fail("cannot create dataset " + name);
  if (count == 0) return true;
  ChunkGrid<T> grid;
  if (chunked && deflate_level > 0 && host_is_little_endian() &&
      grid.set_shape(dims.size(), dims.data(), chunk.data())) {
    grid.fill = fill ? *fill : T{};
    if (!write_chunks_in_parallel(dset.get(), grid, data, std::min(deflate_level, 9), fill, ticker_))
      return fail("cannot write dataset " + name);
    return true;
  }
  if (H5Dwrite(dset.get(), TypeTraits<T>::memory_type(), H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
    return fail("cannot write dataset " + name);
  if (ticker_) ticker_->add(count * sizeof(T));
  return true;
}

#define VOXFMT_INSTANTIATE(T)                                                                                        \
  template std::optional<std::vector<T>> Reader::numeric_attribute<T>(hid_t, const std::string&, const std::string&, \
                                                                      const Shape&);                                 \
  template std::optional<std::vector<T>> Reader::dataset<T>(hid_t, const std::string&, const std::string&,           \
                                                            const Shape&, std::vector<uint64_t>*);                   \
  template std::optional<OpenDataset> Reader::open_dataset<T>(hid_t, const std::string&, const std::string&,         \
                                                              const Shape&, uint64_t);                               \
  template bool Reader::read_rows<T>(const OpenDataset&, uint64_t, uint64_t, T*);                                    \
  template bool Writer::numeric_attribute<T>(hid_t, const std::string&, const std::vector<uint64_t>&, const T*);     \
  template bool Writer::dataset<T>(hid_t, const std::string&, const std::vector<uint64_t>&, const T*, int,           \
                                   const std::vector<uint64_t>&, const T*);
VOXFMT_INSTANTIATE(int16_t)
VOXFMT_INSTANTIATE(int32_t)
VOXFMT_INSTANTIATE(uint32_t)
VOXFMT_INSTANTIATE(float)
VOXFMT_INSTANTIATE(double)
#undef VOXFMT_INSTANTIATE

}  // namespace voxfmt::h5
