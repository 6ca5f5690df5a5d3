#include "formats/image/texture.h"

#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <string>
#include <string_view>
#include <system_error>

#include <OpenImageIO/imageio.h>
#include <OpenImageIO/strutil.h>
#include <OpenImageIO/texture.h>
#include <fmt/format.h>

#include "core/util/log.h"

namespace pbgi {
namespace {

using OIIO::TextureOpt;
using OIIO::TextureSystem;
using OIIO::ustring;

// One TextureSystem for the process, shared by every texture and thread: its tile cache and
// memory cap only work if all lookups go through the same instance.
TextureSystem& textureSystem() {
  static TextureSystem* const ts = [] {
    TextureSystem* t = TextureSystem::create(/*shared=*/true);
    t->attribute("automip", 1);
    t->attribute("accept_untiled", 1);
    t->attribute("max_memory_MB", 256.0f);
    return t;
  }();
  return *ts;
}

// Limits on what a header may claim (see openTexture). 1 GiB is an untiled 16k x 16k RGBA
// 8-bit image.
constexpr int kMaxTextureSide = 65536;
constexpr uint64_t kMaxTextureTileBytes = uint64_t{1} << 30;

enum class Encoding { kLinear, kSrgb, kGamma };

float srgbToLinear(float c) {
  return c <= 0.04045f ? c * (1.0f / 12.92f) : std::pow((c + 0.055f) * (1.0f / 1.055f), 2.4f);
}

// A table decodes 8-bit texels exactly and without a pow() per channel.
const std::array<float, 256>& srgbTable() {
  static const std::array<float, 256> table = [] {
    std::array<float, 256> t{};
    for (int i = 0; i < 256; ++i) t[i] = srgbToLinear(static_cast<float>(i) / 255.0f);
    return t;
  }();
  return table;
}

bool startsWithNoCase(std::string_view s, std::string_view prefix) {
  return s.size() >= prefix.size() && OIIO::Strutil::iequals(s.substr(0, prefix.size()), prefix);
}

struct ColourSpace {
  Encoding encoding = Encoding::kLinear;
  float gamma = 1.0f;
};

// What the texels' numbers mean. OIIO's readers put their best knowledge in
// "oiio:ColorSpace": PNG and JPEG say "sRGB", unless a PNG's gAMA chunk makes it "linear" or
// "Gamma2.2" (with "oiio:Gamma"). Without it, integer data is display-referred by
// convention and float data scene-linear.
ColourSpace colourSpaceOf(const OIIO::ImageSpec& spec) {
  const std::string cs = spec.get_string_attribute("oiio:ColorSpace");
  if (OIIO::Strutil::iequals(cs, "sRGB")) return {Encoding::kSrgb, 1.0f};
  if (startsWithNoCase(cs, "linear") || OIIO::Strutil::iequals(cs, "scene_linear")) {
    return {Encoding::kLinear, 1.0f};
  }
  if (startsWithNoCase(cs, "Gamma")) {
    float gamma = spec.get_float_attribute("oiio:Gamma", 0.0f);
    if (!(gamma > 0.0f)) gamma = OIIO::Strutil::from_string<float>(cs.substr(5));
    if (!(gamma > 0.0f)) gamma = 2.2f;
    if (gamma == 1.0f) return {Encoding::kLinear, 1.0f};
    return {Encoding::kGamma, gamma};
  }
  if (spec.format.is_floating_point()) return {Encoding::kLinear, 1.0f};
  return {Encoding::kSrgb, 1.0f};
}

class ImageTexture final : public Texture {
 public:
  ImageTexture(std::string path, TextureSystem::TextureHandle* handle, const OIIO::ImageSpec& spec,
               int channels, ColourSpace colourSpace, bool eightBit)
      : path_(std::move(path)),
        handle_(handle),
        originX_(spec.x),
        originY_(spec.y),
        width_(spec.width),
        height_(spec.height),
        channels_(channels),
        colourSpace_(colourSpace),
        eightBit_(eightBit) {}

