#include "plot.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <map>
#include <stdexcept>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>

namespace svo::tools::plot {

namespace {

// Distinct colors for up to 10 series (Tableau 10), then they repeat.
constexpr std::array<std::array<float, 3>, 10> kPalette = {{{0.12f, 0.47f, 0.71f},
                                                            {1.00f, 0.50f, 0.05f},
                                                            {0.17f, 0.63f, 0.17f},
                                                            {0.84f, 0.15f, 0.16f},
                                                            {0.58f, 0.40f, 0.74f},
                                                            {0.55f, 0.34f, 0.29f},
                                                            {0.89f, 0.47f, 0.76f},
                                                            {0.50f, 0.50f, 0.50f},
                                                            {0.74f, 0.74f, 0.13f},
                                                            {0.09f, 0.75f, 0.81f}}};
// Panel margins in pixels: room for tick labels and titles.
constexpr int kMarginLeft = 70, kMarginRight = 20, kMarginTop = 40, kMarginBottom = 50;
// Legend rows (wrapped to the image width) and the line under them naming the y axis.
constexpr int kLegendRowHeight = 25, kLegendFooterHeight = 35;
constexpr int kFontSize = 16;

struct Canvas {
  int w, h;
  std::vector<float> rgb;
  Canvas(int width, int height) : w(width), h(height), rgb(std::size_t(width) * height * 3, 1.0f) {}
  void set(int x, int y, const std::array<float, 3>& c) {
    if (x < 0 || y < 0 || x >= w || y >= h) return;
    float* p = &rgb[(std::size_t(y) * w + x) * 3];
    p[0] = c[0], p[1] = c[1], p[2] = c[2];
  }
  // Bresenham, `thick` pixels wide.
  void line(int x0, int y0, int x1, int y1, const std::array<float, 3>& c, int thick = 1) {
    const int dx = std::abs(x1 - x0), dy = -std::abs(y1 - y0), sx = x0 < x1 ? 1 : -1, sy = y0 < y1 ? 1 : -1;
    int err = dx + dy;
    for (;;) {
      for (int i = -(thick / 2); i <= thick / 2; ++i)
        for (int j = -(thick / 2); j <= thick / 2; ++j) set(x0 + i, y0 + j, c);
      if (x0 == x1 && y0 == y1) break;
      const int e2 = 2 * err;
      if (e2 >= dy) err += dy, x0 += sx;
      if (e2 <= dx) err += dx, y0 += sy;
    }
  }
  void square(int x, int y, int r, const std::array<float, 3>& c) {
    for (int i = -r; i <= r; ++i)
      for (int j = -r; j <= r; ++j) set(x + i, y + j, c);
  }
};

struct Label {
  int x, y;
  std::string text;
};

// Ticks a linear axis aims for: a step of 1, 2 or 5 times a power of ten giving at least this many.
constexpr int kLinearTicks = 5;

// One axis of a panel: its range, its ticks and where a value lies in [0, 1].
struct Axis {
  Scale scale;
  double lo = 1e300, hi = -1e300;  // of the values, then widened to whole ticks
  double step = 1.0;
  bool plottable(double v) const { return std::isfinite(v) && (scale == Scale::Linear || v > 0); }
  double coordinate(double v) const { return scale == Scale::Log ? std::log10(v) : v; }
  void add(double v) { lo = std::min(lo, coordinate(v)), hi = std::max(hi, coordinate(v)); }
  bool empty() const { return lo > hi; }
  // Decades for a log axis; for a linear one from 0 (or below, for negative values) in round steps.
  void widen() {
    if (scale == Scale::Log) {
      lo = std::floor(lo), hi = std::max(std::ceil(hi), lo + 1);
      return;
    }
    lo = std::min(lo, 0.0);
    const double span = std::max(hi - lo, 1e-300);
    const double magnitude = std::pow(10.0, std::floor(std::log10(span / kLinearTicks)));
    step = magnitude;
    for (const double m : {2.0, 5.0, 10.0})
      if (span / step > 2 * kLinearTicks) step = m * magnitude;
    lo = std::floor(lo / step) * step, hi = std::max(std::ceil(hi / step) * step, lo + step);
  }
  double unit(double v) const { return (coordinate(v) - lo) / (hi - lo); }
  std::vector<double> ticks() const {
    std::vector<double> out;
    for (double t = lo; t <= hi + step * 1e-9; t += step)
      out.push_back(scale == Scale::Log ? std::pow(10.0, t) : t);
    return out;
  }
  std::string label(double tick) const {
    char text[32];
    if (scale == Scale::Log)
      std::snprintf(text, sizeof text, "1e%d", int(std::lround(std::log10(tick))));
    else
      std::snprintf(text, sizeof text, "%g", tick);
    return text;
  }
};

}  // namespace

void writeLogLogPlot(const std::filesystem::path& path, const std::vector<Panel>& panels,
                     const std::string& xLabel, const std::string& yLabel, int width, int height) {
  writePlot(path, panels, xLabel, yLabel, Scale::Log, Scale::Log, width, height);
}

void writePlot(const std::filesystem::path& path, const std::vector<Panel>& panels, const std::string& xLabel,
               const std::string& yLabel, Scale xScale, Scale yScale, int width, int height) {
  if (panels.empty()) throw std::runtime_error("plot " + path.string() + ": nothing to plot");
  Canvas canvas(width, height);
  std::vector<Label> labels;
  std::map<std::string, std::array<float, 3>> colors;
  for (const Panel& p : panels)
    for (const Series& s : p.series)
      if (!colors.count(s.name)) colors[s.name] = kPalette[colors.size() % kPalette.size()];
  const int cols = int(std::ceil(std::sqrt(double(panels.size()))));
  const int rows = int((panels.size() + cols - 1) / cols);
  // Legend layout first, wrapped to the width: its rows take height from the panels.
  std::vector<std::pair<int, int>> legendAt;  // per series name, in `colors` order: x and row
  for (int lx = 20, row = 0; const auto& [name, c] : colors) {
    const int entryWidth = 30 + 10 * int(name.size());
    if (lx > 20 && lx + entryWidth > width) ++row, lx = 20;
    legendAt.push_back({lx, row});
    lx += entryWidth;
  }
  const int legendRows = legendAt.empty() ? 1 : legendAt.back().second + 1;
  const int legendHeight = legendRows * kLegendRowHeight + kLegendFooterHeight;
  const int pw = width / cols, ph = (height - legendHeight) / rows;
  const std::array<float, 3> black{0, 0, 0}, grid{0.85f, 0.85f, 0.85f};
  for (std::size_t k = 0; k < panels.size(); ++k) {
    const Panel& panel = panels[k];
    const int ox = int(k % cols) * pw, oy = int(k / cols) * ph;
    const int x0 = ox + kMarginLeft, x1 = ox + pw - kMarginRight, y0 = oy + kMarginTop,
              y1 = oy + ph - kMarginBottom;
    Axis ax{xScale}, ay{yScale};
    const auto plottable = [&](double x, double y) { return ax.plottable(x) && ay.plottable(y); };
    for (const Series& s : panel.series)
      for (auto [x, y] : s.points)
        if (plottable(x, y)) ax.add(x), ay.add(y);
    if (ax.empty()) continue;
    ax.widen(), ay.widen();
    const auto px = [&](double x) { return x0 + int(std::lround(ax.unit(x) * (x1 - x0))); };
    const auto py = [&](double y) { return y1 - int(std::lround(ay.unit(y) * (y1 - y0))); };
    for (const double t : ax.ticks()) {
      const int x = px(t);
      canvas.line(x, y0, x, y1, grid);
      labels.push_back({x - 12, y1 + 20, ax.label(t)});
    }
    for (const double t : ay.ticks()) {
      const int y = py(t);
      canvas.line(x0, y, x1, y, grid);
      labels.push_back({ox + 8, y + 5, ay.label(t)});
    }
    canvas.line(x0, y1, x1, y1, black);
    canvas.line(x0, y0, x0, y1, black);
    labels.push_back({x0, oy + 25, panel.title});
    labels.push_back({(x0 + x1) / 2 - 40, y1 + 40, xLabel});
    for (const Series& s : panel.series) {
      const auto& c = colors[s.name];
      bool first = true;
      int lastX = 0, lastY = 0;
      for (auto [x, y] : s.points) {
        if (!plottable(x, y)) continue;
        const int cx = px(x), cy = py(y);
        if (!first) canvas.line(lastX, lastY, cx, cy, c, 2);
        canvas.square(cx, cy, 3, c);
        first = false, lastX = cx, lastY = cy;
      }
    }
  }
  // Legend: one colored square per series name.
  auto at = legendAt.begin();
  for (const auto& [name, c] : colors) {
    const auto [lx, row] = *at++;
    const int ly = height - legendHeight + kLegendRowHeight + 5 + row * kLegendRowHeight;
    canvas.square(lx, ly, 6, c);
    labels.push_back({lx + 12, ly + 6, name});
  }
  labels.push_back({20, height - 5, "y: " + yLabel});

  OIIO::ImageSpec spec(width, height, 3, OIIO::TypeDesc::FLOAT);
  OIIO::ImageBuf buf(spec, canvas.rgb.data());
  OIIO::ImageBuf out;
  out.copy(buf);
  const float textColor[3] = {0, 0, 0};
  for (const Label& l : labels)  // without a usable font the plot is still written, unlabeled
    OIIO::ImageBufAlgo::render_text(out, l.x, l.y, l.text, kFontSize, "DejaVuSans", textColor);
  out.set_write_format(OIIO::TypeDesc::UINT8);
  const std::filesystem::path tmp = path.string() + ".tmp.png";
  if (!out.write(tmp.string(), OIIO::TypeDesc::UINT8, "png"))
    throw std::runtime_error("plot " + path.string() + ": " + out.geterror());
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw std::runtime_error("plot " + path.string() + ": " + ec.message());
}

}  // namespace svo::tools::plot
