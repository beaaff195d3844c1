// voxfmt._voxfmt: the compiled half of the Python package (nanobind). It binds libvoxfmt (read, validate,
// inspect), the bake library and the runtime (load, contacts, wrench, batched contacts). The pure-Python half
// (python/voxfmt/__init__.py) adds the keyword handling of bake() and the typed report classes.
//
// Errors: every failure of a library call becomes a voxfmt.Error subclass carrying the library's code
// (spec/issue-codes.md), raised through CodedError and the translator registered below.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/string_view.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <Eigen/Core>
#include <Eigen/LU>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <filesystem>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "core/frame.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/detail/cores.h"
#include "voxfmt/detail/report.h"
#include "voxfmt/io.h"
#include "voxfmt/runtime/collision_object.h"
#include "voxfmt/runtime/query.h"
#include "voxfmt/version.h"

#include "common.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace voxfmt::python {

namespace {

using runtime::CollisionObject;
using runtime::ContactSet;
using runtime::Pose;
using runtime::QueryOptions;

// ---------------------------------------------------------------------------------------------------------------
// Arrays in and out.

using InArray = nb::ndarray<const double, nb::device::cpu>;

/// `value` as a float64 array on the CPU (any strides). Anything else NumPy can read as one (lists, float32,
/// ints) is converted; what it cannot is BAD_OPTION naming `what`.
InArray as_float64(nb::handle value, const char* what) {
  InArray array;
  if (nb::try_cast(value, array, false)) return array;
  nb::object converted;
  std::string kind;
  try {
    const nb::object numpy = nb::module_::import_("numpy");
    converted = numpy.attr("asarray")(value);
    kind = nb::str(converted.attr("dtype").attr("kind")).c_str();
    if (kind == "i" || kind == "u" || kind == "f") converted = numpy.attr("asarray")(converted, "dtype"_a = "float64");
  } catch (const nb::python_error&) {
    fail(IssueCode::BadOption, std::string(what) + ": expected an array of numbers");
  }
  // Complex numbers would lose their imaginary part, booleans and objects are no coordinates.
  if (kind != "i" && kind != "u" && kind != "f")
    fail(IssueCode::BadOption, std::string(what) + ": expected an array of real numbers, got dtype " +
                                   nb::str(converted.attr("dtype").attr("name")).c_str());
  if (nb::try_cast(converted, array, false)) return array;
  // Strides that are no multiple of 8 bytes (a field of packed records) no float64 view can take: a copy can.
  try {
    converted = nb::module_::import_("numpy").attr("ascontiguousarray")(converted, "dtype"_a = "float64");
  } catch (const nb::python_error&) {
    fail(IssueCode::BadOption, std::string(what) + ": expected an array of numbers");
  }
  if (!nb::try_cast(converted, array, false))
    fail(IssueCode::BadOption, std::string(what) + ": expected an array of numbers");
  return array;
}

std::string shape_text(const InArray& a) {
  std::string s = "(";
  for (size_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

/// A new C-contiguous NumPy array that owns its memory (allocated once, filled in C++).

template <class T>
nb::ndarray<nb::numpy, T> vector_array(const Eigen::Matrix<T, 3, 1>& v) {
  OutArray<T> out({3});
  for (int i = 0; i < 3; ++i) out.data[i] = v[i];
  return out.array;
}

/// A str, bytes or os.PathLike as a file name, as open() takes it: its bytes by os.fsencode (a name that is not
/// UTF-8 included). Anything else, or a name holding a NUL byte (which would name another file), is BAD_OPTION.
std::string path_arg(nb::handle value, const char* what) {
  std::string path;
  try {
    nb::module_ os = nb::module_::import_("os");
    const nb::bytes bytes = nb::cast<nb::bytes>(os.attr("fsencode")(os.attr("fspath")(value)));
    path.assign(bytes.c_str(), bytes.size());
  } catch (const nb::python_error&) {
    fail(IssueCode::BadOption, std::string(what) + ": expected a path (str, bytes or os.PathLike)");
  } catch (const nb::cast_error&) {
    fail(IssueCode::BadOption, std::string(what) + ": expected a path (str, bytes or os.PathLike)");
  }
  if (path.find('\0') != std::string::npos) fail(IssueCode::BadOption, std::string(what) + ": embedded null byte");
  return path;
}

/// Text that may hold a file's name, as os.fsdecode gives it: a name that is not UTF-8 keeps its bytes (as
/// surrogates), where nanobind's strict UTF-8 would fail the call.
nb::str fs_text(const std::string& text) {
  PyObject* decoded = PyUnicode_DecodeFSDefaultAndSize(text.data(), Py_ssize_t(text.size()));
  if (!decoded) throw nb::python_error();
  return nb::steal<nb::str>(decoded);
}

/// One of the package's option rules (voxfmt/batch.py: _real, _whole), so that a compiled function judges a number
/// as the Python ones do: never a bool, an int beyond int64 an OptionError, not nanobind's TypeError.
nb::object package_rule(const char* name) {
  static nb::object* batch = new nb::object(nb::module_::import_("voxfmt.batch"));  // kept to the end: no teardown
  return batch->attr(name);
}

/// A number option (int or float, NumPy's too); a plain float at once.
double real_arg(nb::handle value, const char* name) {
  if (PyFloat_CheckExact(value.ptr())) return PyFloat_AS_DOUBLE(value.ptr());
  return nb::cast<double>(package_rule("_real")(name, value));
}

/// An integer option, or None; its range is the caller's to check.
std::optional<int64_t> optional_int_arg(nb::handle value, const char* name) {
  if (value.is_none()) return std::nullopt;
  return nb::cast<int64_t>(
      package_rule("_whole")(name, value, std::numeric_limits<int64_t>::min(), std::numeric_limits<int64_t>::max()));
}

/// A number option, or None.
std::optional<double> optional_real_arg(nb::handle value, const char* name) {
  if (value.is_none()) return std::nullopt;
  return real_arg(value, name);
}

// ---------------------------------------------------------------------------------------------------------------
// Poses: 4x4 body-to-world matrices that must be rigid.

using runtime::core::kRigidTolerance;  // the batches' rule (core::pose_from_matrix)

/// Fills `pose` from the 4x4 matrix at `m` (element strides `row`, `col`); an error message if it is not rigid.
std::optional<std::string> read_pose(const double* m, int64_t row, int64_t col, Pose& pose) {
  Eigen::Matrix4d t;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) t(r, c) = m[r * row + c * col];
  if (!t.allFinite()) return std::string("has a non-finite entry");
  if (t(3, 0) != 0.0 || t(3, 1) != 0.0 || t(3, 2) != 0.0 || t(3, 3) != 1.0)
    return std::string("last row is not 0 0 0 1");
  const Eigen::Matrix3d rotation = t.topLeftCorner<3, 3>();
  const double off = (rotation.transpose() * rotation - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (off > kRigidTolerance)
    return "rotation part is not orthonormal (|R^T R - I| = " + std::to_string(off) +
           "; scale and shear are not supported)";
  if (rotation.determinant() < 0) return std::string("rotation part has determinant -1 (a reflection)");
  pose.rotation = rotation;
  pose.translation = t.topRightCorner<3, 1>();
  pose.scale = 1.0;
  return std::nullopt;
}

Pose parse_pose(nb::handle value, const char* what) {
  const InArray a = as_float64(value, what);
  if (a.ndim() != 2 || a.shape(0) != 4 || a.shape(1) != 4)
    fail(IssueCode::BadOption, std::string(what) + ": expected a 4x4 matrix, got shape " + shape_text(a));
  Pose pose;
  if (auto problem = read_pose(a.data(), a.stride(0), a.stride(1), pose))
    fail(IssueCode::BadPose, std::string(what) + " is not a rigid transform: " + *problem);
  return pose;
}

/// K poses from a (K, 4, 4) array, or one (4, 4) pose repeated `count` times (count = 0: K decides).
std::vector<Pose> parse_poses(nb::handle value, const char* what, size_t count) {
  const InArray a = as_float64(value, what);
  std::vector<Pose> poses;
  if (a.ndim() == 2 && a.shape(0) == 4 && a.shape(1) == 4) {
    poses.assign(std::max<size_t>(count, 1), parse_pose(value, what));
    return poses;
  }
  if (a.ndim() != 3 || a.shape(1) != 4 || a.shape(2) != 4)
    fail(IssueCode::BadOption, std::string(what) + ": expected (K, 4, 4) matrices, got shape " + shape_text(a));
  if (count && a.shape(0) != count)
    fail(IssueCode::BadOption, std::string(what) + ": " + std::to_string(a.shape(0)) +
                                   " poses where the other side has " + std::to_string(count));
  poses.resize(a.shape(0));
  for (size_t k = 0; k < poses.size(); ++k)
    if (auto problem = read_pose(a.data() + k * a.stride(0), a.stride(1), a.stride(2), poses[k]))
      fail(IssueCode::BadPose, std::string(what) + "[" + std::to_string(k) + "] is not a rigid transform: " + *problem);
  return poses;
}

// Where a query stops above the leaves: the deepest level (max_level) and what that level's points report.
struct Cut {
  std::optional<int64_t> max_level;
  std::string level = "spheres";
};

QueryOptions query_options(std::optional<int64_t> point_budget, std::optional<double> time_budget_us, double proximity,
                           const Cut& cut = {}, const std::string& interpolation = "trilinear") {
  QueryOptions options;
  options.interpolation = interpolation_of(interpolation);
  if (cut.max_level) {
    if (*cut.max_level < 0) fail(IssueCode::BadOption, "max_level must be >= 0 (or None: the whole tree)");
    options.max_level = uint32_t(std::min<int64_t>(*cut.max_level, std::numeric_limits<uint32_t>::max()));
  }
  if (cut.level == "points")
    options.cut_level = runtime::CutLevel::Points;
  else if (cut.level != "spheres")
    fail(IssueCode::BadOption, "cut_level must be 'spheres' or 'points', not '" + cut.level + "'");
  if (point_budget) {
    if (*point_budget < 1) fail(IssueCode::BadOption, "point_budget must be >= 1 (or None: the whole tree)");
    options.point_budget = size_t(*point_budget);
  }
  if (time_budget_us) {
    if (!(std::isfinite(*time_budget_us) && *time_budget_us > 0))
      fail(IssueCode::BadOption, "time_budget_us must be a finite number > 0 (or None: no budget)");
    options.time_budget_us = *time_budget_us;
  }
  if (!(std::isfinite(proximity) && proximity >= 0))
    fail(IssueCode::BadOption, "proximity must be a finite number >= 0 (metres)");
  options.proximity = proximity;
  return options;
}

// ---------------------------------------------------------------------------------------------------------------
// Body and Contacts.

/// A read-only NumPy view of `count` rows of `Cols` values of T at `data`, kept alive by `owner`.
template <class T>
nb::ndarray<nb::numpy, const T> view(const T* data, std::initializer_list<size_t> shape,
                                     std::initializer_list<int64_t> strides, nb::handle owner) {
  static const T empty{};
  return nb::ndarray<nb::numpy, const T>(data ? data : &empty, shape, owner, strides);
}

struct Contacts {
  ContactSet set;
  Eigen::Vector3d reference = Eigen::Vector3d::Zero();  ///< A's centre of mass, world frame
};

/// A pair queried pose after pose (a trajectory, a simulation): the query keeps its last traversal, so a step
/// costs what moved; the contacts are those of voxfmt.contacts() at the same poses, bit for bit.
struct Tracker {
  Body a, b;
  runtime::QueryState state;
  runtime::QueryScratch scratch;
  ContactSet work;
  std::mutex busy;  // one query at a time: the state is the pair's history

  /// The tracker for one query, or a coded error while another thread's query holds it. Never waited for: the
  /// holder may be a batch that has released the GIL and needs it back before it lets go.
  std::unique_lock<std::mutex> claim() {
    std::unique_lock<std::mutex> lock(busy, std::try_to_lock);
    if (!lock.owns_lock())
      fail(IssueCode::BadOption, "this Tracker is answering another thread's query: one query at a time per Tracker");
    return lock;
  }
};

static_assert(sizeof(runtime::Contact) % sizeof(double) == 0 && sizeof(runtime::Contact) % sizeof(uint32_t) == 0,
              "strided views into the contacts need whole-element strides");

/// A read-only view of one field across a Contacts' contacts (strided by the Contact struct, no copy), kept alive
/// by `self`: `field` gives the field's address in a contact, `columns` is 1 (shape (M,)) or 3 (shape (M, 3)).
template <class T, class Field>
nb::ndarray<nb::numpy, const T> contact_field(nb::handle self, Field field, size_t columns) {
  const Contacts& c = nb::cast<const Contacts&>(self);
  const T* data = c.set.contacts.empty() ? nullptr : field(c.set.contacts.front());
  const int64_t stride = int64_t(sizeof(runtime::Contact) / sizeof(T));
  if (columns == 1) return view<T>(data, {c.set.contacts.size()}, {stride}, self);
  return view<T>(data, {c.set.contacts.size(), columns}, {stride, 1}, self);
}

/// The largest depth of a set, metres (0.0 without contacts).
double deepest_depth(const ContactSet& set) {
  double deepest = 0.0;
  for (const runtime::Contact& x : set.contacts) deepest = std::max(deepest, x.depth);
  return deepest;
}

Contacts query(const Body& a, nb::handle pose_a, const Body& b, nb::handle pose_b, nb::handle point_budget,
               nb::handle time_budget_us, nb::handle proximity, nb::handle max_level, const std::string& cut_level,
               const std::string& interpolation) {
  const Pose pa = parse_pose(pose_a, "pose_a");
  const Pose pb = parse_pose(pose_b, "pose_b");
  const QueryOptions options = query_options(
      optional_int_arg(point_budget, "point_budget"), optional_real_arg(time_budget_us, "time_budget_us"),
      real_arg(proximity, "proximity"), Cut{optional_int_arg(max_level, "max_level"), cut_level}, interpolation);
  // The traversal fills a per-thread set that keeps its capacity; the result gets one allocation of the exact
  // size (a fresh vector grown contact by contact cost more than the copy).
  thread_local runtime::QueryScratch scratch;
  thread_local ContactSet work;
  work.clear();
  runtime::query_contacts(*a.object, pa, *b.object, pb, options, work, scratch);
  Contacts out;
  out.set.contacts.assign(work.contacts.begin(), work.contacts.end());
  out.set.stats = work.stats;
  out.reference = pa.apply(a.object->center_of_mass());
  return out;
}

Contacts tracked_query(Tracker& tracker, nb::handle pose_a, nb::handle pose_b, nb::handle proximity,
                       const std::string& interpolation) {
  const Pose pa = parse_pose(pose_a, "pose_a");
  const Pose pb = parse_pose(pose_b, "pose_b");
  const QueryOptions options =
      query_options(std::nullopt, std::nullopt, real_arg(proximity, "proximity"), {}, interpolation);
  const std::unique_lock<std::mutex> lock = tracker.claim();
  tracker.work.clear();
  runtime::query_contacts(*tracker.a.object, pa, *tracker.b.object, pb, options, tracker.work, tracker.scratch,
                          tracker.state);
  Contacts out;
  out.set.contacts.assign(tracker.work.contacts.begin(), tracker.work.contacts.end());
  out.set.stats = tracker.work.stats;
  out.reference = pa.apply(tracker.a.object->center_of_mass());
  return out;
}

std::tuple<nb::ndarray<nb::numpy, double>, nb::ndarray<nb::numpy, double>> wrench(const Contacts& contacts,
                                                                                  nb::handle stiffness_object,
                                                                                  std::optional<nb::handle> reference) {
  const double stiffness = real_arg(stiffness_object, "stiffness");
  if (!(std::isfinite(stiffness) && stiffness >= 0)) fail(IssueCode::BadOption, "stiffness must be finite and >= 0");
  Eigen::Vector3d ref = contacts.reference;
  if (reference && !reference->is_none()) {
    const InArray r = as_float64(*reference, "reference");
    if (r.ndim() != 1 || r.shape(0) != 3)
      fail(IssueCode::BadOption, "reference: expected a point (3,), got shape " + shape_text(r));
    for (int i = 0; i < 3; ++i) ref[i] = r.data()[i * r.stride(0)];
    if (!ref.allFinite()) fail(IssueCode::BadOption, "reference: expected a finite point");
  }
  const runtime::Wrench w = runtime::penalty_wrench(contacts.set, ref, stiffness);
  return {vector_array<double>(w.force), vector_array<double>(w.torque)};
}

// ---------------------------------------------------------------------------------------------------------------
// contacts_batch: K pose pairs on worker threads, the GIL released, outputs allocated once.

using BatchDict = nb::typed<nb::dict, nb::str, nb::any>;

// K poses as the row-major 4x4 matrices a batch reads.
std::vector<double> matrices_of(const std::vector<Pose>& poses) {
  std::vector<double> m;
  m.reserve(16 * poses.size());
  for (const Pose& p : poses) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) m.push_back(p.rotation(r, c));
      m.push_back(p.translation[r]);
    }
    for (const double x : {0.0, 0.0, 0.0, 1.0}) m.push_back(x);
  }
  return m;
}

