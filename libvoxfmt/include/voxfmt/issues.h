// Codes of findings and errors. Codes and severities are the stable contract of spec/issue-codes.md: validation
// findings, and the errors of every library call (reading, writing, baking, exporting, batch runs).
#pragma once

#include <optional>
#include <string>
#include <vector>

namespace voxfmt {

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

}  // namespace voxfmt
