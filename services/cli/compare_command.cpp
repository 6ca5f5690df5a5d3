// `pbgi compare IMAGE REFERENCE [--diff OUT.exr] [--block N] [--blur R] [--json]`: error metrics of a render
// against a reference (definitions in formats/image/compare.h).

#include <cmath>
#include <cstdio>
#include <memory>
#include <string>

#include <absl/strings/str_cat.h>
#include <fmt/format.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "formats/image/compare.h"
#include "formats/image/image_io.h"
#include "services/cli/cli.h"

namespace pbgi::cli {
namespace {

struct CompareCommandOptions {
  std::string image;
  std::string reference;
  std::string diff;
  bool json = false;
  CompareOptions metrics;
};

// JSON has no NaN or infinity; null stands for both (PSNR of identical images, metrics of an
// image with no finite pixel).
nlohmann::ordered_json number(double v) {
  return std::isfinite(v) ? nlohmann::ordered_json(v) : nlohmann::ordered_json(nullptr);
}

std::string toJson(const CompareCommandOptions& options, const Image& image, const ImageMetrics& m) {
  static constexpr const char* kNames[3] = {"R", "G", "B"};
  nlohmann::ordered_json channels = nlohmann::ordered_json::object();
  for (int c = 0; c < 3; ++c) {
    const ChannelMetrics& ch = m.channels[c];
    channels[kNames[c]] = {{"mean", number(ch.meanImage)},
                           {"mean_reference", number(ch.meanReference)},
                           {"rmse", number(ch.rmse)},
                           {"relmse", number(ch.relMse)},
                           {"psnr", number(ch.psnr)},
                           {"lowfreq_relmse", number(m.lowFrequencyRelMseChannels[c])}};
  }
  nlohmann::ordered_json out = {{"image", options.image},
                                {"reference", options.reference},
                                {"width", image.width()},
                                {"height", image.height()},
                                {"rmse", number(m.rmse)},
                                {"relmse", number(m.relMse)},
                                {"psnr", number(m.psnr)},
                                {"lowfreq_relmse", number(m.lowFrequencyRelMse)},
                                {"seam_step_ratio", number(m.seamStepRatio)},
                                {"block", options.metrics.blockSize},
                                {"blur", 2 * options.metrics.blurRadius + 1},
                                {"relmse_epsilon", number(kRelMseEpsilon)},
                                {"psnr_peak", number(kPsnrPeak)},
                                {"compared_pixels", m.comparedPixels},
                                {"nonfinite_image", m.nonFiniteImage},
                                {"nonfinite_reference", m.nonFiniteReference},
                                {"channels", std::move(channels)}};
  if (!options.diff.empty()) out["diff"] = options.diff;
  // Paths that are not UTF-8 are printed with U+FFFD in place of the bytes that are not.
  return out.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace);
}

void printTable(const CompareCommandOptions& options, const Image& image, const ImageMetrics& m) {
  std::printf("image      %s (%dx%d)\n", options.image.c_str(), image.width(), image.height());
  std::printf("reference  %s\n", options.reference.c_str());
  std::printf("%-8s %12s %12s %12s %12s %10s %14s\n", "channel", "mean", "mean ref", "RMSE",
              "relMSE", "PSNR dB", "low-freq relMSE");
  static constexpr const char* kNames[3] = {"R", "G", "B"};
  for (int c = 0; c < 3; ++c) {
    const ChannelMetrics& ch = m.channels[c];
    std::printf("%-8s %12.6g %12.6g %12.6g %12.6g %10.2f %14.6g\n", kNames[c], ch.meanImage,
                ch.meanReference, ch.rmse, ch.relMse, ch.psnr, m.lowFrequencyRelMseChannels[c]);
  }
  const double meanImage =
      (m.channels[0].meanImage + m.channels[1].meanImage + m.channels[2].meanImage) / 3.0;
  const double meanRef =
      (m.channels[0].meanReference + m.channels[1].meanReference + m.channels[2].meanReference) /
      3.0;
  std::printf("%-8s %12.6g %12.6g %12.6g %12.6g %10.2f %14.6g\n", "RGB", meanImage, meanRef,
              m.rmse, m.relMse, m.psnr, m.lowFrequencyRelMse);
  std::printf("relMSE = mean((a-b)^2 / (b^2 + %g)); PSNR peak %g; low-freq: both blurred %dx%d\n",
              kRelMseEpsilon, kPsnrPeak, 2 * options.metrics.blurRadius + 1,
              2 * options.metrics.blurRadius + 1);
  std::printf("seams      error step across %d-pixel block borders / elsewhere: %.3f\n",
              options.metrics.blockSize, m.seamStepRatio);
  const int64_t total = static_cast<int64_t>(image.width()) * image.height();
  std::printf("compared %lld of %lld pixels; non-finite pixels: image %lld, reference %lld\n",
              static_cast<long long>(m.comparedPixels), static_cast<long long>(total),
              static_cast<long long>(m.nonFiniteImage),
              static_cast<long long>(m.nonFiniteReference));
  if (!options.diff.empty()) std::printf("diff       %s\n", options.diff.c_str());
}

int runCompare(const CompareCommandOptions& options) {
  absl::StatusOr<Image> image = readImage(options.image);
  if (!image.ok()) return reportError(image.status());
  absl::StatusOr<Image> reference = readImage(options.reference);
  if (!reference.ok()) return reportError(reference.status());

  Image diff;
  absl::StatusOr<ImageMetrics> metrics =
      compareImages(*image, *reference, options.diff.empty() ? nullptr : &diff, options.metrics);
  if (!metrics.ok()) {
    return reportError(absl::Status(
        metrics.status().code(),
        absl::StrCat(options.image, " vs ", options.reference, ": ", metrics.status().message())));
  }
  if (!options.diff.empty()) {
    diff.setMetadata("pbgi:diffImage", options.image);
    diff.setMetadata("pbgi:diffReference", options.reference);
    if (absl::Status s = writeExr(diff, options.diff); !s.ok()) return reportError(s);
  }
  if (options.json) {
    std::printf("%s\n", toJson(options, *image, *metrics).c_str());
  } else {
    printTable(options, *image, *metrics);
  }
  return std::fflush(stdout) == 0 ? kExitOk : kExitFailed;
}

}  // namespace

