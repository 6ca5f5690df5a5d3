#pragma once
// What the farm's tests share: small copies of the sample shot, daemons started as real
// processes (killed with real signals), and pixel-for-pixel image comparison.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "core/render/image.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/test_paths.h"

namespace pbgi::testing {

struct SmallShot {
  int width = 64;
  int height = 64;
  int firstFrame = 1;
  int lastFrame = 2;
  int spp = 2;
  std::string integrator = "path";
  std::string output = "out/small.####.exr";
  std::string extraRender;  // more lines for [render]
  std::string extraCamera;  // more lines for [camera] (views, view_spacing, lens)
};

// The sample Cornell box shot, written to `dir/small.shot.toml` at another size, frame range,
// sample count, integrator and output; its geometry is the sample's own file.
inline std::filesystem::path writeSmallShot(const std::filesystem::path& dir, const SmallShot& s) {
  const auto sample = sourceDir() / "config/scenes/cornell/cornell.shot.toml";
  std::string text = slurpFile(sample);
  const auto replace = [&](const std::string& pattern, const std::string& with) {
    text = std::regex_replace(text, std::regex(pattern), with,
                              std::regex_constants::format_first_only);
  };
  replace(R"(frames = \[1, 3\])", "frames = [" + std::to_string(s.firstFrame) + ", " +
                                      std::to_string(s.lastFrame) + "]");
  replace(R"(resolution = \[256, 256\])",
          "resolution = [" + std::to_string(s.width) + ", " + std::to_string(s.height) + "]");
  replace(R"(output = "[^"]*")", "output = \"" + s.output + "\"");
  replace(R"(file = "cornell_box.obj")",
          "file = \"" + (sample.parent_path() / "cornell_box.obj").string() + "\"");
  // The sample's own PBGI settings go: a test states what it renders (extraRender).
  replace(R"(integrator = "[a-z]+"[^\n]*)", "integrator = \"" + s.integrator + "\"");
  for (const char* key : {"gather", "quality", "bake_points"}) {
    replace(std::string("\n") + key + " = [^\n]*", "");
  }
  replace(R"(spp = 16)", "spp = " + std::to_string(s.spp) + "\n" + s.extraRender);
  replace(R"(fov_y_deg = 37.0)", "fov_y_deg = 37.0\n" + s.extraCamera);
  const auto path = dir / "small.shot.toml";
  std::ofstream(path) << text;
  return path;
}

inline std::filesystem::path binary(const std::string& name) { return binaryDir() / "bin" / name; }

// A daemon as a real child process, its output in a log file. Killed (SIGKILL) when dropped.
class Process {
 public:
  Process() = default;
  Process(const std::vector<std::string>& argv, const std::filesystem::path& log,
          const std::vector<std::string>& env = {}) : log_(log) {
    pid_ = ::fork();
    if (pid_ == 0) {
      for (const std::string& e : env) ::putenv(const_cast<char*>(e.c_str()));
      std::FILE* f = std::fopen(log.c_str(), "a");
      if (f != nullptr) {
        ::dup2(::fileno(f), 1);
        ::dup2(::fileno(f), 2);
      }
      std::vector<char*> args;
      for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
      args.push_back(nullptr);
      ::execv(args[0], args.data());
      ::_exit(127);
    }
  }
  Process(Process&& other) noexcept { *this = std::move(other); }
  Process& operator=(Process&& other) noexcept {
    std::swap(pid_, other.pid_);
    std::swap(log_, other.log_);
    return *this;
  }
  ~Process() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  pid_t pid() const { return pid_; }
  void signal(int sig) const { ::kill(pid_, sig); }
  // The exit status (or 128 + the signal); -1 when it has not exited within `seconds`.
  int wait(double seconds) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (pid_ > 0) {
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      }
      if (std::chrono::steady_clock::now() > until) return -1;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return -1;
  }
  std::string log() const { return slurpFile(log_); }

 private:
  pid_t pid_ = -1;
  std::filesystem::path log_;
};

// Polls `done` every 50 ms for up to `seconds`.
inline bool waitFor(const std::function<bool()>& done, double seconds) {
  const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < until) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return done();
}

// Same size, same channels in the same order, and every value bit for bit (metadata aside).
inline bool samePixels(const Image& a, const Image& b, std::string* why) {
  if (a.width() != b.width() || a.height() != b.height() || a.channels() != b.channels()) {
    *why = "sizes or channels differ";
    return false;
  }
  const size_t n = a.pixels().size();
  if (std::memcmp(a.pixels().data(), b.pixels().data(), n * sizeof(float)) != 0) {
    *why = "pixel values differ";
    return false;
  }
  return true;
}

}  // namespace pbgi::testing
