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
// Artefacts, which more samples do not fix (noise does not survive either measure):
//   low-frequency relMSE = relMSE of the two images after both are box-blurred over
//            (2 blurRadius + 1)^2 pixels (7 x 7 by default), over the compared pixels (the
//            box is clipped at the image's edges and at left-out pixels, the same for both).
//            Patches and a wrong mean show; noise falls by the box's area.
//   seam step ratio = the mean squared step of the error across the borders of the render's
//            cut blocks (a grid of `blockSize` pixels from the origin of the image's frame, so a
//            crop's borders lie where the full frame's do), against the mean squared step
//            between every other pair of neighbouring pixels. The error is
//            (a - b) / sqrt(b_blurred^2 + epsilon) summed over R, G and B, averaged along the
//            border's direction over 2 blurRadius + 1 pixels, so that a step that runs along
//            a border stands out of the noise. 1 where blocks join seamlessly; NaN when the
//            image has no border (no larger than one block).
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
  // Artefacts (above).
  double lowFrequencyRelMse = 0.0;
  std::array<double, 3> lowFrequencyRelMseChannels{};
  double seamStepRatio = 0.0;
};

struct CompareOptions {
  int blockSize = 64;  // the render's cut_block
  int blurRadius = 3;  // 7 x 7
};

// Compares `image` against `reference`; both must have the same width and height
// (InvalidArgument naming both sizes otherwise) and at least one pixel and channel. When
// `diffOut` is not null it receives |image - reference| per pixel as channels R, G, B
// (non-finite where either input is). Options out of range (a block or radius below 1) are
// InvalidArgument.
absl::StatusOr<ImageMetrics> compareImages(const Image& image, const Image& reference,
                                           Image* diffOut = nullptr,
                                           const CompareOptions& options = {});

}  // namespace pbgi
