#include <CLI/CLI.hpp>

#include "services/cli/cli.h"

namespace pbgi::cli {
// Filled in by the compare work (pbgi compare IMAGE REF [--diff OUT.exr]).
void registerCompareCommand(CLI::App& app, CommandAction& action) {}
}  // namespace pbgi::cli
