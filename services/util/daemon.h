#pragma once
// What the farm's processes share: stop signals, the farm token file, small files written
// atomically.
#include <string>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

namespace pbgi {

// Blocks SIGTERM and SIGINT in the calling thread and every thread it starts afterwards, so
// that waitForStopSignal() receives them instead of the default handler killing the process.
// Call before starting threads.
void blockStopSignals();
// Waits for SIGTERM or SIGINT (blocked first with blockStopSignals) and returns it.
int waitForStopSignal();

// Writes `text` to a temporary beside `path` with the given mode, then renames it into place.
absl::Status writeFileAtomic(const std::string& path, const std::string& text, unsigned mode);

// The farm token at `path`: its first line; when the file does not exist, a new random token
// is written there (mode 0600) and returned.
absl::StatusOr<std::string> loadOrCreateToken(const std::string& path);

}  // namespace pbgi
