#include "services/util/cli_checks.h"

#include <cmath>
#include <functional>

#include <absl/strings/numbers.h>

namespace pbgi {

namespace {

CLI::Validator numberCheck(std::function<bool(double)> ok, const std::string& expected,
                           const std::string& name) {
  return CLI::Validator(
      [ok = std::move(ok), expected](std::string& text) -> std::string {
        double value = 0.0;
        if (absl::SimpleAtod(text, &value) && std::isfinite(value) && ok(value)) return {};
        return "expected " + expected + ", found " + text;
      },
      name);
}

}  // namespace

const CLI::Validator& positiveNumber() {
  static const CLI::Validator check =
      numberCheck([](double v) { return v > 0.0; }, "a number above 0", "POSITIVE");
  return check;
}

const CLI::Validator& nonNegativeNumber() {
  static const CLI::Validator check =
      numberCheck([](double v) { return v >= 0.0; }, "0 or a number above it", "NONNEGATIVE");
  return check;
}

}  // namespace pbgi
