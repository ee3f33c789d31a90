// What the renderers of every pool layout share (render.cpp for blocks, level_render.cpp for level arrays):
// frame set-up and clearing, the normal a voxel without one shows, and batched Phong shading, so that the
// same hits shade to the same pixels bit for bit.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <glm/geometric.hpp>
#if defined(__SSE__)
#include <immintrin.h>
#endif

#include "svo/client/render.hpp"

namespace svo::frame_shading {

inline bool finite(glm::vec3 v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

// Outward normal of the hit voxel's surface nearest to the hit position: one of the six cube faces, or the
// voxel's contour slab (`contour`, its bits, where it has one) when the position lies closer to it (sec. 5.2:
// the slab is what the ray entered). `size`: the voxel's edge (CastHit::voxelSize).
inline glm::vec3 estimateNormal(glm::vec3 position, glm::vec3 cubeMin, float size,
                                std::optional<std::uint32_t> contour) {
  const glm::vec3 rel = (position - cubeMin) / size;  // [0, 1]^3 inside the voxel
  int axis = 0;
  float faceDistance = std::numeric_limits<float>::infinity();
  float sign = 1.0f;
  for (int i = 0; i < 3; ++i) {
    const float low = rel[i], high = 1.0f - rel[i];
    if (low < faceDistance) faceDistance = low, axis = i, sign = -1.0f;
    if (high < faceDistance) faceDistance = high, axis = i, sign = 1.0f;
  }
  glm::vec3 normal(0.0f);
  normal[axis] = sign;
  if (contour) {
    const Contour c = decodeContour(*contour);
    const float length = glm::length(c.normal);
    if (length > 0.0f) {
      const float offset = glm::dot(c.normal, rel - 0.5f) - c.position;  // voxel units along c.normal
      const float slabDistance = std::abs(std::abs(offset) - 0.5f * c.thickness) / length;
      if (slabDistance < faceDistance) normal = c.normal / length * (offset < 0.0f ? -1.0f : 1.0f);
    }
  }
  return normal;
}

// Runs `work` in an arena of `threads` threads, or in the caller's arena (all cores by default) for 0.
template <class Work>
void inArena(int threads, const Work& work) {
  if (threads > 0) {
    tbb::task_arena arena(threads);
    arena.execute(work);
  } else {
    work();
  }
}

// Frame clears in pieces of at least this many pixels, one task each: a 1024 x 1024 frame in up to 16 (1 MiB
// of colors each), few enough that scheduling them costs nothing beside the writes.
constexpr std::size_t kClearGrainPixels = std::size_t(1) << 16;

// Writes `pattern` (four floats, repeated) over out[0, count), by non-temporal stores where the CPU has them:
// a frame is larger than the caches and the casting evicts it before most of its pixels are written again,
// so a clear through the caches would read every line first and write it back later.
inline void streamFill(float* out, std::size_t count, const std::array<float, 4>& pattern) {
  std::size_t i = 0;
#if defined(__SSE__)
  while (i < count && reinterpret_cast<std::uintptr_t>(out + i) % 16 != 0) out[i] = pattern[i % 4], ++i;
  const __m128 value =
      _mm_setr_ps(pattern[i % 4], pattern[(i + 1) % 4], pattern[(i + 2) % 4], pattern[(i + 3) % 4]);
  for (; i + 4 <= count; i += 4) _mm_stream_ps(out + i, value);
  _mm_sfence();  // the stores are seen when the task ends, as ordinary ones are
#endif
  for (; i < count; ++i) out[i] = pattern[i % 4];
}

// Every pixel of the frame a miss, on the calling arena's threads.
static_assert(sizeof(glm::vec4) == 4 * sizeof(float), "a color is four floats side by side");
inline void clearFrame(Frame& frame, glm::vec4 missColor) {
  const float inf = std::numeric_limits<float>::infinity();
  const auto clear = [&](const tbb::blocked_range<std::size_t>& pixels) {
    const std::size_t first = pixels.begin(), count = pixels.size();
    streamFill(&frame.color[first].x, 4 * count, {missColor.r, missColor.g, missColor.b, missColor.a});
    streamFill(&frame.depth[first], count, {inf, inf, inf, inf});
    streamFill(&frame.voxelPixels[first], count, {0.0f, 0.0f, 0.0f, 0.0f});
  };
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, frame.depth.size(), kClearGrainPixels), clear);
}

