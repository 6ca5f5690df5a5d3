#pragma once
// A float image with named channels, interleaved per pixel, plus typed metadata. This is what
// the renderer produces and what formats/image writes to OpenEXR (channel names are EXR
// names: "R", "G", "B", "A", "albedo.R", "normal.X", "depth.Z", ...).
//
// Its window: where its pixels lie in a larger frame (OpenEXR's data window inside the display
// window). By default the image is the whole frame; a farm tile is its own pixels, placed at
// the tile's corner of the frame.

#include <array>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "core/util/check.h"

namespace pbgi {

using MetadataValue = std::variant<std::string, int, float>;

struct MetadataEntry {
  std::string name;
  MetadataValue value;
};

// The frame an image's pixels belong to: pixel (0, 0) is the frame's (x, y); the frame is
// fullWidth x fullHeight.
struct ImageWindow {
  int x = 0, y = 0;
  int fullWidth = 0, fullHeight = 0;
  bool operator==(const ImageWindow&) const = default;
};

class Image {
 public:
  Image() = default;
  Image(int width, int height, std::vector<std::string> channels)
      : width_(width), height_(height), channels_(std::move(channels)),
        pixels_(static_cast<size_t>(width) * height * channels_.size(), 0.0f) {
    PBGI_CHECK_GE(width, 0);
    PBGI_CHECK_GE(height, 0);
  }

  int width() const { return width_; }
  int height() const { return height_; }
  // Where the pixels lie in their frame (the image itself unless set).
  ImageWindow window() const {
    return window_ ? *window_ : ImageWindow{0, 0, width_, height_};
  }
  void setWindow(const ImageWindow& w) { window_ = w; }
  bool wholeFrame() const { return window() == ImageWindow{0, 0, width_, height_}; }
  int channelCount() const { return static_cast<int>(channels_.size()); }
  const std::vector<std::string>& channels() const { return channels_; }
  // Index of a channel by name, or -1.
  int channelIndex(const std::string& name) const {
    for (size_t i = 0; i < channels_.size(); ++i)
      if (channels_[i] == name) return static_cast<int>(i);
    return -1;
  }

  float& at(int x, int y, int c) { return pixels_[index(x, y, c)]; }
  float at(int x, int y, int c) const { return pixels_[index(x, y, c)]; }
  std::vector<float>& pixels() { return pixels_; }
  const std::vector<float>& pixels() const { return pixels_; }

  std::vector<MetadataEntry>& metadata() { return metadata_; }
  const std::vector<MetadataEntry>& metadata() const { return metadata_; }
  void setMetadata(const std::string& name, MetadataValue value) {
    for (auto& m : metadata_) {
      if (m.name == name) {
        m.value = std::move(value);
        return;
      }
    }
    metadata_.push_back({name, std::move(value)});
  }

 private:
  size_t index(int x, int y, int c) const {
    return (static_cast<size_t>(y) * width_ + x) * channels_.size() + c;
  }

  int width_ = 0;
  int height_ = 0;
  std::optional<ImageWindow> window_;
  std::vector<std::string> channels_;
  std::vector<float> pixels_;
  std::vector<MetadataEntry> metadata_;
};

// The mean over all pixels of the three channels from `first` on ("R", "indirect.R", ...).
inline std::array<double, 3> meanRgb(const Image& image, const std::string& first) {
  std::array<double, 3> sum{0.0, 0.0, 0.0};
  const int c0 = image.channelIndex(first);
  for (int y = 0; y < image.height(); ++y) {
    for (int x = 0; x < image.width(); ++x) {
      for (int c = 0; c < 3; ++c) sum[c] += image.at(x, y, c0 + c);
    }
  }
  const double pixels = static_cast<double>(image.width()) * image.height();
  for (double& s : sum) s = pixels > 0.0 ? s / pixels : 0.0;
  return sum;
}

}  // namespace pbgi