  Rgb evaluate(const Vec2f& uv) const override {
    Rgb out(0.0f);
    std::string error;
    // Said once per texture: a file that went bad after loading would otherwise flood the
    // log from every sample.
    if (lookup(uv, &out, &error)) return out;
    if (!warned_.exchange(true)) {
      log::warn("texture={} lookup failed, using black: {}", path_, error);
    }
    return Rgb(0.0f);
  }

  // The lookup evaluate() does, with the failure reported instead of swallowed.
  bool lookup(const Vec2f& uv, Rgb* out, std::string* error) const {
    // OIIO's t runs from the top row down; our v from the bottom row up.
    const float s = std::isfinite(uv.x) ? uv.x : 0.0f;
    const float t = std::isfinite(uv.y) ? 1.0f - uv.y : 0.0f;
    // Bilinear filtering written out over the 2x2 texels around (s, t), read raw from OIIO's
    // tile cache: encoded texels must be decoded before they are blended, which OIIO 2.4's
    // own filtering cannot do, and one block read is faster than its bilinear lookup anyway.
    const double x = static_cast<double>(s) * width_ - 0.5;
    const double y = static_cast<double>(t) * height_ - 0.5;
    const double xFloor = std::floor(x), yFloor = std::floor(y);
    const float fx = static_cast<float>(x - xFloor), fy = static_cast<float>(y - yFloor);
    const int x0 = wrapIndex(xFloor, width_), y0 = wrapIndex(yFloor, height_);
    const int x1 = x0 + 1 == width_ ? 0 : x0 + 1;
    const int y1 = y0 + 1 == height_ ? 0 : y0 + 1;
    std::array<Rgb, 4> c;  // (x0, y0), (x1, y0), (x0, y1), (x1, y1)
    if (x1 == x0 + 1 && y1 == y0 + 1) {
      if (!texels(x0, y0, 2, 2, c.data(), error)) return false;
    } else {  // across the wrap-around seam
      const std::array<int, 4> xs{x0, x1, x0, x1}, ys{y0, y0, y1, y1};
      for (size_t i = 0; i < 4; ++i) {
        if (!texels(xs[i], ys[i], 1, 1, &c[i], error)) return false;
      }
    }
    *out = (c[0] * (1.0f - fx) + c[1] * fx) * (1.0f - fy) + (c[2] * (1.0f - fx) + c[3] * fx) * fy;
    return true;
  }

 private:
  static int wrapIndex(double i, int n) {
    double m = std::fmod(i, static_cast<double>(n));
    if (m < 0.0) m += n;
    const int r = static_cast<int>(m);
    return r >= n ? 0 : r;
  }

  // The nx by ny texels at (x, y), row by row, decoded to linear.
  bool texels(int x, int y, int nx, int ny, Rgb* out, std::string* error) const {
    TextureSystem& ts = textureSystem();
    TextureOpt opt;
    const int count = nx * ny;
    x += originX_;
    y += originY_;
    std::array<uint8_t, 12> bytes{};
    std::array<float, 12> floats{};
    const bool ok = eightBit_ ? ts.get_texels(handle_, nullptr, opt, 0, x, x + nx, y, y + ny, 0, 1,
                                              0, channels_, OIIO::TypeDesc::UINT8, bytes.data())
                              : ts.get_texels(handle_, nullptr, opt, 0, x, x + nx, y, y + ny, 0, 1,
                                              0, channels_, OIIO::TypeDesc::FLOAT, floats.data());
    if (!ok) {
      *error = ts.geterror();
      return false;
    }
    for (int i = 0; i < count; ++i) {
      std::array<float, 3> c{};
      for (int ch = 0; ch < channels_; ++ch) {
        const int k = i * channels_ + ch;
        c[ch] = eightBit_ ? decode(bytes[k]) : decode(floats[k]);
      }
      out[i] = toRgb(c);
    }
    return true;
  }

  float decode(uint8_t v) const {
    if (colourSpace_.encoding == Encoding::kSrgb) return srgbTable()[v];
    return decode(static_cast<float>(v) / 255.0f);
  }

  float decode(float v) const {
    switch (colourSpace_.encoding) {
      case Encoding::kLinear:
        return v;
      case Encoding::kSrgb:
        return srgbToLinear(v);
      case Encoding::kGamma:
        return std::pow(std::max(v, 0.0f), colourSpace_.gamma);
    }
    return v;
  }

