// Base-color textures: decoding with OpenImageIO to linear RGBA floats, a box-filtered mip pyramid, and the
// footprint average the voxelizer asks for (the texture integrated over a clipped triangle's UV polygon).
//
// Conventions: pixel rows run top to bottom as in image files; UVs follow assimp / OpenGL, v = 0 at the
// bottom row (assimp already flips glTF's top-left origin into this); addressing wraps.
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>
#include <utility>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <glm/common.hpp>
#include <glm/geometric.hpp>

#include "svo/builder/mesh.hpp"

namespace svo {

namespace detail {
std::shared_ptr<const TextureImage> decodeTexture(const std::string& name, const void* data,
                                                  std::size_t size);
std::shared_ptr<const TextureImage> textureFromSrgb8(int width, int height, const std::uint8_t* rgba);
}  // namespace detail

namespace {

// The footprint average works on the finest mip level where the UV polygon's bounding box touches at most
// this many texels: enough for the exact polygon coverage to follow the polygon's shape (also for a long thin
// one, which keeps its resolution across), few enough that one average costs a few dozen cell clips.
constexpr double kMaxCells = 32.0;
// A polygon whose UV area covers less than this fraction of a texel at the chosen level is treated as a
// point.
constexpr double kMinCoverage = 1e-9;

float srgbToLinear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}

struct Level {
  int width = 0, height = 0;
  std::vector<glm::vec4> texels;
  const glm::vec4& at(int x, int y) const { return texels[static_cast<std::size_t>(y) * width + x]; }
};

int wrap(long long i, int n) {
  const long long m = i % n;
  return static_cast<int>(m < 0 ? m + n : m);
}

// Polygon clipped to one side of an axis-aligned line (Sutherland-Hodgman step).
void clipAxis(const std::vector<glm::dvec2>& in, std::vector<glm::dvec2>& out, int axis, double bound,
              bool keepAbove) {
  out.clear();
  const std::size_t n = in.size();
  for (std::size_t i = 0; i < n; ++i) {
    const glm::dvec2& a = in[i];
    const glm::dvec2& b = in[(i + 1) % n];
    const bool aIn = keepAbove ? a[axis] >= bound : a[axis] <= bound;
    const bool bIn = keepAbove ? b[axis] >= bound : b[axis] <= bound;
    if (aIn) out.push_back(a);
    if (aIn != bIn) {
      const double t = (bound - a[axis]) / (b[axis] - a[axis]);
      out.push_back(a + (b - a) * t);
    }
  }
}

double polygonArea(const std::vector<glm::dvec2>& p) {
  double twice = 0.0;
  for (std::size_t i = 0, n = p.size(); i < n; ++i) {
    const glm::dvec2& a = p[i];
    const glm::dvec2& b = p[(i + 1) % n];
    twice += a.x * b.y - b.x * a.y;
  }
  return std::abs(0.5 * twice);
}

// For each of `coarse` texels spanning the same extent as `fine` ones: the fine texels it covers and the
// fraction of it each one fills (the weights of one coarse texel add up to 1).
std::vector<std::vector<std::pair<int, float>>> boxWeights(int fine, int coarse) {
  std::vector<std::vector<std::pair<int, float>>> weights(coarse);
  const double ratio = static_cast<double>(fine) / coarse;
  for (int c = 0; c < coarse; ++c) {
    const double lo = c * ratio, hi = (c + 1) * ratio;
    for (int f = static_cast<int>(std::floor(lo)); f < std::min(fine, static_cast<int>(std::ceil(hi))); ++f) {
      const double overlap = std::min<double>(hi, f + 1) - std::max<double>(lo, f);
      if (overlap > 0.0) weights[c].emplace_back(f, static_cast<float>(overlap / ratio));
    }
  }
  return weights;
}

class MipTexture final : public TextureImage {
 public:
  MipTexture(int width, int height, std::vector<glm::vec4> pixels) {
    levels_.push_back(Level{width, height, std::move(pixels)});
    // Box filter down to 1x1, halving each side (rounding up). Each coarse texel averages exactly the fine
    // area it covers, with fractional weights where an odd size makes texels straddle, so every level keeps
    // the image's layout and mean.
    while (levels_.back().width > 1 || levels_.back().height > 1) {
      const Level& fine = levels_.back();
      const int cw = (fine.width + 1) / 2, ch = (fine.height + 1) / 2;
      const auto wx = boxWeights(fine.width, cw), wy = boxWeights(fine.height, ch);
      std::vector<glm::vec4> rows(static_cast<std::size_t>(cw) * fine.height, glm::vec4(0.0f));
      for (int y = 0; y < fine.height; ++y) {
        for (int x = 0; x < cw; ++x) {
          glm::vec4& out = rows[static_cast<std::size_t>(y) * cw + x];
          for (const auto& [fx, w] : wx[x]) out += w * fine.at(fx, y);
        }
      }
      Level coarse{cw, ch, std::vector<glm::vec4>(static_cast<std::size_t>(cw) * ch, glm::vec4(0.0f))};
      for (int y = 0; y < ch; ++y) {
        for (const auto& [fy, w] : wy[y]) {
          for (int x = 0; x < cw; ++x) {
            coarse.texels[static_cast<std::size_t>(y) * cw + x] +=
                w * rows[static_cast<std::size_t>(fy) * cw + x];
          }
        }
      }
      levels_.push_back(std::move(coarse));
    }
  }

