# One ctest entry per GoogleTest suite of a test executable, found after each build by running
# it with --gtest_list_tests. A test process costs about 0.3 s before its first test (the
# dynamic loader binds the 300 libraries that OpenImageIO and OpenVDB pull in), which one
# entry per test paid 400 times a run; a suite pays it once and its tests still run one by one
# inside it. A suite that passed with every test skipped is reported as skipped
# (run_suite.sh).
#
#   pbgi_gtest_suites(<target> [PROPERTIES <name> <value> ...] [COSTS <suite>=<seconds> ...])
#
# COSTS orders a fresh build's first run (ctest starts the costliest first, and later runs
# take the times it measured instead): the suites that take longest, or mostly wait, start
# while the short ones fill the other cores.
set(PBGI_GTEST_SUITES_SCRIPT "${CMAKE_CURRENT_LIST_DIR}/list_gtest_suites.cmake")
set(PBGI_GTEST_SUITES_RUNNER "${CMAKE_CURRENT_LIST_DIR}/run_suite.sh")

function(pbgi_gtest_suites target)
  cmake_parse_arguments(PARSE_ARGV 1 ARG "" "" "PROPERTIES;COSTS")
  set(props "")
  foreach(value IN LISTS ARG_PROPERTIES)
    string(APPEND props " [==[${value}]==]")
  endforeach()
  set(props_file "${CMAKE_CURRENT_BINARY_DIR}/${target}_suite_properties.txt")
  file(WRITE "${props_file}" "${props}")
  set(costs_file "${CMAKE_CURRENT_BINARY_DIR}/${target}_suite_costs.txt")
  file(WRITE "${costs_file}" "${ARG_COSTS}")
  set(ctest_file "${CMAKE_CURRENT_BINARY_DIR}/${target}_suites.cmake")
  add_custom_command(
    TARGET ${target} POST_BUILD
    COMMAND "${CMAKE_COMMAND}" -D "EXE=$<TARGET_FILE:${target}>" -D "OUT=${ctest_file}"
            -D "PROPERTIES_FILE=${props_file}" -D "COSTS_FILE=${costs_file}"
            -D "WORKING_DIR=${CMAKE_CURRENT_BINARY_DIR}"
            -D "RUNNER=${PBGI_GTEST_SUITES_RUNNER}"
            -P "${PBGI_GTEST_SUITES_SCRIPT}"
    BYPRODUCTS "${ctest_file}"
    VERBATIM)
  set_property(DIRECTORY APPEND PROPERTY TEST_INCLUDE_FILES "${ctest_file}")
endfunction()
