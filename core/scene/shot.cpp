#include "core/scene/shot.h"

#include <algorithm>
#include <map>

#include <fmt/format.h>

namespace pbgi {

namespace {

// One animated value: keys (frame, value) with the base at firstFrame unless a key sets it.
template <typename T, typename Key>
T evaluateTrack(const T& base, int firstFrame, const std::vector<Key>& keys,
                std::optional<T> Key::*member, int frame) {
  std::map<int, T> track;
  track[firstFrame] = base;
  for (const Key& key : keys) {
    if ((key.*member).has_value()) track[key.frame] = *(key.*member);
  }
  auto after = track.lower_bound(frame);
  if (after == track.end()) return std::prev(after)->second;
  if (after->first == frame || after == track.begin()) return after->second;
  auto before = std::prev(after);
  const float t = static_cast<float>(frame - before->first) /
                  static_cast<float>(after->first - before->first);
  return before->second + (after->second - before->second) * t;
}

}  // namespace

CameraParams cameraAt(const CameraDesc& camera, int firstFrame, int frame) {
  const CameraParams& b = camera.base;
  CameraParams p;
  p.position = evaluateTrack(b.position, firstFrame, camera.keys, &CameraKey::position, frame);
  p.lookAt = evaluateTrack(b.lookAt, firstFrame, camera.keys, &CameraKey::lookAt, frame);
  p.up = evaluateTrack(b.up, firstFrame, camera.keys, &CameraKey::up, frame);
  p.fovYDeg = evaluateTrack(b.fovYDeg, firstFrame, camera.keys, &CameraKey::fovYDeg, frame);
  p.apertureRadius =
      evaluateTrack(b.apertureRadius, firstFrame, camera.keys, &CameraKey::apertureRadius, frame);
  p.focusDistance =
      evaluateTrack(b.focusDistance, firstFrame, camera.keys, &CameraKey::focusDistance, frame);
  return p;
}

TransformParams transformAt(const GeometryDesc& geometry, int firstFrame, int frame) {
  const TransformParams& b = geometry.base;
  TransformParams p;
  p.translate =
      evaluateTrack(b.translate, firstFrame, geometry.keys, &TransformKey::translate, frame);
  p.rotateDeg =
      evaluateTrack(b.rotateDeg, firstFrame, geometry.keys, &TransformKey::rotateDeg, frame);
  p.scale = evaluateTrack(b.scale, firstFrame, geometry.keys, &TransformKey::scale, frame);
  return p;
}

std::string outputPathForFrame(const std::string& pattern, int frame, bool multiFrame) {
  std::string out;
  bool sawHash = false;
  for (size_t i = 0; i < pattern.size();) {
    if (pattern[i] != '#') {
      out += pattern[i++];
      continue;
    }
    size_t j = i;
    while (j < pattern.size() && pattern[j] == '#') ++j;
    out += fmt::format("{:0{}d}", frame, static_cast<int>(j - i));
    sawHash = true;
    i = j;
  }
  if (!sawHash && multiFrame) {
    const size_t slash = out.find_last_of('/');
    const size_t dot = out.find_last_of('.');
    const size_t at = (dot != std::string::npos && (slash == std::string::npos || dot > slash))
                          ? dot
                          : out.size();
    out.insert(at, fmt::format(".{:04d}", frame));
  }
  return out;
}

absl::Status checkImageSize(int width, int height, Vec2i views, std::string_view where) {
  if (width < 1 || height < 1 || width > kMaxShotResolution || height > kMaxShotResolution) {
    return absl::InvalidArgumentError(fmt::format("{}: {} x {}: each side must be from 1 to {}",
                                                  where, width, height, kMaxShotResolution));
  }
  const int64_t pixels = int64_t{width} * height * views.x * views.y;
  if (pixels > kMaxShotPixels) {
    return absl::InvalidArgumentError(
        fmt::format("{}: {} x {} in {} x {} views is {} pixels; at most {} (2^26) are allowed",
                    where, width, height, views.x, views.y, pixels, kMaxShotPixels));
  }
  return absl::OkStatus();
}

absl::Status checkShotFrame(const ShotDesc& shot, int frame) {
  if (frame >= shot.firstFrame && frame <= shot.lastFrame) return absl::OkStatus();
  return absl::OutOfRangeError(fmt::format("{}: frame {} is outside the shot's frames [{}, {}]",
                                           shot.path, frame, shot.firstFrame, shot.lastFrame));
}

}  // namespace pbgi
