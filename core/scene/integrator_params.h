#pragma once
// Typed integrator parameters: what each integrator declares in the registry
// (core/render/integrators.h) and what users set in a shot's [render] table, on the command
// line (`--set key=value` and the named flags) or in a farm job's overrides. A value is parsed
// and range-checked once, against its declaration, and keeps where it came from, so that an
// integrator's own cross-checks can still name the file and line.
#include <cstdint>
#include <map>
#include <span>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/util/source_location.h"

namespace pbgi {

enum class ParamType { kInt, kFloat, kChoice };

// One parameter as an integrator declares it.
struct ParamSpec {
  std::string_view key;  // as written in [render], `--set` and job overrides
  ParamType type = ParamType::kInt;
  double lo = 0.0, hi = 0.0;              // kInt, kFloat: the range, inclusive
  bool loOpen = false;                    // ... except lo itself when set
  std::vector<std::string_view> choices;  // kChoice: the names allowed
  std::string_view defaultText;           // what an unset value means, for help
  std::string_view help;

  // "an integer in [1, 64]", "a number in (0, 0.5]", "one of: draft, default, high".
  std::string expected() const;
  bool contains(double v) const { return (loOpen ? v > lo : v >= lo) && v <= hi; }
};

// A value and where it was set: a shot file's file:line:column, or a flag or override.
struct ParamValue {
  std::variant<int64_t, double, std::string> value;
  SourceLocation where;
  std::string toString() const;
};

// The parameters set for one render: keys that some integrator declares, values of their
// declared type and range. Unset keys take the integrator's defaults.
class IntegratorParams {
 public:
  // Sets `spec.key` from text (a flag or an override): parsed and range-checked against the
  // declaration; InvalidArgument "<where>: '<key>': expected <...>, found \"<text>\"".
  absl::Status setText(const ParamSpec& spec, std::string_view text, const SourceLocation& where);
  // Sets an already typed value (the shot parser reads TOML types itself); the value must be
  // of the spec's type and in range (checked, InvalidArgument naming `value.where`).
  absl::Status set(const ParamSpec& spec, ParamValue value);

  const ParamValue* find(std::string_view key) const;
  bool empty() const { return values_.empty(); }
  const std::map<std::string, ParamValue, std::less<>>& values() const { return values_; }

  // Typed reads of a declared parameter; the fallback when unset. A value of another type
  // cannot be stored (set checks), so these never fail.
  int64_t intOr(std::string_view key, int64_t fallback) const;
  double floatOr(std::string_view key, double fallback) const;
  std::string choiceOr(std::string_view key, std::string_view fallback) const;

  // "key=value" lines, sorted by key: what keys a bake or a cached reference depends on.
  std::string toString() const;

  bool operator==(const IntegratorParams& o) const;

 private:
  std::map<std::string, ParamValue, std::less<>> values_;
};

// "'key': expected <spec.expected()>, found <found>" at `where`, as InvalidArgument.
absl::Status paramError(const ParamSpec& spec, const SourceLocation& where, std::string_view found);

}  // namespace pbgi
