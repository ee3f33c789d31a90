#include "svo/viewer/false_color.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <optional>

#include <glm/geometric.hpp>

namespace svo::viewer {
namespace {

// Distinct hues for consecutive levels (linear RGB), repeating every 8 levels.
constexpr std::array<glm::vec3, 8> kLevelColors{{{0.90f, 0.10f, 0.10f},
                                                 {0.95f, 0.50f, 0.05f},
                                                 {0.90f, 0.85f, 0.10f},
                                                 {0.20f, 0.80f, 0.15f},
                                                 {0.10f, 0.75f, 0.80f},
                                                 {0.15f, 0.30f, 0.95f},
                                                 {0.55f, 0.20f, 0.90f},
                                                 {0.90f, 0.25f, 0.70f}}};

glm::vec3 detailColor(PixelDetail d) {
  switch (d) {
    case PixelDetail::AtTarget:
      return {0.15f, 0.75f, 0.20f};
    case PixelDetail::FinestStored:
      return {0.20f, 0.35f, 0.95f};
    case PixelDetail::Loading:
      return {0.95f, 0.80f, 0.10f};
    case PixelDetail::Waiting:
      return {0.95f, 0.15f, 0.10f};
    case PixelDetail::NoRoom:
      return {0.85f, 0.15f, 0.85f};
    case PixelDetail::Miss:
      break;
  }
  return glm::vec3(0.0f);
}

// Blue through green to red and white as t goes from 0 to 1.
glm::vec3 heat(float t) {
  t = std::clamp(t, 0.0f, 1.0f);
  constexpr std::array<glm::vec3, 5> stops{{{0.02f, 0.02f, 0.25f},
                                            {0.05f, 0.35f, 0.90f},
                                            {0.10f, 0.85f, 0.20f},
                                            {0.95f, 0.30f, 0.05f},
                                            {1.0f, 1.0f, 1.0f}}};
  const float x = t * float(stops.size() - 1);
  const std::size_t i = std::min(std::size_t(x), stops.size() - 2);
  return glm::mix(stops[i], stops[i + 1], x - float(i));
}

// Shading brightness kept under a false color: dim parts stay dim, but never black.
constexpr float kKeptShading = 0.7f;
glm::vec3 tint(glm::vec3 color, const glm::vec4& shaded) {
  const float luminance = glm::dot(glm::vec3(shaded), glm::vec3(0.2126f, 0.7152f, 0.0722f));
  return color * ((1.0f - kKeptShading) + kKeptShading * std::min(1.0f, luminance * 1.5f));
}

}  // namespace

const char* nameOf(FalseColor mode) {
  switch (mode) {
    case FalseColor::Shaded:
      return "shaded";
    case FalseColor::OctreeLevel:
      return "octree level";
    case FalseColor::Iterations:
      return "iterations per pixel";
    case FalseColor::Detail:
      return "resident vs wanted";
  }
  return "?";
}

void paintLevels(Frame& frame, const Camera& camera, double sceneSize) {
  const double pixelAngle = camera.pixelAngle();
  for (std::size_t i = 0; i < frame.color.size(); ++i)
    if (const std::optional<int> level = hitLevel(frame, i, pixelAngle, sceneSize))
      frame.color[i] =
          glm::vec4(tint(kLevelColors[std::size_t(*level) % kLevelColors.size()], frame.color[i]), 1.0f);
}

void paintIterations(Frame& frame) {
  if (frame.iterations.size() != frame.color.size()) return;
  for (std::size_t i = 0; i < frame.color.size(); ++i)
    frame.color[i] =
        glm::vec4(heat(float(frame.iterations[i]) / float(kIterationsRampTop)), frame.color[i].a);
}

void paintDetail(Frame& frame, const std::vector<PixelDetail>& detail) {
  if (detail.size() != frame.color.size()) return;
  for (std::size_t i = 0; i < frame.color.size(); ++i)
    if (detail[i] != PixelDetail::Miss)
      frame.color[i] = glm::vec4(tint(detailColor(detail[i]), frame.color[i]), 1.0f);
}

int deepestLevel(const Frame& frame, const Camera& camera, double sceneSize) {
  // hitLevel falls as a voxel's size grows: the smallest voxel (in pixels times depth) is the deepest.
  std::optional<std::size_t> smallest;
  float smallestSize = std::numeric_limits<float>::infinity();
  for (std::size_t i = 0; i < frame.depth.size(); ++i) {
    const float size = frame.voxelPixels[i] * frame.depth[i];
    if (std::isfinite(frame.depth[i]) && size < smallestSize) smallestSize = size, smallest = i;
  }
  return smallest ? *hitLevel(frame, *smallest, camera.pixelAngle(), sceneSize) : -1;
}

std::vector<LegendEntry> legendOf(FalseColor mode, int deepest) {
  std::vector<LegendEntry> out;
  switch (mode) {
    case FalseColor::Shaded:
      break;
    case FalseColor::OctreeLevel:
      for (int level = std::max(0, deepest - int(kLevelColors.size()) + 1); level <= deepest; ++level)
        out.push_back(
            {"level " + std::to_string(level), kLevelColors[std::size_t(level) % kLevelColors.size()]});
      break;
    case FalseColor::Iterations:
      for (int n : {0, kIterationsRampTop / 4, kIterationsRampTop / 2, kIterationsRampTop * 3 / 4,
                    kIterationsRampTop})
        out.push_back({std::to_string(n) + (n == kIterationsRampTop ? "+ iterations" : " iterations"),
                       heat(float(n) / float(kIterationsRampTop))});
      break;
    case FalseColor::Detail:
      for (PixelDetail d : {PixelDetail::AtTarget, PixelDetail::FinestStored, PixelDetail::Loading,
                            PixelDetail::Waiting, PixelDetail::NoRoom}) {
        static constexpr const char* kLabels[] = {"",
                                                  "at the LOD target",
                                                  "finest the store has",
                                                  "finer slice loading",
                                                  "finer slice not asked for yet",
                                                  "finer slice: no room in the budget, or failed"};
        out.push_back({kLabels[int(d)], detailColor(d)});
      }
      break;
  }
  return out;
}

}  // namespace svo::viewer
