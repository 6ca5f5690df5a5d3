// libFuzzer target for PBGI tree page payloads (core/pbgi/tree_page.h): what a worker decodes
// from every page it loads, after the container's checksums have passed, so a crafted file
// reaches it. Seeds in tests/data/pbgi_tree/fuzz_corpus (tree_file_test writes them when
// PBGI_REGENERATE_TEST_DATA is set).

#include <cstddef>
#include <cstdint>
#include <span>

#include "core/pbgi/tree_page.h"

namespace {

// Codebooks as big as a seed's indices need, with arbitrary but finite shapes.
const pbgi::TreeCodebooks& codebooks() {
  static const pbgi::TreeCodebooks books = [] {
    pbgi::TreeCodebooks b;
    b.power.dimension = pbgi::kPowerShapeDims;
    b.power.entries.resize(300 * pbgi::kPowerShapeDims);
    b.area.dimension = pbgi::kAreaShapeDims;
    b.area.entries.resize(100 * pbgi::kAreaShapeDims);
    for (size_t i = pbgi::kPowerShapeDims; i < b.power.entries.size(); ++i) {
      b.power.entries[i] = static_cast<float>(i % 17) * 0.125f - 1.0f;
    }
    for (size_t i = pbgi::kAreaShapeDims; i < b.area.entries.size(); ++i) {
      b.area.entries[i] = static_cast<float>(i % 13) * 0.125f - 0.75f;
    }
    return b;
  }();
  return books;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  auto page = pbgi::decodeTreePage(7, std::span<const uint8_t>(data, size), &codebooks());
  if (!page.ok()) return 0;
  // Everything a traversal touches must be inside the page.
  float sum = 0.0f;
  for (const pbgi::TreeNode& n : (*page)->nodes) {
    for (const pbgi::NodeRef& c : (*page)->childrenOf(n)) sum += static_cast<float>(c.index);
    for (const pbgi::Surfel& s : (*page)->surfelsOf(n)) sum += s.radius;
    sum += n.attributes.powerSh.c[0].x;
  }
  volatile float sink = sum;
  (void)sink;
  return 0;
}
