#include "formats/image/compare.h"

#include <cmath>
#include <cstdint>
#include <limits>

#include <gtest/gtest.h>

namespace pbgi {
namespace {

Image constantImage(int width, int height, float r, float g, float b) {
  Image image(width, height, {"R", "G", "B"});
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      image.at(x, y, 0) = r;
      image.at(x, y, 1) = g;
      image.at(x, y, 2) = b;
    }
  return image;
}

TEST(CompareTest, IdenticalImagesHaveNoError) {
  Image a(5, 3, {"R", "G", "B"});
  for (size_t i = 0; i < a.pixels().size(); ++i) a.pixels()[i] = 0.01f * static_cast<float>(i);
  Image diff;
  const absl::StatusOr<ImageMetrics> m = compareImages(a, a, &diff);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->rmse, 0.0);
  EXPECT_EQ(m->relMse, 0.0);
  EXPECT_TRUE(std::isinf(m->psnr) && m->psnr > 0) << m->psnr;
  for (const ChannelMetrics& c : m->channels) {
    EXPECT_EQ(c.rmse, 0.0);
    EXPECT_TRUE(std::isinf(c.psnr) && c.psnr > 0);
    EXPECT_DOUBLE_EQ(c.meanImage, c.meanReference);
  }
  EXPECT_EQ(m->comparedPixels, 15);
  EXPECT_EQ(m->nonFiniteImage, 0);
  ASSERT_EQ(diff.width(), 5);
  ASSERT_EQ(diff.height(), 3);
  EXPECT_EQ(diff.channels(), (std::vector<std::string>{"R", "G", "B"}));
  for (float v : diff.pixels()) EXPECT_EQ(v, 0.0f);
}

TEST(CompareTest, ConstantOffsetGivesTheAnalyticMetrics) {
  // Offsets of 0.25, 0.5 and 0.125 (exact in binary) over references 0.5, 1, 2.
  const Image ref = constantImage(8, 4, 0.5f, 1.0f, 2.0f);
  const Image img = constantImage(8, 4, 0.75f, 0.5f, 2.125f);
  Image diff;
  const absl::StatusOr<ImageMetrics> m = compareImages(img, ref, &diff);
  ASSERT_TRUE(m.ok()) << m.status();

  const double d[3] = {0.25, -0.5, 0.125};
  const double b[3] = {0.5, 1.0, 2.0};
  double mse = 0.0, rel = 0.0;
  for (int c = 0; c < 3; ++c) {
    const ChannelMetrics& ch = m->channels[c];
    const double relC = d[c] * d[c] / (b[c] * b[c] + 1e-2);
    EXPECT_NEAR(ch.meanReference, b[c], 1e-12);
    EXPECT_NEAR(ch.meanImage, b[c] + d[c], 1e-12);
    EXPECT_NEAR(ch.rmse, std::abs(d[c]), 1e-9) << c;
    EXPECT_NEAR(ch.relMse, relC, 1e-12) << c;
    EXPECT_NEAR(ch.psnr, 20.0 * std::log10(1.0 / std::abs(d[c])), 1e-6) << c;
    mse += d[c] * d[c] / 3.0;
    rel += relC / 3.0;
  }
  EXPECT_NEAR(m->rmse, std::sqrt(mse), 1e-9);
  EXPECT_NEAR(m->relMse, rel, 1e-12);
  EXPECT_NEAR(m->psnr, 10.0 * std::log10(1.0 / mse), 1e-6);
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 8; ++x)
      for (int c = 0; c < 3; ++c) EXPECT_EQ(diff.at(x, y, c), static_cast<float>(std::abs(d[c])));
}

TEST(CompareTest, UsesChannelsByNameAndGreyReplicates) {
  // RGB stored in another order, with an extra channel that must be ignored.
  Image img(2, 2, {"A", "B", "G", "R", "depth.Z"});
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 2; ++x) {
      img.at(x, y, 0) = 100.0f;
      img.at(x, y, 1) = 0.5f;
      img.at(x, y, 2) = 0.5f;
      img.at(x, y, 3) = 0.5f;
      img.at(x, y, 4) = -7.0f;
    }
  Image grey(2, 2, {"Y"});
  for (float& v : grey.pixels()) v = 0.5f;
  const absl::StatusOr<ImageMetrics> m = compareImages(img, grey);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->rmse, 0.0);
}

