#pragma once
// A PBGI tree in a `.pbgi` file: the container of page_file.h holding the pages of
// core/pbgi/tree_page.h, plus the sections a reader needs to decode them.
//
// Sections (names are part of the format):
//   "tree"            text, one `key = value` per line: payload_version, encoding (float |
//                     quantized | quantized8), leaf_size, exact_from_points, nodes, leaves,
//                     points, codebook entries; a reader refuses unknown payload versions
//   "codebook.power"  encodeCodebook() bytes (quantized trees only)
//   "codebook.area"   encodeCodebook() bytes (quantized trees only)
//   "bake"            text, `key = value` lines of the bake's parameters and measurements,
//                     for people and `pbgi inspect`; readers do not interpret it
// The container header's root page and root offset name the root node: its page, and its
// index in that page (tree pages address nodes by index, not by byte).
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/pbgi/tree_writer.h"
#include "formats/pbgi/page_file.h"

namespace pbgi {

// Bumped when the page payload layout of tree_page.h changes.
// 2: two-sided surfels (back radiance); 3: ghosts of children in other pages.
inline constexpr uint32_t kTreePayloadVersion = 3;

struct TreeFileWriteOptions {
  TreeWriteOptions tree;
  int zstdLevel = kDefaultPageZstdLevel;
  uint64_t sceneHash = 0;
  Bounds3f sceneBounds;
  // Lines for the "bake" section, in order.
  std::vector<std::pair<std::string, std::string>> bakeInfo;
};

// Streams sorted surfels into a tree file at `path`, atomically (temporary, then rename).
class TreeFileWriter {
 public:
  static absl::StatusOr<std::unique_ptr<TreeFileWriter>> create(
      const std::string& path, const TreeFileWriteOptions& options);
  ~TreeFileWriter();

  absl::Status add(const SortedSurfel& point);
  // Builds the tree, writes every page and the sections, renames into place.
  absl::StatusOr<TreeWriteResult> finish();

 private:
  TreeFileWriter(const TreeFileWriteOptions& options, PageFileWriter file);
  TreeFileWriteOptions options_;
  std::unique_ptr<PageFileWriter> file_;
  std::unique_ptr<TreeWriter> tree_;
};

// What the "tree" section says.
struct TreeFileDescription {
  TreeEncoding encoding = TreeEncoding::kFloat;
  int leafSize = 0;
  uint64_t exactFromPoints = 0;
};

// Opens a tree file and hands out its pages, each read with pread, checked and decoded on
// every call (a cache sits above this). Thread-safe.
class TreeFile : public TreePageSource {
 public:
  static absl::StatusOr<std::unique_ptr<TreeFile>> open(const std::string& path);
  // A tree whose bytes come from elsewhere (remote_page_file.h).
  static absl::StatusOr<std::unique_ptr<TreeFile>> open(std::unique_ptr<PageFileStore> store);

  NodeRef root() const override { return root_; }
  // Errors name the file and the page.
  absl::StatusOr<std::shared_ptr<const TreePage>> page(uint32_t id) override;

  const PageFileReader& container() const { return *reader_; }
  const TreeFileDescription& description() const { return description_; }
  const TreeCodebooks& codebooks() const { return codebooks_; }
  // The "tree" section's lines, as written.
  const std::vector<std::pair<std::string, std::string>>& treeInfo() const { return treeInfo_; }
  // The "bake" section's lines, as written.
  const std::vector<std::pair<std::string, std::string>>& bakeInfo() const { return bakeInfo_; }

 private:
  std::unique_ptr<PageFileReader> reader_;
  TreeFileDescription description_;
  TreeCodebooks codebooks_;
  NodeRef root_;
  std::vector<std::pair<std::string, std::string>> treeInfo_;
  std::vector<std::pair<std::string, std::string>> bakeInfo_;
};

// `key = value` lines, the text of the "tree" and "bake" sections.
std::string formatKeyValues(const std::vector<std::pair<std::string, std::string>>& entries);
absl::StatusOr<std::vector<std::pair<std::string, std::string>>> parseKeyValues(
    std::string_view text, std::string_view sectionName);

std::string_view treeEncodingName(TreeEncoding encoding);
// The encoding a name (as treeEncodingName writes it) stands for; nullopt for any other.
std::optional<TreeEncoding> parseTreeEncoding(std::string_view name);

}  // namespace pbgi
