// Small RAII layer over the HDF5 C API, private to libvoxfmt. Read helpers report problems as Issues
// (code, HDF5 path, reason) instead of throwing, so one pass over a file can collect every finding.
#pragma once

#include <hdf5.h>

#include <cstddef>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "voxfmt/detail/utf8.h"
#include "voxfmt/result.h"

namespace voxfmt::h5 {

/// Owns one HDF5 identifier and closes it with the matching H5?close.
class Handle {
 public:
  using Closer = herr_t (*)(hid_t);
  Handle() = default;
  Handle(hid_t id, Closer closer) : id_(id), closer_(closer) {}
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  Handle(Handle&& other) noexcept : id_(other.id_), closer_(other.closer_) { other.id_ = H5I_INVALID_HID; }
  Handle& operator=(Handle&& other) noexcept {
    if (this != &other) {
      reset();
      id_ = other.id_;
      closer_ = other.closer_;
      other.id_ = H5I_INVALID_HID;
    }
    return *this;
  }
  ~Handle() { reset(); }
  void reset() {
    if (id_ >= 0 && closer_) closer_(id_);
    id_ = H5I_INVALID_HID;
  }
  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }

 private:
  hid_t id_ = H5I_INVALID_HID;
  Closer closer_ = nullptr;
};

/// Turns off HDF5's own printing of error stacks (we report errors ourselves).
void silence_hdf5_errors();
/// The innermost reason on HDF5's current error stack, e.g. "truncated file: eof = 1024, ...".
std::string last_hdf5_reason();

/// Held by whatever uses HDF5 in this process outside a forked child (the writer), and by an isolated read while it
/// forks and waits: a child forked while another thread is inside HDF5 inherits HDF5's lock held and sleeps.
std::mutex& process_mutex();
/// Why HDF5's last call failed, read from (and cleared off) its error stack at once.
struct Hdf5Failure {
  std::string reason;          ///< as last_hdf5_reason()
  bool out_of_memory = false;  ///< a failed allocation: OUT_OF_MEMORY, not the disk's or the file's fault
};
Hdf5Failure last_hdf5_failure();

/// Longest string attribute a file may hold, in bytes (spec §1): bounds what a hostile file can make us allocate,
/// and stays below HDF5's 64 KiB limit of a fixed-length attribute in an object header.
inline constexpr size_t kMaxStringBytes = 60000;

/// Most elements a dataset may hold (spec §1).
inline constexpr uint64_t kMaxElements = uint64_t(1) << 31;

/// Largest chunk, in bytes before compression (spec 2.1 §1): decoding one chunk is the unit of work between two
/// progress reports, so it must be small whatever the machine (voxfmt writes 64-128 KiB; h5py at most 1 MiB).
inline constexpr uint64_t kMaxChunkBytes = uint64_t(1) << 22;

/// Most chunks the datasets of one file may be split into, in all (spec 2.1 §1): a 4096^3 asset has ~30,000, a
/// 1.x grid of 2^31 voxels in 32^3 chunks 131,072; each costs a lookup in the chunk index.
inline constexpr uint64_t kMaxChunksPerFile = uint64_t(1) << 18;

/// What one H5Dread may cover (h5.cpp): at most this many elements and this many chunks, so that a watchdog sees
/// progress after a bounded amount of work and HDF5's per-chunk bookkeeping stays small.
inline constexpr uint64_t kElementsPerPiece = uint64_t(1) << 22;
inline constexpr uint64_t kChunksPerPiece = 1024;

/// Joins an HDF5 group path and a member name: ("/", "a") -> "/a", ("/g", "a") -> "/g/a".
std::string join_path(const std::string& group_path, const std::string& name);

