# Third-party packages, all from Debian 12 (scripts/setup.sh installs them). Facts about their
# Debian builds are in ../shared/DEVICE-MOCKS.md.
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
# imgcodecs: only the tests link it (the oracle of core/image_io); the libraries and the
# slshadow binary read and write images through libpng, libjpeg-turbo and libtiff directly.
find_package(OpenCV 4 REQUIRED COMPONENTS core imgproc imgcodecs calib3d structured_light aruco)
find_package(PNG REQUIRED)
find_package(JPEG REQUIRED)
find_package(TIFF REQUIRED)
find_package(yaml-cpp REQUIRED)
find_package(nlohmann_json 3 REQUIRED)
find_package(TBB REQUIRED)
find_package(PkgConfig REQUIRED)

# yaml-cpp 0.7 on Debian exports the plain target name; make a namespaced alias.
if(TARGET yaml-cpp AND NOT TARGET yaml-cpp::yaml-cpp)
  add_library(yaml-cpp::yaml-cpp ALIAS yaml-cpp)
endif()

find_package(CLI11 REQUIRED)
if(SLSHADOW_BUILD_TESTS)
  find_package(GTest REQUIRED)
endif()
if(SLSHADOW_BUILD_BENCHMARKS)
  find_package(benchmark REQUIRED)
endif()