// Each worker's contacts, in the order it found them, and where each environment's are: concatenated in pose
// order afterwards, whichever worker ran them.
struct FoundContacts {
  std::vector<std::vector<runtime::Contact>> by_worker;
  std::vector<std::pair<unsigned, size_t>> first;  // per pose: (worker, index of its first contact there)
};

// contacts_batch's ragged outputs: offsets (K + 1) and the contacts' fields, in pose order.
void add_contact_arrays(BatchDict& out, const FoundContacts& found, const OutArray<int64_t>& count, size_t k) {
  size_t total = 0;
  for (size_t i = 0; i < k; ++i) total += size_t(count.data[i]);
  OutArray<int64_t> offsets({k + 1});
  OutArray<double> points({total, 3}), normals({total, 3}), depths({total});
  OutArray<uint32_t> index({total});
  OutArray<bool> of_b({total});
  offsets.data[0] = 0;
  size_t at = 0;
  for (size_t i = 0; i < k; ++i) {
    offsets.data[i + 1] = offsets.data[i] + count.data[i];
    const auto& [worker, first] = found.first[i];
    for (size_t n = 0; n < size_t(count.data[i]); ++n, ++at) {
      const runtime::Contact& c = found.by_worker[worker][first + n];
      for (int j = 0; j < 3; ++j) {
        points.data[3 * at + j] = c.point[j];
        normals.data[3 * at + j] = c.normal[j];
      }
      depths.data[at] = c.depth;
      index.data[at] = c.point_index;
      of_b.data[at] = c.point_of_b;
    }
  }
  out["offsets"] = offsets.array;
  out["points"] = points.array;
  out["normals"] = normals.array;
  out["depths"] = depths.array;
  out["point_index"] = index.array;
  out["point_of_b"] = of_b.array;
}

