cmake_minimum_required(VERSION 3.22)
# Enforces DESIGN.md's one-way module graph: every #include "<module>/..." in a module's sources
# must name the module itself or one it may depend on. Run as a CTest test:
#   cmake -DROOT=<source dir> -P cmake/CheckModuleDependencies.cmake
set(allowed_core "core")
set(allowed_plot "plot")
set(allowed_patterns "core;patterns")
set(allowed_reconstruct "core;patterns;reconstruct")
set(allowed_sim "core;patterns;sim")
set(allowed_capture "core;patterns;capture")
set(allowed_calib "core;patterns;plot;calib")
set(allowed_compare "core;plot;compare")
# shadow/ (workflows) may use every module but apps/.
set(allowed_shadow "core;plot;patterns;reconstruct;sim;capture;calib;compare;shadow")
# workflows/<name>/ may use every module, shadow/ and the workflows before it (DESIGN.md).
set(allowed_workflows "core;plot;patterns;reconstruct;sim;capture;calib;compare;shadow;workflows")
set(allowed_apps "core;plot;patterns;reconstruct;sim;capture;calib;compare;shadow;workflows;apps")
# python/ (the slshadow Python module) binds the libraries, never the command line.
set(allowed_python "core;plot;patterns;reconstruct;sim;capture;calib;compare;shadow;workflows;python")
set(modules core plot patterns reconstruct sim capture calib compare shadow workflows apps python)

set(violations "")
foreach(module IN LISTS modules)
  if(NOT EXISTS "${ROOT}/${module}")
    continue()
  endif()
  file(GLOB_RECURSE sources "${ROOT}/${module}/*.h" "${ROOT}/${module}/*.cc")
  foreach(source IN LISTS sources)
    file(STRINGS "${source}" includes REGEX "^#include \"[a-z_]+/")
    foreach(line IN LISTS includes)
      string(REGEX REPLACE "^#include \"([a-z_]+)/.*" "\\1" target "${line}")
      if(target IN_LIST modules AND NOT target IN_LIST allowed_${module})
        file(RELATIVE_PATH rel "${ROOT}" "${source}")
        list(APPEND violations "${rel}: ${module}/ may not include ${target}/ (${line})")
      endif()
    endforeach()
  endforeach()
endforeach()

if(violations)
  list(JOIN violations "\n  " text)
  message(FATAL_ERROR "module dependency violations (DESIGN.md):\n  ${text}")
endif()
message(STATUS "module dependencies follow DESIGN.md")
