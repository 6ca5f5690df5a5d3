#include "services/coordinator/metrics.h"

#include <algorithm>

#include <fmt/format.h>

#include "core/util/check.h"

namespace pbgi::metrics {

namespace {

bool isMetricName(const std::string& name) {
  if (name.empty() || std::isdigit(static_cast<unsigned char>(name[0]))) return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == ':';
  });
}

// Label values escape backslash, double quote and newline; help text backslash and newline.
std::string escaped(std::string_view text, bool quote) {
  std::string out;
  for (const char c : text) {
    if (c == '\\') {
      out += "\\\\";
    } else if (c == '\n') {
      out += "\\n";
    } else if (c == '"' && quote) {
      out += "\\\"";
    } else {
      out += c;
    }
  }
  return out;
}

std::string labels(const std::string& label, const std::string& value,
                   const std::string& extra = {}) {
  std::string out;
  if (!label.empty()) out = fmt::format("{}=\"{}\"", label, escaped(value, true));
  if (!extra.empty()) out += (out.empty() ? "" : ",") + extra;
  return out.empty() ? out : "{" + out + "}";
}

constexpr const char* typeName(int type) {
  constexpr const char* kNames[] = {"counter", "gauge", "histogram"};
  return kNames[type];
}

}  // namespace

Histogram::Histogram(std::vector<double> bounds) : bounds_(std::move(bounds)) {
  PBGI_CHECK(std::is_sorted(bounds_.begin(), bounds_.end()));
}

void Histogram::observe(const std::string& label, double value) {
  std::lock_guard lock(mutex_);
  Series& s = series_[label];
  s.buckets.resize(bounds_.size());
  for (size_t i = 0; i < bounds_.size(); ++i) {
    if (value <= bounds_[i]) ++s.buckets[i];
  }
  ++s.count;
  s.sum += value;
}

Registry::Family& Registry::declare(std::string name, std::string help, Type type,
                                    std::string label) {
  PBGI_CHECK(isMetricName(name));
  PBGI_CHECK(label.empty() || isMetricName(label));
  for (const Family& f : families_) PBGI_CHECK_NE(f.name, name);
  families_.push_back({std::move(name), std::move(help), type, std::move(label), {}, {}, nullptr});
  return families_.back();
}

Counter& Registry::counter(std::string name, std::string help) {
  Counter& c = counters_.emplace_back();
  declare(std::move(name), std::move(help), Type::kCounter, {}).count = [&c] { return c.value(); };
  return c;
}

void Registry::counter(std::string name, std::string help, std::function<uint64_t()> read) {
  declare(std::move(name), std::move(help), Type::kCounter, {}).count = std::move(read);
}

void Registry::gauge(std::string name, std::string help, std::string label,
                     std::function<Samples()> read) {
  declare(std::move(name), std::move(help), Type::kGauge, std::move(label)).read = std::move(read);
}

Histogram& Registry::histogram(std::string name, std::string help, std::string label,
                               std::vector<double> bounds) {
  Histogram& h = histograms_.emplace_back(std::move(bounds));
  declare(std::move(name), std::move(help), Type::kHistogram, std::move(label)).histogram = &h;
  return h;
}

std::string Registry::text() const {
  std::string out;
  for (const Family& f : families_) {
    out += fmt::format("# HELP {} {}\n# TYPE {} {}\n", f.name, escaped(f.help, false), f.name,
                       typeName(static_cast<int>(f.type)));
    if (f.type == Type::kCounter) {
      out += fmt::format("{} {}\n", f.name, f.count());
      continue;
    }
    if (f.type == Type::kGauge) {
      for (const auto& [value, sample] : f.read()) {
        out += fmt::format("{}{} {}\n", f.name, labels(f.label, value), sample);
      }
      continue;
    }
    const Histogram& h = *f.histogram;
    std::lock_guard lock(h.mutex_);
    for (const auto& [value, s] : h.series_) {
      for (size_t i = 0; i < h.bounds_.size(); ++i) {
        out += fmt::format("{}_bucket{} {}\n", f.name,
                           labels(f.label, value, fmt::format("le=\"{}\"", h.bounds_[i])),
                           s.buckets[i]);
      }
      out +=
          fmt::format("{}_bucket{} {}\n", f.name, labels(f.label, value, "le=\"+Inf\""), s.count);
      out += fmt::format("{}_sum{} {}\n", f.name, labels(f.label, value), s.sum);
      out += fmt::format("{}_count{} {}\n", f.name, labels(f.label, value), s.count);
    }
  }
  return out;
}

}  // namespace pbgi::metrics
