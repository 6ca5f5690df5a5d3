#include "services/cli/cli.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>

#include <absl/strings/numbers.h>
#include <absl/strings/str_split.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <CLI/CLI.hpp>

#include "core/render/integrators.h"
#include "core/render/renderer.h"
#include "core/scene/shot.h"
#include "core/util/log.h"
#include "core/util/status.h"
#include "formats/image/image_io.h"
#include "services/util/cli_checks.h"

namespace pbgi::cli {

int reportError(const absl::Status& status) {
  std::fprintf(stderr, "pbgi: error: %s\n", std::string(status.message()).c_str());
  switch (status.code()) {
    case absl::StatusCode::kInvalidArgument:
    case absl::StatusCode::kNotFound:
    case absl::StatusCode::kFailedPrecondition:
    case absl::StatusCode::kOutOfRange:
    case absl::StatusCode::kPermissionDenied:  // an output outside the farm's root
      return kExitBadInput;
    default:
      return kExitFailed;
  }
}

std::string versionString() { return std::string("pbgi ") + PBGI_VERSION; }

absl::StatusOr<uint64_t> parseByteSize(std::string_view text, std::string_view flag) {
  uint64_t value = 0;
  const char* end = text.data() + text.size();
  const auto [p, ec] = std::from_chars(text.data(), end, value);
  int shift = 0;
  if (ec == std::errc() && p + 1 == end) {
    switch (*p) {
      case 'K': case 'k': shift = 10; break;
      case 'M': case 'm': shift = 20; break;
      case 'G': case 'g': shift = 30; break;
      default: shift = -1;
    }
  } else if (ec != std::errc() || p != end) {
    shift = -1;
  }
  if (shift < 0 || value == 0 || value > (UINT64_MAX >> shift)) {
    return absl::InvalidArgumentError(fmt::format(
        "{} {}: expected a positive size in bytes, optionally with K, M or G (e.g. 256M)", flag,
        text));
  }
  return value << shift;
}

absl::StatusOr<std::vector<int>> parseFrameList(const std::string& text) {
  std::vector<int> frames;
  for (const absl::string_view part : absl::StrSplit(text, ',', absl::SkipWhitespace())) {
    const std::vector<absl::string_view> ends = absl::StrSplit(part, absl::MaxSplits('-', 1));
    int first = 0;
    int last = 0;
    const bool ok = absl::SimpleAtoi(ends[0], &first) &&
                    (ends.size() == 1 ? (last = first, true) : absl::SimpleAtoi(ends[1], &last)) &&
                    first <= last && last - first < 1'000'000;
    if (!ok) {
      return absl::InvalidArgumentError(
          fmt::format("--frames {}: '{}' is not a frame or a range (expected e.g. 1-3,7)", text,
                      std::string(part)));
    }
    for (int f = first; f <= last; ++f) frames.push_back(f);
  }
  if (frames.empty()) {
    return absl::InvalidArgumentError(fmt::format("--frames {}: no frames", text));
  }
  return frames;
}

void addImageFlags(CLI::App& cmd, ImageFlags& flags) {
  auto* size = cmd.add_option("--resolution", flags.resolution,
                              "Image size W,H of each view (default: the shot's resolution)");
  cmd.add_option("--scale", flags.scale,
                 "Scale the shot's resolution, e.g. 0.5 for a half-size check render")
      ->check(positiveNumber())
      ->excludes(size);
  cmd.add_option("--seed", flags.seed,
                 "Sampling seed (default: the shot's seed); a render is a function of it");
  cmd.add_option("--aovs", flags.aovs,
                 fmt::format("AOV layers the EXR keeps besides RGBA: a list of {}, or all "
                             "(default) or none",
                             fmt::join(frameAovs(), ", ")));
  cmd.add_option(
      "--exr-compression", flags.exrCompression,
      fmt::format("EXR compression: {} (default zip)", fmt::join(exrCompressions(), ", ")));
}

absl::Status imageOverrides(const ImageFlags& flags, const ShotDesc& shot,
                            RenderOverrides* overrides) {
  if (!flags.resolution.empty()) {
    int w = 0, h = 0;
    const char* end = flags.resolution.data() + flags.resolution.size();
    const auto [comma, ec1] = std::from_chars(flags.resolution.data(), end, w);
    const bool parsed = ec1 == std::errc() && comma != end && *comma == ',' &&
                        std::from_chars(comma + 1, end, h).ptr == end;
    if (!parsed) {
      return absl::InvalidArgumentError(
          fmt::format("--resolution '{}': expected W,H (two whole numbers from 1 to {})",
                      flags.resolution, kMaxShotResolution));
    }
    overrides->width = w;
    overrides->height = h;
  } else if (flags.scale > 0) {
    const auto scaled = [&](int side) {
      return static_cast<int>(
          std::clamp<double>(std::lround(side * flags.scale), 1, kMaxShotResolution));
    };
    overrides->width = scaled(shot.width);
    overrides->height = scaled(shot.height);
  }
  if (!flags.resolution.empty() || flags.scale > 0) {
    PBGI_RETURN_IF_ERROR(checkImageSize(overrides->width, overrides->height, shot.camera.views,
                                        flags.resolution.empty() ? "--scale" : "--resolution"));
  }
  overrides->seed = flags.seed;
  if (flags.aovs || !flags.exrCompression.empty()) {
    OutputOptions& output = overrides->output.emplace();
    if (flags.aovs && *flags.aovs != "all") {
      output.aovs.emplace();
      if (*flags.aovs != "none") {
        for (const absl::string_view part :
             absl::StrSplit(*flags.aovs, ',', absl::SkipWhitespace())) {
          output.aovs->emplace_back(part);
        }
      }
      if (absl::Status s = checkAovs(*output.aovs); !s.ok()) {
        return absl::InvalidArgumentError(
            fmt::format("--aovs {}: {} (or all, or none)", *flags.aovs, std::string(s.message())));
      }
    }
    if (!flags.exrCompression.empty()) {
      PBGI_RETURN_IF_ERROR(checkExrCompression(flags.exrCompression, "--exr-compression"));
      output.exrCompression = flags.exrCompression;
    }
  }
  return absl::OkStatus();
}

void addIntegratorParamFlags(CLI::App& cmd, std::vector<std::string>& set, std::string& gather,
                             std::string& quality) {
  cmd.add_option("--gather", gather,
                 "PBGI: how diffuse receivers gather: bidirectional (default) or per-pixel");
  cmd.add_option("--quality", quality,
                 "PBGI preset of every gather threshold: draft, default, high (default: the "
                 "shot's quality)");
  cmd.add_option("--set", set,
                 fmt::format("An integrator parameter, KEY=VALUE (repeatable): {}",
                             fmt::join(allParamKeys(), ", ")));
}

absl::Status integratorParamFlags(const std::vector<std::string>& set,
                                  const std::vector<std::pair<std::string_view, std::string>>& named,
                                  IntegratorParams* params) {
  for (const auto& [key, text] : named) {
    if (text.empty()) continue;
    std::string flag = "--" + std::string(key);
    std::replace(flag.begin(), flag.end(), '_', '-');
    if (absl::Status s = setParamText(*params, key, text, {flag}); !s.ok()) return s;
  }
  for (const std::string& line : set) {
    const size_t eq = line.find('=');
    if (eq == std::string::npos) {
      return absl::InvalidArgumentError(
          fmt::format("--set {}: expected KEY=VALUE (keys: {})", line, fmt::join(allParamKeys(), ", ")));
    }
    if (absl::Status s = setParamText(*params, line.substr(0, eq), line.substr(eq + 1),
                                      {"--set " + line});
        !s.ok()) {
      return s;
    }
  }
  return absl::OkStatus();
}

int run(int argc, char** argv) {
  CLI::App app{"pbgi: point-based global illumination renderer"};
  app.set_version_flag("--version", versionString());
  app.require_subcommand(1);
  bool verbose = false;
  bool quiet = false;
  // Global flags go before or after the subcommand: a subcommand passes what it does not
  // know up to here.
  app.fallthrough();
  app.add_flag("-v,--verbose", verbose, "Log debug messages");
  app.add_flag("-q,--quiet", quiet, "Log errors only: no progress, no stage times' log lines");

  CommandAction action;
  registerRenderCommand(app, action);
  registerCompareCommand(app, action);
  registerBakeCommand(app, action);
  registerInspectCommand(app, action);
  registerRunCommand(app, action);
  registerCheckCommand(app, action);
  registerFarmCommands(app, action);

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "pbgi: error: %s\n", e.what());
    std::fprintf(stderr, "Run with --help for more information.\n");
    return kExitBadInput;
  }
  log::setLevel(verbose ? log::Level::kDebug : quiet ? log::Level::kError : log::Level::kInfo);
  if (!action) {
    std::fprintf(stderr, "pbgi: error: no command given\n");
    return kExitBadInput;
  }
  try {
    return action();
  } catch (const std::exception& e) {
    // Library errors are Status; an exception here is a bug or resource exhaustion.
    std::fprintf(stderr, "pbgi: error: %s\n", e.what());
    return kExitFailed;
  }
}

}  // namespace pbgi::cli
