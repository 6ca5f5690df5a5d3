#pragma once
// The `pbgi` command line (../shared/spec/cli.md). Exit status: 0 success, 1 the work failed,
// 2 bad usage or bad input. Errors go to stderr as "pbgi: error: ...".

#include <functional>

#include <string>
#include <string_view>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

namespace CLI {
class App;
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

int run(int argc, char** argv);

}  // namespace pbgi::cli
