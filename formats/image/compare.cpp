#include "formats/image/compare.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <limits>
#include <vector>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <absl/strings/str_cat.h>

#include "formats/image/rgb_channels.h"

namespace pbgi {
namespace {

bool finiteRgb(const float* v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

double psnrFromMse(double mse) {
  if (std::isnan(mse)) return mse;
  if (mse == 0.0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(kPsnrPeak * kPsnrPeak / mse);
}

// A box blur of one channel over the pixels marked in `in` (the box clipped at the image's edges
// and at pixels left out), by a summed-area table of values and counts. Left-out pixels get 0.
// OIIO's convolution has no mask: it would average left-out pixels in.
std::vector<double> maskedBoxBlur(const std::vector<float>& rgb, int channel,
                                  const std::vector<uint8_t>& in, int width, int height,
                                  int radius) {
  const size_t stride = static_cast<size_t>(width) + 1;
  std::vector<double> sum(stride * (height + 1), 0.0), count(stride * (height + 1), 0.0);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const size_t p = static_cast<size_t>(y) * width + x;
      const size_t at = (y + 1) * stride + x + 1;
      const double v = in[p] ? rgb[p * 3 + channel] : 0.0;
      sum[at] = v + sum[at - 1] + sum[at - stride] - sum[at - stride - 1];
      count[at] = in[p] + count[at - 1] + count[at - stride] - count[at - stride - 1];
    }
  }
  const auto box = [&](const std::vector<double>& t, int x0, int y0, int x1, int y1) {
    return t[y1 * stride + x1] - t[y0 * stride + x1] - t[y1 * stride + x0] + t[y0 * stride + x0];
  };
  std::vector<double> out(static_cast<size_t>(width) * height, 0.0);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const size_t p = static_cast<size_t>(y) * width + x;
      if (!in[p]) continue;
      const int x0 = std::max(0, x - radius), x1 = std::min(width, x + radius + 1);
      const int y0 = std::max(0, y - radius), y1 = std::min(height, y + radius + 1);
      out[p] = box(sum, x0, y0, x1, y1) / box(count, x0, y0, x1, y1);
    }
  }
  return out;
}

// The low-frequency relMSE and the seam step ratio (compare.h), from the packed images with
// left-out pixels marked. Pixel (0, 0) is the frame's (originX, originY): block borders lie on the
// frame's grid, wherever a crop starts.
void artefactMetrics(const std::vector<float>& a, const std::vector<float>& b,
                     const std::vector<uint8_t>& in, int width, int height, int originX, int originY,
                     const CompareOptions& options, ImageMetrics* metrics) {
  const size_t pixels = static_cast<size_t>(width) * height;
  const double n = static_cast<double>(metrics->comparedPixels);
  std::vector<double> error(pixels, 0.0);
  double total = 0.0;
  for (int c = 0; c < 3; ++c) {
    const std::vector<double> blurA = maskedBoxBlur(a, c, in, width, height, options.blurRadius);
    const std::vector<double> blurB = maskedBoxBlur(b, c, in, width, height, options.blurRadius);
    double rel = 0.0;
    for (size_t p = 0; p < pixels; ++p) {
      if (!in[p]) continue;
      const double d = blurA[p] - blurB[p];
      rel += d * d / (blurB[p] * blurB[p] + kRelMseEpsilon);
      error[p] += (a[p * 3 + c] - b[p * 3 + c]) / std::sqrt(blurB[p] * blurB[p] + kRelMseEpsilon);
    }
    metrics->lowFrequencyRelMseChannels[c] = rel / n;
    total += rel / n;
  }
  metrics->lowFrequencyRelMse = total / 3.0;

  // Steps of the error between neighbours, each side averaged along the border's direction
  // (the error at (x, y) and (x + 1, y) over y - r .. y + r; transposed for rows).
  const int r = options.blurRadius;
  const auto at = [&](int x, int y) { return static_cast<size_t>(y) * width + x; };
  double border = 0.0, elsewhere = 0.0;
  uint64_t borderPairs = 0, elsewherePairs = 0;
  const auto step = [&](bool columns, int u, int v) {
    // columns: the pair (u, v), (u + 1, v); else (v, u), (v, u + 1). u runs across the
    // border, v along it.
    const int alongSize = columns ? height : width;
    if (v - r < 0 || v + r >= alongSize) return;
    double left = 0.0, right = 0.0;
    for (int k = v - r; k <= v + r; ++k) {
      const size_t p = columns ? at(u, k) : at(k, u);
      const size_t q = columns ? at(u + 1, k) : at(k, u + 1);
      if (!in[p] || !in[q]) return;
      left += error[p];
      right += error[q];
    }
    const double d = (right - left) / (2 * r + 1);
    if (((columns ? originX : originY) + u + 1) % options.blockSize == 0) {
      border += d * d;
      ++borderPairs;
    } else {
      elsewhere += d * d;
      ++elsewherePairs;
    }
  };
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x + 1 < width; ++x) step(true, x, y);
  }
  for (int x = 0; x < width; ++x) {
    for (int y = 0; y + 1 < height; ++y) step(false, y, x);
  }
  metrics->seamStepRatio = borderPairs > 0 && elsewherePairs > 0 && elsewhere > 0.0
                               ? (border / borderPairs) / (elsewhere / elsewherePairs)
                               : std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

