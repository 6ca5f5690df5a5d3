// deploy/grafana/pbgi-farm.json against a live coordinator's /metrics: every metric a panel
// queries is one the coordinator declares (its # TYPE line), and every series a panel selects
// by label (`pbgi_tasks{state="ready"}`) is one it serves, so that a renamed metric or state
// cannot leave a panel silently empty.
#include <gtest/gtest.h>

#include <regex>
#include <set>
#include <string>

#include <fmt/format.h>

#include "tests/support/idle_coordinator.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/test_paths.h"

namespace pbgi::testing {
namespace {

TEST(GrafanaDashboard, EveryQueriedMetricIsOneTheCoordinatorServes) {
  const std::string dashboard = slurpFile(sourceDir() / "deploy/grafana/pbgi-farm.json");
  const absl::StatusOr<std::string> served = idleCoordinatorMetrics("grafana");
  ASSERT_TRUE(served.ok()) << served.status();
  const std::string metrics = "\n" + *served;

  const std::regex expr(R"re("expr": "((?:[^"\\]|\\.)*)")re");
  const std::regex metric(R"((pbgi_[a-z_]+)(\{([a-z_]+)=\\"([a-z_]+)\\"\})?)");
  int queries = 0;
  std::set<std::string> names;
  for (auto e = std::sregex_iterator(dashboard.begin(), dashboard.end(), expr);
       e != std::sregex_iterator(); ++e) {
    ++queries;
    const std::string text = (*e)[1];
    for (auto m = std::sregex_iterator(text.begin(), text.end(), metric);
         m != std::sregex_iterator(); ++m) {
      std::string name = (*m)[1];
      // A histogram's series are its name's _bucket, _count and _sum.
      for (const char* suffix : {"_bucket", "_count", "_sum"}) {
        if (name.ends_with(suffix) && metrics.find("\n# TYPE " + name + " ") == std::string::npos) {
          name.resize(name.size() - std::string(suffix).size());
        }
      }
      names.insert(name);
      EXPECT_NE(metrics.find("\n# TYPE " + name + " "), std::string::npos)
          << text << ": the coordinator declares no " << name;
      if ((*m)[2].matched) {
        const std::string series = fmt::format("\n{}{{{}=\"{}\"}} ", name, (*m)[3].str(), (*m)[4].str());
        EXPECT_NE(metrics.find(series), std::string::npos) << text << ": no series" << series;
      }
    }
  }
  EXPECT_GE(queries, 8);
  EXPECT_GE(names.size(), 10u);
}

}  // namespace
}  // namespace pbgi::testing
