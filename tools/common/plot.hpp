// Report plots drawn by gnuplot (Debian package gnuplot-nox, pngcairo terminal): line charts on log or linear
// axes, panels side by side, a legend per panel. Each plot's data goes beside it as CSV, with the gnuplot
// script that draws the PNG from it (`gnuplot NAME.gp` in that folder draws it again).
#pragma once

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace svo::tools::plot {

struct Series {
  std::string name;
  std::vector<std::pair<double, double>>
      points;  // (x, y); only finite ones (and > 0 on a log axis) are drawn
};

enum class Scale { Log, Linear };

struct Panel {
  std::string title;
  std::vector<Series> series;
};

// Writes `path` (PNG), and beside it NAME.csv (columns panel, series, x, y: the points drawn) and NAME.gp.
// Panels fill a grid (columns x rows as needed); a series name keeps its color in every panel. Log axes
// have decade ticks; linear ones start at 0 (or below, for negative values). Throws std::runtime_error with
// one line naming the path: gnuplot missing (naming its package), or gnuplot's exit status and message.
void writePlot(const std::filesystem::path& path, const std::vector<Panel>& panels, const std::string& xLabel,
               const std::string& yLabel, Scale xScale, Scale yScale, int width = 1400, int height = 1000);
// writePlot with both axes log10.
void writeLogLogPlot(const std::filesystem::path& path, const std::vector<Panel>& panels,
                     const std::string& xLabel, const std::string& yLabel, int width = 1400,
                     int height = 1000);

}  // namespace svo::tools::plot
