# Helpers in the spirit of COLMAP's CMakeHelper: one library per module, explicit public and
# private link lists, one test executable per unit registered with CTest.

set(SLSHADOW_WARNINGS -Wall -Wextra -Wpedantic)
if(SLSHADOW_WERROR)
  list(APPEND SLSHADOW_WARNINGS -Werror)
endif()

# slshadow_add_library(NAME name SRCS ... [PUBLIC_LINK_LIBS ...] [PRIVATE_LINK_LIBS ...])
# Creates target slshadow_<name> with alias slshadow::<name>; the project root is the include
# root, so headers are included as "core/camera_model.h".
function(slshadow_add_library)
  cmake_parse_arguments(ARG "" "NAME" "SRCS;PUBLIC_LINK_LIBS;PRIVATE_LINK_LIBS;PRIVATE_OPTIONS" ${ARGN})
  set(target slshadow_${ARG_NAME})
  add_library(${target} STATIC ${ARG_SRCS})
  add_library(slshadow::${ARG_NAME} ALIAS ${target})
  target_include_directories(${target} PUBLIC ${PROJECT_SOURCE_DIR} ${PROJECT_BINARY_DIR}/generated)
  target_link_libraries(${target} PUBLIC ${ARG_PUBLIC_LINK_LIBS} PRIVATE ${ARG_PRIVATE_LINK_LIBS})
  target_compile_options(${target} PRIVATE ${SLSHADOW_WARNINGS} ${ARG_PRIVATE_OPTIONS})
endfunction()

# slshadow_add_bench(NAME name SRCS ... [LINK_LIBS ...] [GOOGLE_BENCHMARK])
# A benchmark or study program under bench/<module>/ (not run by CTest); GOOGLE_BENCHMARK links
# Google Benchmark with its main. Test fixtures are included as "tests/<module>/...".
function(slshadow_add_bench)
  cmake_parse_arguments(ARG "GOOGLE_BENCHMARK" "NAME" "SRCS;LINK_LIBS" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SRCS})
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_LINK_LIBS})
  if(ARG_GOOGLE_BENCHMARK)
    target_link_libraries(${ARG_NAME} PRIVATE benchmark::benchmark)
  endif()
  target_compile_options(${ARG_NAME} PRIVATE ${SLSHADOW_WARNINGS})
  target_compile_definitions(${ARG_NAME} PRIVATE
    SLSHADOW_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    SLSHADOW_SHARED_DATA_DIR="${PROJECT_SOURCE_DIR}/../shared/data")
endfunction()

# slshadow_add_test(NAME name SRCS ... [LINK_LIBS ...] [LABELS ...] [PROPERTIES ...])
# Test executables are named <module>_<unit>_test so that `ctest -R sim` runs one module.
function(slshadow_add_test)
  cmake_parse_arguments(ARG "" "NAME" "SRCS;LINK_LIBS;LABELS;PROPERTIES" ${ARGN})
  add_executable(${ARG_NAME} ${ARG_SRCS})
  # Tests may use cv::imread / cv::imwrite (the oracle of core/image_io); the libraries do not.
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_LINK_LIBS} opencv_imgcodecs GTest::gtest GTest::gtest_main GTest::gmock)
  target_compile_options(${ARG_NAME} PRIVATE ${SLSHADOW_WARNINGS})
  target_compile_definitions(${ARG_NAME} PRIVATE
    SLSHADOW_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    SLSHADOW_SHARED_DATA_DIR="${PROJECT_SOURCE_DIR}/../shared/data")
  add_test(NAME ${ARG_NAME} COMMAND ${ARG_NAME})
  set_tests_properties(${ARG_NAME} PROPERTIES ENVIRONMENT "SLSHADOW_TEST_TMP=${PROJECT_BINARY_DIR}/test_tmp")
  if(ARG_LABELS)
    set_tests_properties(${ARG_NAME} PROPERTIES LABELS "${ARG_LABELS}")
  endif()
  if(ARG_PROPERTIES)
    set_tests_properties(${ARG_NAME} PROPERTIES ${ARG_PROPERTIES})
  endif()
endfunction()
