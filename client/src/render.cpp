// Frame rendering: world rays mapped into the octree, ESVO castRay per pixel over 8x8 tiles with oneTBB,
// Phong shading with one directional light, and PNG / EXR output through OpenImageIO.
#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cassert>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include <OpenImageIO/imageio.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <glm/geometric.hpp>
#if defined(__SSE__)
#include <immintrin.h>
#endif

#include "frame_shading.hpp"
#include "svo/client/post_filter.hpp"
#include "svo/client/render.hpp"

namespace svo {
namespace {

using namespace frame_shading;

// Pixels per tile edge when the beam pass is off (sec. 6.2's 8x8; one task traces whole tiles).
constexpr int kTileSize = 8;
// Largest beam tile: past this the beam is wider than the detail it could skip to.
constexpr int kMaxBeamTile = 64;

// Shades a tile's hits: raw attributes through one look-up per parent for both, units per attribute, and
// the voxel's own surface where the scene has no normals.
class TileShading {
 public:
  TileShading(const BlockView& block, Frame& frame, const Shading& shading, double sceneSize,
              double pixelAngle)
      : shading_(shading),
        raw_(block.attributeLayout() == AttributeLayout::Raw),
        rawAttributes_(block),
        colorUnits_(block, AttachmentType::Color),
        normalUnits_(block, AttachmentType::Normal),
        batch_(frame, shading, sceneSize, pixelAngle, raw_ && shading.hasColor, raw_ && shading.hasNormal) {}
  void add(std::size_t pixel, const OctreeRay& ray, const CastHit& hit) {
    const int k = batch_.add(pixel, ray.direction, hit.t, hit.voxelSize());
    if (!shading_.hasColor) {
      batch_.setColor(k, glm::vec3(kNeutralGreyAlbedo));
    } else if (raw_) {
      batch_.setColor(k, rawAttributes_.color(hit));
    } else {
      batch_.setColor(k, colorUnits_.color(hit));
    }
    if (!shading_.hasNormal) {
      batch_.setNormal(
          k, estimateNormal(hit.position, hit.cubeMin, hit.voxelSize(),
                            shading_.contours && hit.parent ? BlockView::contour(hit.parent, hit.childSlot)
                                                            : std::nullopt));
    } else if (raw_) {
      batch_.setNormal(k, rawAttributes_.normal(hit));
    } else {
      batch_.setNormal(k, normalUnits_.normal(hit));
    }
  }
  void flush() { batch_.flush(); }