// Both sides' K poses as row-major 4x4 matrices; either side may be one (4, 4) pose for all K.
struct BatchPoses {
  std::vector<double> a, b;
  size_t count = 0;
};

BatchPoses batch_poses(nb::handle poses_a, nb::handle poses_b) {
  const InArray first_a = as_float64(poses_a, "poses_a");
  std::vector<Pose> pa = parse_poses(poses_a, "poses_a", 0);
  if (first_a.ndim() == 3) {  // a stack of K (K = 0 included): B is one pose for all, or K of them
    const size_t k = pa.size();
    const InArray first_b = as_float64(poses_b, "poses_b");
    if (first_b.ndim() == 3 && first_b.shape(0) != k)
      fail(IssueCode::BadOption,
           "poses_b: " + std::to_string(first_b.shape(0)) + " poses where the other side has " + std::to_string(k));
    std::vector<Pose> pb = parse_poses(poses_b, "poses_b", k);
    pb.resize(k);  // one pose for none: none
    return {matrices_of(pa), matrices_of(pb), k};
  }
  const std::vector<Pose> pb = parse_poses(poses_b, "poses_b", 0);
  const Pose one = pa.front();  // A is one pose (parse_poses gave exactly one)
  pa.assign(pb.size(), one);
  return {matrices_of(pa), matrices_of(pb), pb.size()};
}