  int width() const override { return levels_.front().width; }
  int height() const override { return levels_.front().height; }

  glm::vec4 average(std::span<const glm::vec2> uvPolygon) const override {
    if (uvPolygon.empty()) return levels_.back().texels.front();
    glm::dvec2 lo(uvPolygon[0]), hi(uvPolygon[0]), centroid(0.0);
    for (const glm::vec2& uv : uvPolygon) {
      lo = glm::min(lo, glm::dvec2(uv));
      hi = glm::max(hi, glm::dvec2(uv));
      centroid += glm::dvec2(uv);
    }
    centroid /= static_cast<double>(uvPolygon.size());
    if (!std::isfinite(lo.x) || !std::isfinite(lo.y) || !std::isfinite(hi.x) || !std::isfinite(hi.y)) {
      return levels_.back().texels.front();
    }

    // Footprint in texels of a level; under one finest texel the answer is the texture at the centroid.
    const Level& finest = levels_.front();
    if (std::max((hi.x - lo.x) * finest.width, (hi.y - lo.y) * finest.height) < 1.0)
      return bilinear(finest, centroid);
    auto cells = [&](const Level& l) {
      return (std::floor(hi.x * l.width) - std::floor(lo.x * l.width) + 1.0) *
             (std::floor(hi.y * l.height) - std::floor(lo.y * l.height) + 1.0);
    };
    std::size_t li = 0;
    while (li + 1 < levels_.size() && cells(levels_[li]) > kMaxCells) ++li;
    const Level& level = levels_[li];
    // The coarsest level is the texture's mean; a polygon spanning many repeats gets that too.
    if ((level.width == 1 && level.height == 1) || cells(level) > kMaxCells)
      return levels_.back().texels.front();

    // Texel space of this level: x to the right, y down from the top row (v = 1).
    // Scratch buffers kept per thread: this runs once per voxel and triangle.
    thread_local std::vector<glm::dvec2> poly, column, cell, tmp;
    poly.resize(uvPolygon.size());
    for (std::size_t i = 0; i < uvPolygon.size(); ++i) {
      poly[i] = glm::dvec2(uvPolygon[i].x * level.width, (1.0 - uvPolygon[i].y) * level.height);
    }
    const double x0 = lo.x * level.width, x1 = hi.x * level.width;
    const double y0 = (1.0 - hi.y) * level.height, y1 = (1.0 - lo.y) * level.height;
    const long long cx0 = static_cast<long long>(std::floor(x0)), cx1 = static_cast<long long>(std::ceil(x1));
    const long long cy0 = static_cast<long long>(std::floor(y0)), cy1 = static_cast<long long>(std::ceil(y1));

    // Exact coverage: clip the polygon to each column, then each cell of the column, and weight by area.
    glm::dvec4 sum(0.0);
    double total = 0.0;
    for (long long cx = cx0; cx < std::max(cx1, cx0 + 1); ++cx) {
      clipAxis(poly, tmp, 0, static_cast<double>(cx), true);
      clipAxis(tmp, column, 0, static_cast<double>(cx + 1), false);
      if (column.size() < 3) continue;
      for (long long cy = cy0; cy < std::max(cy1, cy0 + 1); ++cy) {
        clipAxis(column, tmp, 1, static_cast<double>(cy), true);
        clipAxis(tmp, cell, 1, static_cast<double>(cy + 1), false);
        if (cell.size() < 3) continue;
        const double a = polygonArea(cell);
        if (a <= 0.0) continue;
        sum += a * glm::dvec4(level.at(wrap(cx, level.width), wrap(cy, level.height)));
        total += a;
      }
    }
    // A polygon that is a line in UV space (a texture stretched along one axis) has no area to weight by.
    if (total < kMinCoverage) return bilinear(level, centroid);
    return glm::vec4(sum / total);
  }

