#pragma once
// Private to formats/image: which channels of an image hold its colour. Shared by the EXR
// reader, the image writers and the comparison so that all of them agree on it.

#include <array>
#include <vector>

#include "core/render/image.h"

namespace pbgi::detail {

// R, G and B by name when the image has all three (EXR files may order channels in any
// way); otherwise the first three channels; otherwise the first channel repeated, so that
// grey and grey+alpha images read as grey. Requires at least one channel.
inline std::array<int, 3> rgbChannelIndices(const Image& image) {
  PBGI_CHECK_GT(image.channelCount(), 0);
  const int r = image.channelIndex("R");
  const int g = image.channelIndex("G");
  const int b = image.channelIndex("B");
  if (r >= 0 && g >= 0 && b >= 0) return {r, g, b};
  if (image.channelCount() >= 3) return {0, 1, 2};
  return {0, 0, 0};
}

// R, G, B of `image`, packed three floats per pixel, as OIIO and OCIO want them.
inline std::vector<float> packRgb(const Image& image) {
  const auto rgb = rgbChannelIndices(image);
  const size_t pixels = static_cast<size_t>(image.width()) * image.height();
  const size_t stride = image.channelCount();
  const std::vector<float>& src = image.pixels();
  std::vector<float> out(pixels * 3);
  for (size_t p = 0; p < pixels; ++p) {
    for (int c = 0; c < 3; ++c) out[p * 3 + c] = src[p * stride + rgb[c]];
  }
  return out;
}

}  // namespace pbgi::detail
