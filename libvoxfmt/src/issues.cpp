#include "voxfmt/result.h"

namespace voxfmt {

namespace {
struct CodeInfo {
  IssueCode code;
  const char* name;
  Severity severity;
};
// One row per code of spec/issue-codes.md.
constexpr CodeInfo kCodes[] = {
    {IssueCode::FileNotFound, "FILE_NOT_FOUND", Severity::Error},
    {IssueCode::NotHdf5, "NOT_HDF5", Severity::Error},
    {IssueCode::ReadFailed, "READ_FAILED", Severity::Error},
    {IssueCode::WriteFailed, "WRITE_FAILED", Severity::Error},
    {IssueCode::FormatNameMismatch, "FORMAT_NAME_MISMATCH", Severity::Error},
    {IssueCode::VersionUnsupported, "VERSION_UNSUPPORTED", Severity::Error},
    {IssueCode::VersionNewerMinor, "VERSION_NEWER_MINOR", Severity::Warning},
    {IssueCode::MissingObject, "MISSING_OBJECT", Severity::Error},
    {IssueCode::WrongKind, "WRONG_KIND", Severity::Error},
    {IssueCode::WrongDtype, "WRONG_DTYPE", Severity::Error},
    {IssueCode::WrongShape, "WRONG_SHAPE", Severity::Error},
    {IssueCode::BadAttributeValue, "BAD_ATTRIBUTE_VALUE", Severity::Error},
    {IssueCode::ValueOutOfRange, "VALUE_OUT_OF_RANGE", Severity::Error},
    {IssueCode::NonFiniteValue, "NON_FINITE_VALUE", Severity::Error},
    {IssueCode::ChildRangeInvalid, "CHILD_RANGE_INVALID", Severity::Error},
    {IssueCode::LevelOffsetsInvalid, "LEVEL_OFFSETS_INVALID", Severity::Error},
    {IssueCode::TreeNotBreadthFirst, "TREE_NOT_BREADTH_FIRST", Severity::Error},
    {IssueCode::InvalidJson, "INVALID_JSON", Severity::Error},
    {IssueCode::BadSha256, "BAD_SHA256", Severity::Error},
    {IssueCode::NormalNotUnit, "NORMAL_NOT_UNIT", Severity::Error},
    {IssueCode::UnknownObject, "UNKNOWN_OBJECT", Severity::Info},
    {IssueCode::LayerDistanceMismatch, "LAYER_DISTANCE_MISMATCH", Severity::Error},
    {IssueCode::LayerOutsideBandTooSmall, "LAYER_OUTSIDE_BAND_TOO_SMALL", Severity::Error},
    {IssueCode::LayerStepTooLarge, "LAYER_STEP_TOO_LARGE", Severity::Error},
    {IssueCode::DistanceJump, "DISTANCE_JUMP", Severity::Error},
    {IssueCode::NormalNotInward, "NORMAL_NOT_INWARD", Severity::Warning},
    {IssueCode::SphereNotEnclosing, "SPHERE_NOT_ENCLOSING", Severity::Error},
    {IssueCode::InertiaNotPositiveDefinite, "INERTIA_NOT_POSITIVE_DEFINITE", Severity::Error},
    {IssueCode::CenterOfMassOutsideBounds, "CENTER_OF_MASS_OUTSIDE_BOUNDS", Severity::Error},
    {IssueCode::DistanceOutsideBand, "DISTANCE_OUTSIDE_BAND", Severity::Error},
    {IssueCode::EstimateMismatch, "ESTIMATE_MISMATCH", Severity::Error},
    {IssueCode::SignMismatch, "SIGN_MISMATCH", Severity::Error},
    {IssueCode::StringNotUtf8, "STRING_NOT_UTF8", Severity::Error},
    {IssueCode::LatticeMismatch, "LATTICE_MISMATCH", Severity::Error},
    {IssueCode::PointOffSurface, "POINT_OFF_SURFACE", Severity::Error},
    {IssueCode::InputNotFound, "INPUT_NOT_FOUND", Severity::Error},
    {IssueCode::UnsupportedFormat, "UNSUPPORTED_FORMAT", Severity::Error},
    {IssueCode::ImportFailed, "IMPORT_FAILED", Severity::Error},
    {IssueCode::RepairFailed, "REPAIR_FAILED", Severity::Error},
    {IssueCode::EmptyScene, "EMPTY_SCENE", Severity::Error},
    {IssueCode::NonFiniteCoordinates, "NON_FINITE_COORDINATES", Severity::Error},
    {IssueCode::ZeroVolume, "ZERO_VOLUME", Severity::Error},
    {IssueCode::GridTooLarge, "GRID_TOO_LARGE", Severity::Error},
    {IssueCode::ScaleOutOfRange, "SCALE_OUT_OF_RANGE", Severity::Error},
    {IssueCode::InvalidAsset, "INVALID_ASSET", Severity::Error},
    {IssueCode::OutOfMemory, "OUT_OF_MEMORY", Severity::Error},
    {IssueCode::BadOption, "BAD_OPTION", Severity::Error},
    {IssueCode::BadPose, "BAD_POSE", Severity::Error},
    {IssueCode::Timeout, "TIMEOUT", Severity::Error},
    {IssueCode::Crashed, "CRASHED", Severity::Error},
    {IssueCode::Internal, "INTERNAL", Severity::Error},
};
const CodeInfo& info(IssueCode code) {
  for (const CodeInfo& c : kCodes)
    if (c.code == code) return c;
  return kCodes[2];  // unreachable: every enumerator has a row
}
}  // namespace

const char* code_name(IssueCode code) { return info(code).name; }
std::optional<IssueCode> code_from_name(const std::string& name) {
  for (const CodeInfo& c : kCodes)
    if (name == c.name) return c.code;
  return std::nullopt;
}
Severity severity_of(IssueCode code) { return info(code).severity; }
const char* severity_name(Severity severity) {
  switch (severity) {
    case Severity::Error:
      return "error";
    case Severity::Warning:
      return "warning";
    case Severity::Info:
      return "info";
  }
  return "error";
}

}  // namespace voxfmt
