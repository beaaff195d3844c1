// What the binding's sources share (module.cpp, batch.cpp): the error on its way to Python, output arrays, and
// the loaded asset a Python Body holds.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <algorithm>
#include <chrono>
#include <initializer_list>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "voxfmt/result.h"
#include "voxfmt/runtime/collision_object.h"
#include "voxfmt/runtime/query.h"

namespace voxfmt::python {

namespace nb = nanobind;

/// A library error on its way to Python (see the translator in NB_MODULE).
struct CodedError : std::exception {
  Error error;
  explicit CodedError(Error e) : error(std::move(e)) {}
  const char* what() const noexcept override { return error.message.c_str(); }
};

[[noreturn]] inline void fail(IssueCode code, std::string message) {
  throw CodedError(Error{code, std::move(message)});
}

/// Python's name of a reading ('trilinear' or 'tricubic'), as QueryOptions::interpolation; BAD_OPTION otherwise.
inline runtime::Interpolation interpolation_of(const std::string& name) {
  if (name == "tricubic") return runtime::Interpolation::Tricubic;
  if (name != "trilinear")
    fail(IssueCode::BadOption, "interpolation must be 'trilinear' or 'tricubic', not '" + name + "'");
  return runtime::Interpolation::Trilinear;
}

/// A NumPy array of `shape` the binding fills (zeroed), owned by Python once returned.
template <class T>
struct OutArray {
  T* data = nullptr;
  nb::ndarray<nb::numpy, T> array;
  OutArray(std::initializer_list<size_t> shape) {
    size_t n = 1;
    for (size_t s : shape) n *= s;
    data = new T[std::max<size_t>(n, 1)]();
    nb::capsule owner(data, [](void* p) noexcept { delete[] static_cast<T*>(p); });
    array = nb::ndarray<nb::numpy, T>(data, shape, owner);
  }
};

/// Ctrl-C in a long call that has released the GIL: Python only notes the signal, so without a look the call ran
/// to its end (minutes for a big batch). Called from the call's workers, it acts on the calling thread only (a
/// batch's worker 0; only the main thread handles signals), at most every 20 ms: takes the GIL, and throws the
/// handler's exception (KeyboardInterrupt), which stops the workers and is raised from the call.
class SignalCheck {
 public:
  void operator()() {
    if (std::this_thread::get_id() != caller_) return;
    const auto now = std::chrono::steady_clock::now();
    if (now < next_) return;
    next_ = now + std::chrono::milliseconds(20);
    nb::gil_scoped_acquire gil;
    if (PyErr_CheckSignals() != 0) throw nb::python_error();
  }

 private:
  std::thread::id caller_ = std::this_thread::get_id();
  std::chrono::steady_clock::time_point next_ = std::chrono::steady_clock::now() + std::chrono::milliseconds(20);
};

/// A loaded asset as Python holds it (voxfmt.Body).
struct Body {
  std::shared_ptr<const runtime::CollisionObject> object;
  double density = 1.0;
  std::string path;
  /// What a pickled Body loads again: the file as the load found it (a relative path against the working directory
  /// then, not at pickling), and the same memory budget.
  std::string absolute_path;
  std::optional<int64_t> max_memory_mib;
};

/// Binds the batched queries of every environment (batch.cpp): the CPU path, and the CUDA one where built.
void bind_batch(nb::module_& m);
/// Binds the engine layouts of a loaded asset (engines.cpp): Newton's texture SDF, NanoVDB grids.
void bind_engines(nb::module_& m);

}  // namespace voxfmt::python