/// Element types this project stores, with their little-endian file type and native memory type.
template <class T>
struct TypeTraits;
template <>
struct TypeTraits<int16_t> {
  static constexpr H5T_class_t kClass = H5T_INTEGER;
  static constexpr bool kSigned = true;
  static constexpr const char* kName = "i16";
  static hid_t file_type() { return H5T_STD_I16LE; }
  static hid_t memory_type() { return H5T_NATIVE_INT16; }
};
template <>
struct TypeTraits<int32_t> {
  static constexpr H5T_class_t kClass = H5T_INTEGER;
  static constexpr bool kSigned = true;
  static constexpr const char* kName = "i32";
  static hid_t file_type() { return H5T_STD_I32LE; }
  static hid_t memory_type() { return H5T_NATIVE_INT32; }
};
template <>
struct TypeTraits<uint32_t> {
  static constexpr H5T_class_t kClass = H5T_INTEGER;
  static constexpr bool kSigned = false;
  static constexpr const char* kName = "u32";
  static hid_t file_type() { return H5T_STD_U32LE; }
  static hid_t memory_type() { return H5T_NATIVE_UINT32; }
};
template <>
struct TypeTraits<float> {
  static constexpr H5T_class_t kClass = H5T_FLOAT;
  static constexpr bool kSigned = true;
  static constexpr const char* kName = "f32";
  static hid_t file_type() { return H5T_IEEE_F32LE; }
  static hid_t memory_type() { return H5T_NATIVE_FLOAT; }
};
template <>
struct TypeTraits<double> {
  static constexpr H5T_class_t kClass = H5T_FLOAT;
  static constexpr bool kSigned = true;
  static constexpr const char* kName = "f64";
  static hid_t file_type() { return H5T_IEEE_F64LE; }
  static hid_t memory_type() { return H5T_NATIVE_DOUBLE; }
};

/// Expected shape: empty = scalar; -1 = any extent (the actual one is returned).
using Shape = std::vector<int64_t>;

/// What a dataset's metadata say about its storage, read before any of its data is decoded.
struct Layout {
  std::vector<uint64_t> shape;
  std::vector<uint64_t> chunk;  ///< empty: not chunked (contiguous or compact)
  size_t element_bytes = 0;
  uint64_t elements() const;
  /// Chunks of the chunk grid (written or not); 0 when not chunked. Saturates at 2^63.
  uint64_t chunk_count() const;
  uint64_t chunk_bytes() const;
};

/// A dataset opened and checked (dtype, shape, filters, chunk grid, size), ready to be read row by row.
struct OpenDataset {
  Handle handle;
  std::string path;
  std::vector<uint64_t> shape;
  std::vector<uint64_t> chunk;  ///< empty: not chunked
  uint64_t elements() const {
    uint64_t n = 1;
    for (uint64_t d : shape) n *= d;
    return n;
  }
};

/// Reads objects of one open file, appending every problem to `issues`.
class Reader {
 public:
  Reader(std::string file, std::vector<Issue>& issues) : file_(std::move(file)), issues_(issues) {}

  /// Opens the file read-only; FILE_NOT_FOUND or NOT_HDF5 on failure.
  bool open();
  hid_t file() const { return file_handle_.get(); }

  /// Opens member `name` of group `parent` (at `parent_path`) as a group.
  std::optional<Handle> group(hid_t parent, const std::string& parent_path, const std::string& name);
  bool has_attribute(hid_t object, const std::string& name);
  bool has_member(hid_t parent, const std::string& name);

  std::optional<std::string> string_attribute(hid_t object, const std::string& object_path, const std::string& name);
  template <class T>
  std::optional<std::vector<T>> numeric_attribute(hid_t object, const std::string& object_path, const std::string& name,
                                                  const Shape& shape);
  /// Reads dataset `name` of `group`; `shape_out` receives its extents.
  template <class T>
  std::optional<std::vector<T>> dataset(hid_t group, const std::string& group_path, const std::string& name,
                                        const Shape& shape, std::vector<uint64_t>* shape_out = nullptr);
  /// Opens dataset `name` and checks it before anything is decoded (dtype T, shape, storage, size).
  /// `chunk_cache_bytes` > 0: HDF5's chunk cache for it (a reader that reads each chunk in several pieces).
  template <class T>
  std::optional<OpenDataset> open_dataset(hid_t group, const std::string& group_path, const std::string& name,
                                          const Shape& shape, uint64_t chunk_cache_bytes = 0);
  /// The storage of dataset `name` of `group`, from its metadata alone; nothing (and no finding) when it is
  /// absent, not a dataset or unreadable: the read itself reports those.
  std::optional<Layout> layout(hid_t group, const std::string& name);
  /// Reads rows [first, first + count) along the first dimension into `out` (count x the other extents), in
  /// pieces of at most kElementsPerPiece elements and kChunksPerPiece chunks, reporting progress after each.
  template <class T>
  bool read_rows(const OpenDataset& dataset, uint64_t first, uint64_t count, T* out);
  /// Called after each piece of a large read: a watchdog in a parent process sees the read move on.
  void set_progress(std::function<void()> progress) { progress_ = std::move(progress); }
  void progress() {
    if (progress_) progress_();
  }

