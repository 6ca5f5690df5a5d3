#include <CLI/CLI.hpp>

#include "services/cli/cli.h"

namespace pbgi::cli {
void registerRenderCommand(CLI::App& app, CommandAction& action) {}
}  // namespace pbgi::cli
