// The Prometheus registry: each kind of metric in the text format, in declaration order.

#include <gtest/gtest.h>

#include "services/coordinator/metrics.h"

namespace pbgi::metrics {
namespace {

TEST(Metrics, TextFormatOfEveryKind) {
  Registry r;
  r.gauge("jobs", "Jobs by state.", "state", [] {
    return Samples{{"active", 2}, {"say \"hi\"\n", 0.5}};
  });
  Counter& calls = r.counter("calls_total", "Calls.\\ Counted.");
  uint64_t outside = 7;
  r.counter("outside_total", "Read when scraped.", [&] { return outside; });
  Histogram& seconds = r.histogram("task_seconds", "Durations.", "kind", {0.5, 2});
  calls.add();
  calls.add(41);
  outside = 12345678901234567ull;  // exactly, not as a double
  seconds.observe("tile", 0.25);
  seconds.observe("tile", 1.0);
  seconds.observe("bake", 5.0);
  EXPECT_EQ(r.text(),
            "# HELP jobs Jobs by state.\n"
            "# TYPE jobs gauge\n"
            "jobs{state=\"active\"} 2\n"
            "jobs{state=\"say \\\"hi\\\"\\n\"} 0.5\n"
            "# HELP calls_total Calls.\\\\ Counted.\n"
            "# TYPE calls_total counter\n"
            "calls_total 42\n"
            "# HELP outside_total Read when scraped.\n"
            "# TYPE outside_total counter\n"
            "outside_total 12345678901234567\n"
            "# HELP task_seconds Durations.\n"
            "# TYPE task_seconds histogram\n"
            "task_seconds_bucket{kind=\"bake\",le=\"0.5\"} 0\n"
            "task_seconds_bucket{kind=\"bake\",le=\"2\"} 0\n"
            "task_seconds_bucket{kind=\"bake\",le=\"+Inf\"} 1\n"
            "task_seconds_sum{kind=\"bake\"} 5\n"
            "task_seconds_count{kind=\"bake\"} 1\n"
            "task_seconds_bucket{kind=\"tile\",le=\"0.5\"} 1\n"
            "task_seconds_bucket{kind=\"tile\",le=\"2\"} 2\n"
            "task_seconds_bucket{kind=\"tile\",le=\"+Inf\"} 2\n"
            "task_seconds_sum{kind=\"tile\"} 1.25\n"
            "task_seconds_count{kind=\"tile\"} 2\n");
}

TEST(Metrics, AnUnlabelledGaugeAndAnEmptyHistogram) {
  Registry r;
  r.gauge("rate", "A ratio.", "", [] { return Samples{{"", 0.75}}; });
  r.histogram("empty_seconds", "Nothing yet.", "kind", {1});
  EXPECT_EQ(r.text(),
            "# HELP rate A ratio.\n# TYPE rate gauge\nrate 0.75\n"
            "# HELP empty_seconds Nothing yet.\n# TYPE empty_seconds histogram\n");
}

TEST(MetricsDeathTest, ANameIsDeclaredOnce) {
  Registry r;
  r.counter("twice_total", "Once.");
  EXPECT_DEATH(r.counter("twice_total", "Twice."), "twice_total");
  EXPECT_DEATH(r.counter("9lives", "Not a name."), "isMetricName");
}

}  // namespace
}  // namespace pbgi::metrics
