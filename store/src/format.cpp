#include "svo/store/format.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include <glm/geometric.hpp>
#include <glm/vec2.hpp>

namespace svo {

glm::ivec3 quantizeContourNormal(glm::dvec3 n) {
  const double largest = std::max({std::abs(n.x), std::abs(n.y), std::abs(n.z)});
  if (!(largest > 0.0)) return {0, 0, int(kContourNormalScale)};
  const glm::dvec3 q = glm::round(n * (double(kContourNormalScale) / largest));
  return glm::ivec3(q);
}

bool encodeContour(glm::ivec3 qn, double lo, double hi, std::uint32_t& bits) {
  const double maxPosition = 63.0, maxThickness = 127.0;
  const double centre =
      std::clamp(std::round(0.5 * (lo + hi) / kContourPositionStep), -maxPosition, maxPosition);
  const double position = centre * kContourPositionStep;
  const double halfWidth = std::max(position - lo, hi - position);
  // Round the width up so the stored slab always contains [lo, hi]; a hair more for float decoding.
  const double thickness = std::ceil(2.0 * halfWidth / kContourThicknessStep + 1e-6);
  if (thickness > maxThickness) return false;
  const double cubeWidth = (std::abs(qn.x) + std::abs(qn.y) + std::abs(qn.z)) / double(kContourNormalScale);
  if (thickness * kContourThicknessStep >= cubeWidth) return false;
  bits = packContourBits(qn.x, qn.y, qn.z, int(centre), int(std::max(thickness, 0.0)));
  return true;
}

std::uint32_t encodeColor(glm::vec4 rgba) {
  const auto q = [](float c) { return std::uint8_t(std::lround(std::clamp(c, 0.0f, 1.0f) * 255.0f)); };
  return packABGR(q(rgba.r), q(rgba.g), q(rgba.b), q(rgba.a));
}

namespace {
// The two face coordinates for each axis, in axis order.
constexpr int kFaceAxes[3][2] = {{1, 2}, {0, 2}, {0, 1}};
}  // namespace

std::uint32_t encodeNormal(glm::vec3 n) {
  const glm::vec3 a = glm::abs(n);
  const int axis = (a.x >= a.y && a.x >= a.z) ? 0 : (a.y >= a.z ? 1 : 2);
  if (!(a[axis] > 0.0f)) return encodeNormal({0.0f, 0.0f, 1.0f});
  const bool negative = n[axis] < 0.0f;
  const float u = n[kFaceAxes[axis][0]] / a[axis], v = n[kFaceAxes[axis][1]] / a[axis];
  const auto q = [](float c, std::uint32_t max) {
    return std::uint32_t(std::lround((std::clamp(c, -1.0f, 1.0f) + 1.0f) * 0.5f * float(max)));
  };
  return (std::uint32_t(axis * 2 + negative) << 29) | (q(u, kNormalUMax) << 14) | q(v, kNormalVMax);
}

namespace {
// Coordinates as signed 8-bit fractions of 127 (snorm8): 0 and +-1 are on the lattice, so the axes are.
constexpr int kOctMax = (1 << (kOctNormalBits - 1)) - 1;
float signNotZero(float x) {
  return x < 0.0f ? -1.0f : 1.0f;
}
// The tables are built once, on first use: 65536 entries each.
template <class Fill>
const std::vector<std::uint32_t>& table(Fill fill) {
  static const std::vector<std::uint32_t> t = [&] {
    std::vector<std::uint32_t> out(std::size_t(1) << (2 * kOctNormalBits));
    for (std::size_t code = 0; code < out.size(); ++code) out[code] = fill(std::uint16_t(code));
    return out;
  }();
  return t;
}
}  // namespace

std::uint16_t octNormalCode(glm::vec3 n) {
  const float l1 = std::abs(n.x) + std::abs(n.y) + std::abs(n.z);
  if (!(l1 > 0.0f)) return octNormalCode({0.0f, 0.0f, 1.0f});
  glm::vec2 p = glm::vec2(n.x, n.y) / l1;
  if (n.z < 0.0f)
    p = glm::vec2((1.0f - std::abs(p.y)) * signNotZero(p.x), (1.0f - std::abs(p.x)) * signNotZero(p.y));
  // std::lround's rounding (halves away from zero) without its call: x + 0.5 is exact in double. The pager
  // runs this per decoded normal, where lroundf was a third of its cost.
  const auto q = [](float c) {
    const float x = std::clamp(c, -1.0f, 1.0f) * float(kOctMax);
    return std::uint8_t(std::int8_t(int(double(x) + std::copysign(0.5, double(x)))));
  };
  return std::uint16_t(q(p.x) << kOctNormalBits | q(p.y));
}

glm::vec3 octNormalDirection(std::uint16_t code) {
  const auto c = [](std::uint8_t b) { return std::max(float(std::int8_t(b)) / float(kOctMax), -1.0f); };
  const float x = c(std::uint8_t(code >> kOctNormalBits)), y = c(std::uint8_t(code));
  glm::vec3 v(x, y, 1.0f - std::abs(x) - std::abs(y));
  if (v.z < 0.0f)
    v = glm::vec3((1.0f - std::abs(y)) * signNotZero(x), (1.0f - std::abs(x)) * signNotZero(y), v.z);
  return glm::normalize(v);
}

const std::uint32_t* latticeNormalTable() {
  static const auto& t = table([](std::uint16_t c) { return encodeNormal(octNormalDirection(c)); });
  return t.data();
}

const std::uint32_t* canonicalNormalCodeTable() {
  static const auto& t =
      table([](std::uint16_t c) { return std::uint32_t(octNormalCodeOf(latticeNormalBits(c))); });
  return t.data();
}

const std::uint32_t* contourNormalPredictionTable() {
  static const auto& t = table([](std::uint16_t c) {
    const glm::ivec3 q = quantizeContourNormal(glm::dvec3(normalDirection(latticeNormalBits(c))));
    return packContourBits(q.x, q.y, q.z, 0, 0);
  });
  return t.data();
}

}  // namespace svo
