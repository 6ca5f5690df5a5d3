#pragma once
// The body of the surfel cloud's fuzz target (tests/fuzz/surfel_vdb_fuzz.cpp). It lives in a
// header so that tests/formats/vdb/surfel_vdb_fuzz_corpus_test.cpp replays every seed through
// the same code in builds without libFuzzer (CI builds with gcc).
//
// Each input is a .vdb file's bytes, read from memory (readSurfelVdb and inspectSurfelVdb take
// a stream), one of two ways:
//   - kFrontDoor: as given. The reader's front door is the content hash: it rejects a file
//     whose contents do not hash to the UUID in its header before OpenVDB parses a byte
//     (formats/vdb/surfel_vdb.h), so this tests what pbgi checks up to there (magic number,
//     format version, header, hash). An input whose UUID is its hash is left out: the fuzzer
//     learns the hash from the reader's comparison and writes it in, which would take it to
//     OpenVDB's parser, the next mode's business.
//   - kRehashed: with its UUID replaced by the hash of its contents, as writeSurfelVdb makes
//     it, so that mutations reach OpenVDB's parser and pbgi's checks of the grid behind it.
//     OpenVDB trusts every size it reads, as the header says: there the fuzzer finds
//     OpenVDB's faults before pbgi's: in 6 minutes, allocations of sizes it never checked
//     (string lengths, metadata values, blosc chunks, attribute descriptors), assertions in
//     Debian's libopenvdb (Page::readHeader, Page::doLoad) and its headers, which abort, an
//     invalid bool in RootNode::readTopology, and leaks when a read throws; its writes past
//     its buffers are known (tests/data/vdb/crashes_openvdb.vdb). So
//     tests/fuzz/surfel_vdb_fuzz.cpp rehashes only when asked (PBGI_VDB_FUZZ_REHASH=1), for
//     runs whose crashes are triaged.
//
// What must hold, beyond "no crash, no sanitizer report": every refusal names the input, and
// inspect agrees with read (a file that reads inspects without a problem, with as many points).

#include <algorithm>
#include <cstdint>
#include <span>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/statusor.h>
#include <fmt/format.h>
#include <xxhash.h>

#include "formats/vdb/surfel_vdb.h"

namespace pbgi::fuzz {

inline constexpr std::string_view kSurfelVdbFuzzName = "fuzz.vdb";

namespace detail {
// OpenVDB's header: magic (8), format version (4), library version (4 + 4), has-grid-offsets
// (1), then the UUID as 36 characters (formats/vdb/surfel_vdb.cpp, contentUuid).
inline constexpr size_t kVdbUuidOffset = 21, kVdbUuidSize = 36;
}  // namespace detail

// The bytes with the UUID that writeSurfelVdb would give them: XXH3-128 of every byte but the
// UUID's, as an RFC 9562 version 8 UUID. Inputs too short to hold a UUID come back unchanged.
inline std::string withContentUuid(std::string_view bytes) {
  using namespace detail;
  std::string out(bytes);
  if (out.size() < kVdbUuidOffset + kVdbUuidSize) return out;
  XXH3_state_t* state = XXH3_createState();
  XXH3_128bits_reset(state);
  XXH3_128bits_update(state, out.data(), kVdbUuidOffset);
  XXH3_128bits_update(state, out.data() + kVdbUuidOffset + kVdbUuidSize,
                      out.size() - kVdbUuidOffset - kVdbUuidSize);
  const XXH128_hash_t h = XXH3_128bits_digest(state);
  XXH3_freeState(state);
  const uint64_t hi = (h.high64 & ~uint64_t{0xf000}) | uint64_t{0x8000};
  const uint64_t lo = (h.low64 & ~(uint64_t{3} << 62)) | (uint64_t{2} << 62);
  const std::string uuid =
      fmt::format("{:08x}-{:04x}-{:04x}-{:04x}-{:012x}", hi >> 32, (hi >> 16) & 0xffff, hi & 0xffff,
                  lo >> 48, lo & 0xffffffffffffULL);
  std::copy(uuid.begin(), uuid.end(), out.begin() + kVdbUuidOffset);
  return out;
}

struct SurfelVdbFuzzResult {
  bool read = false;   // the bytes read as surfels
  std::string broken;  // the promise a result broke; empty when it kept them all
};

enum class SurfelVdbFuzzMode { kFrontDoor, kRehashed };

inline SurfelVdbFuzzResult readSurfelVdbInput(std::string_view bytes, SurfelVdbFuzzMode mode) {
  const std::string name(kSurfelVdbFuzzName);
  const std::string file = withContentUuid(bytes);
  SurfelVdbFuzzResult result;
  if (mode == SurfelVdbFuzzMode::kFrontDoor && file == bytes) return result;
  auto check = [&](const absl::Status& s, std::string_view how) {
    if (!s.ok() && !std::string(s.message()).starts_with(name) && result.broken.empty()) {
      result.broken =
          fmt::format("{}: a refusal that does not name the input: {}", how, s.ToString());
    }
  };
  const std::string& read = mode == SurfelVdbFuzzMode::kRehashed ? file : std::string(bytes);
  std::istringstream in(read);
  const absl::StatusOr<std::vector<Surfel>> surfels = readSurfelVdb(in, name);
  check(surfels.status(), "read");
  std::istringstream again(read);
  const absl::StatusOr<SurfelVdbInfo> info = inspectSurfelVdb(again, name);
  check(info.status(), "inspect");
  result.read = surfels.ok();
  if (surfels.ok() && result.broken.empty() &&
      (!info.ok() || !info->problem.empty() || info->pointCount != surfels->size())) {
    result.broken = fmt::format(
        "{} surfels read, but inspect says: {}", surfels->size(),
        info.ok() ? fmt::format("{} points, problem \"{}\"", info->pointCount, info->problem)
                  : info.status().ToString());
  }
  return result;
}

}  // namespace pbgi::fuzz
