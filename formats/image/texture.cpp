#include "formats/image/texture.h"

#include <array>
#include <atomic>
#include <cmath>
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

enum class Encoding { kLinear, kSrgb, kGamma };

float srgbToLinear(float c) {
  return c <= 0.04045f ? c * (1.0f / 12.92f) : std::pow((c + 0.055f) * (1.0f / 1.055f), 2.4f);
}

// 8-bit sources come back from OIIO as byte / 255, so a table decodes them exactly and
// without a pow() per texel channel.
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
// "oiio:ColorSpace" (PNG and JPEG say "sRGB" unless the file says otherwise, PNG with a gAMA
// chunk says "GammaCorrected" or "GammaX.Y" with "oiio:Gamma"); without it, integer data is
// display-referred by convention and float data scene-linear.
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
  ImageTexture(std::string path, TextureSystem::TextureHandle* handle, int width, int height,
               int channels, ColourSpace colourSpace, bool eightBit)
      : path_(std::move(path)),
        handle_(handle),
        width_(width),
        height_(height),
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
    TextureOpt opt;
    opt.swrap = opt.twrap = TextureOpt::WrapPeriodic;
    opt.mipmode = TextureOpt::MipModeNoMIP;
    if (colourSpace_.encoding == Encoding::kLinear) {
      opt.interpmode = TextureOpt::InterpBilinear;
      std::array<float, 3> c{};
      if (!fetch(opt, s, t, c.data(), error)) return false;
      *out = toRgb(c);
      return true;
    }
    // Encoded texels must be decoded before they are blended, so this is bilinear filtering
    // done here: four nearest-texel lookups at the texel centres around (s, t), where OIIO
    // still does the wrapping and the tile caching.
    opt.interpmode = TextureOpt::InterpClosest;
    const float x = s * static_cast<float>(width_) - 0.5f;
    const float y = t * static_cast<float>(height_) - 0.5f;
    const float x0 = std::floor(x), y0 = std::floor(y);
    const float fx = x - x0, fy = y - y0;
    Rgb sum(0.0f);
    for (int dy = 0; dy < 2; ++dy) {
      const float wy = dy == 0 ? 1.0f - fy : fy;
      if (wy == 0.0f) continue;
      const float tc = (y0 + static_cast<float>(dy) + 0.5f) / static_cast<float>(height_);
      for (int dx = 0; dx < 2; ++dx) {
        const float wx = dx == 0 ? 1.0f - fx : fx;
        if (wx == 0.0f) continue;
        const float sc = (x0 + static_cast<float>(dx) + 0.5f) / static_cast<float>(width_);
        std::array<float, 3> c{};
        if (!fetch(opt, sc, tc, c.data(), error)) return false;
        for (float& v : c) v = decode(v);
        sum += toRgb(c) * (wx * wy);
      }
    }
    *out = sum;
    return true;
  }

 private:
  bool fetch(TextureOpt& opt, float s, float t, float* result, std::string* error) const {
    TextureSystem& ts = textureSystem();
    if (ts.texture(handle_, /*thread_info=*/nullptr, opt, s, t, 0.0f, 0.0f, 0.0f, 0.0f,
                   channels_, result)) {
      return true;
    }
    // Taking the message also clears it, so that errors do not pile up per thread.
    *error = ts.geterror();
    return false;
  }

  float decode(float v) const {
    if (colourSpace_.encoding == Encoding::kSrgb) {
      if (eightBit_) {
        const long i = std::lround(v * 255.0f);
        if (i >= 0 && i <= 255) return srgbTable()[static_cast<size_t>(i)];
      }
      return srgbToLinear(v);
    }
    return std::pow(std::max(v, 0.0f), colourSpace_.gamma);
  }

  Rgb toRgb(const std::array<float, 3>& c) const {
    return channels_ == 1 ? Rgb(c[0], c[0], c[0]) : Rgb(c[0], c[1], c[2]);
  }

  std::string path_;
  TextureSystem::TextureHandle* handle_;  // owned by the TextureSystem, lives as long as it
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
    return absl::InvalidArgumentError(fmt::format(
        "texture '{}': expected a flat 2D image, found {}x{} with {} channels{}", path,
        spec.width, spec.height, spec.nchannels, spec.deep ? " (deep)" : ""));
  }
  const int channels = spec.nchannels >= 3 ? 3 : 1;
  const bool eightBit = spec.format.basetype == OIIO::TypeDesc::UINT8;
  auto texture = std::make_shared<ImageTexture>(path, handle, spec.width, spec.height, channels,
                                                colourSpaceOf(spec), eightBit);
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
