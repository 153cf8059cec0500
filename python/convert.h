// Conversions between the library's types and Python's, shared by the binding files of the
// `slshadow` module (python/module.cc). Internal to python/.
//
// Memory: arrays handed to Python share memory with C++ where the C++ object's lifetime can follow
// the array's (cv::Mat is reference counted; a std::vector is moved into a capsule the array
// owns); arrays read from Python are viewed in place for the duration of one call (no copy) when
// they are C-contiguous and of the expected dtype, and copied otherwise.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/progress.h"
#include "core/rigid3.h"

namespace slshadow::python {

namespace py = pybind11;

// An array over the Mat's pixels (shape (rows, cols) or (rows, cols, channels), the Mat's strides),
// keeping the Mat's buffer alive through a reference-counted copy of its header: no pixel copy.
py::array MatToArray(const cv::Mat& mat);

// A cv::Mat header over a 2-D uint8 or uint16 array's buffer (no copy when it is C-contiguous;
// else over a contiguous copy, held by `keep`). Throws slshadow::Error naming `what` on another
// dtype or rank. The array (and `keep`) must outlive the Mat.
cv::Mat ImageFromArray(const py::array& array, const std::string& what, py::object* keep);

// A stack of images: a 3-D uint8/uint16 array (N, H, W) or a sequence of 2-D arrays. Returns one
// Mat header per image; `keep` collects the buffers the headers point into.
std::vector<cv::Mat> ImagesFromObject(const py::handle& object, const std::string& what,
                                      std::vector<py::object>* keep);

// The images stacked into one (N, H, W) array (one copy; Mats from the library are not contiguous
// with each other). All must have the same size and type.
py::array StackImages(const std::vector<cv::Mat>& images);

// A vector of fixed-size rows (Eigen::Vector3d, std::array<uint8_t, 3>, float, ...) moved into an
// array of shape (n, cols) (cols 0: shape (n,)) owned by the array: no copy.
template <typename Scalar, typename Row>
py::array VectorToArray(std::vector<Row>&& rows, size_t cols) {
  static_assert(sizeof(Row) == sizeof(Scalar) * (sizeof(Row) / sizeof(Scalar)));
  auto* owned = new std::vector<Row>(std::move(rows));
  py::capsule base(owned, [](void* p) { delete static_cast<std::vector<Row>*>(p); });
  const auto n = static_cast<py::ssize_t>(owned->size());
  const auto* data = reinterpret_cast<const Scalar*>(owned->data());
  if (cols == 0) return py::array_t<Scalar>({n}, data, base);
  return py::array_t<Scalar>({n, static_cast<py::ssize_t>(cols)}, data, base);
}

// A read-only array viewing `data` (shape (n, cols), or (n,) when cols is 0) that keeps `owner`
// (a Python object holding the C++ data) alive.
template <typename Scalar>
py::array ViewArray(const Scalar* data, size_t n, size_t cols, const py::handle& owner) {
  py::array out =
      cols == 0 ? py::array_t<Scalar>({static_cast<py::ssize_t>(n)}, data, owner)
                : py::array_t<Scalar>({static_cast<py::ssize_t>(n), static_cast<py::ssize_t>(cols)},
                                      data, owner);
  out.attr("setflags")(py::arg("write") = false);
  return out;
}

// Runs f() (a config reader given `source` as its file name); an slshadow::Error whose message
// starts with "<source>: " is rethrown without it, so that a keyword option's message is the
// command line's for the same value, word for word (the checks are the same code). Messages of
// Python-only mistakes (an unknown keyword, a value of the wrong Python type) keep the call's name.
template <typename F>
auto WithoutSource(const std::string& source, F&& f) -> decltype(f()) {
  try {
    return f();
  } catch (const Error& e) {
    const std::string message = e.what();
    const std::string prefix = source + ": ";
    if (message.rfind(prefix, 0) == 0) throw Error(message.substr(prefix.size()));
    throw;
  }
}

// The transform as a 4x4 matrix (a new array).
py::array Matrix4(const Rigid3d& transform);

// JSON <-> Python values (dict, list, str, int, float, bool, None). Python floats that are
// infinite become "inf" (the config files' spelling of a disabled gate); numpy scalars and arrays
// become numbers and lists. Throws slshadow::Error naming `what` on other types.
nlohmann::json ToJson(const py::handle& object, const std::string& what);
py::object FromJson(const nlohmann::json& json);

// The optional progress callback of long calls: fn(stage: str, done: int, total: int), called
// with the GIL held (acquired by whichever thread reports: the calling thread, which has released
// it, or a worker thread of the library). None: no calls. An exception raised by the callback
// propagates out of the call.
class ProgressCallback {
 public:
  explicit ProgressCallback(py::object fn) : fn_(std::move(fn)) {}
  void operator()(const std::string& stage, int64_t done, int64_t total) const;
  bool active() const { return !fn_.is_none(); }

 private:
  py::object fn_;
};

// While alive (construct it on the calling thread, GIL held or not), the library's own progress
// made on this thread (core/progress.h: per camera traced, image rendered, camera decoded, ...)
// reaches `callback` as (task, done, total), done increasing within each run of a task; with
// `only`, the tasks of that name only (a sweep's jobs, not each job's own rendering). Nothing when
// the callback is None.
class ForwardLibraryProgress {
 public:
  explicit ForwardLibraryProgress(const ProgressCallback& callback, std::string only = "") {
    if (callback.active())
      scope_.emplace([&callback, only = std::move(only)](const std::string& task, int64_t done,
                                                         int64_t total) {
        if (only.empty() || task == only) callback(task, done, total);
      });
  }

 private:
  std::optional<ScopedProgressObserver> scope_;
};

}  // namespace slshadow::python
