// deploy/kubernetes against the daemons they run: every container's arguments are parsed by
// the real binary (`pbgi-coordinator ARGS --help` validates each value, then exits 0; each
// flag must be one its help lists),
// every path an argument names lies on one of the container's volume mounts, and a file on a
// secret's mount is a key that README.md's `kubectl create secret` puts in that secret; the
// coordinator's certificate, made by README.md's make-certs.sh command, holds the name the
// workers dial, and a coordinator and a worker started with the manifests' TLS arguments on
// those files (followed through the secrets) connect; the workers' --coordinator names the
// coordinator's Service and a port that reaches its --listen port, the readiness probe asks
// the --http port, and the metric the autoscaler scales on is one a live coordinator serves.
#include <gtest/gtest.h>

#include <filesystem>
#include <map>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "tests/deploy/deploy_farm.h"
#include "tests/support/idle_coordinator.h"

namespace pbgi::testing {
namespace {

namespace fs = std::filesystem;

fs::path manifests() { return sourceDir() / "deploy/kubernetes"; }

struct Mount {
  std::string volume;
  std::string path;
};

struct Container {
  std::string file;
  std::string binary;                                // from `command: ["..."]`
  std::vector<std::string> args;                     // `- --flag=value` items
  std::vector<Mount> mounts;                         // volumeMounts
  std::map<std::string, std::string> secretVolumes;  // the pod's volumes: name -> secretName
  std::vector<int> containerPorts;
  std::vector<int> probePorts;  // readiness/liveness probes' ports
};

int indentOf(const std::string& line) { return static_cast<int>(line.find_first_not_of(' ')); }

// The containers of a manifest, read by their keys' indentation (the manifests keep one key a
// line; a line this reader does not understand fails the test that needed it).
std::vector<Container> containersOf(const fs::path& file) {
  std::vector<Container> out;
  std::istringstream in(slurpFile(file));
  std::string line;
  const std::regex command(R"re(^\s*command: \["([^"]+)"\])re");
  const std::regex item(R"(^\s*- (.*)$)");
  const std::regex name(R"(^\s*- name: (\S+))");
  const std::regex mount(R"(^\s*mountPath: (\S+))");
  const std::regex secretName(R"(^\s*secretName: (\S+))");
  const std::regex containerPort(R"(^\s*(- )?containerPort: (\d+))");
  const std::regex probePort(R"(^\s*port: (\d+))");
  bool inArgs = false;
  int argsIndent = 0;
  bool inProbe = false;
  int probeIndent = 0;
  // volumeMounts: or volumes:, and the `- name:` of the item being read.
  std::string list;
  int listIndent = 0;
  std::string itemName;
  size_t podStart = 0;  // this document's first container
  while (std::getline(in, line)) {
    if (line == "---") {
      podStart = out.size();
      list.clear();
      continue;
    }
    if (line.find_first_not_of(' ') == std::string::npos || line.starts_with("#")) continue;
    std::smatch m;
    if (std::regex_search(line, m, command)) {
      out.push_back({file.filename().string(), m[1], {}, {}, {}, {}, {}});
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
    if (!list.empty() && indent <= listIndent) list.clear();
    if (line.find("args:") != std::string::npos) {
      inArgs = true;
      argsIndent = indent;
    } else if (line.find("Probe:") != std::string::npos) {
      inProbe = true;
      probeIndent = indent;
    } else if (line.ends_with("volumeMounts:") || line.ends_with("volumes:")) {
      list = line.substr(indent);
      listIndent = indent;
    } else if (!list.empty() && std::regex_search(line, m, name)) {
      itemName = m[1];
    } else if (std::regex_search(line, m, mount)) {
      EXPECT_EQ(list, "volumeMounts:") << file << ": " << line;
      c.mounts.push_back({itemName, m[1]});
    } else if (std::regex_search(line, m, secretName)) {
      EXPECT_EQ(list, "volumes:") << file << ": " << line;
      for (size_t i = podStart; i < out.size(); ++i) out[i].secretVolumes[itemName] = m[1];
    } else if (line.find("items:") != std::string::npos) {
      ADD_FAILURE() << file << ": a secret volume's items: are not read here";
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

// README.md's commands, continued lines joined.
std::string readmeCommands() {
  return std::regex_replace(slurpFile(manifests() / "README.md"), std::regex(R"(\\\n\s*)"), "");
}

// The secrets README.md makes (`kubectl create secret generic NAME --from-file=[KEY=]PATH...`):
// name -> key -> the file given.
std::map<std::string, std::map<std::string, std::string>> readmeSecrets() {
  std::map<std::string, std::map<std::string, std::string>> out;
  const std::string text = readmeCommands();
  const std::regex create(R"(kubectl create secret generic (\S+)((?: --from-file=\S+)+))");
  const std::regex fromFile(R"(--from-file=(\S+))");
  for (std::sregex_iterator it(text.begin(), text.end(), create), end; it != end; ++it) {
    const std::string files = (*it)[2];
    auto& keys = out[(*it)[1]];
    for (std::sregex_iterator f(files.begin(), files.end(), fromFile); f != end; ++f) {
      const std::string given = (*f)[1];
      const size_t eq = given.find('=');
      if (eq == std::string::npos) {
        keys[fs::path(given).filename().string()] = given;
      } else {
        keys[given.substr(0, eq)] = given.substr(eq + 1);
      }
    }
  }
  return out;
}

// README.md's `deploy/tls/make-certs.sh DIR HOSTNAME...`.
std::vector<std::string> readmeMakeCerts() {
  const std::string text = readmeCommands();
  std::smatch m;
  EXPECT_TRUE(std::regex_search(text, m, std::regex(R"(\ndeploy/tls/make-certs\.sh ([^\n]+))")))
      << "README.md makes no certificates";
  std::vector<std::string> out;
  std::istringstream words(m.empty() ? std::string() : m[1].str());
  for (std::string w; words >> w;) out.push_back(w);
  return out;
}

// Where `value` (a flag's file) comes from: the secret whose volume is mounted over it and the
// key under the mount; nullopt when no secret is mounted there.
struct SecretFile {
  std::string secret;
  std::string key;
};
std::optional<SecretFile> secretFileOf(const Container& c, const std::string& value) {
  for (const Mount& m : c.mounts) {
    const auto secret = c.secretVolumes.find(m.volume);
    if (secret == c.secretVolumes.end() || !value.starts_with(m.path + "/")) continue;
    return SecretFile{secret->second, value.substr(m.path.size() + 1)};
  }
  return std::nullopt;
}

// The file on this machine that a container's flag reads through its secret: the file the
// README's command puts under that key, in `certs`, where README.md's make-certs.sh command
// was run.
std::string localTlsFile(const Container& c, const std::string& flag, const std::string& value,
                         const fs::path& certs) {
  const auto from = secretFileOf(c, value);
  EXPECT_TRUE(from) << c.file << ": " << flag << "=" << value << " is on no secret";
  if (!from) return {};
  const auto secrets = readmeSecrets();
  const auto secret = secrets.find(from->secret);
  EXPECT_NE(secret, secrets.end()) << from->secret << " is made by no command in README.md";
  if (secret == secrets.end() || !secret->second.count(from->key)) return {};
  const fs::path given = secret->second.at(from->key);
  const std::vector<std::string> makeCerts = readmeMakeCerts();
  EXPECT_FALSE(makeCerts.empty());
  EXPECT_EQ(given.parent_path(), makeCerts.empty() ? "" : makeCerts[0])
      << from->secret << "'s " << from->key << " is not from make-certs.sh's folder";
  return (certs / given.filename()).string();
}

TEST(KubernetesManifests, EveryContainersArgumentsAreOnesItsBinaryAccepts) {
  const std::vector<Container> all = allContainers();
  int checked = 0;
  for (const Container& c : all) {
    if (!c.binary.starts_with("pbgi")) continue;  // postgres
    ASSERT_FALSE(c.args.empty()) << c.file << ": " << c.binary << " without args";
    EXPECT_TRUE(binaryAccepts(c.binary, c.args)) << c.file;
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
      for (const Mount& m : c->mounts) {
        mounted = mounted || value == m.path || value.starts_with(m.path + "/");
      }
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

TEST(KubernetesManifests, FilesFromSecretsAreKeysTheReadmePutsThere) {
  const auto secrets = readmeSecrets();
  ASSERT_FALSE(secrets.empty()) << "README.md creates no secret";
  int tlsFlagsSeen = 0;
  for (const Container& c : allContainers()) {
    for (const auto& [flag, value] : flags(c)) {
      const auto from = secretFileOf(c, value);
      if (!from) {
        EXPECT_FALSE(flag.starts_with("--tls-"))
            << c.file << ": " << flag << "=" << value << " is on no secret's mount";
        continue;
      }
      tlsFlagsSeen += flag.starts_with("--tls-") ? 1 : 0;
      const auto secret = secrets.find(from->secret);
      ASSERT_NE(secret, secrets.end())
          << c.file << ": the secret " << from->secret << " is made by no command in README.md";
      EXPECT_TRUE(secret->second.count(from->key))
          << c.file << ": " << flag << "=" << value << " is no key of the secret " << from->secret
          << " as README.md makes it";
    }
    // A worker never holds the keys that sign certificates or make a coordinator.
    if (c.binary != "pbgi-worker") continue;
    for (const auto& [volume, secretName] : c.secretVolumes) {
      if (!secrets.count(secretName)) continue;
      for (const char* key : {"ca.key", "server.key"}) {
        EXPECT_FALSE(secrets.at(secretName).count(key))
            << c.file << ": the workers' secret " << secretName << " holds " << key;
      }
    }
  }
  EXPECT_GE(tlsFlagsSeen, 3) << "the coordinator's certificate and key, and the workers' CA";
  for (const auto& [name, keys] : secrets) {
    EXPECT_FALSE(keys.count("ca.key")) << "the secret " << name << " holds the CA's key";
  }
}

// The manifests' coordinator and worker, and the certificates README.md's make-certs command
// makes, in `certs`.
struct TlsFarm {
  TlsFarm() = default;
  TlsFarm(const TlsFarm&) = delete;  // the pointers point into `all`
  std::vector<Container> all = allContainers();
  const Container* coordinator = find(all, "pbgi-coordinator");
  const Container* worker = find(all, "pbgi-worker");
};
::testing::AssertionResult makeTlsFarm(TlsFarm& farm, const fs::path& certs) {
  if (farm.coordinator == nullptr || farm.worker == nullptr) {
    return ::testing::AssertionFailure() << "no pbgi-coordinator or pbgi-worker container";
  }
  const std::vector<std::string> command = readmeMakeCerts();
  if (command.empty()) return ::testing::AssertionFailure() << "README.md makes no certificates";
  return makeCerts(certs, {command.begin() + 1, command.end()});
}

TEST(KubernetesManifests, TheCoordinatorsCertificateHoldsTheNameTheWorkersDial) {
  TlsFarm farm;
  const fs::path certs = makeTempDir("k8s-certs") / "certs";
  ASSERT_TRUE(makeTlsFarm(farm, certs));
  const Container* coordinator = farm.coordinator;
  const Container* worker = farm.worker;
  const auto cf = flags(*coordinator);
  ASSERT_TRUE(cf.count("--tls-cert")) << "the coordinator serves no TLS";
  const std::string cert = localTlsFile(*coordinator, "--tls-cert", cf.at("--tls-cert"), certs);
  ASSERT_FALSE(cert.empty());
  const ShellResult san =
      shell("openssl x509 -noout -ext subjectAltName -in " + shellQuote(cert) + " 2>&1");
  ASSERT_EQ(san.status, 0) << san.out;
  const std::string target = flags(*worker).at("--coordinator");
  const std::string host = target.substr(0, target.rfind(':'));
  EXPECT_TRUE(std::regex_search(san.out, std::regex("DNS:" + host + "(,|\\s|$)")))
      << "the workers dial " << host << "; the certificate holds " << san.out;
}

TEST(KubernetesManifests, ACoordinatorAndAWorkerWithTheManifestsTlsArgumentsConnect) {
  TlsFarm farm;
  const fs::path dir = makeTempDir("k8s-tls");
  const fs::path certs = dir / "certs";
  ASSERT_TRUE(makeTlsFarm(farm, certs));
  const Container* coordinator = farm.coordinator;
  const Container* worker = farm.worker;

  // Their own state, ports and token; the manifests' TLS arguments, on the files the secrets
  // hold.
  std::vector<std::string> coordinatorArgv = {binary("pbgi-coordinator").string(),
                                              "--state",
                                              (dir / "state").string(),
                                              "--listen",
                                              "127.0.0.1:0",
                                              "--token-file",
                                              (dir / "token").string()};
  for (const auto& [flag, value] : tlsFlags(coordinator->args)) {
    coordinatorArgv.push_back(flag + "=" + localTlsFile(*coordinator, flag, value, certs));
  }
  Process coordinatorProcess;
  std::string address;
  ASSERT_TRUE(startCoordinator(coordinatorArgv, dir / "state" / "coordinator.addr",
                               dir / "coordinator.log", &coordinatorProcess, &address));
  std::vector<std::string> workerArgv = {
      binary("pbgi-worker").string(), "--coordinator", address,      "--token-file",
      (dir / "token").string(),       "--id",          "k8s-worker", "--cache-dir",
      (dir / "cache").string()};
  farm::TlsFiles client;
  for (const auto& [flag, value] : tlsFlags(worker->args)) {
    const std::string local = localTlsFile(*worker, flag, value, certs);
    workerArgv.push_back(flag + "=" + local);
    (flag == "--tls-ca" ? client.ca : flag == "--tls-cert" ? client.cert : client.key) = local;
  }
  Process workerProcess(workerArgv, dir / "worker.log");
  const absl::StatusOr<std::string> token = farm::loadClientToken((dir / "token").string());
  ASSERT_TRUE(token.ok()) << token.status();
  EXPECT_TRUE(workerRegisters(workerProcess, address, *token, client, "k8s-worker"))
      << "coordinator log:\n"
      << coordinatorProcess.log();
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
