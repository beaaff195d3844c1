// The one error model of every voxfmt library: fallible calls return Result<T> or Status carrying an Error
// (a stable code of spec/issue-codes.md, a message, and where it happened). Nothing throws across the API but
// what docs/architecture.md lists: here, reading the value of a failed Result (or the error of a successful
// one) without checking ok() first.
#pragma once

#include <cstdlib>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <variant>
#include <vector>

namespace voxfmt {

// ---- Codes of findings and errors. Codes and severities are the stable contract of spec/issue-codes.md: validation
// findings, and the errors of every library call (reading, writing, baking, exporting, batch runs).
enum class IssueCode {
  FileNotFound,
  NotHdf5,
  ReadFailed,
  WriteFailed,
  FormatNameMismatch,
  VersionUnsupported,
  VersionNewerMinor,
  MissingObject,
  WrongKind,
  WrongDtype,
  WrongShape,
  BadAttributeValue,
  ValueOutOfRange,
  NonFiniteValue,
  ChildRangeInvalid,
  LevelOffsetsInvalid,
  TreeNotBreadthFirst,
  InvalidJson,
  BadSha256,
  NormalNotUnit,
  UnknownObject,
  LayerDistanceMismatch,
  LayerOutsideBandTooSmall,
  LayerStepTooLarge,
  DistanceJump,
  NormalNotInward,
  SphereNotEnclosing,
  InertiaNotPositiveDefinite,
  CenterOfMassOutsideBounds,
  DistanceOutsideBand,
  EstimateMismatch,
  SignMismatch,
  StringNotUtf8,
  LatticeMismatch,
  PointOffSurface,
  // Errors of the bake, the exports and batch runs (never validation findings).
  InputNotFound,
  UnsupportedFormat,
  ImportFailed,
  RepairFailed,
  EmptyScene,
  NonFiniteCoordinates,
  ZeroVolume,
  GridTooLarge,
  ScaleOutOfRange,
  InvalidAsset,
  OutOfMemory,
  BadOption,
  BadPose,
  Timeout,
  Crashed,
  Internal,
};

enum class Severity { Error, Warning, Info };

/// UPPER_SNAKE name of a code, as written in spec/issue-codes.md.
const char* code_name(IssueCode code);
/// The code of an UPPER_SNAKE name (as found in manifests and JSON reports), if it is one.
std::optional<IssueCode> code_from_name(const std::string& name);
const char* severity_name(Severity severity);
/// The severity a code always has.
Severity severity_of(IssueCode code);

struct Issue {
  IssueCode code;
  Severity severity;
  std::string path;  ///< HDF5 object path the finding concerns ("/" for the file itself)
  std::string message;
};

inline bool has_errors(const std::vector<Issue>& issues) {
  for (const Issue& issue : issues)
    if (issue.severity == Severity::Error) return true;
  return false;
}

// ---- The error model.

/// What went wrong. `message` is a complete sentence for a person (it names the file and the reason);
/// `code` is for programs (stable, spec/issue-codes.md); `file` and `object` locate it for tools.
struct Error {
  IssueCode code = IssueCode::Internal;
  std::string message;
  std::string file;    ///< the file concerned (asset, mesh, export), if any
  std::string object;  ///< the HDF5 object in `file` ("/voxelmap/layers"), if any

  Error() = default;
  Error(IssueCode c, std::string m, std::string f = {}, std::string o = {})
      : code(c), message(std::move(m)), file(std::move(f)), object(std::move(o)) {}
  /// "CODE: message", for logs.
  std::string describe() const { return std::string(code_name(code)) + ": " + message; }
};

/// Thrown by Result::value() of a failed result (a caller that did not check ok()): carries the error, and its
/// what() is the error's describe(), so an unchecked failure still says what failed. Also by the error() of
/// a Result or Status that succeeded (INTERNAL).
class BadResultAccess : public std::logic_error {
 public:
  explicit BadResultAccess(Error e) : std::logic_error(e.describe()), error_(std::move(e)) {}
  const Error& error() const { return error_; }

 private:
  Error error_;
};

namespace detail {
// Built without exceptions, a caller that did not check ends the program instead (std::get did too).
[[noreturn]] inline void fail_access(const BadResultAccess& e) {
#if defined(__cpp_exceptions)
  throw e;
#else
  (void)e;
  std::abort();
#endif
}
}  // namespace detail

template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : state_(std::move(value)) {}      // NOLINT(google-explicit-constructor)
  Result(Error error) : state_(std::move(error)) {}  // NOLINT(google-explicit-constructor)
  bool ok() const { return state_.index() == 0; }
  explicit operator bool() const { return ok(); }
  /// The value; throws BadResultAccess (with the error) when the call failed.
  T& value() & { return checked(), std::get<0>(state_); }
  const T& value() const& { return checked(), std::get<0>(state_); }
  T&& value() && { return checked(), std::get<0>(std::move(state_)); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  /// The error; throws BadResultAccess (INTERNAL) when the call succeeded.
  const Error& error() const {
    if (ok())
      detail::fail_access(
          BadResultAccess(Error{IssueCode::Internal, "voxfmt::Result::error() of a successful result"}));
    return std::get<1>(state_);
  }

 private:
  void checked() const {
    if (!ok()) detail::fail_access(BadResultAccess(std::get<1>(state_)));
  }
  std::variant<T, Error> state_;
};

/// Result of a call that produces nothing but may fail.
class [[nodiscard]] Status {
 public:
  static Status success() { return Status{}; }
  Status() = default;
  Status(Error e) : error_(std::move(e)), failed_(true) {}  // NOLINT(google-explicit-constructor)
  bool ok() const { return !failed_; }
  explicit operator bool() const { return ok(); }
  /// The error; throws BadResultAccess (INTERNAL) when the call succeeded, as Result::error() does.
  const Error& error() const {
    if (ok()) detail::fail_access(BadResultAccess(Error{IssueCode::Internal, "voxfmt::Status::error() of a success"}));
    return error_;
  }

 private:
  Error error_;
  bool failed_ = false;
};

}  // namespace voxfmt
