#include "plot.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <optional>
#include <stdexcept>

#include <fmt/format.h>

#include "process.hpp"
#include "text_file.hpp"

namespace svo::tools::plot {
namespace {

// Line colors by series name, in order of first appearance (Tableau 10), then they repeat.
constexpr const char* kPalette[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                                    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"};
// Text size in points at the default 1400 x 1000 pixels; DejaVu Sans is what fontconfig gives for "Sans".
constexpr int kFontPoints = 11;
// Line width and point size, in gnuplot's units: two-pixel antialiased lines under small round points.
constexpr double kLineWidth = 2.0, kPointSize = 0.6;
// The Debian package that has gnuplot with the pngcairo terminal.
constexpr const char* kGnuplotPackage = "gnuplot-nox";

// A gnuplot string literal: single quotes take everything literally but a doubled quote.
std::string quoted(const std::string& text) {
  std::string out = "'";
  for (const char c : text) out += c == '\'' ? std::string("''") : std::string(1, c);
  return out + "'";
}

// An RFC 4180 CSV field, quoted when it holds a comma, a quote or a line break (gnuplot reads it so).
std::string csvField(const std::string& text) {
  if (text.find_first_of(",\"\n") == std::string::npos) return text;
  std::string out = "\"";
  for (const char c : text) out += c == '"' ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

bool plottable(double v, Scale scale) {
  return std::isfinite(v) && (scale == Scale::Linear || v > 0.0);
}

// The CSV rows of one series: the first and last data row (0-based, header not counted), for `every`.
struct Rows {
  std::size_t first = 0, last = 0;
};

// One axis's settings: log10 with decade ticks, or linear from 0 (or from the smallest value when below).
std::string axisCommands(const char* axis, Scale scale, double smallest) {
  if (scale == Scale::Log)
    return fmt::format("set logscale {0} 10\nset format {0} '10^{{%L}}'\nset m{0}tics 10\n", axis);
  return fmt::format("unset logscale {0}\nset format {0} '%g'\nset {0}range [{1}:*]\nset m{0}tics\n", axis,
                     std::min(0.0, smallest));
}

// The range an empty panel shows: one decade of a log axis, [0, 1] of a linear one.
const char* emptyRange(Scale scale) {
  return scale == Scale::Log ? "[1:10]" : "[0:1]";
}

// Panels in a grid of columns x rows, as near to square as the count allows.
struct Layout {
  int columns = 1, rows = 1;
};
Layout gridFor(std::size_t panels) {
  const int columns = int(std::ceil(std::sqrt(double(panels))));
  return {columns, int((panels + std::size_t(columns) - 1) / std::size_t(columns))};
}

// Writes the CSV and returns, per panel and series, its rows (or none when nothing of it is plottable).
std::vector<std::vector<std::optional<Rows>>> writeData(const std::filesystem::path& csvPath,
                                                        const std::vector<Panel>& panels, Scale xScale,
                                                        Scale yScale) {
  std::ofstream csv(csvPath);
  csv << "panel,series,x,y\n";
  std::vector<std::vector<std::optional<Rows>>> rows(panels.size());
  std::size_t row = 0;
  for (std::size_t p = 0; p < panels.size(); ++p)
    for (const Series& s : panels[p].series) {
      const std::size_t first = row;
      for (const auto& [x, y] : s.points) {
        if (!plottable(x, xScale) || !plottable(y, yScale)) continue;
        csv << csvField(panels[p].title) << ',' << csvField(s.name) << ',' << fmt::format("{},{}", x, y)
            << '\n';
        ++row;
      }
      rows[p].push_back(row > first ? std::optional(Rows{first, row - 1}) : std::nullopt);
    }
  csv.close();
  if (!csv) throw std::runtime_error("plot " + csvPath.string() + ": cannot write");
  return rows;
}

// The gnuplot script that draws `png` from `csv`: shared axis settings, then one plot per panel of a
// multiplot grid, each series from its rows of the CSV.
std::string script(const std::filesystem::path& png, const std::filesystem::path& csv,
                   const std::vector<Panel>& panels,
                   const std::vector<std::vector<std::optional<Rows>>>& rows, const std::string& xLabel,
                   const std::string& yLabel, Scale xScale, Scale yScale, int width, int height) {
  std::map<std::string, std::string> colors;
  for (const Panel& p : panels)
    for (const Series& s : p.series)
      if (!colors.count(s.name)) colors[s.name] = kPalette[colors.size() % std::size(kPalette)];
  double smallestX = 0.0, smallestY = 0.0;
  for (const Panel& p : panels)
    for (const Series& s : p.series)
      for (const auto& [x, y] : s.points)
        if (plottable(x, xScale) && plottable(y, yScale))
          smallestX = std::min(smallestX, x), smallestY = std::min(smallestY, y);
  const Layout grid = gridFor(panels.size());
  std::string gp = fmt::format(
      "# Draws {} from {} (columns panel, series, x, y); run in this folder: gnuplot {}\n"
      "set terminal pngcairo size {},{} enhanced font 'Sans,{}'\nset output {}\n"
      "set datafile separator comma\nset grid xtics ytics lc rgb '#dddddd'\nset key below noenhanced\n"
      "set xlabel {} noenhanced\nset ylabel {} noenhanced\n{}{}set multiplot layout {},{}\n",
      png.filename().string(), csv.filename().string(), png.stem().string() + ".gp", width, height,
      kFontPoints, quoted(png.filename().string()), quoted(xLabel), quoted(yLabel),
      axisCommands("x", xScale, smallestX), axisCommands("y", yScale, smallestY), grid.rows, grid.columns);
  for (std::size_t p = 0; p < panels.size(); ++p) {
    gp += fmt::format("set title {} noenhanced\n", quoted(panels[p].title));
    std::vector<std::string> plots;
    for (std::size_t s = 0; s < panels[p].series.size(); ++s) {
      const std::optional<Rows>& r = rows[p][s];
      if (!r) continue;
      const Series& series = panels[p].series[s];
      plots.push_back(fmt::format(
          "{} skip 1 every ::{}::{} using 3:4 with linespoints lw {} pt 7 ps {} lc rgb '{}' title {}",
          quoted(csv.filename().string()), r->first, r->last, kLineWidth, kPointSize, colors[series.name],
          quoted(series.name)));
    }
    // A panel with nothing to draw keeps its place in the grid, with its title and axes and a line saying so.
    if (plots.empty()) {
      gp += fmt::format("set label 1 {} at graph 0.5,0.5 center\nplot {} {} NaN notitle\nunset label 1\n",
                        quoted("nothing to draw (no finite value, or none above 0 on a log axis)"),
                        emptyRange(xScale), emptyRange(yScale));
      continue;
    }
    gp += "plot ";
    for (std::size_t k = 0; k < plots.size(); ++k) gp += (k ? ", \\\n     " : "") + plots[k];
    gp += "\n";
  }
  return gp + "unset multiplot\n";
}

}  // namespace

void writeLogLogPlot(const std::filesystem::path& path, const std::vector<Panel>& panels,
                     const std::string& xLabel, const std::string& yLabel, int width, int height) {
  writePlot(path, panels, xLabel, yLabel, Scale::Log, Scale::Log, width, height);
}

void writePlot(const std::filesystem::path& path, const std::vector<Panel>& panels, const std::string& xLabel,
               const std::string& yLabel, Scale xScale, Scale yScale, int width, int height) {
  if (panels.empty()) throw std::runtime_error("plot " + path.string() + ": nothing to plot");
  const std::filesystem::path folder = path.has_parent_path() ? path.parent_path() : ".";
  std::filesystem::path csv = path, gp = path;
  csv.replace_extension(".csv");
  gp.replace_extension(".gp");
  const auto rows = writeData(csv, panels, xScale, yScale);
  writeTextFile(gp, script(path, csv, panels, rows, xLabel, yLabel, xScale, yScale, width, height));
  const std::optional<ProcessResult> gnuplot =
      runProcess({"gnuplot", gp.filename().string()}, {.workingDirectory = folder});
  if (!gnuplot)
    throw std::runtime_error(fmt::format("plot {}: gnuplot not found (install the Debian package {})",
                                         path.string(), kGnuplotPackage));
  if (!gnuplot->succeeded()) {
    std::error_code ignored;
    std::filesystem::remove(path, ignored);
    std::string message = gnuplot->output;
    std::replace(message.begin(), message.end(), '\n', ' ');
    throw std::runtime_error(fmt::format("plot {}: gnuplot {} exited with {}: {}", path.string(), gp.string(),
                                         gnuplot->exitCode, message));
  }
}

}  // namespace svo::tools::plot
