// The binding files of the `slshadow` Python module, one per area, each registering its classes
// and functions on the module (python/module.cc calls them in this order, so that a type is
// registered before a later signature names it). Internal to python/.
#pragma once

#include <memory>
#include <string>

#include <pybind11/pybind11.h>

#include "core/image_set.h"
#include "core/point_cloud.h"
#include "patterns/pattern_spec.h"

namespace slshadow::python {

namespace py = pybind11;

// Rig, CameraModel, Device, PointCloud (read_ply / write_ply), Scene, ImageSet, write_image_set.
void BindCore(py::module_& m);
// PatternSpec, ProjectorMap, decode, simulate (Scan).
void BindPatternsAndSim(py::module_& m);
// reconstruct (Reconstruction), compare (Reference, Comparison).
void BindReconstructAndCompare(py::module_& m);

// A PatternSpec from a Python argument: a PatternSpec, a dict (the fields of PatternSpecToJson) or
// a path to a .yaml/.json spec. Throws slshadow::Error naming `what`.
PatternSpec PatternSpecFromObject(const py::handle& object, const std::string& what);

// The ImageSet behind the Python class (kept with the folder it was opened from).
struct PyImageSet {
  ImageSet image_set;
};

}  // namespace slshadow::python