  /// Names of the members and attributes of `object` (for UNKNOWN_OBJECT reporting).
  std::vector<std::string> member_names(hid_t group);
  std::vector<std::string> attribute_names(hid_t object);

  void report(IssueCode code, const std::string& path, const std::string& message);
  /// False (reported) where a link of the file leaves it (external, user-defined), directly or behind a soft link:
  /// an asset is one file (spec §1). Called once the header is read, before any other object is opened.
  bool stays_in_file();

 private:
  /// Opens member `name` of `parent` and checks it is a group (or a dataset).
  std::optional<Handle> open_member(hid_t parent, const std::string& parent_path, const std::string& name,
                                    bool want_group);
  /// Opens attribute `name` of `object`; `path` receives its "/group/@name" path for messages.
  std::optional<Handle> open_attribute(hid_t object, const std::string& object_path, const std::string& name,
                                       std::string& path);
  bool check_type(hid_t type, H5T_class_t cls, size_t size, bool is_signed, const char* name, const std::string& path);
  bool check_shape(hid_t space, const Shape& expected, const std::string& path, std::vector<uint64_t>& actual);
  /// `bytes` as text if they are UTF-8 and within the format's length, else a STRING_NOT_UTF8 or VALUE_OUT_OF_RANGE
  /// finding at `path`.
  std::optional<std::string> checked_text(std::string bytes, const std::string& path);
  /// Filters and chunk grid of a dataset, checked before its data is decoded.
  bool check_storage(hid_t dset, const std::vector<uint64_t>& dims, const std::string& path);
  /// Reads a whole dataset by its raw chunks and inflates them on all cores, if it is stored as voxfmt writes
  /// (shuffle then deflate, the native type); false otherwise, or at anything unusual, reporting nothing.
  template <class T>
  bool read_raw_chunks(const OpenDataset& dataset, T* out);

  std::string file_;
  std::vector<Issue>& issues_;
  Handle file_handle_;
  std::function<void()> progress_;
};

/// Told the bytes of every chunk compressed, from whichever thread compressed it (the writer's included).
class WriteTicker {
 public:
  virtual ~WriteTicker() = default;
  virtual void add(uint64_t bytes) = 0;
};

/// Writes objects into one file; every call returns false and records the reason on failure.
class Writer {
 public:
  explicit Writer(hid_t file, WriteTicker* ticker = nullptr) : file_(file), ticker_(ticker) {}
  hid_t file() const { return file_; }

  std::optional<Handle> create_group(hid_t parent, const std::string& name);
  bool string_attribute(hid_t object, const std::string& name, const std::string& value);
  template <class T>
  bool numeric_attribute(hid_t object, const std::string& name, const std::vector<uint64_t>& shape, const T* data);
  /// With `fill` (chunked only): the dataset's fill value; chunks holding nothing else are not written (they
  /// read back as the fill value), which saves their compression and their space.
  /// `chunk` empty: contiguous; else the chunk shape (clamped to the dataset's extents), compressed with shuffle
  /// and deflate at `deflate_level` when it is > 0.
  template <class T>
  bool dataset(hid_t group, const std::string& name, const std::vector<uint64_t>& shape, const T* data,
               int deflate_level = 0, const std::vector<uint64_t>& chunk = {}, const T* fill = nullptr);

  const std::string& failure() const { return failure_; }
  /// Whether the failure was HDF5 running out of memory (OUT_OF_MEMORY, not WRITE_FAILED).
  bool out_of_memory() const { return out_of_memory_; }

 private:
  bool fail(const std::string& what);
  hid_t file_;
  WriteTicker* ticker_;
  std::string failure_;
  bool out_of_memory_ = false;
};

}  // namespace voxfmt::h5