absl::StatusOr<ImageMetrics> compareImages(const Image& image, const Image& reference,
                                           Image* diffOut, const CompareOptions& options) {
  if (options.blockSize < 1 || options.blurRadius < 1) {
    return absl::InvalidArgumentError(absl::StrCat("compare: the block size (",
                                                   options.blockSize, ") and blur radius (",
                                                   options.blurRadius, ") must be at least 1"));
  }
  if (image.width() != reference.width() || image.height() != reference.height()) {
    return absl::InvalidArgumentError(absl::StrCat("image sizes differ: image is ", image.width(),
                                                   "x", image.height(), ", reference is ",
                                                   reference.width(), "x", reference.height()));
  }
  if (image.width() == 0 || image.height() == 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot compare empty images (", image.width(), "x", image.height(), ")"));
  }
  if (image.channelCount() == 0 || reference.channelCount() == 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("cannot compare images without channels: image has ", image.channelCount(),
                     ", reference has ", reference.channelCount()));
  }

  const int width = image.width();
  const int height = image.height();
  const size_t pixels = static_cast<size_t>(width) * height;
  std::vector<float> a = detail::packRgb(image);
  std::vector<float> b = detail::packRgb(reference);

  try {
    const OIIO::ImageSpec spec(width, height, 3, OIIO::TypeDesc::FLOAT);
    OIIO::ImageBuf bufA(spec, a.data());
    OIIO::ImageBuf bufB(spec, b.data());

    if (diffOut != nullptr) {
      Image diff(width, height, {"R", "G", "B"});
      OIIO::ImageBuf bufDiff(spec, diff.pixels().data());
      if (!OIIO::ImageBufAlgo::absdiff(bufDiff, bufA, bufB)) {
        return absl::InternalError(absl::StrCat("OIIO absdiff failed: ", bufDiff.geterror()));
      }
      *diffOut = std::move(diff);
    }

    // Left-out pixels become 0 in both buffers, so they add nothing to OIIO's sums; the
    // means are then rescaled from all pixels to the compared ones.
    ImageMetrics metrics;
    std::array<double, 3> sumA{}, sumB{}, sumRel{};
    std::vector<uint8_t> compared(pixels, 0);
    for (size_t p = 0; p < pixels; ++p) {
      float* va = &a[p * 3];
      float* vb = &b[p * 3];
      const bool finiteA = finiteRgb(va);
      const bool finiteB = finiteRgb(vb);
      if (!finiteA) ++metrics.nonFiniteImage;
      if (!finiteB) ++metrics.nonFiniteReference;
      if (!finiteA || !finiteB) {
        for (int c = 0; c < 3; ++c) va[c] = vb[c] = 0.0f;
        continue;
      }
      ++metrics.comparedPixels;
      compared[p] = 1;
      for (int c = 0; c < 3; ++c) {
        const double da = va[c];
        const double db = vb[c];
        sumA[c] += da;
        sumB[c] += db;
        sumRel[c] += (da - db) * (da - db) / (db * db + kRelMseEpsilon);
      }
    }

    const double n = static_cast<double>(metrics.comparedPixels);
    const double toCompared =
        n > 0 ? static_cast<double>(pixels) / n : std::numeric_limits<double>::quiet_NaN();
    double mseTotal = 0.0;
    double relTotal = 0.0;
    for (int c = 0; c < 3; ++c) {
      OIIO::ROI roi = OIIO::get_roi(spec);
      roi.chbegin = c;
      roi.chend = c + 1;
      // Thresholds only classify differences as warnings or failures, which we do not use;
      // with them at the maximum `error` means that OIIO itself failed.
      constexpr float kNoThreshold = std::numeric_limits<float>::max();
      const auto result = OIIO::ImageBufAlgo::compare(bufA, bufB, kNoThreshold, kNoThreshold, roi);
      if (result.error || bufA.has_error() || bufB.has_error()) {
        return absl::InternalError(
            absl::StrCat("OIIO compare failed: ", bufA.geterror(), bufB.geterror()));
      }
      const double mse = result.rms_error * result.rms_error * toCompared;
      ChannelMetrics& m = metrics.channels[c];
      m.meanImage = sumA[c] / n;
      m.meanReference = sumB[c] / n;
      m.rmse = std::sqrt(mse);
      m.relMse = sumRel[c] / n;
      m.psnr = psnrFromMse(mse);
      mseTotal += mse;
      relTotal += m.relMse;
    }
    metrics.rmse = std::sqrt(mseTotal / 3.0);
    metrics.relMse = relTotal / 3.0;
    metrics.psnr = psnrFromMse(mseTotal / 3.0);
    if (metrics.comparedPixels > 0) {
      const ImageWindow window = image.window();
      artefactMetrics(a, b, compared, width, height, window.x, window.y, options, &metrics);
    } else {
      metrics.lowFrequencyRelMse = metrics.seamStepRatio = std::numeric_limits<double>::quiet_NaN();
      metrics.lowFrequencyRelMseChannels.fill(metrics.lowFrequencyRelMse);
    }
    return metrics;
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat("comparing images: ", e.what()));
  }
}

}  // namespace pbgi
