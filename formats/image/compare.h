#pragma once
// Error metrics of a rendered image against a reference, over the R, G and B channels (by
// name; else the first three channels; a one-channel image counts as grey).
//
// Definitions (a = image, b = reference, one value per pixel and channel):
//   RMSE   = sqrt(mean((a - b)^2))
//   relMSE = mean((a - b)^2 / (b^2 + kRelMseEpsilon)), kRelMseEpsilon = 1e-2. Dividing by
//            the reference's square makes an error of 1% cost the same in a dark corner as
//            on a light source; epsilon keeps near-black pixels from dominating.
//   PSNR   = 10 * log10(kPsnrPeak^2 / MSE) dB with kPsnrPeak = 1.0, i.e. 20 * log10(1 / RMSE),
//            which is OIIO's (ImageBufAlgo::compare, idiff) definition. A fixed peak keeps
//            PSNR comparable between renders of different scenes; for HDR images with values
//            above 1 it is only a relative figure. +infinity when the images are equal.
// The means run over the pixels compared. Pixels where either image has a NaN or an
// infinity in R, G or B are counted and left out of every metric: one firefly would
// otherwise make every figure NaN or infinite. When no pixel is left, the metrics are NaN.

#include <array>
#include <cstdint>

#include <absl/status/statusor.h>

#include "core/render/image.h"

namespace pbgi {

inline constexpr double kRelMseEpsilon = 1e-2;
inline constexpr double kPsnrPeak = 1.0;

struct ChannelMetrics {
  double meanImage = 0.0;
  double meanReference = 0.0;
  double rmse = 0.0;
  double relMse = 0.0;
  double psnr = 0.0;  // dB
};

struct ImageMetrics {
  std::array<ChannelMetrics, 3> channels;  // R, G, B
  // Over R, G and B together (every value of every compared pixel weighs the same).
  double rmse = 0.0;
  double relMse = 0.0;
  double psnr = 0.0;  // dB
  int64_t comparedPixels = 0;
  // Pixels with a non-finite R, G or B value in each image.
  int64_t nonFiniteImage = 0;
  int64_t nonFiniteReference = 0;
};

// Compares `image` against `reference`; both must have the same width and height
// (InvalidArgument naming both sizes otherwise) and at least one pixel and channel. When
// `diffOut` is not null it receives |image - reference| per pixel as channels R, G, B
// (non-finite where either input is).
absl::StatusOr<ImageMetrics> compareImages(const Image& image, const Image& reference,
                                           Image* diffOut = nullptr);

}  // namespace pbgi