// contacts_batch's outputs, filled environment by environment from the batch's worker threads.
struct BatchOutputs {
  size_t k;
  double stiffness;
  bool with_contacts;
  OutArray<int64_t> count{{k}};
  OutArray<double> max_depth{{k}};
  OutArray<double> force{{k, 3}};
  OutArray<double> torque{{k, 3}};
  FoundContacts found;

  BatchOutputs(size_t environments, double k_stiffness, bool contacts, unsigned workers)
      : k(environments), stiffness(k_stiffness), with_contacts(contacts) {
    found.by_worker.resize(workers);
    found.first.resize(with_contacts ? k : 0);
  }

  void record(const runtime::BatchScene::Visit& v) {
    const size_t i = v.environment;
    // parse_poses judged every pose already; the batch judges its matrices again, by the same rule.
    if (v.error != 0)
      fail(IssueCode::BadPose,
           "pose " + std::to_string(i) + " is not a rigid transform (batch error " + std::to_string(v.error) + ")");
    const runtime::Wrench w = runtime::penalty_wrench(v.contacts, v.reference, stiffness);
    count.data[i] = int64_t(v.contacts.contacts.size());
    max_depth.data[i] = deepest_depth(v.contacts);
    for (int j = 0; j < 3; ++j) {
      force.data[3 * i + j] = w.force[j];
      torque.data[3 * i + j] = w.torque[j];
    }
    if (!with_contacts) return;
    std::vector<runtime::Contact>& mine = found.by_worker[v.worker];
    found.first[i] = {v.worker, mine.size()};
    mine.insert(mine.end(), v.contacts.contacts.begin(), v.contacts.contacts.end());
  }

  BatchDict to_dict() const {
    BatchDict out;
    out["count"] = count.array;
    out["max_depth"] = max_depth.array;
    out["force"] = force.array;
    out["torque"] = torque.array;
    if (with_contacts) add_contact_arrays(out, found, count, k);
    return out;
  }
};

// K pose pairs through runtime::BatchScene's worker loop. With a tracker: in order on one thread, each query
// coherent with the one before (a trajectory).
BatchDict contacts_batch(const Body& a, nb::handle poses_a, const Body& b, nb::handle poses_b,
                         std::optional<int64_t> threads, bool with_contacts, double stiffness,
                         std::optional<int64_t> point_budget, std::optional<double> time_budget_us, double proximity,
                         Tracker* tracker, std::optional<int64_t> max_level, const std::string& cut_level,
                         const std::string& interpolation) {
  const QueryOptions options =
      query_options(point_budget, time_budget_us, proximity, Cut{max_level, cut_level}, interpolation);
  if (!(std::isfinite(stiffness) && stiffness >= 0)) fail(IssueCode::BadOption, "stiffness must be finite and >= 0");
  if (threads && *threads < 1) fail(IssueCode::BadOption, "threads must be >= 1 (or None: every core)");
  const BatchPoses poses = batch_poses(poses_a, poses_b);
  runtime::BatchEnvironments in;
  in.count = poses.count;
  in.poses_a_f64 = poses.a.data();
  in.poses_b_f64 = poses.b.data();
  in.proximity = options.proximity;
  in.tie = runtime::DirectionTie::ByAddress;  // each pose's contacts are contacts()'s, ties included
  Result<runtime::BatchScene> scene = runtime::BatchScene::create({a.object, b.object}, {{0u, 1u}});
  if (!scene) throw CodedError(scene.error());

  const unsigned thread_count = threads ? unsigned(*threads) : 0u;
  BatchOutputs outputs(poses.count, stiffness, with_contacts, runtime::BatchScene::workers(poses.count, thread_count));
  std::unique_lock<std::mutex> tracker_lock;
  std::optional<runtime::BatchScene::Trajectory> trajectory;
  if (tracker) {
    tracker_lock = tracker->claim();
    trajectory.emplace(runtime::BatchScene::Trajectory{tracker->scratch, tracker->state});
  }
  Status done = Status::success();
  SignalCheck interrupted;
  {
    nb::gil_scoped_release release;
    done = scene.value().each_environment(
        in, options, thread_count,
        [&](const runtime::BatchScene::Visit& v) {
          outputs.record(v);
          interrupted();
        },
        trajectory ? &*trajectory : nullptr);
  }
  if (!done) throw CodedError(done.error());
  return outputs.to_dict();
}

// ---------------------------------------------------------------------------------------------------------------
// Bake, validate, inspect.

/// The bake's progress callable: called with the GIL between stages; an exception it raises stops the bake at
/// the next stage and is raised again from bake(). Without one, a signal's (KeyboardInterrupt) does.
struct ProgressBridge {
  nb::object callable;
  std::optional<nb::python_error> raised;
  struct Stop : std::runtime_error {
    Stop() : std::runtime_error("stopped by the progress callable") {}
  };
  void operator()(std::string_view stage, double fraction) {
    if (raised) throw Stop();
    nb::gil_scoped_acquire gil;
    try {
      // Without a callable, Ctrl-C stops the bake at its next stage (else the bake ran on and wrote the file).
      if (callable.is_none() && PyErr_CheckSignals() != 0) throw nb::python_error();
      if (!callable.is_none()) callable(std::string(stage), fraction);
    } catch (nb::python_error& e) {
      raised.emplace(std::move(e));
      throw Stop();
    }
  }
};

std::string bake(nb::handle mesh_object, nb::handle output_object, const bake::Settings& s, nb::object progress) {
  const std::string mesh = path_arg(mesh_object, "mesh_path"), output = path_arg(output_object, "out_path");
  ProgressBridge bridge{progress, std::nullopt};
  const bake::ProgressCallback callback = [&bridge](std::string_view stage, double f) { bridge(stage, f); };
  std::optional<Result<bake::Summary>> summary;
  std::exception_ptr escaped;
  {
    nb::gil_scoped_release release;
    try {
      summary.emplace(bake::bake_to_file(mesh, output, s, callback));
    } catch (...) {  // the progress callable's stop after the bake's own error handling (the final stages)
      escaped = std::current_exception();
    }
  }
  if (bridge.raised) {
    nb::python_error error = std::move(*bridge.raised);
    bridge.raised.reset();
    throw error;
  }
  if (escaped) std::rethrow_exception(escaped);
  if (!summary->ok()) throw CodedError(summary->error());
  return bake::to_json(summary->value());
}

