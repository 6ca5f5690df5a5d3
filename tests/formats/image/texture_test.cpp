#include "formats/image/texture.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

using ::pbgi::testing::makeTempDir;
using ::pbgi::testing::testDataDir;

// The sRGB EOTF, written out independently of the implementation.
double srgbToLinear(double c) {
  return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
}

std::shared_ptr<const Texture> load(const std::string& name) {
  auto texture = loadImageTexture((testDataDir() / "textures" / name).string());
  EXPECT_TRUE(texture.ok()) << texture.status();
  return texture.ok() ? *texture : nullptr;
}

void expectRgbNear(const Rgb& got, const Rgb& want, float tol = 1e-5f) {
  EXPECT_NEAR(got.x, want.x, tol) << "got " << got << ", want " << want;
  EXPECT_NEAR(got.y, want.y, tol) << "got " << got << ", want " << want;
  EXPECT_NEAR(got.z, want.z, tol) << "got " << got << ", want " << want;
}

// checker.png is 2x2, 8-bit sRGB: top row red, green; bottom row blue, grey 128.
TEST(ImageTexture, TexelCentresGiveTheTexelsInLinearRgb) {
  const auto tex = load("checker.png");
  ASSERT_NE(tex, nullptr);
  const float grey = static_cast<float>(srgbToLinear(128.0 / 255.0));
  EXPECT_NEAR(grey, 0.2158605f, 1e-6f);
  // v = 0 is the bottom row (OBJ convention), u = 0 the left column.
  expectRgbNear(tex->evaluate({0.25f, 0.75f}), {1, 0, 0});
  expectRgbNear(tex->evaluate({0.75f, 0.75f}), {0, 1, 0});
  expectRgbNear(tex->evaluate({0.25f, 0.25f}), {0, 0, 1});
  expectRgbNear(tex->evaluate({0.75f, 0.25f}), {grey, grey, grey});
}

TEST(ImageTexture, InterpolatesBilinearlyInLinearSpace) {
  const auto tex = load("checker.png");
  ASSERT_NE(tex, nullptr);
  const float grey = static_cast<float>(srgbToLinear(128.0 / 255.0));
  // Halfway between red and green: decoding after blending would give 0.214 per channel.
  expectRgbNear(tex->evaluate({0.5f, 0.75f}), {0.5f, 0.5f, 0.0f});
  // A quarter of the way from blue towards grey.
  expectRgbNear(tex->evaluate({0.375f, 0.25f}), {0.25f * grey, 0.25f * grey, 0.75f + 0.25f * grey});
  // The centre blends all four equally.
  expectRgbNear(tex->evaluate({0.5f, 0.5f}), {(1 + grey) / 4, (1 + grey) / 4, (1 + grey) / 4});
}

TEST(ImageTexture, WrapsPeriodically) {
  const auto tex = load("checker.png");
  ASSERT_NE(tex, nullptr);
  expectRgbNear(tex->evaluate({1.25f, 0.75f}), {1, 0, 0});
  expectRgbNear(tex->evaluate({-0.75f, -0.25f}), {1, 0, 0});
  expectRgbNear(tex->evaluate({3.75f, 2.25f}), {0.2158605f, 0.2158605f, 0.2158605f});
  // Across the left/right seam: halfway between green (right) and red (left).
  expectRgbNear(tex->evaluate({0.0f, 0.75f}), {0.5f, 0.5f, 0.0f});
  expectRgbNear(tex->evaluate({1.0f, 0.75f}), {0.5f, 0.5f, 0.0f});
}