void registerCompareCommand(CLI::App& app, CommandAction& action) {
  auto options = std::make_shared<CompareCommandOptions>();
  CLI::App* cmd = app.add_subcommand(
      "compare",
      "Print error metrics (per-channel means, RMSE, relMSE, PSNR, and the artefacts: "
      "low-frequency relMSE and seams at the cut blocks' borders) of IMAGE against REFERENCE");
  cmd->add_option("IMAGE", options->image, "Image to measure (any format OIIO reads)")->required();
  cmd->add_option("REFERENCE", options->reference, "Reference image of the same size")->required();
  cmd->add_option("--diff", options->diff,
                  "Write |IMAGE - REFERENCE| per pixel (R, G, B) to this OpenEXR file");
  cmd->add_option("--block", options->metrics.blockSize,
                  "Pixels a side of the render's cut blocks, whose borders the seam measure "
                  "looks at (the shot's cut_block)")
      ->default_val(64)
      ->check(CLI::Range(8, 1024));
  cmd->add_option("--blur", options->metrics.blurRadius,
                  "Radius of the box blur of the low-frequency error, in pixels (3: 7x7)")
      ->default_val(3)
      ->check(CLI::Range(1, 64));
  cmd->add_flag("--json", options->json,
                "Print one line of JSON instead of the table (null for NaN or infinity)");
  // `action` belongs to run() and outlives parsing, which is when this callback fires.
  cmd->callback([options, &action] { action = [options] { return runCompare(*options); }; });
}

}  // namespace pbgi::cli