// The read's settings from the Python arguments: max_memory_mib None keeps the library's default budget.
ReadOptions read_options(bool full, const std::optional<int64_t>& max_memory_mib) {
  ReadOptions options;
  options.level = full ? ValidationLevel::Full : ValidationLevel::Quick;
  if (max_memory_mib) {
    if (*max_memory_mib < 1 || *max_memory_mib > (int64_t(1) << 40))
      fail(IssueCode::BadOption, "max_memory_mib must be in 1..2^40 (a mebibyte to a pebibyte)");
    options.max_memory_bytes = uint64_t(*max_memory_mib) << 20;
  }
  return options;
}

nb::list validate(nb::handle path_object, bool full, nb::handle max_memory_mib) {
  const std::string path = path_arg(path_object, "path");
  const ReadOptions options = read_options(full, optional_int_arg(max_memory_mib, "max_memory_mib"));
  std::vector<Issue> issues;
  {
    nb::gil_scoped_release release;
    issues = validate_file(path, options);
  }
  nb::list out;
  for (const Issue& i : issues)
    out.append(nb::make_tuple(code_name(i.code), severity_name(i.severity), fs_text(i.message), fs_text(i.path)));
  return out;
}

std::string inspect(nb::handle path_object, nb::handle max_memory_mib) {
  const std::string path = path_arg(path_object, "path");
  const ReadOptions options = read_options(true, optional_int_arg(max_memory_mib, "max_memory_mib"));
  std::vector<Issue> warnings;
  std::optional<Result<Asset>> asset;
  {
    nb::gil_scoped_release release;
    asset.emplace(read_asset(path, &warnings, options));
  }
  if (!asset->ok()) throw CodedError(asset->error());
  return inspect_json(path, asset->value(), summarize_asset(path, asset->value()), warnings);
}

/// A mesh as the bake's import reads it (no repair): (vertices (V, 3) float64 metres, triangles (T, 3) uint32).
std::tuple<nb::ndarray<nb::numpy, double>, nb::ndarray<nb::numpy, uint32_t>> read_mesh(nb::handle path_object,
                                                                                       double unit_scale) {
  const std::string path = path_arg(path_object, "path");
  bake::ImportSettings settings;
  settings.unit_scale = unit_scale;
  std::optional<Result<bake::TriangleMesh>> mesh;
  {
    nb::gil_scoped_release release;
    mesh.emplace(bake::read_mesh(path, settings));
  }
  if (!mesh->ok()) throw CodedError(mesh->error());
  const bake::TriangleMesh& m = mesh->value();
  OutArray<double> vertices({m.vertices.size(), 3});
  for (size_t v = 0; v < m.vertices.size(); ++v)
    for (size_t a = 0; a < 3; ++a) vertices.data[3 * v + a] = m.vertices[v][a];
  OutArray<uint32_t> triangles({m.triangles.size(), 3});
  for (size_t t = 0; t < m.triangles.size(); ++t)
    for (size_t a = 0; a < 3; ++a) triangles.data[3 * t + a] = m.triangles[t][a];
  return {vertices.array, triangles.array};
}

Body load(nb::handle path_object, nb::handle density_object, nb::handle max_memory_mib) {
  const std::string path = path_arg(path_object, "path");
  const double density = real_arg(density_object, "density");
  if (!(std::isfinite(density) && density > 0)) fail(IssueCode::BadOption, "density must be a finite number > 0");
  runtime::LoadOptions options;
  const std::optional<int64_t> budget = optional_int_arg(max_memory_mib, "max_memory_mib");
  options.read = read_options(true, budget);
  std::error_code ec;
  const std::filesystem::path absolute = std::filesystem::absolute(path, ec);
  std::optional<Result<std::shared_ptr<const CollisionObject>>> object;
  {
    nb::gil_scoped_release release;
    object.emplace(CollisionObject::load(path, options));
  }
  if (!object->ok()) throw CodedError(object->error());
  if (!object->value()->has_voxelmap() || !object->value()->has_point_shell())
    fail(IssueCode::MissingObject, path + ": the asset has no voxelmap or no point shell");
  return Body{object->value(), density, path, ec ? path : absolute.string(), budget};
}

nb::ndarray<nb::numpy, double> signed_distance(const Body& body, nb::handle points) {
  const InArray p = as_float64(points, "points");
  if (p.ndim() != 2 || p.shape(1) != 3)
    fail(IssueCode::BadOption, "points: expected an (M, 3) array, got shape " + shape_text(p));
  const size_t m = p.shape(0);
  // A broadcast view of a few bytes can ask for any number of points: refused before the output is made.
  if (double(m) * sizeof(double) > double(voxfmt::default_memory_limit_bytes()))
    fail(IssueCode::OutOfMemory, "points: " + std::to_string(m) +
                                     " distances would take more than 3/4 of this machine's memory (smaller batches)");
  OutArray<double> out({m});
  const runtime::SparseVoxelmap& map = body.object->voxelmap();
  {
    nb::gil_scoped_release release;
    for (size_t i = 0; i < m; ++i) {
      const double* row = p.data() + i * p.stride(0);
      const Eigen::Vector3d q(row[0], row[p.stride(1)], row[2 * p.stride(1)]);
      out.data[i] = double(map.sample(map.to_grid(q)).distance) * map.voxel_size();
    }
  }
  return out.array;
}

/// Mean seconds of one C++ query_contacts call (same options, one scratch), for the overhead benchmark of
/// bench/python_peers.py and the README: what contacts() costs on top of it is the binding's.
double time_query(const Body& a, nb::handle pose_a, const Body& b, nb::handle pose_b, int64_t iterations,
                  std::optional<int64_t> point_budget, std::optional<double> time_budget_us, double proximity) {
  if (iterations < 1) fail(IssueCode::BadOption, "iterations must be >= 1");
  const Pose pa = parse_pose(pose_a, "pose_a");
  const Pose pb = parse_pose(pose_b, "pose_b");
  const QueryOptions options = query_options(point_budget, time_budget_us, proximity);
  nb::gil_scoped_release release;
  ContactSet set;
  runtime::QueryScratch scratch;
  const auto start = std::chrono::steady_clock::now();
  for (int64_t i = 0; i < iterations; ++i) {
    set.clear();
    runtime::query_contacts(*a.object, pa, *b.object, pb, options, set, scratch);
  }
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() / double(iterations);
}

// voxfmt errors become the voxfmt._errors exception of their code (the translator is global to nanobind), an
// unchecked Result's too (BadResultAccess carries its error), so no binding can raise a bare RuntimeError for one.
void raise_coded(const voxfmt::Error& error) {
  nb::object exc = nb::module_::import_("voxfmt._errors")
                       .attr("make_error")(voxfmt::code_name(error.code), fs_text(error.message), fs_text(error.file),
                                           fs_text(error.object));
  PyErr_SetObject(reinterpret_cast<PyObject*>(Py_TYPE(exc.ptr())), exc.ptr());
}

