#include "formats/pbgi/page_file.h"

#include "core/util/fd_io.h"
#include "formats/util/atomic_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <filesystem>
#include <optional>
#include <random>
#include <set>
#include <system_error>
#include <utility>

#include <xxhash.h>
#include <zstd.h>

#include "core/util/status.h"
#include "formats/pbgi/page_file_layout.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

using namespace page_file_internal;

struct ZstdCCtxDeleter {
  void operator()(ZSTD_CCtx* c) const { ZSTD_freeCCtx(c); }
};

std::vector<uint8_t> encodeSections(const std::vector<PageFileSection>& sections) {
  std::vector<uint8_t> out;
  appendU32(out, static_cast<uint32_t>(sections.size()));
  for (const PageFileSection& s : sections) {
    out.push_back(static_cast<uint8_t>(s.name.size()));
    out.insert(out.end(), s.name.begin(), s.name.end());
    appendU32(out, static_cast<uint32_t>(s.bytes.size()));
    out.insert(out.end(), s.bytes.begin(), s.bytes.end());
  }
  return out;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Writing

struct PageFileWriter::State {
  std::string path;
  std::string tmpPath;
  std::optional<AtomicFile> file;  // the temporary at tmpPath, until it becomes `path`
  PageFileWriterOptions options;
  int fd = -1;
  uint64_t offset = kPageFileHeaderSize;  // where the next page goes
  std::vector<PageEntry> directory;
  std::vector<uint8_t> scratch;  // one compressed page
  std::unique_ptr<ZSTD_CCtx, ZstdCCtxDeleter> cctx;
  absl::Status failure;  // sticky: set by an I/O failure
  bool done = false;     // finish() was called

  ~State() { discard(); }

  // Closes and removes the temporary file unless it became `path`.
  void discard() {
    if (fd >= 0) ::close(fd);
    fd = -1;
    file.reset();
    tmpPath.clear();
  }

  absl::Status fail(absl::Status status) {
    failure = withContext(status, path);
    discard();
    return failure;
  }
};

PageFileWriter::PageFileWriter(std::unique_ptr<State> state) : state_(std::move(state)) {}
PageFileWriter::PageFileWriter(PageFileWriter&&) noexcept = default;
PageFileWriter& PageFileWriter::operator=(PageFileWriter&&) noexcept = default;
PageFileWriter::~PageFileWriter() = default;

uint32_t PageFileWriter::pageCount() const {
  return state_ ? static_cast<uint32_t>(state_->directory.size()) : 0;
}

const std::string& PageFileWriter::path() const {
  static const std::string kNone;
  return state_ ? state_->path : kNone;
}

absl::StatusOr<PageFileWriter> PageFileWriter::create(const std::string& path,
                                                      const PageFileWriterOptions& options) {
  if (path.empty()) return absl::InvalidArgumentError("PageFileWriter: empty path");
  if (!validPageSize(options.pageSize)) {
    return absl::InvalidArgumentError(
        fmt::format("{}: page size {}; expected {}", path, options.pageSize, pageSizeRule()));
  }
  if (options.zstdLevel < ZSTD_minCLevel() || options.zstdLevel > ZSTD_maxCLevel()) {
    return absl::InvalidArgumentError(fmt::format("{}: zstd level {}; expected {} to {}", path,
                                                  options.zstdLevel, ZSTD_minCLevel(),
                                                  ZSTD_maxCLevel()));
  }
  auto file = AtomicFile::begin(path);
  if (!file.ok()) return file.status();
  auto state = std::make_unique<State>();
  state->path = path;
  state->options = options;
  state->cctx.reset(ZSTD_createCCtx());
  if (!state->cctx) return absl::ResourceExhaustedError("cannot create a zstd context");
  for (auto [param, value] :
       {std::pair{ZSTD_c_compressionLevel, options.zstdLevel}, std::pair{ZSTD_c_contentSizeFlag, 1},
        std::pair{ZSTD_c_checksumFlag, 0}}) {
    const size_t r = ZSTD_CCtx_setParameter(state->cctx.get(), param, value);
    if (ZSTD_isError(r)) {
      return absl::InternalError(fmt::format("{}: zstd parameter {}: {}", path,
                                             static_cast<int>(param), ZSTD_getErrorName(r)));
    }
  }
  state->scratch.resize(ZSTD_compressBound(options.pageSize));
  const std::string tmp = file->tempPath();
  state->fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (state->fd < 0) {
    return absl::ErrnoToStatus(errno, fmt::format("{}: cannot create {}", path, tmp));
  }
  state->tmpPath = tmp;
  state->file = std::move(*file);
  // The header's place, until finish() writes it.
  const std::vector<uint8_t> zeros(kPageFileHeaderSize, 0);
  if (absl::Status s = pwriteAll(state->fd, zeros.data(), zeros.size(), 0); !s.ok()) {
    return withContext(s, fmt::format("{}: {}", path, tmp));
  }
  return PageFileWriter(std::move(state));
}

absl::StatusOr<uint32_t> PageFileWriter::appendPage(std::span<const uint8_t> bytes) {
  if (!state_) return absl::FailedPreconditionError("appendPage on a moved-from PageFileWriter");
  State& s = *state_;
  if (s.done) {
    return absl::FailedPreconditionError(fmt::format("{}: appendPage after finish()", s.path));
  }
  if (!s.failure.ok()) return s.failure;
  if (bytes.size() > s.options.pageSize) {
    return absl::InvalidArgumentError(
        fmt::format("{}: page {} is {} bytes, more than the page size {}", s.path,
                    s.directory.size(), bytes.size(), s.options.pageSize));
  }
  if (s.directory.size() >= kMaxPageCount) {
    return absl::OutOfRangeError(
        fmt::format("{}: a .pbgi file holds at most {} pages", s.path, kMaxPageCount));
  }
  const size_t n =
      ZSTD_compress2(s.cctx.get(), s.scratch.data(), s.scratch.size(), bytes.data(), bytes.size());
  if (ZSTD_isError(n)) {
    return s.fail(absl::InternalError(
        fmt::format("zstd cannot compress page {}: {}", s.directory.size(), ZSTD_getErrorName(n))));
  }
  if (absl::Status w = pwriteAll(s.fd, s.scratch.data(), n, s.offset); !w.ok()) {
    return s.fail(withContext(w, s.tmpPath));
  }
  const auto id = static_cast<uint32_t>(s.directory.size());
  s.directory.push_back({s.offset, static_cast<uint32_t>(n), static_cast<uint32_t>(bytes.size()),
                         pageFileChecksum({s.scratch.data(), n})});
  s.offset += n;
  return id;
}

absl::Status PageFileWriter::finish(const PageFileMetadata& m) {
  if (!state_) return absl::FailedPreconditionError("finish on a moved-from PageFileWriter");
  State& s = *state_;
  if (s.done) return absl::FailedPreconditionError(fmt::format("{}: finish() again", s.path));
  s.done = true;
  if (!s.failure.ok()) return s.failure;

  // The metadata first: a file that its own reader would reject is never written.
  if (s.directory.empty()) {
    return s.fail(absl::FailedPreconditionError("no pages; a file holds at least its root page"));
  }
  if (m.rootPage >= s.directory.size()) {
    return s.fail(absl::InvalidArgumentError(fmt::format(
        "root page {} is not one of the {} pages written", m.rootPage, s.directory.size())));
  }
  if (m.rootOffset >= s.directory[m.rootPage].uncompressedSize) {
    return s.fail(absl::InvalidArgumentError(
        fmt::format("root offset {} is not inside root page {}, which holds {} bytes", m.rootOffset,
                    m.rootPage, s.directory[m.rootPage].uncompressedSize)));
  }
  if (hasNaN(m.sceneBounds)) {
    return s.fail(absl::InvalidArgumentError(fmt::format("scene bounds hold a NaN: min {}, max {}",
                                                         m.sceneBounds.min, m.sceneBounds.max)));
  }
  std::set<std::string_view> names;
  for (const PageFileSection& section : m.sections) {
    if (absl::Status c = checkSectionName(asBytes(section.name)); !c.ok()) return s.fail(c);
    if (!names.insert(section.name).second) {
      return s.fail(
          absl::InvalidArgumentError(fmt::format("two sections are called \"{}\"", section.name)));
    }
    if (section.bytes.size() > kMaxPageFileSectionsSize) {
      return s.fail(absl::InvalidArgumentError(
          fmt::format("section \"{}\" is {} bytes; all sections together may hold at most {}",
                      section.name, section.bytes.size(), kMaxPageFileSectionsSize)));
    }
  }
  const std::vector<uint8_t> sections = encodeSections(m.sections);
  if (sections.size() > kMaxPageFileSectionsSize) {
    return s.fail(
        absl::InvalidArgumentError(fmt::format("the sections take {} bytes; at most {} are allowed",
                                               sections.size(), kMaxPageFileSectionsSize)));
  }

  // The directory streams out in blocks, hashed as it goes: 24 bytes a page stay the only
  // per-page memory.
  std::unique_ptr<XXH3_state_t, decltype(&XXH3_freeState)> hash(XXH3_createState(),
                                                                &XXH3_freeState);
  if (!hash || XXH3_64bits_reset(hash.get()) != XXH_OK) {
    return s.fail(absl::ResourceExhaustedError("cannot create an XXH3 state"));
  }
  constexpr size_t kEntriesPerBlock = 4096;
  std::vector<uint8_t> block;
  block.reserve(kEntriesPerBlock * kPageFileDirectoryEntrySize);
  for (size_t first = 0; first < s.directory.size(); first += kEntriesPerBlock) {
    const size_t last = std::min(first + kEntriesPerBlock, s.directory.size());
    block.assign((last - first) * kPageFileDirectoryEntrySize, 0);
    for (size_t i = first; i < last; ++i) {
      uint8_t* p = block.data() + (i - first) * kPageFileDirectoryEntrySize;
      const PageEntry& e = s.directory[i];
      storeU64(p, e.offset);
      storeU32(p + 8, e.compressedSize);
      storeU32(p + 12, e.uncompressedSize);
      storeU64(p + 16, e.checksum);
    }
    XXH3_64bits_update(hash.get(), block.data(), block.size());
    if (absl::Status w = pwriteAll(s.fd, block.data(), block.size(), s.offset); !w.ok()) {
      return s.fail(withContext(w, s.tmpPath));
    }
    s.offset += block.size();
  }
  const uint64_t directoryChecksum = XXH3_64bits_digest(hash.get());
  if (absl::Status w = pwriteAll(s.fd, sections.data(), sections.size(), s.offset); !w.ok()) {
    return s.fail(withContext(w, s.tmpPath));
  }
  s.offset += sections.size();

  uint8_t header[kPageFileHeaderSize] = {};
  std::copy(kPageFileMagic.begin(), kPageFileMagic.end(), header);
  storeU32(header + kOffVersion, kPageFileVersion);
  storeU32(header + kOffHeaderSize, kPageFileHeaderSize);
  storeU32(header + kOffPageSize, s.options.pageSize);
  storeU32(header + kOffPageCount, static_cast<uint32_t>(s.directory.size()));
  storeU64(header + kOffFileSize, s.offset);
  storeU64(header + kOffDirectoryChecksum, directoryChecksum);
  storeU64(header + kOffSectionsSize, sections.size());
  storeU64(header + kOffSectionsChecksum, pageFileChecksum(sections));
  storeU32(header + kOffRootPage, m.rootPage);
  storeU32(header + kOffRootOffset, m.rootOffset);
  const float bounds[6] = {m.sceneBounds.min.x, m.sceneBounds.min.y, m.sceneBounds.min.z,
                           m.sceneBounds.max.x, m.sceneBounds.max.y, m.sceneBounds.max.z};
  for (int i = 0; i < 6; ++i) storeF32(header + kOffBounds + 4 * i, bounds[i]);
  storeU64(header + kOffPointCount, m.pointCount);
  storeU64(header + kOffNodeCount, m.nodeCount);
  storeU64(header + kOffLeafCount, m.leafCount);
  storeU64(header + kOffSceneHash, m.sceneHash);
  storeU64(header + kOffHeaderChecksum, pageFileChecksum({header, kOffHeaderChecksum}));
  if (absl::Status w = pwriteAll(s.fd, header, sizeof header, 0); !w.ok()) {
    return s.fail(withContext(w, s.tmpPath));
  }

  if (::close(s.fd) != 0) {
    s.fd = -1;
    return s.fail(absl::ErrnoToStatus(errno, fmt::format("cannot close {}", s.tmpPath)));
  }
  s.fd = -1;
  // Flushes, renames into place and flushes the folder; a failure before the rename removes
  // the temporary, and one after it says the file is in place.
  const absl::Status committed = s.file->commit();
  s.discard();
  if (!committed.ok()) s.failure = committed;
  return committed;
}

// ---------------------------------------------------------------------------------------------
// Reading

namespace {

class LocalPageFile final : public PageFileStore {
 public:
  LocalPageFile(std::string path, int fd, uint64_t size)
      : path_(std::move(path)), fd_(fd), size_(size) {}
  ~LocalPageFile() override { ::close(fd_); }

  const std::string& name() const override { return path_; }
  uint64_t size() const override { return size_; }
  absl::StatusOr<size_t> read(uint64_t offset, std::span<uint8_t> out) override {
    absl::StatusOr<size_t> n = preadAll(fd_, out.data(), out.size(), offset);
    if (!n.ok()) return withContext(n.status(), path_);
    return n;
  }

 private:
  std::string path_;
  int fd_;
  uint64_t size_;
};

}  // namespace

absl::StatusOr<std::vector<uint8_t>> PageFileStore::readPage(uint32_t id, const PageEntry& entry) {
  std::vector<uint8_t> bytes(entry.compressedSize);
  absl::StatusOr<size_t> n = read(entry.offset, bytes);
  if (!n.ok()) return withContext(n.status(), describePage(id, entry));
  bytes.resize(*n);
  return bytes;
}

absl::StatusOr<std::unique_ptr<PageFileStore>> openLocalPageFile(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return absl::ErrnoToStatus(errno, fmt::format("{}: cannot open", path));
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    const int e = errno;
    ::close(fd);
    return absl::ErrnoToStatus(e, fmt::format("{}: cannot stat", path));
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    return absl::InvalidArgumentError(fmt::format("{}: not a regular file", path));
  }
  return std::make_unique<LocalPageFile>(path, fd, static_cast<uint64_t>(st.st_size));
}

