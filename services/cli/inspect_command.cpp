// pbgi inspect FILE: a tree (.pbgi) or point cloud (OpenVDB) file's header and statistics,
// every page verified; exit 1 on any damage.

#include <cstdio>
#include <fstream>
#include <map>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "formats/pbgi/tree_file.h"
#include "formats/shot/shot_file.h"
#include "formats/vdb/surfel_vdb.h"
#include "services/cli/cli.h"
#include "services/render/shot_check.h"

namespace pbgi::cli {

namespace {

struct TreeStatistics {
  std::map<int, uint64_t> depthHistogram;  // nodes per depth
  uint64_t nodes = 0, leaves = 0, surfels = 0, pagesVisited = 0;
  uint64_t waveletPages = 0, waveletVectors = 0, waveletStoredNodes = 0, waveletBytes = 0;
};

// Walks the tree from the root, decoding every page it reaches; a damaged page or a
// reference to nowhere is an error. Depth is capped, so a cycle a hostile file builds ends.
absl::Status walkTree(TreeFile& tree, TreeStatistics* stats) {
  struct Entry {
    NodeRef ref;
    int depth;
  };
  std::vector<Entry> stack{{tree.root(), 0}};
  std::shared_ptr<const TreePage> page;
  std::vector<uint8_t> seen(tree.container().info().pageCount, 0);
  while (!stack.empty()) {
    const Entry e = stack.back();
    stack.pop_back();
    if (e.depth > kMaxTreeLevels + 1) {
      return absl::DataLossError(fmt::format(
          "{}: node (page {}, index {}) is deeper than a tree can be ({} levels): the file's "
          "references loop",
          tree.container().path(), e.ref.page, e.ref.index, kMaxTreeLevels));
    }
    if (!page || page->id != e.ref.page) {
      auto next = tree.page(e.ref.page);
      if (!next.ok()) return next.status();
      page = *next;
      if (e.ref.page < seen.size() && !seen[e.ref.page]) {
        seen[e.ref.page] = 1;
        ++stats->pagesVisited;
        if (!page->wavelets.empty()) {
          ++stats->waveletPages;
          stats->waveletVectors += page->wavelets.size();
          stats->waveletStoredNodes += page->waveletStoredNodes;
          stats->waveletBytes += page->waveletSectionBytes;
        }
      }
    }
    if (e.ref.index >= page->nodes.size()) {
      return absl::DataLossError(fmt::format("{}: reference to node {} of page {}, which has {}",
                                             tree.container().path(), e.ref.index, e.ref.page,
                                             page->nodes.size()));
    }
    const TreeNode& node = page->nodes[e.ref.index];
    ++stats->nodes;
    ++stats->depthHistogram[e.depth];
    if (node.leaf()) {
      ++stats->leaves;
      stats->surfels += node.surfelCount;
      continue;
    }
    for (const NodeRef& c : page->childrenOf(node)) stack.push_back({c, e.depth + 1});
  }
  return absl::OkStatus();
}

// The wavelet BSDFs the render projects for the tree's glossy materials (they are made from the
// shot's materials when a render starts, not stored in the tree): from the shot and frame the
// tree's header names, as `pbgi check` reports them. A shot that cannot be read any more is
// said, not an error: the tree itself is whole.
void printGlossyBsdfs(const TreeFile& tree) {
  std::string shotPath;
  int frame = 0;
  for (const auto& [k, v] : tree.bakeInfo()) {
    if (k == "shot") shotPath = v;
    if (k == "frame") frame = std::atoi(v.c_str());
  }
  if (shotPath.empty()) return;
  absl::StatusOr<ShotDesc> shot = loadShotFile(shotPath);
  absl::StatusOr<ShotCheck> check =
      shot.ok() ? checkShot(*shot, {frame}) : absl::StatusOr<ShotCheck>(shot.status());
  if (!check.ok()) {
    std::printf("  glossy BSDFs: not reported, the shot it was baked from cannot be read: %s\n",
                std::string(check.status().message()).c_str());
    return;
  }
  for (const GlossyMaterialCheck& g : check->glossy) {
    std::printf("  %s\n", describeGlossyMaterial(g).c_str());
  }
}

int inspectTree(const std::string& path) {
  auto tree = TreeFile::open(path);
  if (!tree.ok()) return reportError(tree.status());
  const PageFileReader& file = (*tree)->container();
  const PageFileInfo& info = file.info();
  const TreeFileDescription& d = (*tree)->description();
  std::printf("%s: PBGI tree, format version %u, payload version %u\n", path.c_str(), info.version,
              kTreePayloadVersion);
  std::printf("  encoding %s, leaf size %d, exact SH from %llu points\n",
              std::string(treeEncodingName(d.encoding)).c_str(), d.leafSize,
              static_cast<unsigned long long>(d.exactFromPoints));
  std::printf("  points %llu, nodes %llu, leaves %llu\n",
              static_cast<unsigned long long>(info.pointCount),
              static_cast<unsigned long long>(info.nodeCount),
              static_cast<unsigned long long>(info.leafCount));
  std::printf("  pages %u of %u KiB, file %llu bytes, %.1f bytes per node, %.1f per point\n",
              info.pageCount, info.pageSize / 1024, static_cast<unsigned long long>(info.fileSize),
              info.nodeCount ? double(info.fileSize) / double(info.nodeCount) : 0.0,
              info.pointCount ? double(info.fileSize) / double(info.pointCount) : 0.0);
  uint64_t compressed = 0, uncompressed = 0;
  for (const PageEntry& e : file.directory()) {
    compressed += e.compressedSize;
    uncompressed += e.uncompressedSize;
  }
  std::printf("  page payload %llu bytes, compressed %llu (ratio %.2f)\n",
              static_cast<unsigned long long>(uncompressed),
              static_cast<unsigned long long>(compressed),
              compressed ? double(uncompressed) / double(compressed) : 0.0);
  std::printf("  bounds [%g %g %g] - [%g %g %g], scene hash %016llx\n", info.sceneBounds.min.x,
              info.sceneBounds.min.y, info.sceneBounds.min.z, info.sceneBounds.max.x,
              info.sceneBounds.max.y, info.sceneBounds.max.z,
              static_cast<unsigned long long>(info.sceneHash));
  if (quantized(d.encoding)) {
    std::printf("  codebooks: power %d entries x %d, area %d entries x %d\n",
                (*tree)->codebooks().power.size(), kPowerShapeDims,
                (*tree)->codebooks().area.size(), kAreaShapeDims);
  }
  for (const auto& [k, v] : (*tree)->treeInfo()) {
    if (k.find("error") != std::string::npos || k.find("clamped") != std::string::npos) {
      std::printf("  tree.%s = %s\n", k.c_str(), v.c_str());
    }
  }
  for (const auto& [k, v] : (*tree)->bakeInfo()) std::printf("  bake.%s = %s\n", k.c_str(), v.c_str());

  if (absl::Status s = file.verifyAll(); !s.ok()) {
    std::fprintf(stderr, "pbgi: error: %s\n", std::string(s.message()).c_str());
    return kExitFailed;
  }
  std::printf("  every page's checksum verified (%u pages)\n", info.pageCount);
  TreeStatistics stats;
  if (absl::Status s = walkTree(**tree, &stats); !s.ok()) {
    std::fprintf(stderr, "pbgi: error: %s\n", std::string(s.message()).c_str());
    return kExitFailed;
  }
  if (stats.nodes != info.nodeCount || stats.leaves != info.leafCount ||
      stats.surfels != info.pointCount) {
    std::fprintf(stderr,
                 "pbgi: error: %s: the tree holds %llu nodes, %llu leaves and %llu surfels; the "
                 "header says %llu, %llu and %llu\n",
                 path.c_str(), static_cast<unsigned long long>(stats.nodes),
                 static_cast<unsigned long long>(stats.leaves),
                 static_cast<unsigned long long>(stats.surfels),
                 static_cast<unsigned long long>(info.nodeCount),
                 static_cast<unsigned long long>(info.leafCount),
                 static_cast<unsigned long long>(info.pointCount));
    return kExitFailed;
  }
  std::printf("  every node decoded from the root (%llu pages reached)\n",
              static_cast<unsigned long long>(stats.pagesVisited));
  if (stats.waveletPages > 0) {
    auto key = [&](const char* k) {
      for (const auto& [name, value] : (*tree)->treeInfo()) {
        if (name == k) return value;
      }
      return std::string("?");
    };
    std::printf(
        "  wavelets (glossy light): %llu vectors in %llu pages, %llu coefficients stored (%llu "
        "quadtree nodes), %llu bytes (%.1f%% of the payload); coded within %s, measured worst "
        "relative error %s\n",
        static_cast<unsigned long long>(stats.waveletVectors),
        static_cast<unsigned long long>(stats.waveletPages),
        static_cast<unsigned long long>(3 * (6 * stats.waveletVectors + 3 * stats.waveletStoredNodes)),
        static_cast<unsigned long long>(stats.waveletStoredNodes),
        static_cast<unsigned long long>(stats.waveletBytes),
        uncompressed > 0 ? 100.0 * double(stats.waveletBytes) / double(uncompressed) : 0.0,
        key("wavelet_error").c_str(), key("wavelet_max_relative_error").c_str());
    printGlossyBsdfs(**tree);
  } else {
    std::printf("  wavelets: none\n");
  }
  std::printf("  depth histogram (depth: nodes):");
  for (const auto& [depth, count] : stats.depthHistogram) {
    std::printf(" %d:%llu", depth, static_cast<unsigned long long>(count));
  }
  std::printf("\n");
  return kExitOk;
}

int inspectPointCloud(const std::string& path) {
  auto info = inspectSurfelVdb(path);
  if (!info.ok()) {
    std::fprintf(stderr, "pbgi: error: %s\n", std::string(info.status().message()).c_str());
    return kExitFailed;
  }
  std::printf("%s", info->toString().c_str());
  if (!info->problem.empty()) {
    std::fprintf(stderr, "pbgi: error: %s: %s\n", path.c_str(), info->problem.c_str());
    return kExitFailed;
  }
  return kExitOk;
}

int runInspect(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return reportError(absl::NotFoundError(fmt::format("{}: cannot open the file", path)));
  }
  char magic[8] = {};
  in.read(magic, sizeof magic);
  if (std::string_view(magic, static_cast<size_t>(in.gcount())) == kPageFileMagic) {
    return inspectTree(path);
  }
  // OpenVDB files start with the int32 magic 0x56444220 ("VDB " little-endian).
  if (in.gcount() >= 4 && std::string_view(magic, 4) == std::string_view(" BDV", 4)) {
    return inspectPointCloud(path);
  }
  return reportError(absl::InvalidArgumentError(fmt::format(
      "{}: neither a PBGI tree (magic \"PBGITREE\") nor an OpenVDB point cloud", path)));
}

}  // namespace

void registerInspectCommand(CLI::App& app, CommandAction& action) {
  auto path = std::make_shared<std::string>();
  CLI::App* cmd = app.add_subcommand(
      "inspect", "Print a .pbgi tree's or OpenVDB point cloud's header and statistics, and "
                 "verify every page (exit 1 on any damage)");
  cmd->add_option("FILE", *path, "A .pbgi or .vdb file")->required();
  cmd->callback([path, &action] { action = [path] { return runInspect(*path); }; });
}

}  // namespace pbgi::cli