TEST(CompareTest, NonFinitePixelsAreCountedAndLeftOut) {
  const Image ref = constantImage(2, 2, 1.0f, 1.0f, 1.0f);
  Image img = constantImage(2, 2, 1.5f, 1.5f, 1.5f);
  img.at(0, 0, 1) = std::numeric_limits<float>::quiet_NaN();
  img.at(1, 1, 2) = std::numeric_limits<float>::infinity();
  Image diff;
  const absl::StatusOr<ImageMetrics> m = compareImages(img, ref, &diff);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->nonFiniteImage, 2);
  EXPECT_EQ(m->nonFiniteReference, 0);
  EXPECT_EQ(m->comparedPixels, 2);
  EXPECT_NEAR(m->rmse, 0.5, 1e-9) << "the two finite pixels are off by 0.5";
  EXPECT_NEAR(m->channels[0].meanImage, 1.5, 1e-12);
  EXPECT_NEAR(m->relMse, 0.25 / 1.01, 1e-12);
  EXPECT_TRUE(std::isnan(diff.at(0, 0, 1)));
  EXPECT_TRUE(std::isinf(diff.at(1, 1, 2)));
}

TEST(CompareTest, NoFinitePixelLeavesNaNMetrics) {
  Image img = constantImage(1, 1, 1.0f, 1.0f, 1.0f);
  img.at(0, 0, 0) = std::numeric_limits<float>::quiet_NaN();
  const absl::StatusOr<ImageMetrics> m = compareImages(img, constantImage(1, 1, 1, 1, 1));
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->comparedPixels, 0);
  EXPECT_TRUE(std::isnan(m->rmse));
  EXPECT_TRUE(std::isnan(m->psnr));
}

TEST(CompareTest, SizeMismatchNamesBothSizes) {
  const absl::StatusOr<ImageMetrics> m =
      compareImages(constantImage(64, 32, 0, 0, 0), constantImage(32, 64, 0, 0, 0));
  ASSERT_FALSE(m.ok());
  EXPECT_EQ(m.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(m.status().message().find("64x32"), std::string::npos) << m.status();
  EXPECT_NE(m.status().message().find("32x64"), std::string::npos) << m.status();
}

// A deterministic normal deviate per (pixel, channel, stream): a hash, Box-Muller.
double gaussian(uint64_t i) {
  auto unit = [](uint64_t x) {
    x ^= x >> 33;
    x *= 0xff51afd7ed558ccdULL;
    x ^= x >> 33;
    x *= 0xc4ceb9fe1a85ec53ULL;
    x ^= x >> 33;
    return (static_cast<double>(x >> 11) + 0.5) / 9007199254740992.0;
  };
  return std::sqrt(-2.0 * std::log(unit(2 * i + 1))) * std::cos(6.283185307179586 * unit(2 * i + 2));
}

// Noise and patches of the same relMSE: only the patches keep their error after the blur.
TEST(CompareTest, LowFrequencyErrorSeparatesPatchesFromNoise) {
  const int w = 128, h = 128;
  const Image ref = constantImage(w, h, 0.5f, 0.5f, 0.5f);
  Image noisy = ref, patchy = ref;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c) {
        const uint64_t pixel = (static_cast<uint64_t>(y) * w + x) * 3 + c;
        const uint64_t patch = (static_cast<uint64_t>(y / 8) * (w / 8) + x / 8) * 3 + c;
        noisy.at(x, y, c) += static_cast<float>(0.05 * gaussian(pixel));
        patchy.at(x, y, c) += static_cast<float>(0.05 * gaussian(1u << 30 | patch));
      }
    }
  }
  const absl::StatusOr<ImageMetrics> n = compareImages(noisy, ref);
  const absl::StatusOr<ImageMetrics> p = compareImages(patchy, ref);
  ASSERT_TRUE(n.ok() && p.ok());
  EXPECT_NEAR(n->relMse / p->relMse, 1.0, 0.3);
  // Noise: about 1/49 of its relMSE (a 7 x 7 box); 8 x 8 patches: most of it.
  EXPECT_LT(n->lowFrequencyRelMse, n->relMse / 30.0);
  EXPECT_GT(p->lowFrequencyRelMse, p->relMse / 3.0);
  EXPECT_NEAR(n->seamStepRatio, 1.0, 0.25);
  for (int c = 0; c < 3; ++c) EXPECT_GT(p->lowFrequencyRelMseChannels[c], 0.0);
}