uint64_t PageFileHead::treeId() const { return pageFileChecksum(header); }

PageFileReader::PageFileReader(std::unique_ptr<PageFileStore> store) : store_(std::move(store)) {}

PageFileReader::~PageFileReader() = default;

absl::StatusOr<std::unique_ptr<PageFileReader>> PageFileReader::open(const std::string& path) {
  absl::StatusOr<std::unique_ptr<PageFileStore>> store = openLocalPageFile(path);
  if (!store.ok()) return store.status();
  return open(*std::move(store));
}

absl::StatusOr<std::unique_ptr<PageFileReader>> PageFileReader::open(
    std::unique_ptr<PageFileStore> store) {
  std::unique_ptr<PageFileReader> reader(new PageFileReader(std::move(store)));
  PageFileStore& in = *reader->store_;
  const std::string& path = in.name();
  const uint64_t fileSize = in.size();

  // Reads a region whose size the header has already checked against the file size.
  auto readRegion = [&](uint64_t offset, uint64_t size) -> absl::StatusOr<std::vector<uint8_t>> {
    std::vector<uint8_t> bytes(size);
    absl::StatusOr<size_t> n = in.read(offset, bytes);
    if (!n.ok()) return n.status();
    bytes.resize(*n);
    reader->bytesRead_ += *n;
    return bytes;
  };

  // This version's header, then the rest of a longer one if the preamble claims it: a later
  // version's header is read whole so that its checksum, and so its version, can be trusted.
  absl::StatusOr<std::vector<uint8_t>> headerBytes =
      readRegion(0, std::min<uint64_t>(fileSize, kPageFileHeaderSize));
  if (!headerBytes.ok()) return headerBytes.status();
  if (headerBytes->size() >= kPreambleSize &&
      std::equal(kPageFileMagic.begin(), kPageFileMagic.end(), headerBytes->begin())) {
    const uint64_t claimed = std::min<uint64_t>(
        {loadU32(headerBytes->data() + kOffHeaderSize), kPageFileMaxHeaderSize, fileSize});
    if (claimed > headerBytes->size()) {
      absl::StatusOr<std::vector<uint8_t>> rest =
          readRegion(headerBytes->size(), claimed - headerBytes->size());
      if (!rest.ok()) return rest.status();
      headerBytes->insert(headerBytes->end(), rest->begin(), rest->end());
    }
  }
  absl::StatusOr<PageFileHeader> header = decodePageFileHeader(*headerBytes, fileSize);
  if (!header.ok()) return withContext(header.status(), path);

  absl::StatusOr<std::vector<uint8_t>> directoryBytes =
      readRegion(header->directoryOffset, header->directorySize);
  if (!directoryBytes.ok()) return directoryBytes.status();
  absl::StatusOr<std::vector<PageEntry>> directory = decodePageDirectory(*directoryBytes, *header);
  if (!directory.ok()) return withContext(directory.status(), path);

  absl::StatusOr<std::vector<uint8_t>> sectionBytes =
      readRegion(header->sectionsOffset, header->sectionsSize);
  if (!sectionBytes.ok()) return sectionBytes.status();
  absl::StatusOr<std::vector<PageFileSection>> sections =
      decodePageFileSections(*sectionBytes, *header);
  if (!sections.ok()) return withContext(sections.status(), path);

  // The regions follow each other (page_file.h): the tail is the directory, then the sections.
  reader->head_.header = std::move(*headerBytes);
  reader->head_.tailOffset = header->directoryOffset;
  reader->head_.tail = std::move(*directoryBytes);
  reader->head_.tail.insert(reader->head_.tail.end(), sectionBytes->begin(), sectionBytes->end());
  reader->head_.fileSize = fileSize;
  reader->info_ = std::move(header->info);
  reader->info_.sections = std::move(*sections);
  reader->directory_ = std::move(*directory);
  return reader;
}

