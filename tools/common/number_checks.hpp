// Checks for numeric command-line options. CLI11 reads "nan" and "inf" as floats, and its Range,
// PositiveNumber and NonNegativeNumber let both through (every comparison with a NaN is false); these refuse
// them.
#pragma once

#include <CLI/CLI.hpp>

namespace svo::tools {

// Any finite number.
CLI::Validator finiteNumber();
// A finite number in [min, max].
CLI::Validator finiteRange(double min, double max);
// A finite number above 0.
CLI::Validator finitePositive();
// A finite number of at least 0.
CLI::Validator finiteNonNegative();

}  // namespace svo::tools