// pattern.png: 7x5 8-bit sRGB, texel (x, y) channel c = (37x + 91y + 53c + 11) mod 256, row 0
// on top. The reference here is bilinear filtering written out by hand.
TEST(ImageTexture, MatchesHandWrittenBilinearOnAnOddSizedImage) {
  const auto tex = load("pattern.png");
  ASSERT_NE(tex, nullptr);
  constexpr int kW = 7, kH = 5;
  auto texel = [](int x, int y, int c) {
    x = ((x % kW) + kW) % kW;
    y = ((y % kH) + kH) % kH;
    return srgbToLinear(((37 * x + 91 * y + 53 * c + 11) % 256) / 255.0);
  };
  uint32_t state = 12345;
  auto next = [&state] {
    state = state * 1664525u + 1013904223u;
    return static_cast<float>(state >> 8) / static_cast<float>(1u << 24);
  };
  for (int i = 0; i < 200; ++i) {
    const Vec2f uv(next() * 3.0f - 1.0f, next() * 3.0f - 1.0f);
    const double x = uv.x * kW - 0.5, y = (1.0 - uv.y) * kH - 0.5;
    const double x0 = std::floor(x), y0 = std::floor(y), fx = x - x0, fy = y - y0;
    Rgb want;
    for (int c = 0; c < 3; ++c) {
      const int ix = static_cast<int>(x0), iy = static_cast<int>(y0);
      want[c] = static_cast<float>(
          (1 - fx) * (1 - fy) * texel(ix, iy, c) + fx * (1 - fy) * texel(ix + 1, iy, c) +
          (1 - fx) * fy * texel(ix, iy + 1, c) + fx * fy * texel(ix + 1, iy + 1, c));
    }
    SCOPED_TRACE(::testing::Message() << "uv " << uv);
    expectRgbNear(tex->evaluate(uv), want, 2e-5f);
  }
}

// checker.png with a gAMA chunk: OIIO calls gamma 1 "linear" and gamma 2 "Gamma2".
TEST(ImageTexture, PngGammaChunksAreHonoured) {
  const auto linear = load("checker_gamma1.png");
  const auto gamma2 = load("checker_gamma2.png");
  ASSERT_NE(linear, nullptr);
  ASSERT_NE(gamma2, nullptr);
  const float v = 128.0f / 255.0f;
  expectRgbNear(linear->evaluate({0.75f, 0.25f}), {v, v, v});
  expectRgbNear(gamma2->evaluate({0.75f, 0.25f}), {v * v, v * v, v * v});
  expectRgbNear(gamma2->evaluate({0.25f, 0.75f}), {1, 0, 0});
}

TEST(ImageTexture, SingleChannelIsGrey) {
  const auto tex = load("gray.png");  // 2x1: 64, 200
  ASSERT_NE(tex, nullptr);
  const float a = static_cast<float>(srgbToLinear(64.0 / 255.0));
  const float b = static_cast<float>(srgbToLinear(200.0 / 255.0));
  expectRgbNear(tex->evaluate({0.25f, 0.5f}), {a, a, a});
  expectRgbNear(tex->evaluate({0.75f, 0.1f}), {b, b, b});
}

TEST(ImageTexture, FloatSourcesAreLinearAlready) {
  const auto tex = load("linear.exr");  // 2x1 float: (0.25, 0.5, 2), (1, 1, 1)
  ASSERT_NE(tex, nullptr);
  expectRgbNear(tex->evaluate({0.25f, 0.5f}), {0.25f, 0.5f, 2.0f});
  expectRgbNear(tex->evaluate({0.75f, 0.5f}), {1.0f, 1.0f, 1.0f});
  expectRgbNear(tex->evaluate({0.5f, 0.5f}), {0.625f, 0.75f, 1.5f});
  expectRgbNear(tex->evaluate({0.0f, 0.5f}), {0.625f, 0.75f, 1.5f});
}

TEST(ImageTexture, DataWindowNeedNotStartAtTheOrigin) {
  const auto tex = load("offset_window.exr");  // linear.exr's texels, data window at (5, 7)
  ASSERT_NE(tex, nullptr);
  expectRgbNear(tex->evaluate({0.25f, 0.5f}), {0.25f, 0.5f, 2.0f});
  expectRgbNear(tex->evaluate({0.75f, 0.5f}), {1.0f, 1.0f, 1.0f});
}

