#pragma once
// The body of the shot parser's fuzz target (tests/fuzz/shot_fuzz.cpp). It lives in a header so
// that tests/formats/shot/shot_fuzz_corpus_test.cpp replays every seed through the same code in
// builds without libFuzzer (CI builds with gcc).
//
// An input is the text of a shot file (../shared/spec/shot.md), parsed as
// <scratch>/shots/fuzz.shot.toml. The scratch folder holds an empty file for every geometry,
// texture and environment map the seeds name (the parser checks only that they exist), so that
// a mutated seed gets past its [[geometry]] to the materials, lights and [render] behind it.
//
// What must hold for every input, beyond "no crash, no sanitizer report":
//   - a refusal starts with "<path>:<line>:<column>: " (formats/shot/shot_file.h promises it);
//   - a parsed shot has what a render relies on: a name, frames first <= last, a resolution
//     within the limits, geometry, and a finite camera at its first and last frames.

#include <unistd.h>

#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>

#include <absl/status/statusor.h>
#include <fmt/format.h>

#include "core/scene/shot.h"
#include "formats/shot/shot_file.h"

namespace pbgi::fuzz {

// Every file name the seeds refer to, relative to their shot (tests/data/shots and
// config/scenes/*): a seed that names another needs it added here.
inline constexpr const char* kShotFuzzFiles[] = {
    "tri.obj",     "checker.png", "sky_grey.exr",           "cornell_box.obj",
    "caustic.obj", "plates.obj",  "cornell_box_glossy.obj",
};

// A folder of this process's, removed when it exits (a run that crashes leaves it).
class ScratchFolder {
 public:
  explicit ScratchFolder(std::filesystem::path path) : path_(std::move(path)) {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
    std::filesystem::create_directories(path_);
  }
  ~ScratchFolder() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  ScratchFolder(const ScratchFolder&) = delete;
  ScratchFolder& operator=(const ScratchFolder&) = delete;
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// The shot target's scratch folder, made once per process.
inline const std::filesystem::path& shotFuzzDir() {
  struct Folder : ScratchFolder {
    Folder()
        : ScratchFolder(std::filesystem::temp_directory_path() /
                        fmt::format("pbgi-shot-fuzz-{}", ::getpid())) {
      std::filesystem::create_directories(path() / "shots");
      for (const char* name : kShotFuzzFiles) std::ofstream(path() / "shots" / name).put('\n');
      // A triangle that loads: the coordinator loads a job's first frame at submission.
      std::ofstream(path() / "shots" / "tri.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    }
  };
  static const Folder dir;
  return dir.path();
}

inline std::string shotFuzzPath() { return (shotFuzzDir() / "shots" / "fuzz.shot.toml").string(); }

// "<path>:<line>:<column>: " with a positive line and column.
inline bool startsWithLocation(std::string_view message, std::string_view path) {
  if (!message.starts_with(path) || message.substr(path.size(), 1) != ":") return false;
  size_t i = path.size() + 1;
  for (int part = 0; part < 2; ++part) {
    const size_t digits = i;
    while (i < message.size() && std::isdigit(static_cast<unsigned char>(message[i]))) ++i;
    if (i == digits || message[digits] == '0') return false;
    if (message.substr(i, part == 0 ? 1 : 2) != (part == 0 ? ":" : ": ")) return false;
    ++i;
  }
  return true;
}

inline bool finite(const Vec3f& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

struct ShotFuzzResult {
  bool parsed = false;
  std::string broken;  // the promise a result broke; empty when it kept them all
};

inline ShotFuzzResult parseShotInput(std::string_view text) {
  const std::string path = shotFuzzPath();
  const absl::StatusOr<ShotDesc> shot = parseShot(text, path);
  ShotFuzzResult result;
  if (!shot.ok()) {
    if (!startsWithLocation(std::string(shot.status().message()), path)) {
      result.broken =
          fmt::format("a refusal without file:line:column: {}", shot.status().ToString());
    }
    return result;
  }
  result.parsed = true;
  const int64_t pixels = int64_t{shot->width} * shot->height;
  if (shot->name.empty() || shot->firstFrame > shot->lastFrame || shot->width <= 0 ||
      shot->height <= 0 || pixels > (int64_t{1} << 26) || shot->geometry.empty()) {
    result.broken = fmt::format(
        "accepted: name \"{}\", frames [{}, {}], {} x {} pixels, {} geometry", shot->name,
        shot->firstFrame, shot->lastFrame, shot->width, shot->height, shot->geometry.size());
    return result;
  }
  for (const int frame : {shot->firstFrame, shot->lastFrame}) {
    const CameraParams c = cameraAt(shot->camera, shot->firstFrame, frame);
    if (!finite(c.position) || !finite(c.lookAt) || !finite(c.up) || !std::isfinite(c.fovYDeg)) {
      result.broken = fmt::format("accepted: the camera at frame {} is not finite", frame);
      return result;
    }
    (void)outputPathForFrame(shot->output, frame, shot->firstFrame != shot->lastFrame);
  }
  return result;
}

}  // namespace pbgi::fuzz
