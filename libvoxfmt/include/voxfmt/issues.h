// Validation findings. Codes and severities are the stable contract of spec/issue-codes.md.
#pragma once

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
};

enum class Severity { Error, Warning, Info };

/// UPPER_SNAKE name of a code, as written in spec/issue-codes.md.
const char* code_name(IssueCode code);
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
