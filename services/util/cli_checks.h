#pragma once
// Checks for numeric command-line options that say what they expected in words. CLI11's own
// PositiveNumber and NonNegativeNumber are ranges of doubles and say so: "Value 0 not in range
// 2.22507e-308 to 1.79769e+308" for `--spp 0`.
#include <string>

#include <CLI/CLI.hpp>

namespace pbgi {

// A number above 0 ("POSITIVE" in help); "expected a number above 0, found 0".
const CLI::Validator& positiveNumber();
// A number of 0 or more ("NONNEGATIVE" in help); "expected 0 or a number above it, found -1".
const CLI::Validator& nonNegativeNumber();

}  // namespace pbgi