absl::StatusOr<std::vector<uint8_t>> PageFileReader::storedPage(uint32_t id) const {
  if (id >= directory_.size()) {
    return absl::OutOfRangeError(fmt::format("{}: page {} does not exist; the file has {} pages",
                                             path(), id, directory_.size()));
  }
  absl::StatusOr<std::vector<uint8_t>> bytes = store_->readPage(id, directory_[id]);
  if (!bytes.ok()) return bytes.status();
  bytesRead_.fetch_add(bytes->size(), std::memory_order_relaxed);
  pagesRead_.fetch_add(1, std::memory_order_relaxed);
  return bytes;
}

absl::StatusOr<std::vector<uint8_t>> PageFileReader::readPage(uint32_t id) const {
  absl::StatusOr<std::vector<uint8_t>> compressed = storedPage(id);
  if (!compressed.ok()) return compressed.status();
  absl::StatusOr<std::vector<uint8_t>> page =
      decodePage(id, directory_[id], *compressed, info_.pageSize);
  if (!page.ok()) return withContext(page.status(), path());
  return page;
}

absl::StatusOr<std::vector<uint8_t>> PageFileReader::readStoredPage(uint32_t id) const {
  absl::StatusOr<std::vector<uint8_t>> compressed = storedPage(id);
  if (!compressed.ok()) return compressed.status();
  if (absl::Status s = checkStoredPage(id, directory_[id], *compressed); !s.ok()) {
    return withContext(s, path());
  }
  return compressed;
}

absl::Status PageFileReader::verifyAll() const {
  absl::Status first;
  uint64_t failed = 0;
  for (uint32_t id = 0; id < directory_.size(); ++id) {
    absl::StatusOr<std::vector<uint8_t>> page = readPage(id);
    if (page.ok()) continue;
    if (failed++ == 0) first = page.status();
  }
  if (failed == 0) return absl::OkStatus();
  return absl::Status(first.code(), fmt::format("{} ({} of {} pages failed)", first.message(),
                                                failed, directory_.size()));
}

}  // namespace pbgi