// The `slshadow` Python module (pybind11): the project's libraries with numpy in and out.
// Built as slshadow/_slshadow; slshadow/__init__.py re-exports it (docs/python.md).
#include <pybind11/pybind11.h>

#include "core/error.h"
#include "python/bindings.h"

PYBIND11_MODULE(_slshadow, m) {
  namespace py = pybind11;
  m.doc() =
      "slshadow: structured-light scanning and its digital shadow. Rig, PatternSpec, ImageSet, "
      "simulate, decode, reconstruct, compare; units mm, rad, px; docs/python.md.";
  // Bad input raises slshadow.Error with the command line's one-line message (the text after
  // "slshadow: error: ").
  static py::exception<slshadow::Error> error(m, "Error", PyExc_ValueError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const slshadow::Error& e) {
      PyErr_SetString(error.ptr(), e.what());
    }
  });
  slshadow::python::BindCore(m);
  slshadow::python::BindPatternsAndSim(m);
  slshadow::python::BindReconstructAndCompare(m);
  slshadow::python::BindShadow(m);
  slshadow::python::BindSweep(m);
  slshadow::python::BindCalibrate(m);
#ifdef SLSHADOW_VERSION
  m.attr("__version__") = SLSHADOW_VERSION;
#endif
}
