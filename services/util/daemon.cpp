#include "services/util/daemon.h"

#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>

#include <fcntl.h>
#include <fmt/format.h>
#include <pthread.h>
#include <unistd.h>

namespace pbgi {

namespace {

sigset_t stopSignals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGINT);
  return set;
}

}  // namespace

void blockStopSignals() {
  const sigset_t set = stopSignals();
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
}

int waitForStopSignal() {
  const sigset_t set = stopSignals();
  int signal = 0;
  while (sigwait(&set, &signal) != 0) {
  }
  return signal;
}

absl::Status writeFileAtomic(const std::string& path, const std::string& text, unsigned mode) {
  const std::string temp = fmt::format("{}.tmp{}", path, static_cast<long>(::getpid()));
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_TRUNC, mode);
  if (fd < 0) return absl::PermissionDeniedError(fmt::format("{}: cannot write", temp));
  const bool written = ::write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size());
  const bool synced = ::fsync(fd) == 0;
  ::close(fd);
  if (!written || !synced || std::rename(temp.c_str(), path.c_str()) != 0) {
    ::unlink(temp.c_str());
    return absl::InternalError(fmt::format("{}: write failed (disk full?)", path));
  }
  return absl::OkStatus();
}

std::string newToken() {
  std::random_device entropy;  // /dev/urandom on Linux
  std::string token;
  for (int i = 0; i < 4; ++i) token += fmt::format("{:08x}", entropy());
  return token;
}

absl::StatusOr<std::string> readTokenFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) {
    // A value without a folder or an extension that names no file may be the token itself,
    // passed by mistake: never echo it.
    const bool pathLike =
        path.find('/') != std::string::npos || path.find('.') != std::string::npos;
    return absl::NotFoundError(
        pathLike ? fmt::format("{}: cannot read the token file", path)
                 : "--token-file: no such file (the value is not shown: it may be the token "
                   "itself; pass the file that holds it, such as the coordinator's <state>/token, "
                   "or set PBGI_TOKEN)");
  }
  std::string token;
  std::getline(in, token);
  if (token.empty()) {
    return absl::InvalidArgumentError(
        fmt::format("{}:1: expected the farm's token on the first line", path));
  }
  return token;
}

absl::StatusOr<std::string> loadOrCreateToken(const std::string& path) {
  if (std::filesystem::exists(path)) return readTokenFile(path);
  const std::string token = newToken();
  std::error_code ec;
  std::filesystem::create_directories(std::filesystem::path(path).parent_path(), ec);
  if (absl::Status s = writeFileAtomic(path, token + "\n", 0600); !s.ok()) return s;
  return token;
}

}  // namespace pbgi
