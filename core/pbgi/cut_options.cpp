// The cut's options, presets and counters.
#include <algorithm>
#include <string_view>

#include <fmt/format.h>

#include "core/math/vec.h"
#include "core/pbgi/bidirectional_cut.h"

namespace pbgi {

absl::Status CutOptions::validate() const {
  auto check = [](const char* name, float v, float hi) -> absl::Status {
    if (!(v >= 0.0f && v <= hi)) {
      return absl::InvalidArgumentError(
          fmt::format("cut options: {} must be in [0, {}], got {}", name, hi, v));
    }
    return absl::OkStatus();
  };
  if (auto s = check("lightSolidAngle", lightSolidAngle, 4.0f * kPi); !s.ok()) return s;
  if (auto s = check("lightBound", lightBound, 4.0f * kPi); !s.ok()) return s;
  if (auto s = check("receiverBound", receiverBound, 4.0f * kPi); !s.ok()) return s;
  if (auto s = check("normalAngle", normalAngle, kPi); !s.ok()) return s;
  if (auto s = check("selfSkipRadius", selfSkipRadius, 100.0f); !s.ok()) return s;
  if (nearRays < 0 || nearRays > kMaxNearRays) {
    return absl::InvalidArgumentError(
        fmt::format("cut options: nearRays must be in [0, {}], got {}", kMaxNearRays, nearRays));
  }
  if (clusterRays < 1 || clusterRays > kMaxClusterRays) {
    return absl::InvalidArgumentError(fmt::format(
        "cut options: clusterRays must be in [1, {}], got {}", kMaxClusterRays, clusterRays));
  }
  if (receiverLeafSize < 1 || receiverLeafSize > 64) {
    return absl::InvalidArgumentError(
        fmt::format("cut options: receiverLeafSize must be in [1, 64], got {}", receiverLeafSize));
  }
  return absl::OkStatus();
}

namespace {

// The quality presets' thresholds, from the coarsest.
struct CutPreset {
  std::string_view name;
  float lightSolidAngle, lightBound, receiverBound, normalAngleDeg;
  int nearRays;
};
constexpr CutPreset kCutPresets[] = {
    {"draft", 0.03f, 0.3f, 0.05f, 45.0f, 16},
    {"default", 0.02f, 0.2f, 0.03f, 30.0f, 32},
    {"high", 0.005f, 0.05f, 0.01f, 20.0f, 64},
};
// Every preset's cluster pairs take their visibility per receiver (CutOptions::recordVisibility);
// the bake's bounces, whose records stand for patches of surfels, keep one ray a pair
// (bounceCutPreset).

}  // namespace

absl::StatusOr<CutOptions> cutPreset(std::string_view name) {
  for (const CutPreset& p : kCutPresets) {
    if (p.name != name) continue;
    CutOptions o;
    o.lightSolidAngle = p.lightSolidAngle;
    o.lightBound = p.lightBound;
    o.receiverBound = p.receiverBound;
    o.normalAngle = radians(p.normalAngleDeg);
    o.nearRays = p.nearRays;
    o.recordVisibility = true;
    return o;
  }
  return absl::InvalidArgumentError(
      fmt::format("cut preset \"{}\" unknown; known presets: draft, default, high", name));
}

// (nearRays and clusterRays only where they are set: a bake's hash holds its bounces' cut.)
std::string CutOptions::toString() const {
  return fmt::format(
      "cut(lightSolidAngle={:g} lightBound={:g} receiverBound={:g} normalAngle={:g} "
      "receiverLeafSize={} selfSkipRadius={:g}{}{}{}{})",
      lightSolidAngle, lightBound, receiverBound, normalAngle, receiverLeafSize, selfSkipRadius,
      nearRays > 0 ? fmt::format(" nearRays={}", nearRays) : "",
      clusterRays > 1 ? fmt::format(" clusterRays={}", clusterRays) : "",
      recordVisibility ? " recordVisibility" : "", coneDescent ? " coneDescent" : "");
}

CutStats& CutStats::operator+=(const CutStats& o) {
#define PBGI_CUT_COUNTER_ADD(member, counter, name, what) member += o.member;
  PBGI_CUT_COUNTERS(PBGI_CUT_COUNTER_ADD)
#undef PBGI_CUT_COUNTER_ADD
  peakPendingPairs = std::max(peakPendingPairs, o.peakPendingPairs);
  return *this;
}

std::string CutStats::toString() const {
  std::string text;
  const auto add = [&text](std::string_view name, uint64_t value) {
    if (name.starts_with("cut_")) name.remove_prefix(4);
    text += fmt::format("{}{}={}", text.empty() ? "" : " ", name, value);
  };
#define PBGI_CUT_COUNTER_PRINT(member, counter, name, what) add(name, member);
  PBGI_CUT_COUNTERS(PBGI_CUT_COUNTER_PRINT)
#undef PBGI_CUT_COUNTER_PRINT
  add("peak_pending_pairs", peakPendingPairs);
  return text;
}

}  // namespace pbgi
