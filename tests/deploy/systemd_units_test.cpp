// deploy/systemd against the daemons they start: each unit's ExecStart, with its Environment=
// expanded as systemd does, is parsed by the real binary, TLS on; its TLS files are the ones
// the comment's deploy/tls/make-certs.sh command makes; a coordinator and a worker started
// from the two units (their paths moved under a temporary root, the ports made free) meet
// over TLS with those certificates, and over plaintext with the comments' drop-in; without
// the files both exit 2 saying which, a status the units do not restart on. systemd-analyze,
// where installed, reads the units without a warning.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "tests/deploy/deploy_farm.h"

namespace pbgi::testing {
namespace {

namespace fs = std::filesystem;

// The keys of a unit this test reads: [Service]'s Environment= and ExecStart=, and the unit's
// comments (where its drop-ins and certificate commands are written).
struct Unit {
  std::string name;
  std::string comments;                            // the leading '#' lines, '#' kept
  std::map<std::string, std::string> environment;  // Environment=, later assignments win
  std::string execStart;
  std::vector<std::string> restartPreventExitStatus;
};

// systemd's words: split at whitespace, "..." and '...' quote (this reader takes no escapes).
std::vector<std::string> words(const std::string& text) {
  std::vector<std::string> out;
  std::string word;
  bool inWord = false;
  char quote = 0;
  for (const char c : text) {
    EXPECT_NE(c, '\\') << "a backslash in '" << text << "': this reader takes no escapes";
    if (quote != 0) {
      if (c == quote) {
        quote = 0;
      } else {
        word += c;
      }
    } else if (c == '"' || c == '\'') {
      quote = c;
      inWord = true;
    } else if (c == ' ' || c == '\t') {
      if (inWord) out.push_back(word);
      word.clear();
      inWord = false;
    } else {
      word += c;
      inWord = true;
    }
  }
  EXPECT_EQ(quote, 0) << "an unclosed quote in '" << text << "'";
  if (inWord) out.push_back(word);
  return out;
}

// Environment= words, each NAME=VALUE, into `env`.
void assign(const std::string& value, std::map<std::string, std::string>* env) {
  for (const std::string& w : words(value)) {
    const size_t eq = w.find('=');
    ASSERT_NE(eq, std::string::npos) << "Environment= word '" << w << "' has no '='";
    (*env)[w.substr(0, eq)] = w.substr(eq + 1);
  }
}

Unit readUnit(const std::string& name) {
  Unit u;
  u.name = name;
  std::istringstream in(slurpFile(sourceDir() / "deploy/systemd" / name));
  std::string line;
  std::string section;
  while (std::getline(in, line)) {
    if (line.starts_with("#")) {
      if (section.empty()) u.comments += line + "\n";
      continue;
    }
    if (line.empty()) continue;
    EXPECT_FALSE(line.ends_with("\\")) << name << ": this reader takes no continued lines";
    if (line.starts_with("[")) {
      section = line;
      continue;
    }
    if (section != "[Service]") continue;
    const size_t eq = line.find('=');
    const std::string key = line.substr(0, eq);
    const std::string value = line.substr(eq + 1);
    if (key == "Environment") {
      assign(value, &u.environment);
    } else if (key == "ExecStart") {
      EXPECT_TRUE(u.execStart.empty()) << name << ": a second ExecStart";
      u.execStart = value;
    } else if (key == "RestartPreventExitStatus") {
      for (const std::string& w : words(value)) u.restartPreventExitStatus.push_back(w);
    }
  }
  return u;
}

// The drop-in the unit's comment gives for plaintext ("[Service]" then "Environment=..."),
// applied to the unit.
Unit withPlaintextDropIn(Unit u) {
  std::smatch m;
  EXPECT_TRUE(
      std::regex_search(u.comments, m, std::regex(R"(#\s+\[Service\]\n#\s+Environment=(\S*)\n)")))
      << u.name << ": no plaintext drop-in ([Service], Environment=...) in its comment";
  if (!m.empty()) assign(m[1], &u.environment);
  return u;
}

// ExecStart as systemd runs it: a word that is $NAME becomes the variable's value split at
// whitespace (no word when it is empty); ${NAME} inside a word is replaced as is. The
// binary's path is the first word.
std::vector<std::string> commandLine(const Unit& u) {
  EXPECT_FALSE(u.execStart.empty()) << u.name << ": no ExecStart";
  EXPECT_TRUE(u.execStart.starts_with("/")) << u.name << ": ExecStart prefixes are not read here";
  const auto lookup = [&](const std::string& var) {
    const auto it = u.environment.find(var);
    EXPECT_NE(it, u.environment.end()) << u.name << ": $" << var << " is set by no Environment=";
    return it == u.environment.end() ? std::string() : it->second;
  };
  std::vector<std::string> out;
  const std::regex whole(R"(^\$([A-Za-z_][A-Za-z0-9_]*)$)");
  const std::regex braced(R"(\$\{([A-Za-z_][A-Za-z0-9_]*)\})");
  for (const std::string& w : words(u.execStart)) {
    std::smatch m;
    if (std::regex_match(w, m, whole)) {
      for (const std::string& part : words(lookup(m[1]))) out.push_back(part);
      continue;
    }
    std::string expanded;
    auto begin = w.cbegin();
    for (std::sregex_iterator it(w.begin(), w.end(), braced), end; it != end; ++it) {
      expanded.append(begin, w.cbegin() + it->position());
      expanded += lookup((*it)[1]);
      begin = w.cbegin() + it->position() + it->length();
    }
    expanded.append(begin, w.cend());
    EXPECT_EQ(expanded.find('$'), std::string::npos)
        << u.name << ": '" << w << "' is not read here";
    out.push_back(expanded);
  }
  return out;
}

std::vector<std::string> argsOf(const std::vector<std::string>& line) {
  return {line.begin() + 1, line.end()};
}
std::string binaryOf(const std::vector<std::string>& line) {
  return fs::path(line.at(0)).filename().string();
}

// The unit's command line to run here: the test's binary, every absolute path under `root`,
// and the listen addresses on free ports of the loopback.
std::vector<std::string> runnable(const std::vector<std::string>& line, const fs::path& root) {
  std::vector<std::string> argv = {binary(binaryOf(line)).string()};
  for (std::string a : argsOf(line)) {
    if (a.starts_with("/")) a = (root / fs::path(a).relative_path()).string();
    argv.push_back(a);
  }
  for (const char* listen : {"--listen", "--http"}) argv = withFlag(argv, listen, "127.0.0.1:0");
  return argv;
}

fs::path under(const fs::path& root, const std::string& path) {
  return root / fs::path(path).relative_path();
}

// The comment's `deploy/tls/make-certs.sh DIR HOSTNAME...`.
std::vector<std::string> makeCertsCommand(const Unit& u) {
  std::smatch m;
  EXPECT_TRUE(std::regex_search(u.comments, m, std::regex(R"(deploy/tls/make-certs\.sh ([^\n]+))")))
      << u.name << ": its comment says not how to make the certificates";
  return m.empty() ? std::vector<std::string>{} : words(m[1]);
}

const Unit& coordinatorUnit() {
  static const Unit u = readUnit("pbgi-coordinator.service");
  return u;
}
const Unit& workerUnit() {
  static const Unit u = readUnit("pbgi-worker.service");
  return u;
}

TEST(SystemdUnits, EveryArgumentIsOneItsBinaryAcceptsWithTlsAndWithThePlaintextDropIn) {
  for (const Unit* u : {&coordinatorUnit(), &workerUnit()}) {
    const std::vector<std::string> tls = commandLine(*u);
    ASSERT_FALSE(tls.empty()) << u->name;
    EXPECT_EQ(binaryOf(tls), u->name.substr(0, u->name.find('.')));
    EXPECT_TRUE(binaryAccepts(binaryOf(tls), argsOf(tls))) << u->name;
    EXPECT_FALSE(tlsFlags(argsOf(tls)).empty()) << u->name << ": TLS is not on";

    const std::vector<std::string> plain = commandLine(withPlaintextDropIn(*u));
    EXPECT_TRUE(binaryAccepts(binaryOf(plain), argsOf(plain))) << u->name << " in plaintext";
    EXPECT_TRUE(tlsFlags(argsOf(plain)).empty())
        << u->name << ": the plaintext drop-in leaves TLS flags";
  }
  const auto coordinator = argsOf(commandLine(coordinatorUnit()));
  for (const char* flag : {"--tls-cert", "--tls-key"}) {
    EXPECT_TRUE(flagValue(coordinator, flag)) << "the coordinator unit has no " << flag;
  }
  EXPECT_TRUE(flagValue(argsOf(commandLine(workerUnit())), "--tls-ca"))
      << "the worker unit has no --tls-ca";
}

TEST(SystemdUnits, TlsFilesAreTheOnesTheCommentsCommandMakes) {
  const std::vector<std::string> command = makeCertsCommand(coordinatorUnit());
  ASSERT_GE(command.size(), 1u);
  const fs::path certDir = command[0];
  const fs::path made = makeTempDir("systemd-certs") / "tls";
  ASSERT_TRUE(makeCerts(made, {command.begin() + 1, command.end()}));
  for (const Unit* u : {&coordinatorUnit(), &workerUnit()}) {
    for (const auto& [flag, value] : tlsFlags(argsOf(commandLine(*u)))) {
      EXPECT_EQ(fs::path(value).parent_path(), certDir)
          << u->name << ": " << flag << " " << value << " is not in the folder the comment's "
          << "make-certs.sh command writes";
      EXPECT_TRUE(fs::is_regular_file(made / fs::path(value).filename()))
          << u->name << ": " << flag << " " << value << " is no file make-certs.sh makes";
    }
  }
  // A worker host gets no key but its own (the worker unit's comment: never ca.key or
  // server.key).
  for (const auto& [flag, value] : tlsFlags(argsOf(commandLine(workerUnit())))) {
    const std::string file = fs::path(value).filename().string();
    EXPECT_TRUE(file != "ca.key" && file != "server.key") << "the worker unit names " << value;
  }
}

// Both units started here under `root`, with worker.toml written as the worker unit's comment
// says (the coordinator's address, a copy of its token); the worker must register. `dropIn`:
// the units' plaintext drop-in.
void expectUnitsMeet(const fs::path& root, bool dropIn) {
  const Unit coordinatorU = dropIn ? withPlaintextDropIn(coordinatorUnit()) : coordinatorUnit();
  const Unit workerU = dropIn ? withPlaintextDropIn(workerUnit()) : workerUnit();
  const std::vector<std::string> coordinatorLine = commandLine(coordinatorU);
  const std::vector<std::string> workerLine = commandLine(workerU);
  const std::vector<std::string> coordinatorArgv = runnable(coordinatorLine, root);
  const std::vector<std::string> workerArgv = runnable(workerLine, root);

  // What the units expect to find: the config files, and the folders systemd makes
  // (StateDirectory=, CacheDirectory=).
  const auto state = flagValue(argsOf(coordinatorLine), "--state");
  ASSERT_TRUE(state) << "the coordinator unit has no --state";
  for (const auto* argv : {&coordinatorArgv, &workerArgv}) {
    for (const char* folder : {"--state", "--cache-dir"}) {
      if (auto dir = flagValue(argsOf(*argv), folder)) fs::create_directories(*dir);
    }
  }
  const auto coordinatorConfig = flagValue(argsOf(coordinatorArgv), "--config");
  ASSERT_TRUE(coordinatorConfig);
  fs::create_directories(fs::path(*coordinatorConfig).parent_path());
  std::ofstream(*coordinatorConfig) << "";  // "it may be empty"

  Process coordinator;
  std::string address;
  ASSERT_TRUE(startCoordinator(coordinatorArgv, under(root, *state) / "coordinator.addr",
                               root / "coordinator.log", &coordinator, &address));
  const fs::path token = under(root, "/etc/pbgi/token");
  fs::copy_file(under(root, *state) / "token", token, fs::copy_options::overwrite_existing);
  const auto workerConfig = flagValue(argsOf(workerArgv), "--config");
  ASSERT_TRUE(workerConfig) << "the worker unit has no --config";
  ASSERT_NE(workerU.comments.find("`coordinator = \"farm-head:7411\"`"), std::string::npos)
      << "the worker unit's comment changed: say here what worker.toml holds";
  ASSERT_NE(workerU.comments.find("`token-file = \"/etc/pbgi/token\"`"), std::string::npos);
  std::ofstream(*workerConfig) << "coordinator = \"" << address << "\"\ntoken-file = \""
                               << token.string() << "\"\n";

  Process worker(workerArgv, root / "worker.log");
  farm::TlsFiles client;  // the worker's own files, as `pbgi` would use them
  if (auto ca = flagValue(argsOf(workerArgv), "--tls-ca")) client.ca = *ca;
  if (auto cert = flagValue(argsOf(workerArgv), "--tls-cert")) client.cert = *cert;
  if (auto key = flagValue(argsOf(workerArgv), "--tls-key")) client.key = *key;
  const absl::StatusOr<std::string> tokenText = farm::loadClientToken(token.string());
  ASSERT_TRUE(tokenText.ok()) << tokenText.status();
  EXPECT_TRUE(workerRegisters(worker, address, *tokenText, client, "")) << "coordinator log:\n"
                                                                        << coordinator.log();
}

TEST(SystemdUnits, ACoordinatorAndAWorkerStartedFromTheUnitsMeetOverTls) {
  const fs::path root = makeTempDir("systemd-tls");
  const std::vector<std::string> command = makeCertsCommand(coordinatorUnit());
  ASSERT_GE(command.size(), 1u);
  ASSERT_TRUE(makeCerts(under(root, command[0]), {command.begin() + 1, command.end()}));
  expectUnitsMeet(root, false);
}

TEST(SystemdUnits, ACoordinatorAndAWorkerWithThePlaintextDropInMeetWithoutCertificates) {
  expectUnitsMeet(makeTempDir("systemd-plain"), true);
}

TEST(SystemdUnits, WithoutTheCertificatesBothExit2SayingWhichFileAndAreNotRestarted) {
  const fs::path root = makeTempDir("systemd-nocerts");
  for (const Unit* u : {&coordinatorUnit(), &workerUnit()}) {
    std::vector<std::string> argv = runnable(commandLine(*u), root);
    if (auto dir = flagValue(argsOf(argv), "--state")) fs::create_directories(*dir);
    if (auto config = flagValue(argsOf(argv), "--config")) {
      fs::create_directories(fs::path(*config).parent_path());
      // The worker gets a coordinator nobody listens on and a token: only TLS is missing.
      std::ofstream(*config) << (binaryOf(argv) == "pbgi-worker" ? "coordinator = \"127.0.0.1:1\"\n"
                                                                 : "");
    }
    const std::vector<std::string> env = {"PBGI_TOKEN=no-tls-test"};
    Process p(argv, root / (u->name + ".log"), env);
    const int status = p.wait(15.0);
    const std::string log = p.log();
    EXPECT_EQ(status, 2) << u->name << ":\n" << log;
    // One of the files is named, with its flag.
    bool named = false;
    for (const auto& [flag, value] : tlsFlags(argsOf(argv))) {
      named = named || log.find(flag + " " + value + ": cannot read") != std::string::npos;
    }
    EXPECT_TRUE(named) << u->name << ": no TLS flag and file named in\n" << log;
    EXPECT_TRUE(std::ranges::find(u->restartPreventExitStatus, "2") !=
                u->restartPreventExitStatus.end())
        << u->name << ": no RestartPreventExitStatus=2, so systemd would start it again and again";
  }
}

TEST(SystemdUnits, SystemdAnalyzeReadsTheUnitsWithoutAWarning) {
  if (!fs::exists("/usr/bin/systemd-analyze")) {
    GTEST_SKIP() << "systemd-analyze is not installed";
  }
  const fs::path dir = makeTempDir("systemd-analyze");
  for (const Unit* u : {&coordinatorUnit(), &workerUnit()}) {
    // The unit as is, but for its binary's path (systemd-analyze wants it executable).
    const std::string installed = commandLine(*u).at(0);
    std::string text = slurpFile(sourceDir() / "deploy/systemd" / u->name);
    const size_t at = text.find("ExecStart=" + installed);
    ASSERT_NE(at, std::string::npos);
    text.replace(at + 10, installed.size(), binary(binaryOf({installed})).string());
    std::ofstream(dir / u->name) << text;
    const ShellResult r = shell("cd " + shellQuote(dir.string()) + " && systemd-analyze verify " +
                                shellQuote((dir / u->name).string()) + " 2>&1");
    EXPECT_EQ(r.status, 0) << u->name << ":\n" << r.out;
    EXPECT_EQ(r.out, "") << u->name;
  }
}

}  // namespace
}  // namespace pbgi::testing
