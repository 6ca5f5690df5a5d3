#pragma once
// Strict loading of shot files (README, "Shot files") with toml++. Every unknown key, wrong
// type, out-of-range value or missing file is an InvalidArgument (or NotFound) error whose
// message starts with "file:line:column:" and says what was expected.

#include <string>
#include <string_view>

#include <absl/status/statusor.h>

#include "core/scene/shot.h"

namespace pbgi {

absl::StatusOr<ShotDesc> loadShotFile(const std::string& path);
// Parses text as if it were the file at `path` (relative paths resolve against its folder).
absl::StatusOr<ShotDesc> parseShot(std::string_view text, const std::string& path);

}  // namespace pbgi
