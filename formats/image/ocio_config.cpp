#include "formats/image/ocio_config.h"

#include <cstdlib>
#include <filesystem>
#include <system_error>

namespace pbgi {

std::string defaultOcioConfigPath() {
  if (const char* env = std::getenv("OCIO"); env != nullptr && *env != '\0') return env;
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) return {};
  const std::filesystem::path shipped =
      exe.parent_path().parent_path() / "share" / "pbgi" / "ocio" / "config.ocio";
  if (std::filesystem::is_regular_file(shipped, ec)) return shipped.lexically_normal().string();
  return {};
}

}  // namespace pbgi