// A step at every 16-pixel block border, smaller than the noise: the seam ratio sees it at
// --block 16 and not at a grid it does not follow.
TEST(CompareTest, SeamRatioFindsStepsAtTheBlockBorders) {
  const int w = 128, h = 96;
  const Image ref = constantImage(w, h, 1.0f, 1.0f, 1.0f);
  Image seamed = ref, noisy = ref;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float block = static_cast<float>(((x / 16) + (y / 16)) % 2) * 0.03f;
      for (int c = 0; c < 3; ++c) {
        const float noise =
            static_cast<float>(0.05 * gaussian((static_cast<uint64_t>(y) * w + x) * 3 + c));
        noisy.at(x, y, c) += noise;
        seamed.at(x, y, c) += noise + block;
      }
    }
  }
  const absl::StatusOr<ImageMetrics> atBlocks = compareImages(seamed, ref, nullptr, {.blockSize = 16});
  const absl::StatusOr<ImageMetrics> offGrid = compareImages(seamed, ref, nullptr, {.blockSize = 13});
  const absl::StatusOr<ImageMetrics> clean = compareImages(noisy, ref, nullptr, {.blockSize = 16});
  ASSERT_TRUE(atBlocks.ok() && offGrid.ok() && clean.ok());
  EXPECT_GT(atBlocks->seamStepRatio, 2.0);
  EXPECT_NEAR(clean->seamStepRatio, 1.0, 0.25);
  EXPECT_LT(offGrid->seamStepRatio, atBlocks->seamStepRatio / 2.0);
  // No border inside one block: no ratio.
  const absl::StatusOr<ImageMetrics> one = compareImages(seamed, ref, nullptr, {.blockSize = 256});
  ASSERT_TRUE(one.ok());
  EXPECT_TRUE(std::isnan(one->seamStepRatio));
}

// A crop of a frame whose blocks have steps at their borders: the borders are the frame's,
// wherever the crop starts, so the crop's ratio sees them as the whole frame's does.
TEST(CompareTest, SeamRatioOfACropFollowsTheFramesBlocks) {
  const int w = 128, h = 96, x0 = 9, y0 = 5;
  Image frame = constantImage(w, h, 1.0f, 1.0f, 1.0f);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float block = static_cast<float>(((x / 16) + (y / 16)) % 2) * 0.03f;
      for (int c = 0; c < 3; ++c) {
        frame.at(x, y, c) +=
            block + static_cast<float>(0.05 * gaussian((static_cast<uint64_t>(y) * w + x) * 3 + c));
      }
    }
  }
  const int cw = w - x0 - 20, ch = h - y0 - 10;
  Image crop(cw, ch, {"R", "G", "B"});
  for (int y = 0; y < ch; ++y) {
    for (int x = 0; x < cw; ++x) {
      for (int c = 0; c < 3; ++c) crop.at(x, y, c) = frame.at(x + x0, y + y0, c);
    }
  }
  crop.setWindow({x0, y0, w, h});
  Image ref = constantImage(cw, ch, 1.0f, 1.0f, 1.0f);
  ref.setWindow({x0, y0, w, h});
  const absl::StatusOr<ImageMetrics> placed = compareImages(crop, ref, nullptr, {.blockSize = 16});
  crop.setWindow({0, 0, cw, ch});
  ref.setWindow({0, 0, cw, ch});
  const absl::StatusOr<ImageMetrics> unplaced = compareImages(crop, ref, nullptr, {.blockSize = 16});
  ASSERT_TRUE(placed.ok() && unplaced.ok());
  EXPECT_GT(placed->seamStepRatio, 2.0);
  EXPECT_LT(unplaced->seamStepRatio, placed->seamStepRatio / 2.0);
}

TEST(CompareTest, ArtefactOptionsOutOfRangeAreRejected) {
  const Image a = constantImage(4, 4, 1, 1, 1);
  EXPECT_EQ(compareImages(a, a, nullptr, {.blockSize = 0}).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(compareImages(a, a, nullptr, {.blurRadius = 0}).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(CompareTest, EmptyImagesAreRejected) {
  EXPECT_EQ(compareImages(Image(), Image()).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace pbgi
