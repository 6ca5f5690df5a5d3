#include "core/scene/integrator_params.h"

#include <charconv>
#include <cmath>

#include <absl/strings/numbers.h>
#include <fmt/format.h>
#include <fmt/ranges.h>

namespace pbgi {

namespace {

std::string formatNumber(double v) { return fmt::format("{:g}", v); }

bool inRange(const ParamSpec& spec, double v) { return spec.contains(v); }

}  // namespace

std::string ParamSpec::expected() const {
  switch (type) {
    case ParamType::kInt:
      return fmt::format("an integer in [{}, {}]", formatNumber(lo), formatNumber(hi));
    case ParamType::kFloat:
      return fmt::format("a number in {}{}, {}]", loOpen ? "(" : "[", formatNumber(lo),
                         formatNumber(hi));
    case ParamType::kChoice:
      return fmt::format("one of: {}", fmt::join(choices, ", "));
  }
  return {};
}

std::string ParamValue::toString() const {
  if (const auto* i = std::get_if<int64_t>(&value)) return std::to_string(*i);
  if (const auto* d = std::get_if<double>(&value)) return fmt::format("{}", *d);  // round-trips
  return std::get<std::string>(value);
}

absl::Status paramError(const ParamSpec& spec, const SourceLocation& where,
                        std::string_view found) {
  return absl::InvalidArgumentError(fmt::format("{}: '{}': expected {}, found {}", where.toString(),
                                                spec.key, spec.expected(), found));
}

absl::Status IntegratorParams::setText(const ParamSpec& spec, std::string_view text,
                                       const SourceLocation& where) {
  const std::string quoted = fmt::format("\"{}\"", text);
  ParamValue v{.where = where};
  switch (spec.type) {
    case ParamType::kInt: {
      int64_t i = 0;
      if (!absl::SimpleAtoi(absl::string_view(text.data(), text.size()), &i) ||
          !inRange(spec, static_cast<double>(i))) {
        return paramError(spec, where, quoted);
      }
      v.value = i;
      break;
    }
    case ParamType::kFloat: {
      double d = 0.0;
      if (!absl::SimpleAtod(absl::string_view(text.data(), text.size()), &d) ||
          !std::isfinite(d) || !inRange(spec, d)) {
        return paramError(spec, where, quoted);
      }
      v.value = d;
      break;
    }
    case ParamType::kChoice: {
      bool known = false;
      for (std::string_view c : spec.choices) known = known || c == text;
      if (!known) return paramError(spec, where, quoted);
      v.value = std::string(text);
      break;
    }
  }
  values_[std::string(spec.key)] = std::move(v);
  return absl::OkStatus();
}

absl::Status IntegratorParams::set(const ParamSpec& spec, ParamValue value) {
  bool ok = false;
  switch (spec.type) {
    case ParamType::kInt:
      ok = std::holds_alternative<int64_t>(value.value) &&
           inRange(spec, static_cast<double>(std::get<int64_t>(value.value)));
      break;
    case ParamType::kFloat:
      // Integers are numbers too: `max_solid_angle = 1` means 1.0.
      if (const auto* i = std::get_if<int64_t>(&value.value)) value.value = static_cast<double>(*i);
      ok = std::holds_alternative<double>(value.value) &&
           std::isfinite(std::get<double>(value.value)) &&
           inRange(spec, std::get<double>(value.value));
      break;
    case ParamType::kChoice:
      if (const auto* s = std::get_if<std::string>(&value.value)) {
        for (std::string_view c : spec.choices) ok = ok || c == *s;
      }
      break;
  }
  if (!ok) return paramError(spec, value.where, value.toString());
  values_[std::string(spec.key)] = std::move(value);
  return absl::OkStatus();
}

const ParamValue* IntegratorParams::find(std::string_view key) const {
  const auto it = values_.find(key);
  return it == values_.end() ? nullptr : &it->second;
}

int64_t IntegratorParams::intOr(std::string_view key, int64_t fallback) const {
  const ParamValue* v = find(key);
  return v != nullptr ? std::get<int64_t>(v->value) : fallback;
}

double IntegratorParams::floatOr(std::string_view key, double fallback) const {
  const ParamValue* v = find(key);
  return v != nullptr ? std::get<double>(v->value) : fallback;
}

std::string IntegratorParams::choiceOr(std::string_view key, std::string_view fallback) const {
  const ParamValue* v = find(key);
  return v != nullptr ? std::get<std::string>(v->value) : std::string(fallback);
}

std::string IntegratorParams::toString() const {
  std::string out;
  for (const auto& [key, v] : values_) out += fmt::format("{}={}\n", key, v.toString());
  return out;
}

bool IntegratorParams::operator==(const IntegratorParams& o) const {
  if (values_.size() != o.values_.size()) return false;
  for (auto a = values_.begin(), b = o.values_.begin(); a != values_.end(); ++a, ++b) {
    if (a->first != b->first || a->second.value != b->second.value) return false;
  }
  return true;
}

}  // namespace pbgi
