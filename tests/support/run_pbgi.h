#pragma once
// Runs the real `pbgi` binary as a user or a script would, and captures what it says.
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "tests/support/test_paths.h"

namespace pbgi::testing {

struct RunResult {
  int exitCode = -1;
  std::string out;
  std::string err;
  std::string output() const { return out + err; }
};

inline std::string shellQuote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += (c == '\'') ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

inline std::string slurpFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// `args` go to the shell as written (quote paths with shellQuote where needed).
inline RunResult runPbgi(const std::string& args) {
  const std::filesystem::path dir = makeTempDir("run-pbgi");
  const std::filesystem::path out = dir / "stdout.txt", err = dir / "stderr.txt";
  const std::string command = shellQuote(pbgiBinary().string()) + " " + args + " >" +
                              shellQuote(out.string()) + " 2>" + shellQuote(err.string());
  const int status = std::system(command.c_str());
  RunResult result;
  if (status != -1 && WIFEXITED(status)) result.exitCode = WEXITSTATUS(status);
  result.out = slurpFile(out);
  result.err = slurpFile(err);
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);
  return result;
}

}  // namespace pbgi::testing
