#include "python/convert.h"

#include <cmath>
#include <cstring>

#include "core/error.h"

namespace slshadow::python {

namespace {

std::string NumpyFormat(int depth) {
  switch (depth) {
    case CV_8U:
      return py::format_descriptor<uint8_t>::format();
    case CV_8S:
      return py::format_descriptor<int8_t>::format();
    case CV_16U:
      return py::format_descriptor<uint16_t>::format();
    case CV_16S:
      return py::format_descriptor<int16_t>::format();
    case CV_32S:
      return py::format_descriptor<int32_t>::format();
    case CV_32F:
      return py::format_descriptor<float>::format();
    case CV_64F:
      return py::format_descriptor<double>::format();
    default:
      SLSHADOW_THROW("image of unsupported OpenCV depth ", depth);
  }
}

}  // namespace

py::array MatToArray(const cv::Mat& mat) {
  if (mat.empty()) return py::array_t<uint8_t>(std::vector<py::ssize_t>{0, 0});
  auto* owned = new cv::Mat(mat);
  py::capsule base(owned, [](void* p) { delete static_cast<cv::Mat*>(p); });
  const auto elem = static_cast<py::ssize_t>(mat.elemSize1());
  std::vector<py::ssize_t> shape{mat.rows, mat.cols};
  std::vector<py::ssize_t> strides{static_cast<py::ssize_t>(mat.step[0]),
                                   static_cast<py::ssize_t>(mat.elemSize())};
  if (mat.channels() > 1) {
    shape.push_back(mat.channels());
    strides.push_back(elem);
  }
  return py::array(py::dtype(NumpyFormat(mat.depth())), shape, strides, owned->data, base);
}

cv::Mat ImageFromArray(const py::array& array, const std::string& what, py::object* keep) {
  SLSHADOW_THROW_IF(array.ndim() != 2, what, ": expected a 2-D image array (rows, cols) (got ",
                    array.ndim(), " dimensions)");
  int type = -1;
  if (py::isinstance<py::array_t<uint8_t>>(array)) type = CV_8UC1;
  if (py::isinstance<py::array_t<uint16_t>>(array)) type = CV_16UC1;
  SLSHADOW_THROW_IF(type < 0, what, ": expected dtype uint8 or uint16 (got ",
                    std::string(py::str(array.dtype())), ")");
  py::array contiguous = array;
  if (!(array.flags() & py::array::c_style)) {
    contiguous = py::array::ensure(array, py::array::c_style | py::array::forcecast);
  }
  *keep = contiguous;
  return cv::Mat(static_cast<int>(contiguous.shape(0)), static_cast<int>(contiguous.shape(1)), type,
                 const_cast<void*>(contiguous.data()));
}

std::vector<cv::Mat> ImagesFromObject(const py::handle& object, const std::string& what,
                                      std::vector<py::object>* keep) {
  std::vector<cv::Mat> images;
  if (py::isinstance<py::array>(object)) {
    const py::array stack = py::reinterpret_borrow<py::array>(object);
    if (stack.ndim() == 3) {
      for (py::ssize_t i = 0; i < stack.shape(0); ++i) {
        py::object held;
        const py::object item = stack[py::int_(i)];
        const py::array slice = py::array::ensure(item);
        images.push_back(ImageFromArray(slice, what + "[" + std::to_string(i) + "]", &held));
        keep->push_back(std::move(held));
      }
      return images;
    }
    SLSHADOW_THROW(what, ": expected an (N, rows, cols) array or a list of 2-D arrays (got ",
                   stack.ndim(), " dimensions)");
  }
  SLSHADOW_THROW_IF(!py::isinstance<py::sequence>(object) || py::isinstance<py::str>(object), what,
                    ": expected an (N, rows, cols) array or a list of 2-D arrays (got ",
                    std::string(py::str(py::type::of(object))), ")");
  size_t i = 0;
  for (const py::handle item : object) {
    py::object held;
    images.push_back(
        ImageFromArray(py::array::ensure(item), what + "[" + std::to_string(i) + "]", &held));
    keep->push_back(std::move(held));
    ++i;
  }
  return images;
}

py::array StackImages(const std::vector<cv::Mat>& images) {
  if (images.empty()) return py::array_t<uint8_t>(std::vector<py::ssize_t>{0, 0, 0});
  const cv::Mat& first = images.front();
  const auto rows = static_cast<py::ssize_t>(first.rows);
  const auto cols = static_cast<py::ssize_t>(first.cols);
  py::array out(py::dtype(NumpyFormat(first.depth())),
                std::vector<py::ssize_t>{static_cast<py::ssize_t>(images.size()), rows, cols});
  const size_t row_bytes = static_cast<size_t>(cols) * first.elemSize();
  auto* dst = static_cast<uint8_t*>(out.mutable_data());
  for (const cv::Mat& image : images) {
    SLSHADOW_CHECK(image.size() == first.size() && image.type() == first.type());
    for (int r = 0; r < image.rows; ++r) {
      std::memcpy(dst, image.ptr(r), row_bytes);
      dst += row_bytes;
    }
  }
  return out;
}

py::array Matrix4(const Rigid3d& transform) {
  const Eigen::Matrix4d m = transform.ToMatrix();
  py::array_t<double> out({4, 4});
  auto v = out.mutable_unchecked<2>();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) v(r, c) = m(r, c);
  return out;
}

nlohmann::json ToJson(const py::handle& object, const std::string& what) {
  if (object.is_none()) return nullptr;
  if (py::isinstance<py::bool_>(object)) return object.cast<bool>();
  if (py::isinstance<py::int_>(object)) return object.cast<int64_t>();
  if (py::isinstance<py::float_>(object)) {
    const double v = object.cast<double>();
    if (std::isinf(v) && v > 0) return "inf";
    return v;
  }
  if (py::isinstance<py::str>(object)) return object.cast<std::string>();
  if (py::isinstance<py::dict>(object)) {
    nlohmann::json out = nlohmann::json::object();
    for (const auto& [key, value] : py::reinterpret_borrow<py::dict>(object)) {
      const std::string name = py::str(key);
      out[name] = ToJson(value, what + "." + name);
    }
    return out;
  }
  // numpy scalars and arrays: through their Python values.
  if (py::hasattr(object, "tolist") && py::hasattr(object, "dtype")) {
    return ToJson(object.attr("tolist")(), what);
  }
  if (py::isinstance<py::sequence>(object)) {
    nlohmann::json out = nlohmann::json::array();
    size_t i = 0;
    for (const py::handle item : object) {
      out.push_back(ToJson(item, what + "[" + std::to_string(i) + "]"));
      ++i;
    }
    return out;
  }
  SLSHADOW_THROW(what, ": expected a number, string, bool, list or dict (got ",
                 std::string(py::str(py::type::of(object))), ")");
}

py::object FromJson(const nlohmann::json& json) {
  // Leaked on purpose: a static py::object would be released after the interpreter is gone.
  static const py::object* loads = new py::object(py::module_::import("json").attr("loads"));
  return (*loads)(json.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace));
}

void ProgressCallback::operator()(const std::string& stage, int64_t done, int64_t total) const {
  py::gil_scoped_acquire gil;
  if (fn_.is_none()) return;
  fn_(stage, done, total);
}

}  // namespace slshadow::python
