#include "report.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <stdexcept>

#include <fmt/format.h>

namespace svo::tools {
namespace {

// Spaces between two table columns.
constexpr int kColumnGap = 2;

}  // namespace

Summary summarize(std::vector<double> samples) {
  if (samples.empty()) throw std::invalid_argument("summarize: no samples");
  std::sort(samples.begin(), samples.end());
  const std::size_t n = samples.size();
  Summary s;
  s.median = n % 2 ? samples[n / 2] : 0.5 * (samples[n / 2 - 1] + samples[n / 2]);
  s.min = samples.front();
  s.max = samples.back();
  return s;
}

Table::Table(std::vector<std::string> headers) : headers_(std::move(headers)) {}

void Table::addRow(std::vector<std::string> cells) {
  if (cells.size() > headers_.size()) throw std::invalid_argument("Table::addRow: more cells than columns");
  cells.resize(headers_.size());
  rows_.push_back(std::move(cells));
}

void Table::print(std::FILE* out) const {
  std::vector<std::size_t> width(headers_.size());
  for (std::size_t c = 0; c < headers_.size(); ++c) {
    width[c] = headers_[c].size();
    for (const auto& row : rows_) width[c] = std::max(width[c], row[c].size());
  }
  const auto line = [&](const std::vector<std::string>& cells) {
    std::string text;
    for (std::size_t c = 0; c < cells.size(); ++c) {
      if (c) text.append(kColumnGap, ' ');
      text += c == 0 ? fmt::format("{:<{}}", cells[c], width[c]) : fmt::format("{:>{}}", cells[c], width[c]);
    }
    while (!text.empty() && text.back() == ' ') text.pop_back();
    fmt::print(out, "{}\n", text);
  };
  line(headers_);
  std::size_t total = 0;
  for (std::size_t c = 0; c < width.size(); ++c) total += width[c] + (c ? kColumnGap : 0);
  fmt::print(out, "{}\n", std::string(total, '-'));
  for (const auto& row : rows_) line(row);
  std::fflush(out);
}

void printTitle(std::string_view title, std::FILE* out) {
  fmt::print(out, "\n{}\n{}\n", title, std::string(title.size(), '='));
}

std::string formatSeconds(double seconds) {
  if (seconds < 1.0) return fmt::format("{:.1f} ms", seconds * 1e3);
  return fmt::format("{:.2f} s", seconds);
}

std::string formatCount(std::uint64_t count) {
  std::string digits = std::to_string(count);
  std::string out;
  for (std::size_t i = 0; i < digits.size(); ++i) {
    if (i && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return out;
}

std::optional<std::uint64_t> parseCount(const std::string& text) {
  double value = 0.0;
  const char* end = text.data() + text.size();
  const auto [rest, ec] = std::from_chars(text.data(), end, value);
  if (ec != std::errc() || text.empty() || !(value >= 0.0)) return std::nullopt;
  double scale = 1.0;
  if (rest != end) {
    if (rest + 1 != end) return std::nullopt;
    switch (std::toupper(static_cast<unsigned char>(*rest))) {
      case 'K':
        scale = 1e3;
        break;
      case 'M':
        scale = 1e6;
        break;
      case 'G':
        scale = 1e9;
        break;
      default:
        return std::nullopt;
    }
  }
  const double count = std::round(value * scale);
  // Beyond 2^63 the conversion is undefined; such counts are rejected by the range check anyway.
  if (count > 9e18) return std::uint64_t(9e18);
  return std::uint64_t(count);
}

}  // namespace svo::tools