  glm::vec4 trilinear(glm::vec2 uv, glm::vec2 du, glm::vec2 dv) const override {
    const Level& finest = levels_.front();
    const glm::dvec2 texels(finest.width, finest.height);
    const double side = std::max(glm::length(glm::dvec2(du) * texels), glm::length(glm::dvec2(dv) * texels));
    const double lod = std::clamp(std::log2(side), 0.0, double(levels_.size() - 1));
    if (!std::isfinite(uv.x) || !std::isfinite(uv.y) || std::isnan(lod)) return levels_.back().texels.front();
    const std::size_t fine = std::size_t(lod), coarse = std::min(fine + 1, levels_.size() - 1);
    const float t = float(lod - double(fine));
    return (1.0f - t) * bilinear(levels_[fine], uv) + t * bilinear(levels_[coarse], uv);
  }

 private:
  static glm::vec4 bilinear(const Level& level, glm::dvec2 uv) {
    const double x = uv.x * level.width - 0.5, y = (1.0 - uv.y) * level.height - 0.5;
    const double fx = std::floor(x), fy = std::floor(y);
    const float tx = static_cast<float>(x - fx), ty = static_cast<float>(y - fy);
    const long long ix = static_cast<long long>(fx), iy = static_cast<long long>(fy);
    const int xa = wrap(ix, level.width), xb = wrap(ix + 1, level.width);
    const int ya = wrap(iy, level.height), yb = wrap(iy + 1, level.height);
    const glm::vec4 top = (1.0f - tx) * level.at(xa, ya) + tx * level.at(xb, ya);
    const glm::vec4 bottom = (1.0f - tx) * level.at(xa, yb) + tx * level.at(xb, yb);
    return (1.0f - ty) * top + ty * bottom;
  }

  std::vector<Level> levels_;
};

// Reads the whole first subimage as linear RGBA; `name` is for messages (and picks the format for a proxy).
std::shared_ptr<const TextureImage> readImage(const std::string& name, OIIO::Filesystem::IOProxy* proxy) {
  auto in = OIIO::ImageInput::open(name, nullptr, proxy);
  if (!in) {
    std::string err = OIIO::geterror();
    std::replace(err.begin(), err.end(), '\n', ' ');
    throw std::runtime_error(name + ": cannot read image (" + err + ")");
  }
  const OIIO::ImageSpec spec = in->spec();
  if (spec.width <= 0 || spec.height <= 0 || spec.depth > 1 || spec.nchannels <= 0 || spec.deep) {
    throw std::runtime_error(name + ": not a 2D image");
  }
  const int channels = std::min(spec.nchannels, 4);
  const std::size_t count = static_cast<std::size_t>(spec.width) * spec.height;
  std::vector<float> data(count * channels);
  if (!in->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, data.data())) {
    std::string err = in->geterror();
    std::replace(err.begin(), err.end(), '\n', ' ');
    throw std::runtime_error(name + ": cannot decode image (" + err + ")");
  }
  in->close();

