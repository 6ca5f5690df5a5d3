#pragma once
// What the deploy/ tests share: a deployment file's command line as flags, run through its
// binary's own parser; certificates made by deploy/tls/make-certs.sh; and a coordinator and a
// worker started as processes from such command lines, which must meet.
#include <gtest/gtest.h>

#include <filesystem>
#include <optional>
#include <regex>
#include <string>
#include <utility>
#include <vector>

#include "services/farm/farm_client.h"
#include "services/farm/farm_tls.h"
#include "tests/support/farm_fixtures.h"
#include "tests/support/slurm_cluster.h"

namespace pbgi::testing {

// (flag, value) pairs of a command line in order, from `--flag=value` and `--flag value` (the
// daemons have no flag without a value; one before another flag or at the end maps to "").
// A word that is neither a flag nor a flag's value fails the test that needed it.
inline std::vector<std::pair<std::string, std::string>> flagPairs(
    const std::vector<std::string>& args) {
  std::vector<std::pair<std::string, std::string>> out;
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    EXPECT_TRUE(a.starts_with("--")) << "'" << a << "' is not a flag, nor a flag's value";
    const size_t eq = a.find('=');
    if (eq != std::string::npos) {
      out.emplace_back(a.substr(0, eq), a.substr(eq + 1));
    } else if (i + 1 < args.size() && !args[i + 1].starts_with("--")) {
      out.emplace_back(a, args[i + 1]);
      ++i;
    } else {
      out.emplace_back(a, "");
    }
  }
  return out;
}

// The value of `flag` in `args`; nullopt when it is not there.
inline std::optional<std::string> flagValue(const std::vector<std::string>& args,
                                            const std::string& flag) {
  for (const auto& [f, v] : flagPairs(args)) {
    if (f == flag) return v;
  }
  return std::nullopt;
}

// `args` with every value of `flag` replaced by `value`, in the form it was given in.
inline std::vector<std::string> withFlag(std::vector<std::string> args, const std::string& flag,
                                         const std::string& value) {
  for (size_t i = 0; i < args.size(); ++i) {
    if (args[i] == flag && i + 1 < args.size()) {
      args[i + 1] = value;
    } else if (args[i].starts_with(flag + "=")) {
      args[i] = flag + "=" + value;
    }
  }
  return args;
}

// The flags of `args` that start with "--tls-".
inline std::vector<std::pair<std::string, std::string>> tlsFlags(
    const std::vector<std::string>& args) {
  std::vector<std::pair<std::string, std::string>> out;
  for (auto& [f, v] : flagPairs(args)) {
    if (f.starts_with("--tls-")) out.emplace_back(f, v);
  }
  return out;
}

// `BINARY ARGS --help`: CLI11 checks each value as it parses it (a transform, a range) and
// then prints the help and exits 0; it answers --help before it looks for unknown flags, so
// each flag must also be one the help lists.
inline ::testing::AssertionResult binaryAccepts(const std::string& name,
                                                const std::vector<std::string>& args) {
  std::string command = shellQuote(binary(name).string());
  for (const std::string& a : args) command += " " + shellQuote(a);
  const ShellResult r = shell(command + " --help 2>&1");
  if (r.status != 0) {
    return ::testing::AssertionFailure()
           << name << " refuses its arguments (exit " << r.status << "):\n"
           << r.out;
  }
  for (const auto& [flag, value] : flagPairs(args)) {
    if (!std::regex_search(r.out,
                           std::regex("(^|[ ,])" + flag + "( |,|$)", std::regex::multiline))) {
      return ::testing::AssertionFailure() << name << " has no flag " << flag;
    }
  }
  return ::testing::AssertionSuccess();
}

// `deploy/tls/make-certs.sh DIR HOSTS...`.
inline ::testing::AssertionResult makeCerts(const std::filesystem::path& dir,
                                            const std::vector<std::string>& hosts) {
  std::string command = "sh " + shellQuote((sourceDir() / "deploy/tls/make-certs.sh").string()) +
                        " " + shellQuote(dir.string());
  for (const std::string& h : hosts) command += " " + shellQuote(h);
  const ShellResult r = shell(command + " 2>&1");
  if (r.status != 0) return ::testing::AssertionFailure() << command << ":\n" << r.out;
  return ::testing::AssertionSuccess();
}

// A pbgi-coordinator process started with `argv`, its gRPC address once it has written it to
// `addressFile` (the first line); its log in `log`.
inline ::testing::AssertionResult startCoordinator(const std::vector<std::string>& argv,
                                                   const std::filesystem::path& addressFile,
                                                   const std::filesystem::path& log,
                                                   Process* process, std::string* address) {
  std::filesystem::remove(addressFile);
  *process = Process(argv, log);
  int exited = -1;
  const bool listening = waitFor(
      [&] {
        if ((exited = process->wait(0)) >= 0) return true;
        const std::string text = slurpFile(addressFile);
        *address = text.substr(0, text.find('\n'));
        return !address->empty();
      },
      15.0);
  if (exited >= 0) {
    return ::testing::AssertionFailure() << "the coordinator exited " << exited << ":\n"
                                         << slurpFile(log);
  }
  if (!listening) {
    return ::testing::AssertionFailure()
           << "the coordinator wrote no address to " << addressFile << " in 15 s:\n"
           << slurpFile(log);
  }
  return ::testing::AssertionSuccess();
}

// Whether `worker` registers with the coordinator at `address` within `seconds` under a name
// that starts with `idPrefix`, as the coordinator's worker list says (asked with `token` and,
// as a client, `clientTls`: none, a CA, or a CA and a certificate). A worker that exits first
// fails at once, with its log.
inline ::testing::AssertionResult workerRegisters(Process& worker, const std::string& address,
                                                  const std::string& token,
                                                  const farm::TlsFiles& clientTls,
                                                  const std::string& idPrefix,
                                                  double seconds = 15.0) {
  auto tls = farm::readClientTls(clientTls);
  if (!tls.ok()) return ::testing::AssertionFailure() << tls.status();
  farm::FarmClient client(address, token, 5.0, *tls);
  int exited = -1;
  std::string last;
  const bool seen = waitFor(
      [&] {
        if ((exited = worker.wait(0)) >= 0) return true;
        auto list = client.listWorkers({});
        if (!list.ok()) {
          last = std::string(list.status().message());
          return false;
        }
        for (const auto& w : list->workers()) {
          if (w.worker().starts_with(idPrefix)) return true;
        }
        return false;
      },
      seconds);
  if (exited >= 0) {
    return ::testing::AssertionFailure() << "the worker exited " << exited << ":\n" << worker.log();
  }
  if (!seen) {
    return ::testing::AssertionFailure()
           << "no worker '" << idPrefix << "...' registered with " << address << " in " << seconds
           << " s (last answer: " << last << "); its log:\n"
           << worker.log();
  }
  return ::testing::AssertionSuccess();
}

}  // namespace pbgi::testing