struct Shading {
  glm::vec3 lightDirection;  // unit, towards the scene
  bool hasColor, hasNormal, contours;
};

// A tile's hits, shaded a batch at a time: side by side, the attributes' decoding, the Phong model and the
// per-pixel values run over several hits in each SIMD instruction, with the same floats as one by one.
class ShadingBatch {
 public:
  static constexpr int kSize = kPacketLanes;
  // rawColors / rawNormals: the hits' colors / normals come as raw layout values, decoded here.
  ShadingBatch(Frame& frame, const Shading& shading, double sceneSize, double pixelAngle, bool rawColors,
               bool rawNormals)
      : frame_(frame),
        light_(shading.lightDirection),
        sceneSize_(sceneSize),
        pixelAngle_(pixelAngle),
        rawColors_(rawColors),
        rawNormals_(rawNormals) {}
  // The next hit; its color and normal are set before the next add.
  int add(std::size_t pixel, glm::vec3 direction, float t, float voxelSize) {
    if (count_ == kSize) flush();
    const int k = count_++;
    pixel_[k] = pixel;
    // The frame's lines left the caches since the frame was cleared: request them while the batch fills.
    __builtin_prefetch(&frame_.color[pixel], 1);
    __builtin_prefetch(&frame_.depth[pixel], 1);
    __builtin_prefetch(&frame_.voxelPixels[pixel], 1);
    dx_[k] = direction.x, dy_[k] = direction.y, dz_[k] = direction.z;
    t_[k] = t, voxelSize_[k] = voxelSize;
    return k;
  }
  void setColor(int k, glm::vec3 albedo) { ar_[k] = albedo.r, ag_[k] = albedo.g, ab_[k] = albedo.b; }
  void setNormal(int k, glm::vec3 normal) { nx_[k] = normal.x, ny_[k] = normal.y, nz_[k] = normal.z; }
  void setColor(int k, std::uint32_t raw) { colorWord_[k] = raw; }
  void setNormal(int k, std::uint32_t raw) { normalWord_[k] = raw; }

  void flush() {
    if (count_ == 0) return;
    if (rawColors_)
      for (int k = 0; k < kSize; ++k) setColor(k, glm::vec3(decodeColor(colorWord_[k])));
    if (rawNormals_)
      for (int k = 0; k < kSize; ++k) setNormal(k, decodeNormal(normalWord_[k]));
    glm::vec3 color[kSize];
    float voxelPixels[kSize];
    for (int k = 0; k < kSize; ++k) {
      // The octree direction is the unit world direction / size: renormalized, the world one.
      const glm::vec3 view = glm::normalize(glm::vec3(dx_[k], dy_[k], dz_[k]));
      color[k] =
          shadePhong(glm::vec3(ar_[k], ag_[k], ab_[k]), glm::vec3(nx_[k], ny_[k], nz_[k]), view, light_);
      voxelPixels[k] = float(double(voxelSize_[k]) * sceneSize_ / (double(t_[k]) * pixelAngle_));
    }
    for (int k = 0; k < count_; ++k) {
      frame_.color[pixel_[k]] = glm::vec4(color[k], 1.0f);
      frame_.depth[pixel_[k]] = t_[k];
      frame_.voxelPixels[pixel_[k]] = voxelPixels[k];
    }
    count_ = 0;
  }

 private:
  Frame& frame_;
  glm::vec3 light_;
  double sceneSize_, pixelAngle_;
  bool rawColors_, rawNormals_;
  int count_ = 0;
  // A slot past count_ holds an earlier hit's values (or zeros): the loops run over all kSize slots, which
  // the compiler vectorizes without a remainder, and only the first count_ are written out.
  std::size_t pixel_[kSize]{};
  float dx_[kSize]{}, dy_[kSize]{}, dz_[kSize]{}, t_[kSize]{}, voxelSize_[kSize]{};
  float ar_[kSize]{}, ag_[kSize]{}, ab_[kSize]{}, nx_[kSize]{}, ny_[kSize]{}, nz_[kSize]{};
  std::uint32_t colorWord_[kSize]{}, normalWord_[kSize]{};
};

// Checks the options and camera, and sizes the frame for the camera (Frame::iterations and lodStopped where
// options.diagnostics). Throws std::runtime_error naming what is wrong.
void prepareFrame(const Camera& camera, const RenderOptions& options, Frame& frame);

}  // namespace svo::frame_shading
