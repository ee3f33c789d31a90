// Minimal report plots for `svo bench`: line charts on log or linear axes, rasterized into a pixel buffer
// and written as PNG with OpenImageIO (labels drawn with its text renderer when a font is available).
#pragma once

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace svo::tools::plot {

struct Series {
  std::string name;
  std::vector<std::pair<double, double>>
      points;  // (x, y), finite (and > 0 on a log axis); others are skipped
};

enum class Scale { Log, Linear };

struct Panel {
  std::string title;
  std::vector<Series> series;
};

// Panels side by side in a grid (columns × rows as needed), one color per series name (the same across
// panels), a legend. Log axes have decade ticks; linear ones start at 0 and step by 1, 2 or 5 times a power
// of ten. Throws std::runtime_error naming the path on failure.
void writePlot(const std::filesystem::path& path, const std::vector<Panel>& panels, const std::string& xLabel,
               const std::string& yLabel, Scale xScale, Scale yScale, int width = 1400, int height = 1000);
// writePlot with both axes log10.
void writeLogLogPlot(const std::filesystem::path& path, const std::vector<Panel>& panels,
                     const std::string& xLabel, const std::string& yLabel, int width = 1400,
                     int height = 1000);

}  // namespace svo::tools::plot
