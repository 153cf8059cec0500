// The binding files of the `slshadow` Python module, one per area, each registering its classes
// and functions on the module (python/module.cc calls them in this order, so that a type is
// registered before a later signature names it). Internal to python/.
#pragma once

#include <memory>
#include <string>

#include <pybind11/pybind11.h>

#include "core/image_set.h"
#include "core/point_cloud.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct_image_set.h"

namespace slshadow::python {

namespace py = pybind11;

// Rig, CameraModel, Device, PointCloud (read_ply / write_ply), Scene, ImageSet, write_image_set.
void BindCore(py::module_& m);
// PatternSpec, ProjectorMap, decode, simulate (Scan).
void BindPatternsAndSim(py::module_& m);
// reconstruct (Reconstruction), compare (Reference, Comparison).
void BindReconstructAndCompare(py::module_& m);
// shadow (real vs virtual); _sweep (a study planned, run and merged; slshadow.sweep adds tables).
void BindShadow(py::module_& m);
void BindSweep(py::module_& m);
// calibrate_camera | stereo | projector | rig | corners, detect_target (bind_calibrate.cc).
void BindCalibrate(py::module_& m);

// Keyword arguments -> reconstruction options: the ReconstructOptions and DecodeOptions fields
// through their config readers, mode and cameras (only with a rig; mode "auto":
// DefaultReconstructMode), then Check(). Messages: the command line's, word for word.
ImageSetReconstructOptions ReconstructOptionsFromKwargs(const py::kwargs& kwargs, const Rig* rig,
                                                        const std::string& call);

// A PatternSpec from a Python argument: a PatternSpec, a dict (the fields of PatternSpecToJson) or
// a path to a .yaml/.json spec. Throws slshadow::Error naming `what`.
PatternSpec PatternSpecFromObject(const py::handle& object, const std::string& what);

// The ImageSet behind the Python class (kept with the folder it was opened from).
struct PyImageSet {
  ImageSet image_set;
};

}  // namespace slshadow::python
