// Plain terminal reports for the commands and the benchmarks: aligned tables, section titles, the median
// of a set of samples, and numbers formatted for reading.
#pragma once

#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace svo::tools {

// Median, smallest and largest of a set of samples (seconds, or any other unit).
struct Summary {
  double median = 0.0, min = 0.0, max = 0.0;
};
// Throws std::invalid_argument when `samples` is empty. The median of an even count is the mean of the two
// middle samples.
Summary summarize(std::vector<double> samples);

// A table printed with aligned columns: the first column left-aligned, the others right-aligned.
class Table {
 public:
  explicit Table(std::vector<std::string> headers);
  // Rows shorter than the header are padded with empty cells; longer ones throw std::invalid_argument.
  void addRow(std::vector<std::string> cells);
  void print(std::FILE* out = stdout) const;

 private:
  std::vector<std::string> headers_;
  std::vector<std::vector<std::string>> rows_;
};

// Prints a section title underlined, with a blank line before it.
void printTitle(std::string_view title, std::FILE* out = stdout);

// "12.3 ms", "1.23 s".
std::string formatSeconds(double seconds);
// "12,345,678".
std::string formatCount(std::uint64_t count);
// "20000", "20k", "20M", "1.5G" (decimal multipliers) -> a count; nullopt when it is not one.
std::optional<std::uint64_t> parseCount(const std::string& text);

}  // namespace svo::tools
