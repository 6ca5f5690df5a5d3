#pragma once
// Where tests find their inputs: the repo's tests/data, the build tree, and the shared test
// scenes beside the checkout (../shared/scenes), which may be absent.

#include <algorithm>
#include <cstdlib>
#include <mutex>
#include <system_error>
#include <vector>
#include <unistd.h>
#include <filesystem>
#include <optional>
#include <string>

namespace pbgi::testing {

inline std::filesystem::path sourceDir() { return PBGI_SOURCE_DIR; }
inline std::filesystem::path binaryDir() { return PBGI_BINARY_DIR; }
inline std::filesystem::path testDataDir() { return PBGI_TEST_DATA_DIR; }
inline std::filesystem::path pbgiBinary() { return binaryDir() / "bin" / "pbgi"; }

// ../shared/scenes beside the checkout, or $PBGI_SHARED_SCENES; nullopt when neither exists.
inline std::optional<std::filesystem::path> sharedScenesDir() {
  if (const char* env = std::getenv("PBGI_SHARED_SCENES")) {
    if (std::filesystem::is_directory(env)) return std::filesystem::path(env);
  }
  const auto p = sourceDir().parent_path() / "shared" / "scenes";
  if (std::filesystem::is_directory(p)) return p;
  return std::nullopt;
}

// The folders makeTempDir made, removed when the test process exits (a failed test's too;
// set PBGI_KEEP_TEST_DIRS to keep them for a look). A forked child leaves them to its parent.
class TempDirs {
 public:
  static TempDirs& get() {
    static TempDirs dirs;
    return dirs;
  }
  void add(const std::filesystem::path& dir) {
    std::lock_guard<std::mutex> lock(mutex_);
    dirs_.push_back(dir);
  }
  ~TempDirs() {
    if (getpid() != owner_ || std::getenv("PBGI_KEEP_TEST_DIRS") != nullptr) return;
    for (const auto& dir : dirs_) {
      std::error_code ignored;
      std::filesystem::remove_all(dir, ignored);
    }
  }

 private:
  TempDirs() = default;
  const pid_t owner_ = getpid();
  std::mutex mutex_;
  std::vector<std::filesystem::path> dirs_;
};

// A fresh, empty folder under the system's temporary folder, unique per call, removed when
// the test process exits.
inline std::filesystem::path makeTempDir(const std::string& tag) {
  std::string templ = (std::filesystem::temp_directory_path() / ("pbgi-" + tag + "-XXXXXX")).string();
  char* made = mkdtemp(templ.data());
  if (made == nullptr) std::abort();
  TempDirs::get().add(made);
  return std::filesystem::path(made);
}

// Names of the regular files below dir, relative to it, sorted: what a test compares to say
// "no temporary was left behind".
inline std::vector<std::string> filesIn(const std::filesystem::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : std::filesystem::recursive_directory_iterator(dir)) {
    if (e.is_regular_file()) names.push_back(std::filesystem::relative(e.path(), dir).string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

}  // namespace pbgi::testing

// Skips the current test when the shared scenes are missing, saying so.
#define PBGI_REQUIRE_SHARED_SCENES(var)                                              \
  const auto var##_opt = ::pbgi::testing::sharedScenesDir();                         \
  if (!var##_opt) GTEST_SKIP() << "../shared/scenes is absent (set PBGI_SHARED_SCENES)"; \
  const std::filesystem::path var = *var##_opt