void bind_errors() {
  nb::register_exception_translator([](const std::exception_ptr& p, void*) {
    try {
      std::rethrow_exception(p);
    } catch (const CodedError& e) {
      raise_coded(e.error);
    } catch (const voxfmt::BadResultAccess& e) {
      raise_coded(e.error());
    } catch (const std::bad_alloc&) {  // the package's code for it, as every other consumer's
      raise_coded(voxfmt::Error(voxfmt::IssueCode::OutOfMemory, "not enough memory for this call's arrays"));
    }
  });
}

// Body: a loaded asset and read-only views of its arrays.
void bind_body(nb::module_& m) {
  nb::class_<Body>(m, "Body",
                   "A loaded asset: the runtime's collision object (bricked voxelmap, point-sphere tree, mass).\n\n"
                   "Array attributes are read-only NumPy views of the runtime's own memory (no copy), valid as long\n"
                   "as any of them or the Body is alive. Coordinates are metres in the asset frame.")
      .def_prop_ro(
          "points",
          [](nb::handle self) {
            const auto& t = nb::cast<const Body&>(self).object->point_tree();
            if (t.anchor.isZero())
              return nb::cast(
                  view<float>(t.points.empty() ? nullptr : t.points.front().data(), {t.size(), 3}, {3, 1}, self));
            // Held from the tree's anchor (far from the frame's origin): the asset frame's, as a copy.
            OutArray<float> out({t.size(), 3});
            for (size_t i = 0; i < t.size(); ++i)
              for (int a = 0; a < 3; ++a) out.data[3 * i + a] = float(t.asset_point(i)[a]);
            return nb::cast(out.array);
          },
          "(N, 3) float32 point shell, breadth-first tree order: level l is points[levels[l]:levels[l+1]] (a copy\n"
          "for a shell more than 16 times its size from the frame's origin, whose points the runtime holds from its\n"
          "centre).")
      .def_prop_ro(
          "normals",
          [](nb::handle self) {
            const auto& t = nb::cast<const Body&>(self).object->point_tree();
            return view<float>(t.normals.empty() ? nullptr : t.normals.front().data(), {t.size(), 3}, {3, 1}, self);
          },
          "(N, 3) float32 unit normals, pointing INTO the body.")
      .def_prop_ro(
          "levels",
          [](nb::handle self) {
            const auto& t = nb::cast<const Body&>(self).object->point_tree();
            return view<uint32_t>(t.level_offsets.data(), {t.level_offsets.size()}, {1}, self);
          },
          "(L+1,) uint32 offsets of the tree levels in points.")
      .def_prop_ro(
          "sphere_radii",
          [](nb::handle self) {
            const auto& t = nb::cast<const Body&>(self).object->point_tree();
            // A strided view of the packed tree nodes (no copy).
            constexpr int64_t stride = sizeof(voxfmt::runtime::PointTree::Node) / sizeof(float);
            return view<float>(t.nodes.empty() ? nullptr : &t.nodes.front().radius, {t.size()}, {stride}, self);
          },
          "(N,) float32 radius of each node's bounding sphere (the node and its descendants), metres.")
      .def_prop_ro(
          "voxel_size", [](const Body& b) { return b.object->voxelmap().voxel_size(); }, "Voxel edge, metres.")
      .def_prop_ro(
          "dims",
          [](const Body& b) {
            const auto& d = b.object->voxelmap().dims();
            return std::make_tuple(d[0], d[1], d[2]);
          },
          "Voxels along x, y, z.")
      .def_prop_ro(
          "density", [](const Body& b) { return b.density; }, "Density given to load(), kg/m^3.")
      .def_prop_ro(
          "volume", [](const Body& b) { return b.object->volume(); }, "Enclosed volume, m^3.")
      .def_prop_ro(
          "mass", [](const Body& b) { return b.object->volume() * b.density; }, "volume * density, kg.")
      .def_prop_ro(
          "center_of_mass", [](const Body& b) { return vector_array<double>(b.object->center_of_mass()); },
          "(3,) centre of mass in the asset frame, metres (a copy).", nb::rv_policy::automatic)
      .def_prop_ro(
          "inertia",
          [](const Body& b) {
            OutArray<double> out({3, 3});
            const Eigen::Matrix3d i = b.object->inertia_unit_density() * b.density;
            for (int r = 0; r < 3; ++r)
              for (int c = 0; c < 3; ++c) out.data[3 * r + c] = i(r, c);
            return out.array;
          },
          "(3, 3) inertia tensor about the centre of mass, asset axes, kg m^2 (a copy).", nb::rv_policy::automatic)
      .def_prop_ro(
          "bounds",
          [](const Body& b) {
            return std::make_tuple(vector_array<double>(b.object->bounds_min()),
                                   vector_array<double>(b.object->bounds_max()));
          },
          "(min (3,), max (3,)) bounding box in the asset frame, metres.", nb::rv_policy::automatic)
      .def_prop_ro(
          "path", [](const Body& b) { return fs_text(b.path); }, "The file it was loaded from.")
      .def_prop_ro("_absolute_path", [](const Body& b) { return fs_text(b.absolute_path); })
      .def_prop_ro("_max_memory_mib", [](const Body& b) { return b.max_memory_mib; })
      .def_prop_ro(
          "build_parameters", [](const Body& b) { return b.object->provenance().build_parameters_json; },
          "The bake's options that shaped the data, as the asset records them (a JSON object, text).")
      .def_prop_ro(
          "source_file", [](const Body& b) { return b.object->provenance().source_file; },
          "File name of the mesh the asset was baked from (no folder; empty if none).")
      .def_prop_ro(
          "build_warnings",
          [](const Body& b) {
            std::vector<std::tuple<std::string, std::string>> out;
            for (const auto& w : b.object->provenance().build_warnings) out.emplace_back(w.code, w.message);
            return out;
          },
          "The bake's warnings the asset records, as (code, message) pairs (e.g. SHELL_MODE, OPEN_BORDER).")
      .def_prop_ro(
          "memory_bytes", [](const Body& b) { return b.object->memory_bytes(); },
          "Heap bytes of the runtime structures.")
      .def("signed_distance", &signed_distance, "points"_a,
           nb::sig("def signed_distance(self, points: numpy.typing.ArrayLike) -> numpy.typing.NDArray[numpy.float64]"),
           "Signed distance (metres) of each asset-frame point (M, 3) to the surface: NEGATIVE INSIDE, positive\n"
           "outside (trimesh.proximity.signed_distance uses the opposite sign). Exact within the stored band\n"
           "(a few voxels of the surface; 15-bit fixed point), an estimate from the asset's lattice of exact\n"
           "distances beyond it (within 4*sqrt(3) voxels, spec section 3.1), and outside the grid a lower bound\n"
           "that continues the field without a jump: sqrt(t^2 + d^2), t the distance to the grid and d the value\n"
           "at its nearest point, and at least the distance to the bounding box.")
      .def("__repr__", [](const Body& b) {
        const auto& d = b.object->voxelmap().dims();
        return fs_text("<voxfmt.Body '" + b.path + "': " + std::to_string(b.object->point_tree().size()) + " points, " +
                       std::to_string(d[0]) + "x" + std::to_string(d[1]) + "x" + std::to_string(d[2]) + " voxels>");
      });
}