 private:
  const Shading& shading_;
  bool raw_;
  RawAttributePair rawAttributes_;
  SiblingAttribute colorUnits_, normalUnits_;
  ShadingBatch batch_;
};

}  // namespace

std::optional<int> hitLevel(const Frame& frame, std::size_t pixel, double pixelAngle, double sceneSize) {
  const double depth = frame.depth[pixel];
  if (!std::isfinite(depth)) return std::nullopt;
  const double voxelSize = frame.voxelPixels[pixel] * depth * pixelAngle / sceneSize;  // octree units
  return int(std::lround(-std::log2(voxelSize)));
}

PixelRays::PixelRays(const SceneTransform& scene, const Camera& camera, float lodPixels)
    : scene_(scene), camera_(camera), basis_(camera.basis()), origin_(scene.toOctree(camera.eye)) {
  // A pinhole's footprint grows from zero at the eye; lodPixels 0 disables the level-of-detail stop.
  if (lodPixels > 0.0f) footprintSlope_ = float(camera.pixelAngle() * double(lodPixels) / scene.size);
}

void PixelRays::packet(const double* across, const double* down, int count, float tMin,
                       OctreeRay* out) const {
  assert(count <= kPacketLanes);
  // Every lane is computed (a lane past count repeats the first ray), so the loop has no remainder.
  double a[kPacketLanes], d[kPacketLanes];
  for (int k = 0; k < kPacketLanes; ++k) a[k] = across[k < count ? k : 0], d[k] = down[k < count ? k : 0];
  float x[kPacketLanes], y[kPacketLanes], z[kPacketLanes];
  for (int k = 0; k < kPacketLanes; ++k) {
    const glm::vec3 direction = directionAt(a[k], d[k]);
    x[k] = direction.x, y[k] = direction.y, z[k] = direction.z;
  }
  for (int k = 0; k < count; ++k) {
    OctreeRay& ray = out[k];
    ray = OctreeRay{};
    ray.origin = origin_;
    ray.direction = glm::vec3(x[k], y[k], z[k]);
    ray.footprintSlope = footprintSlope_;
    ray.tMin = tMin;
  }
}

glm::dvec3 PixelRays::direction(double px, double py) const {
  glm::dvec3 direction;
  Camera::pixelRay(camera_, basis_, px, py, direction);
  return direction;
}

OctreeRay octreeRay(const SceneTransform& scene, const Camera& camera, double px, double py,
                    float lodPixels) {
  return PixelRays(scene, camera, lodPixels)(px, py);
}

int renderTileSize(const RenderOptions& options) {
  // Without the beam, tiles of the paper's 8x8 still keep a task's rays coherent.
  return options.beamTile > 0 ? options.beamTile : kTileSize;
}

void forEachTile(int width, int height, int tileSize, int threads,
                 const std::function<void(const PixelTile&)>& trace) {
  const int tilesX = (width + tileSize - 1) / tileSize, tilesY = (height + tileSize - 1) / tileSize;
  const auto traceTiles = [&](const tbb::blocked_range<int>& tiles) {
    for (int t = tiles.begin(); t != tiles.end(); ++t) {
      const int x0 = (t % tilesX) * tileSize, y0 = (t / tilesX) * tileSize;
      trace(PixelTile{x0, y0, std::min(x0 + tileSize, width), std::min(y0 + tileSize, height)});
    }
  };
  inArena(threads, [&] { tbb::parallel_for(tbb::blocked_range<int>(0, tilesX * tilesY), traceTiles); });
}

Frame render(const Octree& octree, const Camera& camera, const RenderOptions& options) {
  return render(octree.block.view(), octree.transform, camera, options);
}

Frame render(const BlockView& block, const SceneTransform& scene, const Camera& camera,
             const RenderOptions& options) {
  Frame frame;
  render(block, scene, camera, options, frame);
  return frame;
}

void render(const BlockView& block, const SceneTransform& scene, const Camera& camera,
            const RenderOptions& options, Frame& frame) {
  prepareFrame(camera, options, frame);
  const Shading shading{glm::normalize(options.lightDirection), block.hasColors(), block.hasNormals(),
                        options.cast.contours};
  const double pixelAngle = camera.pixelAngle();
  const PixelRays rays(scene, camera, options.lodPixels);

  const std::size_t pixels = frame.depth.size();
  const auto keepIterations = [&](int x, int y, const CastHit& hit) {
    if (frame.iterations.empty()) return;
    const std::size_t i = std::size_t(y) * std::size_t(camera.width) + std::size_t(x);
    frame.iterations[i] = std::uint16_t(std::min(hit.iterations, int(UINT16_MAX)));
  };

  std::atomic<std::uint64_t> iterations{0};
  const auto start = std::chrono::steady_clock::now();
  const auto clearAndTrace = [&] {
    clearFrame(frame, glm::vec4(options.background, 0.0f));
    forEachTile(camera.width, camera.height, renderTileSize(options), 0, [&](const PixelTile& tile) {
      TileShading shade(block, frame, shading, scene.size, pixelAngle);
      const auto onHit = [&](int x, int y, const OctreeRay& ray, const CastHit& hit) {
        const std::size_t i = std::size_t(y) * std::size_t(camera.width) + std::size_t(x);
        shade.add(i, ray, hit);
        keepIterations(x, y, hit);
        if (!frame.lodStopped.empty()) frame.lodStopped[i] = std::uint8_t(!hit.leaf);
      };
      const bool beam = options.beamTile > 0;
      std::uint64_t tileIterations;
      if (options.prefetchAttributes) {
        AttributePrefetcher prefetcher(block);
        tileIterations = castTile<AttributePrefetcher::kLag>(
            block, rays, tile, beam, options.cast, onHit, keepIterations,
            [&](const CastHit* hits, int count) { prefetcher.packet(hits, count); });
      } else {
        tileIterations = castTile(block, rays, tile, beam, options.cast, onHit, keepIterations);
      }
      shade.flush();
      iterations.fetch_add(tileIterations, std::memory_order_relaxed);
    });
  };
  inArena(options.threads, clearAndTrace);
  if (options.filter) applyFilter(frame, options);
  frame.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  frame.meanIterations = double(iterations.load()) / double(pixels);
}

namespace frame_shading {

void prepareFrame(const Camera& camera, const RenderOptions& options, Frame& frame) {
  camera.validate();
  if (!std::isfinite(options.lodPixels) || options.lodPixels < 0.0f)
    throw std::runtime_error("render: lodPixels must be a finite number >= 0 (got " +
                             std::to_string(options.lodPixels) + ")");
  if (options.threads < 0)
    throw std::runtime_error("render: threads must be >= 0 (got " + std::to_string(options.threads) + ")");
  if (options.beamTile < 0 || options.beamTile > kMaxBeamTile)
    throw std::runtime_error("render: beamTile must be in [0, " + std::to_string(kMaxBeamTile) + "] (got " +
                             std::to_string(options.beamTile) + ")");
  if (!finite(options.lightDirection) || !(glm::length(options.lightDirection) > 0.0f))
    throw std::runtime_error("render: the light direction must be finite and non-zero");
  if (!options.cast.recordPath)
    throw std::runtime_error("render: shading looks attributes up through the hits' paths (cast.recordPath)");

  frame.width = camera.width;
  frame.height = camera.height;
  const std::size_t pixels = std::size_t(camera.width) * std::size_t(camera.height);
  frame.color.resize(pixels);
  frame.depth.resize(pixels);
  frame.voxelPixels.resize(pixels);
  frame.iterations.assign(options.diagnostics ? pixels : 0, 0);
  frame.lodStopped.assign(options.diagnostics ? pixels : 0, 0);
  frame.filterSeconds = frame.deviceSeconds = 0.0;
}

}  // namespace frame_shading

void applyFilter(Frame& frame, const RenderOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  postFilter(frame, PostFilterOptions{.radiusPerVoxel = options.filterRadius, .threads = options.threads});
  frame.filterSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// ---------------------------------------------------------------------------------------------------------
namespace {

std::uint8_t toSrgb8(float linear) {
  const float c = std::isnan(linear) ? 0.0f : std::clamp(linear, 0.0f, 1.0f);
  const float s = c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
  return std::uint8_t(std::lround(std::clamp(s, 0.0f, 1.0f) * 255.0f));
}

// toSrgb8 without a pow per channel: the least linear value of each code 1..255, found once by bisection
// over toSrgb8 itself (monotone in its argument), so the codes equal toSrgb8's for every float.
class SrgbThresholds {
 public:
  SrgbThresholds() {
    // Non-negative floats are ordered as their bit patterns: bisect over those.
    const auto code = [](std::uint32_t bits) { return toSrgb8(std::bit_cast<float>(bits)); };
    for (int c = 1; c < 256; ++c) {
      std::uint32_t low = 0, high = std::bit_cast<std::uint32_t>(1.0f);  // code(low) < c <= code(high)
      while (high - low > 1) {
        const std::uint32_t mid = low + (high - low) / 2;
        (code(mid) < c ? low : high) = mid;
      }
      least_[std::size_t(c - 1)] = std::bit_cast<float>(high);
    }
  }
  std::uint8_t operator()(float linear) const {
    if (!(linear > 0.0f)) return 0;  // NaN, zero and negatives, as toSrgb8
    return std::uint8_t(std::upper_bound(least_.begin(), least_.end(), linear) - least_.begin());
  }

 private:
  std::array<float, 255> least_;
};

const SrgbThresholds& srgbThresholds() {
  static const SrgbThresholds thresholds;
  return thresholds;
}

std::uint8_t toUnorm8(float value) {
  const float c = std::isnan(value) ? 0.0f : std::clamp(value, 0.0f, 1.0f);
  return std::uint8_t(std::lround(c * 255.0f));
}

std::string lowercase(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return s;
}

struct Fail {
  std::string reason;
};

// Writes `pixels` (interleaved, spec.nchannels per pixel, of type `type`) through OIIO's plugin `format`.
void writeOiio(const std::filesystem::path& file, const char* format, const OIIO::ImageSpec& spec,
               OIIO::TypeDesc type, const void* pixels) {
  // The temporary name's extension is ".tmp", so the plugin is chosen by format name, not by file name.
  auto out = OIIO::ImageOutput::create(format);
  if (!out) throw Fail{"no OpenImageIO writer for " + std::string(format) + ": " + OIIO::geterror()};
  if (!out->open(file.string(), spec)) throw Fail{out->geterror()};
  if (!out->write_image(type, pixels)) {
    const std::string error = out->geterror();
    out->close();
    throw Fail{error};
  }
  if (!out->close()) throw Fail{out->geterror()};
}

}  // namespace

void encodeSrgb8(const Frame& frame, std::vector<std::uint8_t>& rgba) {
  const std::size_t pixels = frame.color.size();
  rgba.resize(pixels * 4);
  const SrgbThresholds& srgb = srgbThresholds();
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pixels),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t i = r.begin(); i != r.end(); ++i) {
                        const glm::vec4& c = frame.color[i];
                        std::uint8_t* p = &rgba[i * 4];
                        p[0] = srgb(c.r), p[1] = srgb(c.g), p[2] = srgb(c.b), p[3] = 255;
                      }
                    });
}

