// Scene of the virtual scanner: the objects in front of the rig (triangle meshes, point clouds
// rendered as oriented discs, exactly intersected analytic primitives and VDI/VDE 2634-2
// artefacts), their albedo, the radiometry and the optional physical layers. Stored as YAML
// (docs/formats.md, "Scene YAML"); config/demo/scene.yaml is an example.
//
// Frames and units: every object has a rig_from_object pose; the world of the simulator is the
// rig frame (the first camera's frame, DESIGN.md). Millimetres, radians, pixels.
//
// Radiometry (the core model, always on): a camera pixel's value in digital numbers is
//   DN = exposure_fraction * (2^adc_bits - 1) * (ambient * albedo + albedo * cos_p * (d_ref /
//   d_p)^2 * I)
// where cos_p is the cosine of the projector ray's incidence on the surface, d_p the distance
// from the projector's centre, d_ref the reference distance and I in [0, 1] the projector's
// intensity at the projector coordinate the surface point maps to (pattern value / 255 through
// the projector response). Lambertian surfaces: the camera's viewing angle does not enter.
// Values are rounded to integers and clipped to [0, 2^adc_bits - 1] (saturation).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rigid3.h"

namespace slshadow {

class ConfigNode;

// Reflectance of an object, Lambertian, in [0, 1]. Textures are defined on the object's local
// x-y plane (z = 0), i.e. on planes; on other shapes the local x, y of the hit point are used.
struct Albedo {
  enum class Kind { kUniform, kCheckerboard, kImage };
  Kind kind = Kind::kUniform;
  double value = 0.8;  // kUniform

  // kCheckerboard: squares_x x squares_y squares of square_mm, so (squares_x - 1) x
  // (squares_y - 1) inner corners. Inner corner (i, j) lies at local (i * square_mm,
  // j * square_mm, 0), as OpenCV's object points; the square whose top-left corner is the first
  // inner corner minus one square (the board's corner square) is dark. Outside the board: `light`.
  double square_mm = 20;
  int squares_x = 0;
  int squares_y = 0;
  double dark = 0.05;
  double light = 0.9;

  // kImage: a grey 8-bit image (0..255 -> 0..1) printed on the local x-y plane with pixel
  // (u, v) covering [u, u+1] x [v, v+1] * pixel_mm (so its top-left corner is the local origin),
  // sampled bilinearly; outside the image: `light`. Used for ChArUco and other printed targets.
  cv::Mat image;
  double pixel_mm = 0.1;

  // Reflectance at local coordinates (mm).
  double Evaluate(double x_mm, double y_mm) const;
  bool IsTextured() const { return kind != Kind::kUniform; }
};

enum class ObjectType { kMesh, kPointCloud, kPlane, kSphere, kCylinder, kBox };
std::string ToString(ObjectType type);

// One object. Shapes in the object frame:
//   kMesh        triangles (mm, already scaled from the file's units)
//   kPointCloud  oriented discs at the points with their normals and radii
//   kPlane       the rectangle |x| <= size_mm.x/2, |y| <= size_mm.y/2 of z = 0, two-sided
//   kSphere      centre at the origin, radius_mm
//   kCylinder    axis z, radius_mm, |z| <= height_mm/2, closed by flat caps
//   kBox         |x|, |y|, |z| <= size_mm/2
struct SceneObject {
  std::string name;
  ObjectType type = ObjectType::kPlane;
  Rigid3d rig_from_object;
  Albedo albedo;
  // Texture coordinates are the hit point's local (x, y) plus this offset (mm); lets a centred
  // plane carry a board whose own origin is elsewhere.
  Eigen::Vector2d albedo_offset_mm = Eigen::Vector2d::Zero();
  std::shared_ptr<const TriangleMesh> mesh;           // kMesh
  std::shared_ptr<const PointCloud> points;           // kPointCloud; normals required
  std::vector<float> disc_radii_mm;                   // kPointCloud: one per point
  double radius_mm = 0;                               // kSphere, kCylinder
  double height_mm = 0;                               // kCylinder
  Eigen::Vector3d size_mm = Eigen::Vector3d::Zero();  // kPlane (x, y), kBox (x, y, z)
};

// Physical layers beyond the pinhole + Lambertian core. Each is off unless enabled; what each
// models and costs is in docs/formats.md ("Scene YAML", layers) and docs/benchmarks.md.
struct SceneLayers {
  // n x n stratified samples per pixel (box filter over the pixel), 1 = off.
  int supersampling = 1;

