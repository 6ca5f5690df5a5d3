#pragma once
// Hosts on a private network inside the sandbox, made by a test: each host a network
// namespace joined to this one by a veth pair on a /30 of its own (10.231.S.4h+1 here,
// 10.231.S.4h+2 there, S from the process id), nothing routed beyond. A daemon runs on a host
// through `launcher(h)`; `setLink(h, false)` cuts the host off (its processes keep running,
// their packets go nowhere) until `setLink(h, true)`. Needs root and `ip netns`;
// `unavailable()` says why not. Everything is removed when the object goes.
#include <unistd.h>

#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "tests/support/slurm_cluster.h"

namespace pbgi::testing {

class NetworkHosts {
 public:
  static std::optional<std::string> unavailable() {
    if (::geteuid() != 0) return "not root: network namespaces need root";
    const std::string probe = fmt::format("pbgi-probe-{}", ::getpid());
    const ShellResult r = shell("ip netns add " + probe + " 2>&1 && ip netns del " + probe);
    if (r.status != 0) return "`ip netns add` fails here: " + r.out;
    return std::nullopt;
  }

  explicit NetworkHosts(int count) : subnet_(20 + ::getpid() % 200) {
    for (int h = 0; h < count; ++h) {
      const std::string ns = name(h), here = vethHere(h), there = fmt::format("pb{}t{}", tag(), h);
      const std::string script = fmt::format(
          "ip netns add {ns} && ip link add {here} type veth peer name {there} && "
          "ip link set {there} netns {ns} && ip addr add {local}/30 dev {here} && "
          "ip link set {here} up && ip netns exec {ns} ip addr add {remote}/30 dev {there} && "
          "ip netns exec {ns} ip link set {there} up && ip netns exec {ns} ip link set lo up",
          fmt::arg("ns", ns), fmt::arg("here", here), fmt::arg("there", there),
          fmt::arg("local", localAddress(h)), fmt::arg("remote", address(h)));
      const ShellResult r = shell("(" + script + ") 2>&1");
      made_ = h + 1;
      if (r.status != 0) {
        error_ = fmt::format("host {}: {}", h, r.out);
        return;
      }
    }
  }
  ~NetworkHosts() {
    for (int h = 0; h < made_; ++h) {
      shell(fmt::format("ip netns pids {0} 2>/dev/null | xargs -r kill -9; ip link del {1} "
                        "2>/dev/null; ip netns del {0} 2>/dev/null",
                        name(h), vethHere(h)));
    }
  }
  NetworkHosts(const NetworkHosts&) = delete;
  NetworkHosts& operator=(const NetworkHosts&) = delete;

  const std::string& error() const { return error_; }
  // Host h's address, and this side's address on host h's link (where it reaches us).
  std::string address(int h) const { return fmt::format("10.231.{}.{}", subnet_, 4 * h + 2); }
  std::string localAddress(int h) const { return fmt::format("10.231.{}.{}", subnet_, 4 * h + 1); }
  // Words that run a command on host h.
  std::vector<std::string> launcher(int h) const {
    return {"/usr/sbin/ip", "netns", "exec", name(h)};
  }
  // Takes host h's link down (false) or up (true).
  bool setLink(int h, bool up) {
    return shell(fmt::format("ip link set {} {}", vethHere(h), up ? "up" : "down")).status == 0;
  }

 private:
  int tag() const { return ::getpid() % 100000; }
  std::string name(int h) const { return fmt::format("pbgi-{}-h{}", tag(), h); }
  std::string vethHere(int h) const { return fmt::format("pb{}h{}", tag(), h); }

  int subnet_;
  int made_ = 0;
  std::string error_;
};

}  // namespace pbgi::testing
