# Build and test time (docs/performance.md "Build and test time"; docs/decisions.md D124):
# precompiled headers, and the order of the tests in a fresh build tree.
#
# The third-party headers nearly every file includes (the standard library, Eigen, Abseil,
# nlohmann/json; gRPC and protobuf for the service, the CLI and the tests; GoogleTest for the
# tests) are parsed once per build instead of once per file. Only headers of installed packages
# are precompiled, never the project's own: editing a project header recompiles what includes
# it, as before, and no precompiled header is rebuilt.
#
# Three precompiled headers, each built once by a small object library of its own and reused by
# the targets of the same compile flags (gcc takes a precompiled header only with the same -fPIC
# or -fPIE and the same macros it used; -Winvalid-pch, which CMake adds, warns otherwise):
#   esg_pch_core  libraries without gRPC (estimator, discovery, formats, storage)
#   esg_pch_grpc  libraries with gRPC (proto, server, client)
#   esg_pch_exe   the test binaries and the benchmarks (-fPIE, GoogleTest's macros)
# The test files keep the build type's -O2. At -Og they compiled a third faster, but the linker
# keeps the first copy of an inline function or template instance it meets, and the test objects
# come before the libraries: the filter's Eigen kernels ran at -Og in the test binaries, and one
# diagnosing test took 33.1 s of CPU against 26.5 s (docs/decisions.md D128).
# CLI11 is left out: its header-only validators are namespace-scope objects whose code every file
# that includes the header generates (about 2 s of the 3.3 s an empty file takes with it), so in
# a precompiled header it would cost each file that does not use it more than it saves.
# Configure with -DESG_PRECOMPILED_HEADERS=OFF to build without them.

option(ESG_PRECOMPILED_HEADERS "Precompile the heavy third-party headers (gcc)" ON)

set(ESG_PCH_CORE_HEADERS
  <algorithm> <array> <atomic> <chrono> <cmath> <cstdint> <cstdio> <cstdlib> <cstring>
  <deque> <filesystem> <fstream> <functional> <limits> <map> <memory> <mutex> <optional>
  <random> <set> <sstream> <string> <string_view> <thread> <tuple> <utility> <vector>
  <Eigen/Core> <Eigen/Geometry> <Eigen/Cholesky> <Eigen/LU> <Eigen/Eigenvalues>
  <absl/base/thread_annotations.h> <absl/container/flat_hash_map.h>
  <absl/status/status.h> <absl/status/statusor.h>
  <absl/strings/ascii.h> <absl/strings/match.h> <absl/strings/numbers.h>
  <absl/strings/str_cat.h> <absl/strings/str_format.h> <absl/strings/str_join.h>
  <absl/strings/str_replace.h> <absl/strings/str_split.h> <absl/strings/string_view.h>
  <absl/synchronization/mutex.h> <absl/time/clock.h> <absl/time/time.h> <absl/types/span.h>
  <nlohmann/json.hpp>
)
set(ESG_PCH_GRPC_HEADERS
  ${ESG_PCH_CORE_HEADERS}
  <google/protobuf/arena.h> <google/protobuf/descriptor.h> <google/protobuf/message.h>
  <google/protobuf/generated_message_reflection.h> <google/protobuf/repeated_field.h>
  <google/protobuf/timestamp.pb.h> <google/protobuf/util/json_util.h>
  <grpcpp/grpcpp.h> <grpcpp/support/server_callback.h>
)

# One object library that builds a precompiled header: PIC for libraries, PIE for executables.
function(esg_pch_owner name pie headers_var)
  set(source ${CMAKE_BINARY_DIR}/esg_pch/${name}.cc)
  if(NOT EXISTS ${source})
    file(WRITE ${source} "// The object that builds the precompiled header ${name}.\n")
  endif()
  add_library(${name} OBJECT ${source})
  target_link_libraries(${name} PRIVATE ${ARGN})
  if(pie)
    set_target_properties(${name} PROPERTIES POSITION_INDEPENDENT_CODE OFF)
    target_compile_options(${name} PRIVATE ${CMAKE_CXX_COMPILE_OPTIONS_PIE})
  endif()
  target_precompile_headers(${name} PRIVATE ${${headers_var}})