  // Thin-lens defocus as a Gaussian PSF: blur-circle diameter on the sensor
  //   c = (f / N) * f * |d - d_focus| / (d * (d_focus - f)),  f = focal length = fx * pixel pitch,
  // d the point's depth along the device's axis; sigma = c / 4 (the second moment of a uniform
  // disc of diameter c), in pixels.
  struct Defocus {
    bool enabled = false;
    double f_number = 4;
    double focus_distance_mm = 500;
    double pixel_pitch_um = 5.86;
    // Blur sigma (px) of a point at depth d_mm for a device of focal length fx_px.
    double SigmaPx(double fx_px, double d_mm) const;
  };
  Defocus camera_defocus;
  Defocus projector_defocus;

  // Projector response: I = (value / 255)^gamma, or a 256-entry lookup table in [0, 1].
  bool response_enabled = false;
  double gamma = 1.0;
  std::vector<double> response_lut;  // empty, or 256 entries

  // Camera vignetting: multiplier cos^4(theta) of the pixel ray's angle to the optical axis
  // (natural vignetting), or 1 + a1 r^2 + a2 r^4 + a3 r^6 with r^2 = x^2 + y^2 in normalised
  // (undistorted) coordinates.
  bool vignetting_enabled = false;
  bool vignetting_cos4 = true;
  std::array<double, 3> vignetting_coefficients{0, 0, 0};

  // Ambient light: irradiance as a fraction of the projector's full white at d_ref, head-on.
  double ambient = 0;

  // EMVA 1288 style sensor noise: the noise-free signal, as a fraction of full scale, becomes
  // mu_e = fraction * full_well_e electrons; shot noise (Gaussian with variance mu_e, the
  // Poisson limit) and read noise (Gaussian, read_noise_e) are added, then the ADC scales by
  // K = (2^adc_bits - 1) / full_well_e DN per electron, rounds and clips (saturation).
  // Deterministic: each pixel's random numbers are a hash of (seed, camera, pattern, pixel).
  bool noise_enabled = false;
  double full_well_e = 10000;
  double read_noise_e = 6;
  uint64_t seed = 1;

  // Projector pixel fill factor in (0, 1]: each projector pixel is a lit square of area
  // fill_factor centred in its cell, dark in the gaps (pixel-exact lookup). 1 = off. With
  // projector_defocus, the pixel grid keeps exp(-2 pi^2 sigma^2) of its structure (the Gaussian
  // transfer of its 1-px period) and the rest of the light is the blurred image at fill_factor.
  double fill_factor = 1.0;

  // Throws slshadow::Error naming `what` on an invalid value.
  void Check(const std::string& what) const;
};

struct Radiometry {
  double exposure_fraction = 0.8;    // DN fraction of full scale, see the header comment
  double exposure_us = 10000;        // recorded in the ImageSet manifest only
  double reference_distance_mm = 0;  // d_ref; 0: the rig's working distance
  int adc_bits = 8;                  // 1..16; > 8 writes 16-bit images
  bool bilinear_lookup = true;       // projector pattern lookup: bilinear or nearest pixel
  void Check(const std::string& what) const;
};

struct Scene {
  std::string name;
  Radiometry radiometry;
  SceneLayers layers;
  std::vector<SceneObject> objects;
  // Calibrated values of metrology artefacts (sphere diameters and centres, ball-bar lengths,
  // plane poses, board corners) in the rig frame, for comparison against reconstructions.
  nlohmann::json artefacts = nlohmann::json::object();
  // Where the scene came from, for scan provenance (core/provenance.h): the tree SceneFromConfig
  // read and the absolute folder its relative paths resolve against; null / empty for a scene
  // built in code. A redo rebuilds the scene from them and checks it against SceneToJson.
  nlohmann::json source_config;
  std::filesystem::path source_dir;

  // Throws slshadow::Error naming `what` on an empty scene, non-finite poses, invalid shapes,
  // empty / degenerate / non-manifold meshes, point clouds without normals, invalid layers.
  void Check(const std::string& what) const;
};

// Reads a scene file (.yaml/.yml/.json); relative mesh / cloud / image paths are relative to the
// file's folder. Throws slshadow::Error with file, field and value on any bad input.
Scene LoadScene(const std::filesystem::path& path);
Scene SceneFromConfig(const ConfigNode& node, const std::filesystem::path& base_dir);
// Radiometry, layers and a summary of the objects (recorded in the ImageSet's `extra`).
nlohmann::json SceneToJson(const Scene& scene);

// Disc radius per point from local spacing: radius = scale * mean distance to the k nearest
// neighbours (k = 4; grid-hashed search). A single point gets radius 1 mm.
std::vector<float> DiscRadiiFromSpacing(const std::vector<Eigen::Vector3d>& points,
                                        double scale = 1.0);

// Checks a mesh for use in a scene: Check() of core/mesh.h (empty, bad indices, non-finite,
// degenerate) and, unless allow_non_manifold, no edge shared by more than two triangles.
void CheckSceneMesh(const TriangleMesh& mesh, const std::string& what, bool allow_non_manifold);

}  // namespace slshadow
