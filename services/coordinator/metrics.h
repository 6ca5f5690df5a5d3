#pragma once
// A small Prometheus registry. Each metric is declared once (name, help, type, at most one
// label), and the text exposition format (version 0.0.4) is written in one place, text().
// Debian has no prometheus-cpp; this is what the coordinator's /metrics needs: counters kept
// here, counters and gauges read at each scrape (from the job store, from other counters),
// and histograms by one label.
#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace pbgi::metrics {

class Counter {
 public:
  void add(uint64_t n = 1) { value_.fetch_add(n, std::memory_order_relaxed); }
  uint64_t value() const { return value_.load(std::memory_order_relaxed); }

 private:
  std::atomic<uint64_t> value_{0};
};

// A histogram's series by label value; every series has the same bucket bounds.
class Histogram {
 public:
  explicit Histogram(std::vector<double> bounds);
  void observe(const std::string& label, double value);

 private:
  friend class Registry;
  struct Series {
    std::vector<uint64_t> buckets;  // cumulative: values <= bounds_[i]
    uint64_t count = 0;
    double sum = 0.0;
  };
  std::vector<double> bounds_;
  mutable std::mutex mutex_;
  std::map<std::string, Series> series_;  // by label value, in order
};

// Samples of a metric read at a scrape: (label value, value); the label value is ignored for
// a metric declared without a label.
using Samples = std::vector<std::pair<std::string, double>>;

class Registry {
 public:
  Registry() = default;
  Registry(const Registry&) = delete;
  Registry& operator=(const Registry&) = delete;

  // Declarations, listed by text() in this order. A name is declared once (checked), and
  // must be a Prometheus name.
  Counter& counter(std::string name, std::string help);
  void counter(std::string name, std::string help, std::function<uint64_t()> read);
  // label empty: one sample, unlabelled.
  void gauge(std::string name, std::string help, std::string label, std::function<Samples()> read);
  Histogram& histogram(std::string name, std::string help, std::string label,
                       std::vector<double> bounds);

  // Every metric as Prometheus text: # HELP, # TYPE, then its samples.
  std::string text() const;

 private:
  enum class Type { kCounter, kGauge, kHistogram };
  struct Family {
    std::string name;
    std::string help;
    Type type;
    std::string label;
    std::function<uint64_t()> count;  // counters: integers, exactly
    std::function<Samples()> read;    // gauges
    const Histogram* histogram = nullptr;
  };
  Family& declare(std::string name, std::string help, Type type, std::string label);

  std::vector<Family> families_;
  std::deque<Counter> counters_;  // stable addresses
  std::deque<Histogram> histograms_;
};

}  // namespace pbgi::metrics