endfunction()

# Targets that reuse the precompiled header of owner. The owner's include directories (Eigen's)
# are added so that the header is found also where gcc falls back to parsing it.
function(esg_pch_reuse owner)
  foreach(target IN LISTS ARGN)
    if(TARGET ${target})
      target_precompile_headers(${target} REUSE_FROM ${owner})
      target_include_directories(${target} SYSTEM PRIVATE
        $<TARGET_PROPERTY:Eigen3::Eigen,INTERFACE_INCLUDE_DIRECTORIES>)
    endif()
  endforeach()
endfunction()

function(esg_precompiled_headers)
  if(NOT ESG_PRECOMPILED_HEADERS OR ESG_FUZZ OR NOT CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
    return()
  endif()
  set(core_libs Eigen3::Eigen absl::status absl::statusor absl::strings absl::str_format
    absl::time absl::synchronization absl::flat_hash_map absl::span nlohmann_json::nlohmann_json)
  esg_pch_owner(esg_pch_core OFF ESG_PCH_CORE_HEADERS ${core_libs})
  esg_pch_owner(esg_pch_grpc OFF ESG_PCH_GRPC_HEADERS ${core_libs}
    protobuf::libprotobuf gRPC::grpc++)
  set(exe_headers ${ESG_PCH_GRPC_HEADERS})
  set(exe_libs ${core_libs} protobuf::libprotobuf gRPC::grpc++)
  if(ESG_BUILD_TESTS)
    find_package(GTest REQUIRED)  # imported in tests/ only; the executables' header has its headers
    list(APPEND exe_headers <gtest/gtest.h> <gmock/gmock.h>)
    list(APPEND exe_libs GTest::gtest GTest::gmock)
  endif()
  set(ESG_PCH_EXE_HEADERS ${exe_headers})
  esg_pch_owner(esg_pch_exe ON ESG_PCH_EXE_HEADERS ${exe_libs})

  esg_pch_reuse(esg_pch_core esg_estimator esg_discovery esg_formats esg_storage)
  esg_pch_reuse(esg_pch_grpc esg_proto esg_proto_convert esg_diagnosis_json esg_server_lib
    esg_client_lib)
  esg_pch_reuse(esg_pch_exe estimator_tests proto_tests formats_tests storage_tests
    client_tests server_tests end_to_end_tests nginx_routing_tests failover_tests testing_tests
    esg_bench)
  # The executables' header is built with -pthread (gRPC's usage requirements bring it); the test
  # binaries that link no gRPC take it too, or gcc falls back to parsing the headers ("not used
  # because `_REENTRANT' not defined").
  foreach(target formats_tests storage_tests testing_tests)
    if(TARGET ${target})
      target_compile_options(${target} PRIVATE -pthread)
    endif()
  endforeach()
endfunction()

# The order of ctest -j: ctest starts the tests of highest cost first, from the times of the last
# run (Testing/Temporary/CTestCostData.txt). A fresh build tree has none, so the longest tests
# (the discovery suites, 20-55 s each) could start last and leave one core idle at the end; it is
# given cmake/test_costs.txt, the tests over 1 s of a full run (name, runs, seconds), which ctest
# then replaces with its own. Regenerate it from a full run's
# build/Testing/Temporary/CTestCostData.txt (scripts/test_costs.sh).
function(esg_test_costs)
  set(costs ${CMAKE_BINARY_DIR}/Testing/Temporary/CTestCostData.txt)
  if(ESG_BUILD_TESTS AND NOT EXISTS ${costs})
    file(MAKE_DIRECTORY ${CMAKE_BINARY_DIR}/Testing/Temporary)
    file(COPY_FILE ${PROJECT_SOURCE_DIR}/cmake/test_costs.txt ${costs})
  endif()
endfunction()
