# The service's tests: protocol types, lightfarmd end to end on loopback
# (with a fake engine, so crashes and hangs can be staged), and the client.
# Included from tests/CMakeLists.txt, which defines lightfarm_test().

find_package(OpenEXR REQUIRED)  # the fake engine hands out a small EXR
set(LIGHTFARM_OPENAPI_DOC "${CMAKE_CURRENT_LIST_DIR}/../protocol/openapi.json")

lightfarm_test(test_protocol)
target_link_libraries(test_protocol PRIVATE lightfarm_protocol)

lightfarm_test(test_server server_harness.cpp)
target_link_libraries(test_server PRIVATE lightfarm_server PkgConfig::CPP_HTTPLIB OpenEXR::OpenEXR)
target_compile_definitions(test_server PRIVATE
  LIGHTFARMD="$<TARGET_FILE:lightfarmd>"
  LIGHTFARM_OPENAPI="${LIGHTFARM_OPENAPI_DOC}")
add_dependencies(test_server lightfarmd)

# client_cli/remote.cpp is compiled in here too, so that the client is tested
# against a real server without the GL engine the lightfarm binary links.
lightfarm_test(test_remote server_harness.cpp ${CMAKE_CURRENT_LIST_DIR}/../client_cli/remote.cpp)
target_include_directories(test_remote PRIVATE ${CMAKE_CURRENT_LIST_DIR}/../client_cli)
target_link_libraries(test_remote PRIVATE lightfarm_protocol PkgConfig::CPP_HTTPLIB OpenEXR::OpenEXR)
target_compile_definitions(test_remote PRIVATE LIGHTFARMD="$<TARGET_FILE:lightfarmd>")
add_dependencies(test_remote lightfarmd)

# The same service with the real engine: hostile scenes at upload, and a
# Cornell box bake through the service against `lightfarm bake`.
if(TARGET lightfarm)
  lightfarm_test(test_server_e2e server_harness.cpp)
  target_link_libraries(test_server_e2e PRIVATE lightfarm_server PkgConfig::CPP_HTTPLIB OpenEXR::OpenEXR)
  target_compile_definitions(test_server_e2e PRIVATE
    LIGHTFARMD="$<TARGET_FILE:lightfarmd>"
    LIGHTFARM_ENGINE="$<TARGET_FILE:lightfarm>")
  add_dependencies(test_server_e2e lightfarmd lightfarm)
endif()
