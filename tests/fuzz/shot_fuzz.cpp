// libFuzzer target for the shot parser (formats/shot/shot_file.h): the text of a shot file, as
// a user writes it and as a farm job carries it. Built by tests/fuzz/run_fuzz.sh (CMake with
// PBGI_FUZZ=ON); seeds in tests/data/shots/fuzz_corpus, the shipped scenes' shots and the
// malformed shots of tests/data/shots.

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string_view>

#include "tests/fuzz/shot_fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const pbgi::fuzz::ShotFuzzResult result =
      pbgi::fuzz::parseShotInput(std::string_view(reinterpret_cast<const char*>(data), size));
  if (!result.broken.empty()) {
    std::fprintf(stderr, "shot parser: %s\n", result.broken.c_str());
    std::abort();
  }
  return 0;
}
