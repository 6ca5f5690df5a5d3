# Run by pbgi_gtest_suites (PbgiGTestSuites.cmake) after a test executable is built: lists its
# suites and writes the ctest file that adds one test per suite.
#   EXE              the test executable
#   OUT              the ctest file to write
#   PROPERTIES_FILE  the properties every suite's test gets, already quoted
#   COSTS_FILE       "suite=seconds;..." for the suites that are given a COST
#   WORKING_DIR      where the tests run
#   RUNNER           run_suite.sh, which says when a suite only skipped
execute_process(COMMAND "${EXE}" --gtest_list_tests
                OUTPUT_VARIABLE listing ERROR_VARIABLE errors RESULT_VARIABLE result
                TIMEOUT 60)
if(NOT result EQUAL 0)
  message(FATAL_ERROR "${EXE} --gtest_list_tests failed (${result}):\n${errors}")
endif()
file(READ "${PROPERTIES_FILE}" properties)
file(READ "${COSTS_FILE}" costs)
string(REPLACE ";" "\\;" listing "${listing}")
string(REPLACE "\n" ";" lines "${listing}")
set(script "")
foreach(line IN LISTS lines)
  # A suite's line starts at column 0 and ends its name with '.' (a typed or parameterized
  # suite may add "  # TypeParam = ..."); its tests follow, indented.
  if(line MATCHES "^([^ #][^ ]*)\\.( .*)?$")
    set(suite "${CMAKE_MATCH_1}")
    if(suite MATCHES "^DISABLED_" OR suite MATCHES "/DISABLED_")
      continue()
    endif()
    string(APPEND script
      "add_test([==[${suite}]==] sh [==[${RUNNER}]==] [==[${EXE}]==] [==[--gtest_filter=${suite}.*]==])\n"
      "set_tests_properties([==[${suite}]==] PROPERTIES WORKING_DIRECTORY [==[${WORKING_DIR}]==]"
      " SKIP_RETURN_CODE 77${properties})\n")
    foreach(cost IN LISTS costs)
      if(cost MATCHES "^(.*)=([0-9.]+)$" AND CMAKE_MATCH_1 STREQUAL suite)
        string(APPEND script "set_tests_properties([==[${suite}]==] PROPERTIES COST ${CMAKE_MATCH_2})\n")
      endif()
    endforeach()
  endif()
endforeach()
file(WRITE "${OUT}" "${script}")
