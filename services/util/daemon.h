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

// A new random farm token: 32 hex digits from the system's entropy source.
std::string newToken();
// The farm token in `path`: its first line. NotFound when the file cannot be read,
// InvalidArgument when its first line is empty.
absl::StatusOr<std::string> readTokenFile(const std::string& path);
// readTokenFile(path); when the file does not exist, a newToken() is written there (mode
// 0600) and returned.
absl::StatusOr<std::string> loadOrCreateToken(const std::string& path);

}  // namespace pbgi
