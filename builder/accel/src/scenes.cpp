#include "svo/accel/scenes.hpp"

#include <cmath>
#include <numbers>
#include <random>
#include <stdexcept>

#include <glm/geometric.hpp>

namespace svo::accel {

namespace {
// Thin random triangles: length up to this fraction of the cube, width this much smaller (ORG Fig. 1).
constexpr double kThinLength = 0.5;
constexpr double kThinWidth = 0.002;
// Tiny triangles of the huge-among-tiny and random soups: edge length about this fraction of the cube.
constexpr double kTinySize = 0.01;

void addTriangle(Mesh& m, const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c) {
  const auto base = std::uint32_t(m.positions.size());
  m.positions.push_back(a);
  m.positions.push_back(b);
  m.positions.push_back(c);
  m.triangles.emplace_back(base, base + 1, base + 2);
}

glm::dvec3 randomUnit(std::mt19937_64& rng) {
  std::normal_distribution<double> g;
  for (;;) {
    const glm::dvec3 v(g(rng), g(rng), g(rng));
    const double l = glm::length(v);
    if (l > 1e-9) return v / l;
  }
}

void randomSmall(Mesh& m, std::mt19937_64& rng, std::size_t n, double size) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (std::size_t i = 0; i < n; ++i) {
    const glm::dvec3 p(u(rng), u(rng), u(rng));
    addTriangle(m, p, p + size * randomUnit(rng), p + size * randomUnit(rng));
  }
}

}  // namespace

std::string sceneName(SceneKind kind) {
  switch (kind) {
    case SceneKind::kSphere:
      return "sphere";
    case SceneKind::kThinRandom:
      return "thin";
    case SceneKind::kFlatField:
      return "field";
    case SceneKind::kHugeAmongTiny:
      return "huge-tiny";
    case SceneKind::kRandomSoup:
      return "soup";
  }
  return "?";
}

std::vector<SceneKind> allScenes() {
  return {SceneKind::kSphere, SceneKind::kThinRandom, SceneKind::kFlatField, SceneKind::kHugeAmongTiny,
          SceneKind::kRandomSoup};
}

Mesh makeScene(SceneKind kind, std::size_t n, std::uint64_t seed) {
  if (n == 0) throw std::invalid_argument("makeScene: triangle count must be > 0");
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Mesh m;
  switch (kind) {
    case SceneKind::kSphere: {
      // rings × segments quads, 2 triangles each, segments = 2 · rings.
      const int rings = std::max(2, int(std::lround(std::sqrt(double(n) / 4.0))));
      const int segs = 2 * rings;
      for (int r = 0; r <= rings; ++r)
        for (int s = 0; s < segs; ++s) {
          const double th = std::numbers::pi * r / rings, ph = 2.0 * std::numbers::pi * s / segs;
          m.positions.emplace_back(0.5 + 0.5 * std::sin(th) * std::cos(ph),
                                   0.5 + 0.5 * std::sin(th) * std::sin(ph), 0.5 + 0.5 * std::cos(th));
        }
      for (int r = 0; r < rings; ++r)
        for (int s = 0; s < segs; ++s) {
          const auto i = [&](int rr, int ss) { return std::uint32_t(rr * segs + (ss % segs)); };
          if (r > 0) m.triangles.emplace_back(i(r, s), i(r + 1, s), i(r, s + 1));
          if (r + 1 < rings) m.triangles.emplace_back(i(r, s + 1), i(r + 1, s), i(r + 1, s + 1));
        }
      break;
    }
    case SceneKind::kThinRandom:
      for (std::size_t i = 0; i < n; ++i) {
        const glm::dvec3 p(u(rng), u(rng), u(rng));
        const glm::dvec3 dir = randomUnit(rng) * (kThinLength * u(rng));
        addTriangle(m, p, glm::clamp(p + dir, 0.0, 1.0), p + kThinWidth * randomUnit(rng));
      }
      break;
    case SceneKind::kFlatField: {
      const int k = std::max(1, int(std::lround(std::sqrt(double(n) / 2.0))));
      for (int y = 0; y <= k; ++y)
        for (int x = 0; x <= k; ++x) m.positions.emplace_back(double(x) / k, double(y) / k, 0.0);
      for (int y = 0; y < k; ++y)
        for (int x = 0; x < k; ++x) {
          const auto i = [&](int xx, int yy) { return std::uint32_t(yy * (k + 1) + xx); };
          m.triangles.emplace_back(i(x, y), i(x + 1, y), i(x + 1, y + 1));
          m.triangles.emplace_back(i(x, y), i(x + 1, y + 1), i(x, y + 1));
        }
      break;
    }
    case SceneKind::kHugeAmongTiny: {
      const std::size_t huge = std::max<std::size_t>(1, std::size_t(std::cbrt(double(n))));
      for (std::size_t i = 0; i < huge; ++i)
        addTriangle(m, {u(rng), u(rng), 0.0}, {u(rng), 1.0, u(rng)}, {1.0, u(rng), u(rng)});
      randomSmall(m, rng, n > huge ? n - huge : 0, kTinySize);
      break;
    }
    case SceneKind::kRandomSoup:
      randomSmall(m, rng, n, 3.0 * kTinySize);
      break;
  }
  return m;
}

}  // namespace svo::accel
