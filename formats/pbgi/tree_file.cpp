#include "formats/pbgi/tree_file.h"

#include <charconv>

#include <fmt/format.h>

#include "core/util/status.h"

namespace pbgi {

namespace {

constexpr std::string_view kTreeSection = "tree";
constexpr std::string_view kPowerSection = "codebook.power";
constexpr std::string_view kAreaSection = "codebook.area";
constexpr std::string_view kBakeSection = "bake";

std::vector<uint8_t> textBytes(const std::string& s) { return {s.begin(), s.end()}; }

template <typename T>
absl::StatusOr<T> parseNumber(const std::map<std::string, std::string, std::less<>>& values,
                              std::string_view key, const std::string& path) {
  auto it = values.find(key);
  if (it == values.end()) {
    return absl::DataLossError(fmt::format("{}: section \"tree\" has no \"{}\"", path, key));
  }
  T v{};
  const auto [end, ec] = std::from_chars(it->second.data(), it->second.data() + it->second.size(), v);
  if (ec != std::errc() || end != it->second.data() + it->second.size()) {
    return absl::DataLossError(fmt::format("{}: section \"tree\": \"{}\" is \"{}\", expected a number",
                                           path, key, it->second));
  }
  return v;
}

}  // namespace

std::string_view treeEncodingName(TreeEncoding encoding) {
  switch (encoding) {
    case TreeEncoding::kFloat: return "float";
    case TreeEncoding::kQuantized: return "quantized";
    case TreeEncoding::kQuantized8: return "quantized8";
  }
  return "unknown";
}

std::optional<TreeEncoding> parseTreeEncoding(std::string_view name) {
  for (TreeEncoding e : {TreeEncoding::kFloat, TreeEncoding::kQuantized, TreeEncoding::kQuantized8}) {
    if (name == treeEncodingName(e)) return e;
  }
  return std::nullopt;
}

std::string formatKeyValues(const std::vector<std::pair<std::string, std::string>>& entries) {
  std::string out;
  for (const auto& [k, v] : entries) out += fmt::format("{} = {}\n", k, v);
  return out;
}

absl::StatusOr<std::vector<std::pair<std::string, std::string>>> parseKeyValues(
    std::string_view text, std::string_view sectionName) {
  std::vector<std::pair<std::string, std::string>> out;
  int lineNumber = 0;
  while (!text.empty()) {
    ++lineNumber;
    const size_t eol = text.find('\n');
    std::string_view line = text.substr(0, eol);
    text = eol == std::string_view::npos ? std::string_view() : text.substr(eol + 1);
    if (line.empty()) continue;
    const size_t eq = line.find(" = ");
    if (eq == std::string_view::npos || eq == 0) {
      return absl::DataLossError(fmt::format("section \"{}\" line {}: expected `key = value`",
                                             sectionName, lineNumber));
    }
    out.emplace_back(std::string(line.substr(0, eq)), std::string(line.substr(eq + 3)));
  }
  return out;
}

// ---- Writing -----------------------------------------------------------------------------

absl::StatusOr<std::unique_ptr<TreeFileWriter>> TreeFileWriter::create(
    const std::string& path, const TreeFileWriteOptions& options) {
  if (auto s = TreeWriter::validateOptions(options.tree); !s.ok()) return s;
  PageFileWriterOptions fileOptions;
  fileOptions.pageSize = options.tree.pageSize;
  fileOptions.zstdLevel = options.zstdLevel;
  auto file = PageFileWriter::create(path, fileOptions);
  if (!file.ok()) return file.status();
  return std::unique_ptr<TreeFileWriter>(new TreeFileWriter(options, std::move(*file)));
}

TreeFileWriter::TreeFileWriter(const TreeFileWriteOptions& options, PageFileWriter file)
    : options_(options), file_(std::make_unique<PageFileWriter>(std::move(file))) {
  tree_ = std::make_unique<TreeWriter>(
      options_.tree, [this](std::span<const uint8_t> bytes) { return file_->appendPage(bytes); });
}

TreeFileWriter::~TreeFileWriter() = default;

absl::Status TreeFileWriter::add(const SortedSurfel& point) { return tree_->add(point); }

absl::StatusOr<TreeWriteResult> TreeFileWriter::finish() {
  auto result = tree_->finish();
  if (!result.ok()) return result.status();
  PageFileMetadata meta;
  meta.sceneBounds = options_.sceneBounds;
  meta.sceneHash = options_.sceneHash;
  meta.pointCount = result->build.points;
  meta.nodeCount = result->build.nodes;
  meta.leafCount = result->build.leaves;
  meta.rootPage = result->root.page;
  // The container's root offset holds the node's index in its page.
  meta.rootOffset = result->root.index;
  const std::vector<std::pair<std::string, std::string>> tree = {
      {"payload_version", std::to_string(kTreePayloadVersion)},
      {"encoding", std::string(treeEncodingName(options_.tree.encoding))},
      {"leaf_size", std::to_string(options_.tree.build.leafSize)},
      {"exact_from_points", std::to_string(result->exactFromPoints)},
      {"exact_nodes", std::to_string(result->exactNodeCount)},
      {"nodes", std::to_string(result->build.nodes)},
      {"leaves", std::to_string(result->build.leaves)},
      {"points", std::to_string(result->build.points)},
      {"power_codebook_entries", std::to_string(result->codebooks.power.size())},
      {"area_codebook_entries", std::to_string(result->codebooks.area.size())},
      {"power_relative_rms_error", fmt::format("{:.6g}", result->quantization.power.relativeRms)},
      {"area_relative_rms_error", fmt::format("{:.6g}", result->quantization.area.relativeRms)},
      {"clamped_surfel_radiance", std::to_string(result->quantization.clampedSurfelRadiance)},
  };
  std::vector<std::pair<std::string, std::string>> keys = tree;
  if (result->wavelets.nodes > 0) {  // a tree without glossy light keeps its bytes
    const TreeWaveletReport& w = result->wavelets;
    keys.insert(keys.end(),
                {{"wavelet_error", fmt::format("{:.6g}", options_.tree.wavelets.relativeError)},
                 {"wavelet_vectors", std::to_string(w.stored)},
                 {"wavelet_differences", std::to_string(w.differences)},
                 {"wavelet_coefficients", std::to_string(w.coefficients)},
                 {"wavelet_bytes", std::to_string(w.bytes)},
                 {"wavelet_max_relative_error", fmt::format("{:.6g}", w.maxRelativeError)}});
  }
  meta.sections.push_back({std::string(kTreeSection), textBytes(formatKeyValues(keys))});
  if (quantized(options_.tree.encoding)) {
    meta.sections.push_back({std::string(kPowerSection), encodeCodebook(result->codebooks.power)});
    meta.sections.push_back({std::string(kAreaSection), encodeCodebook(result->codebooks.area)});
  }
  meta.sections.push_back(
      {std::string(kBakeSection), textBytes(formatKeyValues(options_.bakeInfo))});
  if (auto s = file_->finish(meta); !s.ok()) return s;
  return result;
}

// ---- Reading -----------------------------------------------------------------------------

absl::StatusOr<std::unique_ptr<TreeFile>> TreeFile::open(const std::string& path) {
  auto store = openLocalPageFile(path);
  if (!store.ok()) return store.status();
  return open(*std::move(store));
}

absl::StatusOr<std::unique_ptr<TreeFile>> TreeFile::open(std::unique_ptr<PageFileStore> store) {
  auto reader = PageFileReader::open(std::move(store));
  if (!reader.ok()) return reader.status();
  auto file = std::unique_ptr<TreeFile>(new TreeFile());
  file->reader_ = std::move(*reader);
  const std::string& path = file->reader_->path();
  const PageFileInfo& info = file->reader_->info();
  auto sectionText = [&](std::string_view name) -> absl::StatusOr<std::string_view> {
    const PageFileSection* s = info.findSection(name);
    if (s == nullptr) {
      return absl::DataLossError(fmt::format("{}: no \"{}\" section: not a PBGI tree", path, name));
    }
    return std::string_view(reinterpret_cast<const char*>(s->bytes.data()), s->bytes.size());
  };
  auto treeText = sectionText(kTreeSection);
  if (!treeText.ok()) return treeText.status();
  auto entries = parseKeyValues(*treeText, kTreeSection);
  if (!entries.ok()) return withContext(entries.status(), path);
  std::map<std::string, std::string, std::less<>> values(entries->begin(), entries->end());
  file->treeInfo_ = *entries;
  auto version = parseNumber<uint32_t>(values, "payload_version", path);
  if (!version.ok()) return version.status();
  if (*version != kTreePayloadVersion) {
    return absl::FailedPreconditionError(fmt::format(
        "{}: tree payload version {}, this build reads version {}{}", path, *version,
        kTreePayloadVersion,
        *version < kTreePayloadVersion
            ? fmt::format(": the tree was written by an older pbgi ({}); bake it again",
                          *version < 2 ? "one-sided surfels" : "pages without ghosts")
            : ": the tree was written by a newer pbgi"));
  }
  const std::string encoding = values.count("encoding") ? values["encoding"] : "";
  if (const auto e = parseTreeEncoding(encoding)) {
    file->description_.encoding = *e;
  } else {
    return absl::DataLossError(fmt::format(
        "{}: section \"tree\": encoding \"{}\", expected float, quantized or quantized8", path,
        encoding));
  }
  auto leafSize = parseNumber<int>(values, "leaf_size", path);
  if (!leafSize.ok()) return leafSize.status();
  file->description_.leafSize = *leafSize;
  auto exact = parseNumber<uint64_t>(values, "exact_from_points", path);
  if (!exact.ok()) return exact.status();
  file->description_.exactFromPoints = *exact;
  if (quantized(file->description_.encoding)) {
    for (auto [name, dim, book] :
         {std::tuple{kPowerSection, kPowerShapeDims, &file->codebooks_.power},
          std::tuple{kAreaSection, kAreaShapeDims, &file->codebooks_.area}}) {
      const PageFileSection* s = info.findSection(name);
      if (s == nullptr) {
        return absl::DataLossError(fmt::format("{}: quantized tree without a \"{}\" section",
                                               path, name));
      }
      auto decoded = decodeCodebook(s->bytes, dim);
      if (!decoded.ok()) return withContext(decoded.status(), path);
      *book = std::move(*decoded);
    }
  }
  if (const PageFileSection* bake = info.findSection(kBakeSection); bake != nullptr) {
    auto lines = parseKeyValues(
        std::string_view(reinterpret_cast<const char*>(bake->bytes.data()), bake->bytes.size()),
        kBakeSection);
    if (lines.ok()) file->bakeInfo_ = std::move(*lines);
  }
  if (info.rootPage >= info.pageCount) {
    return absl::DataLossError(fmt::format("{}: root page {} of {} pages", path, info.rootPage,
                                           info.pageCount));
  }
  file->root_ = NodeRef{info.rootPage, info.rootOffset};
  return file;
}

absl::StatusOr<std::shared_ptr<const TreePage>> TreeFile::page(uint32_t id) {
  auto bytes = reader_->readPage(id);
  if (!bytes.ok()) return bytes.status();  // names the file already
  auto page = decodeTreePage(id, *bytes, &codebooks_);
  if (!page.ok()) return withContext(page.status(), reader_->path());
  if ((*page)->encoding != description_.encoding) {
    return absl::DataLossError(fmt::format("{}: page {} is {}, the tree is {}", reader_->path(),
                                           id, treeEncodingName((*page)->encoding),
                                           treeEncodingName(description_.encoding)));
  }
  return page;
}

}  // namespace pbgi