TEST(ImageTexture, HostileHeadersAreRejectedBeforeAnyPixelIsRead) {
  // Shared with image_io_test: headers that claim 120 GB, 16 GiB and 30 GB of pixels. OIIO's
  // cache would abort the process on them; which check rejects the EXRs first depends on
  // whether readImage's OpenEXR size limits are set in this process.
  for (const char* name : {"huge_header.exr", "too_many_floats.exr", "huge_header.png"}) {
    const std::string path = (testDataDir() / "images" / name).string();
    const auto tex = loadImageTexture(path);
    ASSERT_FALSE(tex.ok()) << name;
    EXPECT_EQ(tex.status().code(), absl::StatusCode::kInvalidArgument) << tex.status();
    EXPECT_NE(tex.status().message().find(path), std::string::npos) << tex.status();
  }
}

TEST(ImageTexture, ManyThreadsAgree) {
  const auto tex = load("pattern.png");
  ASSERT_NE(tex, nullptr);
  std::vector<Rgb> want;
  for (int i = 0; i < 64; ++i) want.push_back(tex->evaluate({i * 0.0371f, i * 0.0533f}));
  std::vector<int> mismatches(8, 0);
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t) {
    threads.emplace_back([&, t] {
      for (int round = 0; round < 200; ++round) {
        for (int i = 0; i < 64; ++i) {
          if (tex->evaluate({i * 0.0371f, i * 0.0533f}) != want[i]) ++mismatches[t];
        }
      }
    });
  }
  for (auto& th : threads) th.join();
  for (int t = 0; t < 8; ++t) EXPECT_EQ(mismatches[t], 0) << "thread " << t;
}

TEST(ImageTexture, MissingFileIsNotFound) {
  const std::string path = (testDataDir() / "textures" / "no_such_texture.png").string();
  const auto tex = loadImageTexture(path);
  ASSERT_FALSE(tex.ok());
  EXPECT_EQ(tex.status().code(), absl::StatusCode::kNotFound) << tex.status();
  EXPECT_NE(tex.status().message().find(path), std::string::npos) << tex.status();
}

TEST(ImageTexture, GarbageFileIsAnErrorAtLoad) {
  const auto dir = makeTempDir("texture");
  const std::string path = (dir / "garbage.png").string();
  {
    std::ofstream out(path, std::ios::binary);
    uint32_t state = 7;
    for (int i = 0; i < 4096; ++i) {
      state = state * 1664525u + 1013904223u;
      out.put(static_cast<char>(state >> 24));
    }
  }
  const auto tex = loadImageTexture(path);
  ASSERT_FALSE(tex.ok());
  EXPECT_EQ(tex.status().code(), absl::StatusCode::kInvalidArgument) << tex.status();
  EXPECT_NE(tex.status().message().find(path), std::string::npos) << tex.status();
  std::filesystem::remove_all(dir);
}

TEST(ImageTexture, TruncatedPixelsAreAnErrorAtLoad) {
  // A valid header whose pixel data stops short: the file opens, its pixels do not read.
  std::ifstream in(testDataDir() / "textures" / "pattern.png", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  // Signature, IHDR and oFFs take the first 54 bytes; the IDAT chunk starts there.
  ASSERT_EQ(bytes.substr(58, 4), "IDAT");
  const auto dir = makeTempDir("texture");
  const std::string path = (dir / "truncated.png").string();
  std::ofstream(path, std::ios::binary) << bytes.substr(0, 72);
  const auto tex = loadImageTexture(path);
  ASSERT_FALSE(tex.ok());
  EXPECT_EQ(tex.status().code(), absl::StatusCode::kInvalidArgument) << tex.status();
  EXPECT_NE(tex.status().message().find("cannot read the pixels"), std::string::npos)
      << tex.status();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace pbgi
