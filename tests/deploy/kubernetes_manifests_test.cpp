// deploy/kubernetes against the daemons they run: every container's arguments are parsed by
// the real binary (`pbgi-coordinator ARGS --help` validates each value, then exits 0; each
// flag must be one its help lists),
// every path an argument names lies on one of the container's volume mounts, the workers'
// --coordinator names the coordinator's Service and a port that reaches its --listen port, the
// readiness probe asks the --http port, and the metric the autoscaler scales on is one a live
// coordinator serves.
#include <gtest/gtest.h>

#include <filesystem>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "tests/support/farm_fixtures.h"
#include "tests/support/idle_coordinator.h"
#include "tests/support/slurm_cluster.h"

namespace pbgi::testing {
namespace {

namespace fs = std::filesystem;

fs::path manifests() { return sourceDir() / "deploy/kubernetes"; }

struct Container {
  std::string file;
  std::string binary;                      // from `command: ["..."]`
  std::vector<std::string> args;           // `- --flag=value` items
  std::vector<std::string> mounts;         // mountPath values
  std::vector<int> containerPorts;
  std::vector<int> probePorts;             // readiness/liveness probes' ports
};

int indentOf(const std::string& line) {
  return static_cast<int>(line.find_first_not_of(' '));
}

// The containers of a manifest, read by their keys' indentation (the manifests keep one key a
// line; a line this reader does not understand fails the test that needed it).
std::vector<Container> containersOf(const fs::path& file) {
  std::vector<Container> out;
  std::istringstream in(slurpFile(file));
  std::string line;
  const std::regex command(R"re(^\s*command: \["([^"]+)"\])re");
  const std::regex item(R"(^\s*- (.*)$)");
  const std::regex mount(R"(^\s*mountPath: (\S+))");
  const std::regex containerPort(R"(^\s*(- )?containerPort: (\d+))");
  const std::regex probePort(R"(^\s*port: (\d+))");
  bool inArgs = false;
  int argsIndent = 0;
  bool inProbe = false;
  int probeIndent = 0;
  while (std::getline(in, line)) {
    if (line.find_first_not_of(' ') == std::string::npos || line.starts_with("#")) continue;
    std::smatch m;
    if (std::regex_search(line, m, command)) {
      out.push_back({file.filename().string(), m[1], {}, {}, {}, {}});
      continue;
    }
    if (out.empty()) continue;
    Container& c = out.back();
    const int indent = indentOf(line);
    if (inArgs) {
      if (indent >= argsIndent && std::regex_search(line, m, item)) {
        c.args.push_back(m[1]);
        continue;
      }
      inArgs = false;
    }
    if (inProbe && indent <= probeIndent) inProbe = false;
    if (line.find("args:") != std::string::npos) {
      inArgs = true;
      argsIndent = indent;
    } else if (line.find("Probe:") != std::string::npos) {
      inProbe = true;
      probeIndent = indent;
    } else if (std::regex_search(line, m, mount)) {
      c.mounts.push_back(m[1]);
    } else if (std::regex_search(line, m, containerPort)) {
      c.containerPorts.push_back(std::stoi(m[2]));
    } else if (inProbe && std::regex_search(line, m, probePort)) {
      c.probePorts.push_back(std::stoi(m[1]));
    }
  }
  return out;
}

std::vector<Container> allContainers() {
  std::vector<Container> all;
  for (const auto& e : fs::directory_iterator(manifests())) {
    if (e.path().extension() != ".yaml") continue;
    for (Container& c : containersOf(e.path())) all.push_back(std::move(c));
  }
  return all;
}

// --name=value arguments as a map (a flag without a value maps to "").
std::map<std::string, std::string> flags(const Container& c) {
  std::map<std::string, std::string> out;
  for (const std::string& a : c.args) {
    const size_t eq = a.find('=');
    out[a.substr(0, eq)] = eq == std::string::npos ? "" : a.substr(eq + 1);
  }
  return out;
}

int portOf(const std::string& hostPort) {
  return std::stoi(hostPort.substr(hostPort.rfind(':') + 1));
}

const Container* find(const std::vector<Container>& all, const std::string& binary) {
  for (const Container& c : all) {
    if (c.binary == binary) return &c;
  }
  return nullptr;
}

TEST(KubernetesManifests, EveryContainersArgumentsAreOnesItsBinaryAccepts) {
  const std::vector<Container> all = allContainers();
  int checked = 0;
  for (const Container& c : all) {
    if (!c.binary.starts_with("pbgi")) continue;  // postgres
    ASSERT_FALSE(c.args.empty()) << c.file << ": " << c.binary << " without args";
    std::string command = shellQuote(binary(c.binary).string());
    for (const std::string& a : c.args) command += " " + shellQuote(a);
    const ShellResult r = shell(command + " --help 2>&1");
    EXPECT_EQ(r.status, 0) << c.file << ": " << c.binary << " refuses its arguments:\n" << r.out;
    // CLI11 answers --help before it looks for unknown flags: each must be in the help.
    for (const auto& [flag, value] : flags(c)) {
      EXPECT_TRUE(std::regex_search(r.out, std::regex("(^|[ ,])" + flag + "( |,|$)",
                                                      std::regex::multiline)))
          << c.file << ": " << c.binary << " has no " << flag;
    }
    ++checked;
  }
  EXPECT_EQ(checked, 2) << "a coordinator and a worker container";
}

TEST(KubernetesManifests, PathsLieOnMountsAndPortsMeet) {
  const std::vector<Container> all = allContainers();
  const Container* coordinator = find(all, "pbgi-coordinator");
  const Container* worker = find(all, "pbgi-worker");
  ASSERT_NE(coordinator, nullptr);
  ASSERT_NE(worker, nullptr);
  for (const Container* c : {coordinator, worker}) {
    for (const auto& [flag, value] : flags(*c)) {
      if (!value.starts_with("/")) continue;
      bool mounted = false;
      for (const std::string& m : c->mounts) mounted = mounted || value.starts_with(m);
      EXPECT_TRUE(mounted) << c->file << ": " << flag << "=" << value << " is on no volume";
    }
  }
  const auto cf = flags(*coordinator);
  ASSERT_TRUE(cf.count("--listen") && cf.count("--http")) << "the coordinator listens";
  const int grpc = portOf(cf.at("--listen"));
  const int http = portOf(cf.at("--http"));
  EXPECT_NE(std::find(coordinator->containerPorts.begin(), coordinator->containerPorts.end(), grpc),
            coordinator->containerPorts.end());
  EXPECT_NE(std::find(coordinator->containerPorts.begin(), coordinator->containerPorts.end(), http),
            coordinator->containerPorts.end());
  for (const int p : coordinator->probePorts) EXPECT_EQ(p, http) << "the probe asks /metrics";

  // The workers reach the coordinator through its Service: host = the Service's name, port =
  // one of its ports whose targetPort is the --listen port.
  const std::string text = slurpFile(manifests() / "coordinator.yaml");
  const auto wf = flags(*worker);
  ASSERT_TRUE(wf.count("--coordinator"));
  const std::string target = wf.at("--coordinator");
  const std::string host = target.substr(0, target.rfind(':'));
  EXPECT_NE(text.find("kind: Service\nmetadata:\n  name: " + host + "\n"), std::string::npos)
      << "no Service named " << host;
  const std::regex servicePort(R"(- name: \w+\n\s+port: (\d+)\n\s+targetPort: (\d+))");
  bool reaches = false;
  for (auto it = std::sregex_iterator(text.begin(), text.end(), servicePort);
       it != std::sregex_iterator(); ++it) {
    reaches = reaches || (std::stoi((*it)[1]) == portOf(target) && std::stoi((*it)[2]) == grpc);
  }
  EXPECT_TRUE(reaches) << target << " reaches no Service port targeting " << grpc;
}

TEST(KubernetesManifests, TheAutoscalersMetricIsOneTheCoordinatorServes) {
  const std::string hpa = slurpFile(manifests() / "worker-hpa.yaml");
  std::smatch name, label;
  ASSERT_TRUE(std::regex_search(hpa, name, std::regex(R"(metric:\n\s+name: (\w+))")));
  ASSERT_TRUE(std::regex_search(hpa, label, std::regex(R"(matchLabels:\n\s+(\w+): (\w+))")));
  const absl::StatusOr<std::string> served = idleCoordinatorMetrics("k8s-metrics");
  ASSERT_TRUE(served.ok()) << served.status();
  const std::string& metrics = *served;
  const std::string series =
      fmt::format("\n{}{{{}=\"{}\"}} ", name[1].str(), label[1].str(), label[2].str());
  EXPECT_NE(metrics.find(series), std::string::npos) << series << " is not in:\n" << metrics;
}

}  // namespace
}  // namespace pbgi::testing
