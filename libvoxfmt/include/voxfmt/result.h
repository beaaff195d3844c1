// Errors of libvoxfmt: every fallible call returns a Result; nothing throws across the API.
#pragma once

#include <string>
#include <utility>
#include <variant>

#include "voxfmt/issues.h"

namespace voxfmt {

/// What went wrong: a stable code (spec/issue-codes.md) and a message naming the file, the HDF5 object and
/// the reason.
struct Error {
  IssueCode code = IssueCode::ReadFailed;
  std::string message;
};

template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : state_(std::move(value)) {}         // NOLINT(google-explicit-constructor)
  Result(Error error) : state_(std::move(error)) {}     // NOLINT(google-explicit-constructor)
  bool ok() const { return state_.index() == 0; }
  explicit operator bool() const { return ok(); }
  T& value() & { return std::get<0>(state_); }
  const T& value() const& { return std::get<0>(state_); }
  T&& value() && { return std::get<0>(std::move(state_)); }
  const Error& error() const { return std::get<1>(state_); }

 private:
  std::variant<T, Error> state_;
};

/// Result of a call that produces nothing but may fail.
struct Status {
  static Status success() { return Status{}; }
  Status() = default;
  Status(Error e) : error_(std::move(e)), failed_(true) {}  // NOLINT(google-explicit-constructor)
  bool ok() const { return !failed_; }
  explicit operator bool() const { return ok(); }
  const Error& error() const { return error_; }

 private:
  Error error_;
  bool failed_ = false;
};

}  // namespace voxfmt
