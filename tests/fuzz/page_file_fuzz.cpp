// libFuzzer target for .pbgi decoding: header, directory, sections and pages. Built by
// tests/fuzz/run_fuzz.sh, or by CMake when the compiler is clang; seeds in
// tests/data/pbgi/fuzz_corpus (tests/data/pbgi/make_pbgi_files.py writes them).

#include <cstddef>
#include <cstdint>
#include <span>

#include "tests/fuzz/page_file_fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::span<const uint8_t> input(data, size);
  pbgi::fuzz::decodePageFileImage(input);
  pbgi::fuzz::decodePageFileImage(pbgi::fuzz::withRepairedChecksums(input));
  pbgi::fuzz::decodeRawPage(input);
  return 0;
}
