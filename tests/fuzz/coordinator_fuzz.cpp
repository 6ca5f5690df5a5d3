// libFuzzer target for the coordinator's RPC handlers (services/coordinator/farm_service.h):
// sequences of farm requests, applied in-process over a fresh SQLite job store
// (tests/fuzz/coordinator_fuzz_input.h says how an input reads). Built by
// tests/fuzz/run_fuzz.sh (CMake with PBGI_FUZZ=ON); seeds in
// tests/data/coordinator/fuzz_corpus (coordinator_fuzz_corpus_test writes them when
// PBGI_REGENERATE_TEST_DATA is set).

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <string>

#include <google/protobuf/stubs/logging.h>

#include "core/util/log.h"
#include "tests/fuzz/coordinator_fuzz_input.h"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // A line per submission and registration would be most of the run's time, and a request
  // with a string field that is not UTF-8 is refused by its parser with a line of its own.
  pbgi::log::setLevel(pbgi::log::Level::kOff);
  google::protobuf::SetLogHandler(
      [](google::protobuf::LogLevel, const char*, int, const std::string&) {});
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string broken = pbgi::fuzz::runFarmInput(std::span<const uint8_t>(data, size),
                                                      PBGI_TEST_DATA_DIR "/pbgi/valid.pbgi");
  if (!broken.empty()) {
    std::fprintf(stderr, "coordinator: %s\n", broken.c_str());
    std::abort();
  }
  return 0;
}
