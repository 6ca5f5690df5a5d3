// libFuzzer target for surfel point clouds (formats/vdb/surfel_vdb.h), read from memory: what
// `pbgi inspect` and a reader of a bake's .vdb parse. Built by tests/fuzz/run_fuzz.sh (CMake
// with PBGI_FUZZ=ON); seeds in tests/data/vdb/fuzz_corpus, the files of tests/data/vdb.

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string_view>

#include "tests/fuzz/surfel_vdb_fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using pbgi::fuzz::SurfelVdbFuzzMode;
  // Past the content hash into OpenVDB's parser only when asked: see surfel_vdb_fuzz_input.h.
  static const bool rehash = std::getenv("PBGI_VDB_FUZZ_REHASH") != nullptr;
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  for (const SurfelVdbFuzzMode mode :
       {SurfelVdbFuzzMode::kFrontDoor, SurfelVdbFuzzMode::kRehashed}) {
    if (mode == SurfelVdbFuzzMode::kRehashed && !rehash) break;
    const pbgi::fuzz::SurfelVdbFuzzResult result = pbgi::fuzz::readSurfelVdbInput(bytes, mode);
    if (!result.broken.empty()) {
      std::fprintf(stderr, "surfel vdb%s: %s\n",
                   mode == SurfelVdbFuzzMode::kRehashed ? " (rehashed)" : "",
                   result.broken.c_str());
      std::abort();
    }
  }
  return 0;
}
