# Installation and the Debian package (README "Install"). `cmake --install build --prefix P` puts
#   P/bin/slshadow                                  the command line (the demo is compiled in)
#   P/lib/python3/dist-packages/slshadow/           the Python module (python/CMakeLists.txt)
#   P/share/slshadow/config/                        example rigs, scenes, pattern specs, studies,
#                                                   devices files (config/)
#   P/share/doc/slshadow/                           README.md and the reference pages of docs/
# and `cpack` (run in the build folder) makes slshadow_<version>_<arch>.deb with prefix /usr, its
# dependencies found by dpkg-shlibdeps from the linked libraries plus python3 and python3-numpy
# for the module. Tested by tests/python/package_test.sh (CTest package_deb).
include(GNUInstallDirs)

install(TARGETS slshadow RUNTIME DESTINATION "${CMAKE_INSTALL_BINDIR}" COMPONENT runtime)
install(DIRECTORY "${PROJECT_SOURCE_DIR}/config/" DESTINATION "${CMAKE_INSTALL_DATADIR}/slshadow/config"
        COMPONENT runtime)
set(SLSHADOW_DOC_PAGES README.md docs/conventions.md docs/formats.md docs/benchmarks.md
    docs/fuzzing.md docs/sweeps.md docs/python.md)
foreach(page IN LISTS SLSHADOW_DOC_PAGES)
  if(EXISTS "${PROJECT_SOURCE_DIR}/${page}")
    install(FILES "${PROJECT_SOURCE_DIR}/${page}" DESTINATION "${CMAKE_INSTALL_DOCDIR}"
            COMPONENT runtime)
  endif()
endforeach()

set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME slshadow)
set(CPACK_PACKAGE_VENDOR "slshadow")
set(CPACK_PACKAGE_CONTACT "slshadow maintainers <slshadow@localhost>")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY
    "structured-light 3D scanner and its digital shadow (command line and Python module)")
set(CPACK_PACKAGE_DESCRIPTION
    "slshadow scans parts with a structured-light rig (cameras and a projector), re-scans the same\n"
    "calibrated rig virtually on the part's 3D model, reconstructs both image sets the same way\n"
    "and reports where the real scan departs from physics. `slshadow demo` runs the whole loop on\n"
    "an embedded demo; `import slshadow` gives the same libraries to Python with numpy.")
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_STRIP_FILES ON)  # the package without debug symbols
# The charts draw through PLplot's cairo driver, loaded at run time (dpkg-shlibdeps cannot see it).
set(CPACK_DEBIAN_PACKAGE_DEPENDS "python3 (>= 3.11), python3 (<< 3.12), python3-numpy, plplot-driver-cairo")
set(CPACK_DEBIAN_PACKAGE_SUGGESTS "python3-open3d, python3-matplotlib, cloudcompare")
include(CPack)
