# The service's tests: protocol types, lightfarmd end to end on loopback
# (with a fake engine, so crashes and hangs can be staged), and the client.
# Included from tests/CMakeLists.txt, which defines lightfarm_test(), or on its
# own from the root for the ThreadSanitizer build (LIGHTFARM_TSAN), which
# builds only the protocol, the server and these tests.

if(NOT COMMAND lightfarm_test)
  find_package(GTest REQUIRED)
  include(GoogleTest)
  function(lightfarm_test name)
    cmake_parse_arguments(PARSE_ARGV 1 arg "GL;ALONE" "COST" "")  # scheduling: the full suite's concern
    add_executable(${name} ${CMAKE_CURRENT_FUNCTION_LIST_DIR}/${name}.cpp ${arg_UNPARSED_ARGUMENTS})
    target_link_libraries(${name} PRIVATE GTest::gtest_main)
    target_include_directories(${name} PRIVATE ${CMAKE_CURRENT_FUNCTION_LIST_DIR})
    gtest_discover_tests(${name} DISCOVERY_TIMEOUT 60 PROPERTIES LABELS ${name} TIMEOUT 300)
  endfunction()
endif()

find_package(OpenEXR REQUIRED)  # the fake engine hands out a small EXR
set(LIGHTFARM_OPENAPI_DOC "${CMAKE_CURRENT_LIST_DIR}/../protocol/openapi.json")

# What the service's tests share: lightfarmd and fake engines started and
# stopped (server_harness.cpp). Compiled once, not into each of eight tests
# (55 s of CI's compile time).
add_library(lightfarm_server_harness STATIC ${CMAKE_CURRENT_LIST_DIR}/server_harness.cpp)
target_include_directories(lightfarm_server_harness PUBLIC ${CMAKE_CURRENT_LIST_DIR})
target_link_libraries(lightfarm_server_harness PUBLIC lightfarm_protocol PkgConfig::CPP_HTTPLIB OpenEXR::OpenEXR)
target_compile_definitions(lightfarm_server_harness PUBLIC LIGHTFARMD="$<TARGET_FILE:lightfarmd>")
add_dependencies(lightfarm_server_harness lightfarmd)

lightfarm_test(test_protocol)
target_link_libraries(test_protocol PRIVATE lightfarm_protocol)

lightfarm_test(test_server)
target_link_libraries(test_server PRIVATE lightfarm_server lightfarm_server_harness)
target_compile_definitions(test_server PRIVATE
  LIGHTFARM_OPENAPI="${LIGHTFARM_OPENAPI_DOC}")
add_dependencies(test_server lightfarmd)

# The store, the data directory and the upload checks under failure (issue #15);
# the store tests against SQLite and a PostgreSQL the test starts (issue #9).
lightfarm_test(test_store ${CMAKE_CURRENT_LIST_DIR}/postgres_server.cpp)
target_link_libraries(test_store PRIVATE lightfarm_server lightfarm_server_harness)
add_dependencies(test_store lightfarmd)

# The HTTP layer under slow, idle, oversized and hostile clients (issue #15).
# It times the API's answers to the others to a second: alone.
lightfarm_test(test_server_http ALONE)
target_link_libraries(test_server_http PRIVATE lightfarm_server lightfarm_server_harness)
add_dependencies(test_server_http lightfarmd)

# client_cli/remote.cpp is compiled in here too, so that the client is tested
# against a real server without the GL engine the lightfarm binary links.
lightfarm_test(test_remote ${CMAKE_CURRENT_LIST_DIR}/../client_cli/remote.cpp
  ${CMAKE_CURRENT_LIST_DIR}/../client_cli/bake_help.cpp)
target_include_directories(test_remote PRIVATE ${CMAKE_CURRENT_LIST_DIR}/../client_cli)
target_link_libraries(test_remote PRIVATE lightfarm_server_harness)
add_dependencies(test_remote lightfarmd)

# The service under load (50 jobs from 10 clients, 200 readers) with the fake
# engine; LIGHTFARM_LOAD_ENGINE=real runs it with this build's lightfarm (the
# figures in docs/service-benchmarks.md). Not lightfarm_test(): it loads both
# cores for ~10 s, so ctest runs it alone (RUN_SERIAL), with a time limit.
add_executable(test_server_load ${CMAKE_CURRENT_LIST_DIR}/test_server_load.cpp)
target_include_directories(test_server_load PRIVATE ${CMAKE_CURRENT_LIST_DIR})
target_link_libraries(test_server_load PRIVATE GTest::gtest_main lightfarm_server_harness)
target_compile_definitions(test_server_load PRIVATE
  LIGHTFARM_EXAMPLES="${LIGHTFARM_EXAMPLES}")
if(TARGET lightfarm)
  target_compile_definitions(test_server_load PRIVATE LIGHTFARM_ENGINE="$<TARGET_FILE:lightfarm>")
endif()
add_dependencies(test_server_load lightfarmd)
gtest_discover_tests(test_server_load DISCOVERY_TIMEOUT 60
  PROPERTIES LABELS test_server_load RUN_SERIAL TRUE TIMEOUT 120)

# The same service with the real engine: hostile scenes at upload; a Cornell
# box bake through the service against `lightfarm bake` (bit for bit); SIGKILL
# of a worker, and of lightfarmd, mid-bake (about 15 s in all on llvmpipe).
if(TARGET lightfarm)
  lightfarm_test(test_server_e2e GL)
  # lightfarm_gi for its EXR reader only: the test compares pixels, the server stays GL-free.
  target_link_libraries(test_server_e2e PRIVATE lightfarm_server lightfarm_gi lightfarm_server_harness)
  target_compile_definitions(test_server_e2e PRIVATE
    LIGHTFARM_ENGINE="$<TARGET_FILE:lightfarm>"
    LIGHTFARM_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
  add_dependencies(test_server_e2e lightfarmd lightfarm)
endif()

# Many lightfarmd nodes on one PostgreSQL (started by the test) and one data
# directory, with the fake engine: exactly-once across nodes, kill -9 of a
# node, the database restarted mid-run (issue #9; about a minute).
lightfarm_test(test_scale_out ${CMAKE_CURRENT_LIST_DIR}/postgres_server.cpp)
target_link_libraries(test_scale_out PRIVATE lightfarm_server lightfarm_server_harness)
add_dependencies(test_scale_out lightfarmd)

# The service's tests wait on servers and subprocesses: their own code needs
# no optimising, and at -O0 it compiles in half of -O2's time (about 100 s of
# CI's compile time on 2 cores, here and in the ThreadSanitizer build). The
# libraries they test keep the build's optimisation.
foreach(t test_protocol test_server test_store test_server_http test_remote test_server_load test_scale_out
          test_server_e2e lightfarm_server_harness)
  if(TARGET ${t})
    target_compile_options(${t} PRIVATE -O0)
  endif()
endforeach()
