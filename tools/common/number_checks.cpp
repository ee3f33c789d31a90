#include "number_checks.hpp"

#include <cmath>
#include <string>

#include <fmt/format.h>

namespace svo::tools {
namespace {

// `accepts` the finite value, else the message for `input`; "" is CLI11's "passed".
template <class Accepts>
CLI::Validator numberCheck(std::string description, Accepts accepts, std::string bounds) {
  return CLI::Validator(
      [accepts, bounds](std::string& input) -> std::string {
        double value = 0.0;
        if (!CLI::detail::lexical_cast(input, value)) return fmt::format("{} is not a number", input);
        if (!std::isfinite(value)) return fmt::format("{} is not a finite number", input);
        return accepts(value) ? std::string() : fmt::format("Value {} not {}", input, bounds);
      },
      std::move(description));
}

}  // namespace

CLI::Validator finiteNumber() {
  return numberCheck(
      "FINITE", [](double) { return true; }, "");
}

CLI::Validator finiteRange(double min, double max) {
  return numberCheck(
      fmt::format("FLOAT in [{} - {}]", min, max), [min, max](double v) { return v >= min && v <= max; },
      fmt::format("in range [{} - {}]", min, max));
}

CLI::Validator finitePositive() {
  return numberCheck(
      "POSITIVE", [](double v) { return v > 0.0; }, "positive");
}

CLI::Validator finiteNonNegative() {
  return numberCheck(
      "NONNEGATIVE", [](double v) { return v >= 0.0; }, "non-negative");
}

}  // namespace svo::tools