void writeFrame(const std::filesystem::path& path, const Frame& frame, bool withAux) {
  const auto fail = [&](const std::string& reason) {
    return std::runtime_error(path.string() + ": cannot write image (" + reason + ")");
  };
  const std::string extension = lowercase(path.extension().string());
  if (extension != ".png" && extension != ".exr")
    throw fail("unknown extension '" + path.extension().string() + "'; use .png or .exr");
  if (frame.width < 1 || frame.height < 1) throw fail("the frame is empty");
  const std::size_t pixels = std::size_t(frame.width) * std::size_t(frame.height);
  if (frame.color.size() != pixels) throw fail("the frame's color buffer does not match its size");
  if (withAux && (frame.depth.size() != pixels || frame.voxelPixels.size() != pixels))
    throw fail("the frame's depth / voxelPixels buffers do not match its size");

  std::filesystem::path temporary = path;
  temporary += ".tmp";
  try {
    if (extension == ".png") {
      // PNG is for looking at: 8-bit sRGB. The alpha (hit mask) is kept only when auxiliary data is asked
      // for.
      const int channels = withAux ? 4 : 3;
      std::vector<std::uint8_t> bytes(pixels * std::size_t(channels));
      const SrgbThresholds& srgb = srgbThresholds();
      for (std::size_t i = 0; i < pixels; ++i) {
        const glm::vec4& c = frame.color[i];
        std::uint8_t* p = &bytes[i * std::size_t(channels)];
        p[0] = srgb(c.r), p[1] = srgb(c.g), p[2] = srgb(c.b);
        if (channels == 4) p[3] = toUnorm8(c.a);
      }
      OIIO::ImageSpec spec(frame.width, frame.height, channels, OIIO::TypeDesc::UINT8);
      spec.attribute("oiio:ColorSpace", "sRGB");
      // Colors are not premultiplied (a miss keeps the background at alpha 0): store them as they are.
      spec.attribute("oiio:UnassociatedAlpha", 1);
      writeOiio(temporary, "png", spec, OIIO::TypeDesc::UINT8, bytes.data());
    } else {
      // EXR keeps the linear floats: color as half (plenty for display), depth and voxel size as full float.
      const int channels = withAux ? 6 : 4;
      std::vector<float> values(pixels * std::size_t(channels));
      for (std::size_t i = 0; i < pixels; ++i) {
        float* p = &values[i * std::size_t(channels)];
        const glm::vec4& c = frame.color[i];
        p[0] = c.r, p[1] = c.g, p[2] = c.b, p[3] = c.a;
        if (withAux) p[4] = frame.depth[i], p[5] = frame.voxelPixels[i];
      }
      OIIO::ImageSpec spec(frame.width, frame.height, channels, OIIO::TypeDesc::HALF);
      spec.alpha_channel = 3;
      if (withAux) {
        spec.channelnames = {"R", "G", "B", "A", "Z", "voxelPixels"};
        spec.channelformats = {OIIO::TypeDesc::HALF, OIIO::TypeDesc::HALF,  OIIO::TypeDesc::HALF,
                               OIIO::TypeDesc::HALF, OIIO::TypeDesc::FLOAT, OIIO::TypeDesc::FLOAT};
        spec.z_channel = 4;
      }
      spec.attribute("oiio:ColorSpace", "Linear");
      writeOiio(temporary, "openexr", spec, OIIO::TypeDesc::FLOAT, values.data());
    }
    std::error_code error;
    std::filesystem::rename(temporary, path, error);
    if (error) throw Fail{"rename from " + temporary.filename().string() + ": " + error.message()};
  } catch (const Fail& f) {
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    throw fail(f.reason);
  } catch (...) {
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    throw;
  }
}

}  // namespace svo