// QueryStats and Contacts: what a query found and traversed.
void bind_contacts(nb::module_& m) {
  nb::class_<voxfmt::runtime::QueryStats>(m, "QueryStats", "What a query traversed.")
      .def_ro("nodes_visited", &voxfmt::runtime::QueryStats::nodes_visited, "Sphere-tree nodes popped.")
      .def_ro("points_tested", &voxfmt::runtime::QueryStats::points_tested, "Points whose distance was looked up.")
      .def_ro("deepest_level", &voxfmt::runtime::QueryStats::deepest_level, "Deepest tree level completed.")
      .def_prop_ro(
          "levels_completed",
          [](const voxfmt::runtime::QueryStats& s) { return s.nodes_visited ? s.deepest_level + 1 : 0u; },
          "Tree levels completed (0 when the bodies are too far apart for any test).")
      .def_ro("time_budget_hit", &voxfmt::runtime::QueryStats::time_budget_hit,
              "A traversal stopped at time_budget_us.")
      .def("__repr__", [](const voxfmt::runtime::QueryStats& s) {
        return "QueryStats(nodes_visited=" + std::to_string(s.nodes_visited) +
               ", points_tested=" + std::to_string(s.points_tested) +
               ", deepest_level=" + std::to_string(s.deepest_level) +
               ", time_budget_hit=" + (s.time_budget_hit ? "True" : "False") + ")";
      });

  nb::class_<Contacts>(m, "Contacts",
                       "Contacts of one query, world frame. Array attributes are read-only views of the result\n"
                       "(no copy). normals point where A must move to separate; depths are positive when\n"
                       "penetrating (negative: proximity points).")
      .def("__len__", [](const Contacts& c) { return c.set.contacts.size(); })
      .def_prop_ro(
          "points",
          [](nb::handle self) {
            return contact_field<double>(
                self, [](const runtime::Contact& c) { return c.point.data(); }, 3);
          },
          "(M, 3) contact points (the shell point, on the surface of the body that carries it), metres.")
      .def_prop_ro(
          "normals",
          [](nb::handle self) {
            return contact_field<double>(
                self, [](const runtime::Contact& c) { return c.normal.data(); }, 3);
          },
          "(M, 3) unit normals: the direction in which A must move to separate from B.")
      .def_prop_ro(
          "depths",
          [](nb::handle self) {
            return contact_field<double>(
                self, [](const runtime::Contact& c) { return &c.depth; }, 1);
          },
          "(M,) penetration depths, metres (negative for proximity points).")
      .def_prop_ro(
          "point_index",
          [](nb::handle self) {
            return contact_field<uint32_t>(
                self, [](const runtime::Contact& c) { return &c.point_index; }, 1);
          },
          "(M,) index of the point in its body's points.")
      .def_prop_ro(
          "point_of_b",
          [](nb::handle self) {
            return contact_field<bool>(
                self, [](const runtime::Contact& c) { return &c.point_of_b; }, 1);
          },
          "(M,) True where the point is B's (tested in A's voxelmap).")
      .def_prop_ro(
          "max_depth", [](const Contacts& c) { return deepest_depth(c.set); },
          "Largest depth, metres (0.0 without contacts).")
      .def_prop_ro(
          "reference", [](const Contacts& c) { return vector_array<double>(c.reference); },
          "(3,) A's centre of mass in the world: wrench()'s default torque reference.", nb::rv_policy::automatic)
      .def_prop_ro(
          "stats", [](const Contacts& c) { return c.set.stats; }, "QueryStats of the traversal.")
      .def("__repr__", [](const Contacts& c) {
        return "<voxfmt.Contacts: " + std::to_string(c.set.contacts.size()) + " contacts, max depth " +
               std::to_string(deepest_depth(c.set)) + " m>";
      });
}

// load, contacts, wrench, contacts_batch and the Tracker of a pair.
void bind_queries(nb::module_& m) {
  m.def("load", &load, "path"_a.none(), nb::kw_only(), "density"_a = 1.0, "max_memory_mib"_a.none() = nb::none(),
        nb::sig("def load(path: str | os.PathLike[str], *, density: float = 1.0, max_memory_mib: int | None = None) "
                "-> Body"),
        "Loads an asset (.vox.h5) for queries. Raises voxfmt.AssetError (FILE_NOT_FOUND, NOT_HDF5, a validation\n"
        "code, ...) when it cannot be read or breaks a rule of the format (every rule of validate(level='full')),\n"
        "voxfmt.InternalError (OUT_OF_MEMORY) when reading it would need more than max_memory_mib (default 768),\n"
        "decided from the file's metadata before anything is read.");
  m.def("contacts", &query, "a"_a, "pose_a"_a, "b"_a, "pose_b"_a, nb::kw_only(), "point_budget"_a.none() = nb::none(),
        "time_budget_us"_a.none() = nb::none(), "proximity"_a = 0.0, "max_level"_a.none() = nb::none(),
        "cut_level"_a = "spheres", "interpolation"_a = "trilinear",
        nb::sig("def contacts(a: Body, pose_a: numpy.typing.ArrayLike, b: Body, pose_b: numpy.typing.ArrayLike, *, "
                "point_budget: int | None = None, time_budget_us: float | None = None, proximity: float = 0.0, "
                "max_level: int | None = None, cut_level: str = 'spheres', interpolation: str = 'trilinear') "
                "-> Contacts"),
        "Contacts between a and b placed by 4x4 rigid body-to-world poses (voxfmt.PoseError, code BAD_POSE,\n"
        "when not rigid). point_budget stops before the tree level that would exceed it; time_budget_us bounds\n"
        "each traversal; max_level is the deepest tree level tested (0: the root); proximity also reports points\n"
        "outside but closer than it (negative depth). A query stopped above the leaves reports its last level as\n"
        "cut_level says: 'spheres' (each point stands for its sphere: no contact of the full tree is lost, depths\n"
        "up to two radii deeper) or 'points' (each point only for itself, at its true depth: the seed's coarse\n"
        "shell). interpolation: 'trilinear' (8 voxels a point) or 'tricubic' (Catmull-Rom over 64 where they\n"
        "hold stored distances: a curved surface's depth and normal far nearer the exact ones, for haptic forces).");
  m.def("wrench", &wrench, "contacts"_a, "stiffness"_a, nb::kw_only(), "reference"_a = nb::none(),
        nb::sig("def wrench(contacts: Contacts, stiffness: float, *, reference: numpy.typing.ArrayLike | None = "
                "None) -> tuple[numpy.typing.NDArray[numpy.float64], numpy.typing.NDArray[numpy.float64]]"),
        "Penalty force (3,) and torque (3,) on A: F = sum k * depth * n over penetrating contacts, torque about\n"
        "`reference` (default: A's centre of mass in the world).");
  m.def("_contacts_batch", &contacts_batch, "a"_a, "poses_a"_a, "b"_a, "poses_b"_a, nb::kw_only(),
        "threads"_a.none() = nb::none(), "with_contacts"_a = false, "stiffness"_a = 1.0,
        "point_budget"_a.none() = nb::none(), "time_budget_us"_a.none() = nb::none(), "proximity"_a = 0.0,
        "tracker"_a.none() = nb::none(), "max_level"_a.none() = nb::none(), "cut_level"_a = "spheres",
        "interpolation"_a = "trilinear");
  nb::class_<Tracker>(m, "_Tracker")
      .def(
          "__init__",
          [](Tracker* t, const Body& a, const Body& b) {
            new (t) Tracker();
            t->a = a;
            t->b = b;
          },
          "a"_a, "b"_a)
      .def_prop_ro("a", [](const Tracker& t) { return t.a; })
      .def_prop_ro("b", [](const Tracker& t) { return t.b; })
      .def("_contacts", &tracked_query, "pose_a"_a, "pose_b"_a, "proximity"_a, "interpolation"_a = "trilinear")
      .def("reset", [](Tracker& t) {
        const std::unique_lock<std::mutex> lock = t.claim();
        t.state.reset();
      });
}