  // Integer images are display-encoded (sRGB) unless they say they are linear; float images are linear.
  const std::string space = spec.get_string_attribute("oiio:ColorSpace");
  const bool isFloat = spec.format.basetype == OIIO::TypeDesc::FLOAT ||
                       spec.format.basetype == OIIO::TypeDesc::HALF ||
                       spec.format.basetype == OIIO::TypeDesc::DOUBLE;
  const bool linear =
      isFloat || OIIO::Strutil::iequals(space, "linear") || OIIO::Strutil::iequals(space, "scene_linear");
  auto decode = [&](float c) { return linear ? c : srgbToLinear(std::clamp(c, 0.0f, 1.0f)); };

  std::vector<glm::vec4> pixels(count);
  for (std::size_t i = 0; i < count; ++i) {
    const float* p = &data[i * channels];
    glm::vec4& out = pixels[i];
    if (channels <= 2) {  // gray, or gray + alpha
      const float g = decode(p[0]);
      out = glm::vec4(g, g, g, channels == 2 ? p[1] : 1.0f);
    } else {
      out = glm::vec4(decode(p[0]), decode(p[1]), decode(p[2]), channels == 4 ? p[3] : 1.0f);
    }
  }
  return std::make_shared<MipTexture>(spec.width, spec.height, std::move(pixels));
}

}  // namespace

std::shared_ptr<const TextureImage> loadTexture(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw std::runtime_error(path.string() + ": no such file");
  return readImage(path.string(), nullptr);
}

std::shared_ptr<const TextureImage> makeTexture(int width, int height, std::vector<glm::vec4> pixels) {
  if (width <= 0 || height <= 0 || pixels.size() != static_cast<std::size_t>(width) * height) {
    throw std::runtime_error("makeTexture: " + std::to_string(pixels.size()) + " pixels for a " +
                             std::to_string(width) + "x" + std::to_string(height) + " texture");
  }
  return std::make_shared<MipTexture>(width, height, std::move(pixels));
}

namespace detail {

// Decodes an image held in memory (a texture embedded in a mesh file). `name` carries the format as its
// extension. Formats whose OpenImageIO reader cannot read from memory go through a temporary file.
std::shared_ptr<const TextureImage> decodeTexture(const std::string& name, const void* data,
                                                  std::size_t size) {
  {
    OIIO::Filesystem::IOMemReader proxy(data, size);
    auto probe = OIIO::ImageInput::create(name, false, nullptr, &proxy);
    if (probe && probe->supports("ioproxy")) {
      probe.reset();
      return readImage(name, &proxy);
    }
  }
  std::error_code ec;
  const std::filesystem::path tmpDir = std::filesystem::temp_directory_path(ec);
  if (ec) throw std::runtime_error(name + ": no temporary folder to decode it in");
  static std::atomic<unsigned> counter{0};
  const std::filesystem::path tmp =
      tmpDir / ("svo-texture-" + std::to_string(::getpid()) + "-" + std::to_string(counter++) + "-" +
                std::filesystem::path(name).filename().string());
  {
    std::FILE* f = std::fopen(tmp.c_str(), "wb");
    if (!f) throw std::runtime_error(name + ": cannot write temporary file " + tmp.string());
    const bool ok = std::fwrite(data, 1, size, f) == size;
    std::fclose(f);
    if (!ok) {
      std::filesystem::remove(tmp, ec);
      throw std::runtime_error(name + ": cannot write temporary file " + tmp.string());
    }
  }
  try {
    auto texture = readImage(tmp.string(), nullptr);
    std::filesystem::remove(tmp, ec);
    return texture;
  } catch (...) {
    std::filesystem::remove(tmp, ec);
    throw;
  }
}

// Uncompressed 8-bit RGBA as sRGB (assimp's embedded aiTexel arrays, reordered by the caller).
std::shared_ptr<const TextureImage> textureFromSrgb8(int width, int height, const std::uint8_t* rgba) {
  std::vector<glm::vec4> pixels(static_cast<std::size_t>(width) * height);
  for (std::size_t i = 0; i < pixels.size(); ++i) {
    const std::uint8_t* p = rgba + 4 * i;
    pixels[i] = glm::vec4(srgbToLinear(p[0] / 255.0f), srgbToLinear(p[1] / 255.0f),
                          srgbToLinear(p[2] / 255.0f), p[3] / 255.0f);
  }
  return makeTexture(width, height, std::move(pixels));
}

}  // namespace detail

}  // namespace svo
