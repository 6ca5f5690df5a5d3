#pragma once
// The `pbgi` command line (README, "Commands"). Exit status: 0 success, 1 the work failed,
// 2 bad usage or bad input. Errors go to stderr as "pbgi: error: ...".

#include <cstdint>
#include <functional>
#include <optional>

#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

namespace CLI {
class App;
}

namespace pbgi {
class IntegratorParams;
struct RenderOverrides;
struct ShotDesc;
}

namespace pbgi::cli {

enum ExitCode : int { kExitOk = 0, kExitFailed = 1, kExitBadInput = 2 };

// What a subcommand does once its flags are parsed.
using CommandAction = std::function<int()>;

// Each subcommand registers itself on the app and sets `action` for when it is chosen.
void registerRenderCommand(CLI::App& app, CommandAction& action);
void registerCompareCommand(CLI::App& app, CommandAction& action);
void registerBakeCommand(CLI::App& app, CommandAction& action);
void registerInspectCommand(CLI::App& app, CommandAction& action);
void registerRunCommand(CLI::App& app, CommandAction& action);
void registerCheckCommand(CLI::App& app, CommandAction& action);
// submit, status, cancel, retry, logs, workers.
void registerFarmCommands(CLI::App& app, CommandAction& action);

// "pbgi <version>".
std::string versionString();

// A size in bytes: a number with an optional K, M or G (binary: 1K = 1024). Errors name the
// flag.
absl::StatusOr<uint64_t> parseByteSize(std::string_view text, std::string_view flag);

// Prints "pbgi: error: <message>" and returns the exit code for the status: bad input
// (InvalidArgument, NotFound, FailedPrecondition, OutOfRange) is 2, anything else 1.
int reportError(const absl::Status& status);

// The integrator parameter flags that render, run and submit share: --gather, --quality, and
// --set KEY=VALUE for any parameter an integrator declares (repeatable).
void addIntegratorParamFlags(CLI::App& cmd, std::vector<std::string>& set, std::string& gather,
                             std::string& quality);
// Fills `params` from the --set lines and named flags ({key, text}; empty text: not given).
// Errors name the flag and what the parameter expects.
absl::Status integratorParamFlags(const std::vector<std::string>& set,
                                  const std::vector<std::pair<std::string_view, std::string>>& named,
                                  IntegratorParams* params);

// The image flags of render, run and submit: --resolution W,H or --scale F (of each view),
// --seed, --aovs and --exr-compression.
struct ImageFlags {
  std::string resolution;
  double scale = 0;
  std::optional<uint64_t> seed;
  std::optional<std::string> aovs;  // a list of frameAovs(), all or none
  std::string exrCompression;       // empty: zip
};
void addImageFlags(CLI::App& cmd, ImageFlags& flags);
// The flags as overrides of `shot`: its resolution, seed and output options. Errors name the
// flag.
absl::Status imageOverrides(const ImageFlags& flags, const ShotDesc& shot,
                            RenderOverrides* overrides);

// "1-3,7" -> {1, 2, 3, 7}: the --frames of submit, run, render and check. InvalidArgument
// naming the text.
absl::StatusOr<std::vector<int>> parseFrameList(const std::string& text);

int run(int argc, char** argv);

}  // namespace pbgi::cli
