// Minimal report plots for `svo bench`: log-log line charts rasterized into a pixel buffer and written as PNG
// with OpenImageIO (labels drawn with OpenImageIO's text renderer when a font is available).
#pragma once

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

namespace svo::tools::plot {

struct Series {
  std::string name;
  std::vector<std::pair<double, double>> points;  // (x, y), both > 0; others are skipped
};

struct Panel {
  std::string title;
  std::vector<Series> series;
};

// Panels side by side in a grid (columns × rows as needed), log10 axes with decade ticks, one color per
// series name (the same across panels), a legend. Throws std::runtime_error naming the path on failure.
void writeLogLogPlot(const std::filesystem::path& path, const std::vector<Panel>& panels,
                     const std::string& xLabel, const std::string& yLabel, int width = 1400,
                     int height = 1000);

}  // namespace svo::tools::plot