// bake::Settings by the names of `voxfmt build`'s options (dashes as underscores), defaults and all: the defaults
// live in bake::Settings alone, which the CLI's options and bake()'s keywords both read.
template <typename T>
void bake_setting(nb::class_<bake::Settings>& cls, std::vector<std::string>& names, const char* name,
                  T& (*field)(bake::Settings&)) {
  cls.def_prop_rw(
      name, [field](bake::Settings& s) { return field(s); }, [field](bake::Settings& s, T value) { field(s) = value; });
  names.emplace_back(name);
}

void bind_bake_settings(nb::module_& m) {
  using S = bake::Settings;
  nb::class_<S> cls(m, "_BakeSettings");
  cls.def(nb::init<>());
  std::vector<std::string> names;
  bake_setting<uint32_t>(cls, names, "resolution", [](S& s) -> uint32_t& { return s.voxelmap.resolution; });
  bake_setting<double>(cls, names, "voxel_size", [](S& s) -> double& { return s.voxelmap.voxel_size; });
  bake_setting<uint32_t>(cls, names, "points", [](S& s) -> uint32_t& { return s.point_shell.points; });
  bake_setting<double>(cls, names, "point_spacing", [](S& s) -> double& { return s.point_shell.point_spacing; });
  bake_setting<double>(cls, names, "branching", [](S& s) -> double& { return s.point_shell.branching; });
  bake_setting<uint32_t>(cls, names, "margin", [](S& s) -> uint32_t& { return s.voxelmap.margin; });
  bake_setting<double>(cls, names, "band", [](S& s) -> double& { return s.voxelmap.distance_band; });
  bake_setting<double>(cls, names, "shell_thickness", [](S& s) -> double& { return s.voxelmap.shell_thickness; });
  bake_setting<double>(cls, names, "unit_scale", [](S& s) -> double& { return s.import.unit_scale; });
  bake_setting<std::string>(cls, names, "up_axis", [](S& s) -> std::string& { return s.up_axis; });
  bake_setting<bool>(cls, names, "self_intersection_check", [](S& s) -> bool& { return s.check_self_intersections; });
  bake_setting<uint64_t>(cls, names, "seed", [](S& s) -> uint64_t& { return s.point_shell.seed; });
  bake_setting<int>(cls, names, "deflate", [](S& s) -> int& { return s.deflate; });
  bake_setting<unsigned>(cls, names, "threads", [](S& s) -> unsigned& { return s.threads; });
  // `--max-memory`, in MiB as there (0: the bake's default, 3/4 of this machine's memory).
  cls.def_prop_rw(
      "max_memory_mib", [](S& s) { return s.voxelmap.max_memory_bytes >> 20; },
      [](S& s, uint64_t mib) { s.voxelmap.max_memory_bytes = mib << 20; });
  names.emplace_back("max_memory_mib");
  cls.attr("names") = nb::cast(names);
}

// The bake, validate and inspect behind the package's Python wrappers; timing hooks.
void bind_pipeline(nb::module_& m) {
  bind_bake_settings(m);
  m.def("_bake", &bake, "mesh"_a, "output"_a, "settings"_a, "progress"_a.none());
  m.def(
      "_asset_is_current",
      [](nb::handle asset, nb::handle mesh, const bake::Settings& settings) {
        const std::string asset_path = path_arg(asset, "out_path"), mesh_path = path_arg(mesh, "mesh_path");
        nb::gil_scoped_release release;  // a hash of the whole mesh
        return bake::asset_is_current(asset_path, mesh_path, settings);
      },
      "asset"_a, "mesh"_a, "settings"_a);
  m.def("_validate", &validate, "path"_a, "full"_a, "max_memory_mib"_a.none());
  m.def("_inspect", &inspect, "path"_a, "max_memory_mib"_a.none());
  m.def("_time_query", &time_query, "a"_a, "pose_a"_a, "b"_a, "pose_b"_a, "iterations"_a, "point_budget"_a.none(),
        "time_budget_us"_a.none(), "proximity"_a);
  m.def("_library_version", [] { return std::string(VOXFMT_VERSION_STRING); });
  m.def("read_mesh", &read_mesh, "path"_a.none(), nb::kw_only(), "unit_scale"_a = 1.0,
        nb::sig("def read_mesh(path: str | os.PathLike[str], *, unit_scale: float = 1.0) -> "
                "tuple[numpy.typing.NDArray[numpy.float64], numpy.typing.NDArray[numpy.uint32]]"),
        "A mesh file as `voxfmt build` imports it (any format assimp reads, all meshes of a scene merged with their\n"
        "node transforms, coordinates times unit_scale; no repair): (vertices (V, 3) float64 metres, triangles\n"
        "(T, 3) uint32). With an asset's recorded unit_scale it is the surface in the asset's frame.");
}

}  // namespace

}  // namespace voxfmt::python

NB_MODULE(_voxfmt, m) {
  using namespace voxfmt::python;
  m.doc() = "Compiled core of the voxfmt package; use the names re-exported by `voxfmt`.";
  bind_errors();
  bind_body(m);
  bind_contacts(m);
  bind_queries(m);
  bind_pipeline(m);
  bind_batch(m);
  bind_engines(m);
}
