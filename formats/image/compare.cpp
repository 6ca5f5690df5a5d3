#include "formats/image/compare.h"

#include <cmath>
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

}  // namespace

absl::StatusOr<ImageMetrics> compareImages(const Image& image, const Image& reference,
                                           Image* diffOut) {
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
    return metrics;
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat("comparing images: ", e.what()));
  }
}

}  // namespace pbgi