  Rgb toRgb(const std::array<float, 3>& c) const {
    return channels_ == 1 ? Rgb(c[0], c[0], c[0]) : Rgb(c[0], c[1], c[2]);
  }

  std::string path_;
  TextureSystem::TextureHandle* handle_;  // owned by the TextureSystem, lives as long as it
  // The data window: OpenEXR's may start anywhere, and OIIO addresses texels absolutely.
  int originX_;
  int originY_;
  int width_;
  int height_;
  int channels_;  // looked up: 1 (grey) or 3
  ColourSpace colourSpace_;
  bool eightBit_;
  mutable std::atomic<bool> warned_{false};
};

absl::StatusOr<std::shared_ptr<const Texture>> openTexture(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return absl::NotFoundError(fmt::format("texture '{}' not found", path));
  }
  if (!std::filesystem::is_regular_file(path, ec)) {
    return absl::InvalidArgumentError(fmt::format("texture '{}' is not a regular file", path));
  }
  TextureSystem& ts = textureSystem();
  const ustring name(path);
  // A file rewritten since an earlier job read it (or that failed then) is read afresh; an
  // unchanged one stays cached.
  ts.invalidate(name, /*force=*/false);
  TextureSystem::TextureHandle* handle = ts.get_texture_handle(name);
  OIIO::ImageSpec spec;
  if (handle == nullptr || !ts.get_imagespec(handle, nullptr, 0, spec)) {
    return absl::InvalidArgumentError(
        fmt::format("cannot read texture '{}': {}", path, ts.geterror()));
  }
  if (spec.deep || spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0) {
    return absl::InvalidArgumentError(
        fmt::format("texture '{}': expected a flat 2D image, found {}x{} with {} channels{}", path,
                    spec.width, spec.height, spec.nchannels, spec.deep ? " (deep)" : ""));
  }
  // A hostile header can claim any size. OIIO's cache reads an untiled file as one tile of
  // the whole image (the spec it returns says so) and counts a tile's bytes in an int, so an
  // oversized one aborts the process before any allocation could fail.
  const uint64_t tileWidth = spec.tile_width > 0 ? spec.tile_width : spec.width;
  const uint64_t tileHeight = spec.tile_height > 0 ? spec.tile_height : spec.height;
  const uint64_t tileBytes =
      tileWidth * tileHeight * static_cast<uint64_t>(spec.nchannels) * spec.format.size();
  if (spec.width > kMaxTextureSide || spec.height > kMaxTextureSide ||
      tileBytes > kMaxTextureTileBytes) {
    return absl::InvalidArgumentError(fmt::format(
        "texture '{}': {}x{} with {} {} channels is too large: expected sides of at most {} and "
        "at most {} bytes per tile (an untiled file is one tile), found {}",
        path, spec.width, spec.height, spec.nchannels, spec.format.c_str(), kMaxTextureSide,
        kMaxTextureTileBytes, tileBytes));
  }
  const int channels = spec.nchannels >= 3 ? 3 : 1;
  const bool eightBit = spec.format.basetype == OIIO::TypeDesc::UINT8;
  auto texture =
      std::make_shared<ImageTexture>(path, handle, spec, channels, colourSpaceOf(spec), eightBit);
  // Reading the first tile decodes the whole of an untiled PNG or JPEG: truncated pixel data
  // shows up here and not as black texels in the middle of a render.
  Rgb probe;
  std::string error;
  if (!texture->lookup(Vec2f(0.5f, 0.5f), &probe, &error)) {
    return absl::InvalidArgumentError(
        fmt::format("cannot read the pixels of texture '{}': {}", path, error));
  }
  return std::shared_ptr<const Texture>(std::move(texture));
}

}  // namespace

absl::StatusOr<std::shared_ptr<const Texture>> loadImageTexture(const std::string& path) {
  try {
    return openTexture(path);
  } catch (const std::exception& e) {
    return absl::InternalError(fmt::format("texture '{}': {}", path, e.what()));
  }
}

}  // namespace pbgi
