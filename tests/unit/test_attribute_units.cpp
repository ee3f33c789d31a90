// Compressed attribute units (store/attribute_units.hpp, ESVO paper sec. 5.5): decoding checked against
// words built by hand from the documented bit layouts; color encoding against exhaustive searches (one and
// two colors: the optimum; more: every pair of the used colors as endpoints); normal encoding against
// analytic bounds on sphere patches and a naive encoder; degenerate inputs; determinism.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include <glm/geometric.hpp>

#include "svo/store/attribute_units.hpp"
#include "svo/store/format.hpp"

namespace svo {
namespace {

// ---------------------------------------------------------------------------------------------------------
// Colors, decoded here from the layout: word 0 = c1 (31:16) and c0 (15:0), RGB565 with red on top; word 1
// = 2-bit indices, slot i in bits 2i+1:2i; entries c0, c1, (2 c0 + c1 + 1) / 3, (c0 + 2 c1 + 1) / 3.

int expand5(int q) {
  return (q << 3) | (q >> 2);
}
int expand6(int q) {
  return (q << 2) | (q >> 4);
}
int expandBits(int q, int bits) {
  return bits == 5 ? expand5(q) : expand6(q);
}
int entryValue(int a, int b, int index) {
  const int v[4] = {a, b, (2 * a + b + 1) / 3, (a + 2 * b + 1) / 3};
  return v[index];
}
constexpr int kBits[3] = {5, 6, 5};

std::array<int, 3> rgbOf(std::uint32_t abgr) {
  return {int(abgr & 255u), int((abgr >> 8) & 255u), int((abgr >> 16) & 255u)};
}

using Colors = std::array<std::uint32_t, kUnitSlots>;

// Total squared 8-bit RGB error of the decoded unit over the used slots.
long colorError(const ColorUnit& unit, const Colors& colors, std::uint16_t used) {
  long e = 0;
  for (int s = 0; s < kUnitSlots; ++s) {
    if (!((used >> s) & 1u)) continue;
    const auto d = rgbOf(decodeColorUnit(unit, s)), x = rgbOf(colors[s]);
    for (int c = 0; c < 3; ++c) e += long(d[c] - x[c]) * (d[c] - x[c]);
  }
  return e;
}

// The lattice value whose expansion is nearest x (the lower on ties).
int nearestLattice(int x, int bits) {
  int best = 0;
  for (int q = 1; q < (1 << bits); ++q)
    if (std::abs(expandBits(q, bits) - x) < std::abs(expandBits(best, bits) - x)) best = q;
  return best;
}

// Reduced brute force: endpoints restricted to the used colors rounded to RGB565 (every ordered pair),
// each slot on its best entry.
long pairsOfUsedColors(const Colors& colors, std::uint16_t used) {
  long best = std::numeric_limits<long>::max();
  for (int i = 0; i < kUnitSlots; ++i)
    for (int j = 0; j < kUnitSlots; ++j) {
      if (!((used >> i) & 1u) || !((used >> j) & 1u)) continue;
      int a[3], b[3];
      for (int c = 0; c < 3; ++c) {
        a[c] = expandBits(nearestLattice(rgbOf(colors[i])[c], kBits[c]), kBits[c]);
        b[c] = expandBits(nearestLattice(rgbOf(colors[j])[c], kBits[c]), kBits[c]);
      }
      long e = 0;
      for (int s = 0; s < kUnitSlots; ++s) {
        if (!((used >> s) & 1u)) continue;
        long slot = std::numeric_limits<long>::max();
        for (int k = 0; k < 4; ++k) {
          long d = 0;
          for (int c = 0; c < 3; ++c)
            d += long(entryValue(a[c], b[c], k) - rgbOf(colors[s])[c]) *
                 (entryValue(a[c], b[c], k) - rgbOf(colors[s])[c]);
          slot = std::min(slot, d);
        }
        e += slot;
      }
      best = std::min(best, e);
    }
  return best;
}

// The exact optimum for colors x[i] with weights w[i] (at most two): every assignment of entries, and for
// it every endpoint pair per channel (the channels are independent once the entries are fixed).
long exhaustiveOptimum(const std::vector<std::array<int, 3>>& x, const std::vector<int>& w) {
  long best = std::numeric_limits<long>::max();
  const int patterns = x.size() == 1 ? 4 : 16;
  for (int pattern = 0; pattern < patterns; ++pattern) {
    long total = 0;
    for (int c = 0; c < 3; ++c) {
      long channel = std::numeric_limits<long>::max();
      for (int qa = 0; qa < (1 << kBits[c]); ++qa)
        for (int qb = 0; qb < (1 << kBits[c]); ++qb) {
          long e = 0;
          for (std::size_t i = 0; i < x.size(); ++i) {
            const int d =
                entryValue(expandBits(qa, kBits[c]), expandBits(qb, kBits[c]), (pattern >> (2 * i)) & 3) -
                x[i][c];
            e += long(w[i]) * d * d;
          }
          channel = std::min(channel, e);
        }
      total += channel;
    }
    best = std::min(best, total);
  }
  return best;
}

std::uint16_t randomMask(std::mt19937_64& rng, int bits) {
  std::uint16_t mask = 0;
  while (std::popcount(mask) < bits) mask |= std::uint16_t(1u << (rng() % kUnitSlots));
  return mask;
}

std::uint32_t randomColor(std::mt19937_64& rng) {
  return std::uint32_t(rng()) | 0xFF000000u;
}

// ---------------------------------------------------------------------------------------------------------
// Normals.

using Normals = std::array<glm::vec3, kUnitSlots>;

double angleDegrees(const glm::dvec3& a, const glm::dvec3& b) {
  return std::atan2(glm::length(glm::cross(a, b)), glm::dot(a, b)) * 180.0 / M_PI;
}

glm::dvec3 randomUnit(std::mt19937_64& rng) {
  std::normal_distribution<double> g;
  for (;;) {
    glm::dvec3 v;
    for (int k = 0; k < 3; ++k) v[k] = g(rng);  // in order (a constructor's arguments are not)
    if (glm::length(v) > 1e-6) return glm::normalize(v);
  }
}

// Normals of a sphere at the centres of two sibling voxels' children (slot i is child i % 8 of sibling i /
// 8; siblings side by side along x), the sphere's centre along -d at the radius that makes the children's
// normals span `spread` degrees (the lattice's diagonal, sqrt(11) child widths, over the radius).
Normals spherePatch(std::mt19937_64& rng, double spread) {
  const glm::dvec3 d = randomUnit(rng);
  const double radius = std::sqrt(11.0) / (spread * M_PI / 180.0);
  Normals n{};
  for (int s = 0; s < kUnitSlots; ++s) {
    const glm::dvec3 p((s & 1) + 2 * (s / 8) - 1.5, ((s >> 1) & 1) - 0.5, ((s >> 2) & 1) - 0.5);
    n[s] = glm::vec3(glm::normalize(p + radius * d));
  }
  return n;
}

struct AngleStats {
  double mean = 0, max = 0;
  int count = 0;
  void add(double a) { mean += a, max = std::max(max, a), ++count; }
  double average() const { return mean / count; }
};

void addErrors(const NormalUnit& unit, const Normals& normals, std::uint16_t used, AngleStats& stats) {
  for (int s = 0; s < kUnitSlots; ++s)
    if ((used >> s) & 1u)
      stats.add(angleDegrees(glm::dvec3(decodeNormalUnit(unit, s)), glm::dvec3(normals[s])));
}

// An axis's 16 bits from its three mantissas and exponent, as the layout has them.
std::uint32_t axisBits(int x, int y, int z, int e) {
  return std::uint32_t(e) << 12 | std::uint32_t(z & 15) << 8 | std::uint32_t(y & 15) << 4 |
         std::uint32_t(x & 15);
}

// The naive encoder: n_b the mean, the axes spanning the targets' bounding box around it in a fixed
// tangent frame (no principal axes), each quantized with its finest fitting exponent and rounded mantissas,
// selectors the best of 16 by decoded angle; no refinement.
NormalUnit naiveEncoder(const Normals& normals, std::uint16_t used) {
  glm::dvec3 mean(0.0);
  for (int s = 0; s < kUnitSlots; ++s)
    if ((used >> s) & 1u) mean += glm::normalize(glm::dvec3(normals[s]));
  mean = glm::normalize(mean);
  const glm::dvec3 t1 =
      glm::normalize(glm::cross(mean, std::abs(mean.x) < 0.9 ? glm::dvec3(1, 0, 0) : glm::dvec3(0, 1, 0)));
  const glm::dvec3 t2 = glm::cross(mean, t1);
  double reach1 = 0, reach2 = 0;
  for (int s = 0; s < kUnitSlots; ++s) {
    if (!((used >> s) & 1u)) continue;
    const glm::dvec3 p =
        glm::dvec3(normals[s]) / glm::dot(glm::dvec3(normals[s]), mean);  // on the tangent plane
    reach1 = std::max(reach1, std::abs(glm::dot(p, t1))),
    reach2 = std::max(reach2, std::abs(glm::dot(p, t2)));
  }
  const double scale =
      1.0 / std::max({std::abs(mean.x), std::abs(mean.y), std::abs(mean.z)});  // n_b on the cube
  const auto quantize = [&](const glm::dvec3& a) {
    for (int e = 0;; ++e) {
      const double step = std::ldexp(1.0, e - kNormalAxisExponentBias);
      int m[3];
      bool fits = true;
      for (int k = 0; k < 3; ++k)
        m[k] = int(std::lround(a[k] / step)), fits = fits && m[k] >= -8 && m[k] <= 7;
      if (fits || e == 15)
        return axisBits(std::clamp(m[0], -8, 7), std::clamp(m[1], -8, 7), std::clamp(m[2], -8, 7), e);
    }
  };
  NormalUnit unit;
  unit.words[0] = encodeNormal(glm::vec3(mean));
  unit.words[1] = quantize(t1 * reach1 * scale) | quantize(t2 * reach2 * scale) << 16;
  for (int s = 0; s < kUnitSlots; ++s) {
    if (!((used >> s) & 1u)) continue;
    double best = 1e9;
    for (std::uint32_t selector = 0; selector < 16; ++selector) {
      NormalUnit trial = unit;
      trial.words[2 + s / 8] |= selector << (4 * (s % 8));
      const double a = angleDegrees(glm::dvec3(decodeNormalUnit(trial, s)), glm::dvec3(normals[s]));
      if (a < best) best = a, unit.words[2 + s / 8] = trial.words[2 + s / 8];
    }
  }
  return unit;
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------
// Decoding

TEST(AttributeUnits, ColorDecodeBitLayout) {
  // c0 = (10, 40, 3) expands to (82, 162, 24); c1 = (31, 0, 17) to (255, 0, 140).
  ColorUnit unit;
  unit.words[0] = (10u << 11 | 40u << 5 | 3u) | (31u << 11 | 0u << 5 | 17u) << 16;
  // Slots 0..3 on entries 0..3, slot 15 on entry 2, slot 7 on entry 1, the rest on entry 0.
  unit.words[1] = 0u << 0 | 1u << 2 | 2u << 4 | 3u << 6 | 1u << 14 | 2u << 30;
  const std::uint32_t e0 = packABGR(82, 162, 24), e1 = packABGR(255, 0, 140);
  // (2 * 82 + 255 + 1) / 3 = 140, (2 * 162 + 0 + 1) / 3 = 108, (2 * 24 + 140 + 1) / 3 = 63;
  // (82 + 2 * 255 + 1) / 3 = 197, (162 + 0 + 1) / 3 = 54, (24 + 2 * 140 + 1) / 3 = 101.
  const std::uint32_t e2 = packABGR(140, 108, 63), e3 = packABGR(197, 54, 101);
  EXPECT_EQ(decodeColorUnit(unit, 0), e0);
  EXPECT_EQ(decodeColorUnit(unit, 1), e1);
  EXPECT_EQ(decodeColorUnit(unit, 2), e2);
  EXPECT_EQ(decodeColorUnit(unit, 3), e3);
  EXPECT_EQ(decodeColorUnit(unit, 7), e1);
  EXPECT_EQ(decodeColorUnit(unit, 15), e2);
  for (int s : {4, 5, 6, 8, 9, 10, 11, 12, 13, 14}) EXPECT_EQ(decodeColorUnit(unit, s), e0) << s;
  // Bit replication for every lattice value, each channel on its own (alpha is always 255).
  for (int q = 0; q < 64; ++q) {
    ColorUnit u;
    u.words[0] = std::uint32_t(q % 32) << 11 | std::uint32_t(q) << 5 | std::uint32_t(31 - q % 32);
    u.words[0] |= u.words[0] << 16;
    const std::uint32_t d = decodeColorUnit(u, 0);
    EXPECT_EQ(int(d & 255u), ((q % 32) << 3) | ((q % 32) >> 2));
    EXPECT_EQ(int((d >> 8) & 255u), (q << 2) | (q >> 4));
    EXPECT_EQ(int((d >> 16) & 255u), ((31 - q % 32) << 3) | ((31 - q % 32) >> 2));
    EXPECT_EQ(d >> 24, 255u);
  }
}

TEST(AttributeUnits, NormalDecodeBitLayout) {
  // n_b: face 4 (+z), u = 0 and v = max, so the cube point (-1, 1, 1).
  const std::uint32_t base = 4u << 29 | 0u << 14 | kNormalVMax;
  // n_u = (2, -1, 0) * 2^(14 - 16) = (0.5, -0.25, 0); n_v = (0, 7, -8) * 2^(13 - 16) = (0, 0.875, -1).
  const std::uint32_t axes = axisBits(2, -1, 0, 14) | axisBits(0, 7, -8, 13) << 16;
  EXPECT_EQ(axes, 0xE0F2u | 0xD870u << 16);
  NormalUnit unit;
  unit.words = {base, axes, 0, 0};
  // Slot 0: c_u = +1 (code 3), c_v = -1 (code 0). Slot 9 (word 3, bits 7:4): c_u = -1/3 (1), c_v = +1/3 (2).
  // Slot 15 (word 3, bits 31:28): c_u = +1/3 (2), c_v = +1 (3).
  unit.words[2] = 3u;
  unit.words[3] = (1u | 2u << 2) << 4 | (2u | 3u << 2) << 28;
  const glm::dvec3 nb(-1, 1, 1), nu(0.5, -0.25, 0), nv(0, 0.875, -1);
  const auto expect = [&](int slot, double cu, double cv) {
    const glm::dvec3 n = glm::normalize(nb + cu * nu + cv * nv);
    const glm::vec3 d = decodeNormalUnit(unit, slot);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(d[k], n[k], 1e-6) << "slot " << slot;
  };
  expect(0, 1, -1);
  expect(9, -1.0 / 3, 1.0 / 3);
  expect(15, 1.0 / 3, 1);
  expect(1, -1, -1);  // selector 0
  // A sum of zero decodes as n_b: n_u = (4, -4, -4) * 2^-2 = -n_b, c_u = +1, n_v = 0.
  unit.words[1] = axisBits(4, -4, -4, 14);
  unit.words[2] = 3u;
  const glm::vec3 d = decodeNormalUnit(unit, 0);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(d[k], nb[k] / std::sqrt(3.0), 1e-6);
}

// ---------------------------------------------------------------------------------------------------------
// Color encoding

TEST(AttributeUnits, ColorEmptyAndUnusedSlots) {
  std::mt19937_64 rng(1);
  Colors colors{};
  for (auto& c : colors) c = randomColor(rng);
  EXPECT_EQ(encodeColorUnit(colors, 0), ColorUnit{});
  // Unused slots' indices are 0.
  for (int t = 0; t < 50; ++t) {
    const std::uint16_t used = randomMask(rng, 1 + int(rng() % 15));
    const ColorUnit unit = encodeColorUnit(colors, used);
    for (int s = 0; s < kUnitSlots; ++s)
      if (!((used >> s) & 1u)) {
        EXPECT_EQ((unit.words[1] >> (2 * s)) & 3u, 0u);
      }
  }
}

// One color decodes as close as RGB565 allows: the error is the exhaustive optimum (every entry, every
// endpoint pair), which is at most what rounding each channel gives: |error| <= 4, 2, 4 in red, green, blue.
TEST(AttributeUnits, ColorSingleColorIsOptimal) {
  std::mt19937_64 rng(2);
  for (int t = 0; t < 400; ++t) {
    const std::uint32_t color =
        t < 256 ? packABGR(std::uint8_t(t), std::uint8_t(t), std::uint8_t(t)) : randomColor(rng);
    const std::uint16_t used = randomMask(rng, 1 + int(rng() % 16));
    Colors colors{};
    for (auto& c : colors) c = color;
    const ColorUnit unit = encodeColorUnit(colors, used);
    const long e = colorError(unit, colors, used);
    ASSERT_EQ(e, exhaustiveOptimum({rgbOf(color)}, {std::popcount(used)})) << std::hex << color;
    for (int s = 0; s < kUnitSlots; ++s) {
      if (!((used >> s) & 1u)) continue;
      const auto d = rgbOf(decodeColorUnit(unit, s)), x = rgbOf(color);
      EXPECT_LE(std::abs(d[0] - x[0]), 4);
      EXPECT_LE(std::abs(d[1] - x[1]), 2);
      EXPECT_LE(std::abs(d[2] - x[2]), 4);
    }
  }
}

// Two colors: the exhaustive optimum, which is at most the two colors rounded to RGB565 (at most 4^2 + 2^2
// + 4^2 = 36 per slot).
TEST(AttributeUnits, ColorTwoColorsAreOptimal) {
  std::mt19937_64 rng(3);
  for (int t = 0; t < 60; ++t) {
    std::array<int, 3> a = rgbOf(randomColor(rng)), b = a;
    for (int c = 0; c < 3; ++c)
      b[c] = t % 2 ? int(rng() % 256) : std::clamp(a[c] + int(rng() % 31) - 15, 0, 255);
    if (a == b) continue;
    Colors colors{};
    std::uint16_t used = 0;
    int w[2] = {0, 0};
    for (int s = 0; s < kUnitSlots; ++s) {
      if (rng() % 4 == 0) continue;
      const int i = s == 0 ? 0 : s == 1 ? 1 : int(rng() % 2);
      const auto& x = i == 0 ? a : b;
      colors[s] = packABGR(std::uint8_t(x[0]), std::uint8_t(x[1]), std::uint8_t(x[2]));
      used |= std::uint16_t(1u << s), ++w[i];
    }
    if (!w[0] || !w[1]) continue;
    const long e = colorError(encodeColorUnit(colors, used), colors, used);
    EXPECT_EQ(e, exhaustiveOptimum({a, b}, {w[0], w[1]}));
    long rounded = 0;
    for (int c = 0; c < 3; ++c)
      for (int i = 0; i < 2; ++i) {
        const int x = (i == 0 ? a : b)[c], d = expandBits(nearestLattice(x, kBits[c]), kBits[c]) - x;
        rounded += long(w[i]) * d * d;
      }
    EXPECT_LE(e, rounded);
    EXPECT_LE(e, 36L * std::popcount(used));
  }
}

// More colors: at least as good as every pair of the used colors (rounded to RGB565) as endpoints, on random
// colors, clusters and noisy gradients over random slot masks. The encoder tries every such pair up to 8
// distinct colors, so there it is never worse; beyond, its search is heuristic (measured over 18000 sets:
// 0.1% of them worse, by at most 12%).
TEST(AttributeUnits, ColorSetsBeatPairsOfUsedColors) {
  std::mt19937_64 rng(4);
  long encoded = 0, reference = 0;
  int many = 0, worse = 0;
  for (int t = 0; t < 300; ++t) {
    const int kind = t % 3;
    Colors colors{};
    std::array<int, 3> base[3];
    for (auto& c : base) c = rgbOf(randomColor(rng));
    for (int s = 0; s < kUnitSlots; ++s) {
      std::array<int, 3> x = rgbOf(randomColor(rng));  // kind 0: uniform
      const double f = double(rng() % 1000) / 999.0;
      for (int c = 0; c < 3 && kind > 0; ++c) {
        const int noise = int(rng() % 13) - 6;
        x[c] =
            kind == 1 ? base[rng() % 3][c] + noise : int(base[0][c] + f * (base[1][c] - base[0][c])) + noise;
        x[c] = std::clamp(x[c], 0, 255);
      }
      colors[s] = packABGR(std::uint8_t(x[0]), std::uint8_t(x[1]), std::uint8_t(x[2]));
    }
    const std::uint16_t used = randomMask(rng, 3 + int(rng() % 14));
    std::vector<std::uint32_t> distinct;
    for (int s = 0; s < kUnitSlots; ++s)
      if (((used >> s) & 1u) && std::find(distinct.begin(), distinct.end(), colors[s]) == distinct.end())
        distinct.push_back(colors[s]);
    const long e = colorError(encodeColorUnit(colors, used), colors, used),
               r = pairsOfUsedColors(colors, used);
    if (distinct.size() <= 8) {
      EXPECT_LE(e, r) << "set " << t << " kind " << kind;
    } else {
      EXPECT_LE(double(e), 1.25 * double(r)) << "set " << t << " kind " << kind;
      ++many, worse += e > r;
    }
    encoded += e, reference += r;
  }
  EXPECT_LE(worse, many / 50);
  // And clearly better in total (measured: 0.86 of the reference).
  EXPECT_LT(double(encoded), 0.9 * double(reference));
}

// Smooth gradients over all 16 slots, each channel spanning up to 96 levels: four evenly spaced entries
// between the rounded ends leave at most range / 6 per channel, plus 4 for rounding an end (5 bits) and 1
// for rounding a mix; the encoder's total error is within that reference's.
TEST(AttributeUnits, ColorGradients) {
  std::mt19937_64 rng(5);
  long sum = 0;
  int count = 0;
  for (int t = 0; t < 200; ++t) {
    std::array<int, 3> a = rgbOf(randomColor(rng)), b = a;
    for (int c = 0; c < 3; ++c) b[c] = std::clamp(a[c] + int(rng() % 193) - 96, 0, 255);
    Colors colors{};
    for (int s = 0; s < kUnitSlots; ++s) {
      std::array<int, 3> x;
      for (int c = 0; c < 3; ++c) x[c] = a[c] + (b[c] - a[c]) * s / 15;
      colors[s] = packABGR(std::uint8_t(x[0]), std::uint8_t(x[1]), std::uint8_t(x[2]));
    }
    const long e = colorError(encodeColorUnit(colors, 0xFFFF), colors, 0xFFFF);
    double bound = 0;
    for (int c = 0; c < 3; ++c) bound += kUnitSlots * std::pow(std::abs(b[c] - a[c]) / 6.0 + 5.0, 2);
    EXPECT_LE(double(e), bound) << t;
    sum += e, count += 3 * kUnitSlots;
  }
  // Measured RMSE 4.1 (8-bit units).
  EXPECT_LT(std::sqrt(double(sum) / count), 4.5);
}

TEST(AttributeUnits, ColorDeterministicAndDontCares) {
  std::mt19937_64 rng(6);
  for (int t = 0; t < 100; ++t) {
    Colors colors{};
    for (auto& c : colors) c = randomColor(rng);
    const std::uint16_t used = randomMask(rng, 1 + int(rng() % 16));
    const ColorUnit unit = encodeColorUnit(colors, used);
    EXPECT_EQ(encodeColorUnit(colors, used), unit);
    Colors changed = colors;
    for (int s = 0; s < kUnitSlots; ++s)
      if (!((used >> s) & 1u)) changed[s] = randomColor(rng);
    const ColorUnit other = encodeColorUnit(changed, used);
    for (int s = 0; s < kUnitSlots; ++s)
      if ((used >> s) & 1u) {
        EXPECT_EQ(decodeColorUnit(other, s), decodeColorUnit(unit, s));
      }
  }
}

// ---------------------------------------------------------------------------------------------------------
// Normal encoding

// One normal, or one repeated: within the cube encoding's precision (a half step of 15 and 14 bits on a
// face at distance >= 1: under 0.005 degrees).
TEST(AttributeUnits, NormalSingleAndIdentical) {
  std::mt19937_64 rng(7);
  std::vector<glm::dvec3> directions = {{1, 0, 0}, {0, -1, 0}, {0, 0, 1},
                                        {1, 1, 1}, {-1, 1, 0}, {0.3, -0.2, 1}};
  for (int i = 0; i < 300; ++i) directions.push_back(randomUnit(rng));
  for (const glm::dvec3& d : directions) {
    Normals normals{};
    for (auto& n : normals) n = glm::vec3(d * 3.0);
    for (std::uint16_t used :
         {std::uint16_t(1u << (rng() % 16)), std::uint16_t(0xFFFF), randomMask(rng, 5)}) {
      const NormalUnit unit = encodeNormalUnit(normals, used);
      for (int s = 0; s < kUnitSlots; ++s)
        if ((used >> s) & 1u) {
          EXPECT_LT(angleDegrees(glm::dvec3(decodeNormalUnit(unit, s)), d), 0.01);
        }
    }
  }
}

// Sphere patches over two sibling voxels' children: mean and max angular error per spread, against bounds
// a little above the measured values (mean 0.056, 0.28, 1.10, 3.5 degrees; max 0.16, 0.86, 3.05, 9.8), and
// well below the naive encoder's (measured 0.38 to 0.43 of its mean).
TEST(AttributeUnits, NormalSpherePatches) {
  struct Case {
    double spread, meanBound, maxBound;
  };
  for (const Case& c : {Case{1, 0.07, 0.25}, Case{5, 0.33, 1.2}, Case{20, 1.3, 4.5}, Case{60, 4.2, 13}}) {
    std::mt19937_64 rng(8);
    AngleStats ours, naive;
    for (int t = 0; t < 200; ++t) {
      const Normals normals = spherePatch(rng, c.spread);
      const std::uint16_t used = t % 2 ? std::uint16_t(0xFFFF) : randomMask(rng, 8);
      addErrors(encodeNormalUnit(normals, used), normals, used, ours);
      addErrors(naiveEncoder(normals, used), normals, used, naive);
    }
    EXPECT_LT(ours.average(), c.meanBound) << c.spread;
    EXPECT_LT(ours.max, c.maxBound) << c.spread;
    EXPECT_LT(ours.average(), 0.6 * naive.average()) << c.spread;
    // The product goal: children of sibling voxels spanning a few degrees decode within 1 degree on average.
    if (c.spread <= 5) {
      EXPECT_LT(ours.average(), 1.0);
    }
  }
}

// Degenerate inputs decode as finite unit normals. An antipodal pair along an axis is exact (one as n_b, an
// axis reaching the other); along other directions the 4-bit axes cannot point exactly back along n_b
// (measured: mean 1.8 and max 13 degrees here, max 17 over 1000 pairs).
TEST(AttributeUnits, NormalDegenerateInputs) {
  std::mt19937_64 rng(9);
  const auto check = [](const Normals& normals, std::uint16_t used) {
    const NormalUnit unit = encodeNormalUnit(normals, used);
    for (int s = 0; s < kUnitSlots; ++s) {
      const glm::vec3 d = decodeNormalUnit(unit, s);
      EXPECT_TRUE(std::isfinite(d.x) && std::isfinite(d.y) && std::isfinite(d.z));
      EXPECT_NEAR(glm::length(d), 1.0f, 1e-5f);
    }
    return unit;
  };
  const auto antipodal = [&](const glm::dvec3& d, std::uint16_t used) {
    Normals normals{};
    for (int s = 0; s < kUnitSlots; ++s) normals[s] = glm::vec3(s % 2 ? -d : d);
    const NormalUnit unit = check(normals, used);
    AngleStats stats;
    addErrors(unit, normals, used, stats);
    return stats;
  };
  for (const glm::dvec3& axis : {glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, 1)})
    EXPECT_LT(antipodal(axis, 0x0003).max, 0.01);
  AngleStats pairs;
  for (int t = 0; t < 100; ++t) {
    const glm::dvec3 d = randomUnit(rng);
    const AngleStats pair = antipodal(d, std::uint16_t(3u << (2 * (rng() % 8))));
    pairs.mean += pair.mean, pairs.count += pair.count, pairs.max = std::max(pairs.max, pair.max);
    // Antipodal-ish, a full circle (180-degree spreads), a hemisphere, tiny and huge vectors.
    const glm::dvec3 e = glm::normalize(glm::cross(d, randomUnit(rng))), f = glm::cross(d, e);
    Normals normals{};
    for (int s = 0; s < kUnitSlots; ++s) normals[s] = glm::vec3(s % 2 ? -d + 0.01 * e : d);
    check(normals, 0xFFFF);
    for (int s = 0; s < kUnitSlots; ++s)
      normals[s] = glm::vec3(std::cos(s * M_PI / 8) * e + std::sin(s * M_PI / 8) * f);
    check(normals, 0xFFFF);
    for (int s = 0; s < kUnitSlots; ++s) normals[s] = glm::vec3(glm::normalize(randomUnit(rng) + 1.01 * d));
    check(normals, 0xFFFF);
    for (int s = 0; s < kUnitSlots; ++s)
      normals[s] = glm::vec3(randomUnit(rng) * (s % 3 == 0 ? 1e-30 : s % 3 == 1 ? 1e30 : 1.0));
    check(normals, randomMask(rng, 1 + int(rng() % 16)));
  }
  EXPECT_LT(pairs.average(), 3.0);
  EXPECT_LT(pairs.max, 20.0);
}

// The error encodeNormalUnit reports is the decoded unit's: the sum over used slots of the squared distance
// between decoded and given unit directions, recomputed here in double. And no grid unit reads as an exact
// one, not even where an axis is zero (identical normals: both; normals along one great circle: often one).
TEST(AttributeUnits, NormalErrorReportedAndNoGridUnitReadsAsExact) {
  std::mt19937_64 rng(12);
  int zeroAxes = 0;
  for (int t = 0; t < 300; ++t) {
    Normals normals = spherePatch(rng, 0.5 + double(rng() % 60));
    if (t % 3 == 1) normals.fill(glm::vec3(randomUnit(rng)));
    if (t % 3 == 2) {
      const glm::dvec3 d = randomUnit(rng), e = glm::normalize(glm::cross(d, randomUnit(rng)));
      for (int s = 0; s < kUnitSlots; ++s)
        normals[s] = glm::vec3(std::cos(0.02 * s) * d + std::sin(0.02 * s) * e);
    }
    const std::uint16_t used = t % 2 ? std::uint16_t(0xFFFF) : randomMask(rng, 1 + int(rng() % 16));
    float reported = -1.0f;
    const NormalUnit unit = encodeNormalUnit(normals, used, &reported);
    EXPECT_FALSE(isExact(unit)) << t;
    zeroAxes += (unit.words[1] & 0x0FFFu) == 0;
    double squares = 0.0;
    for (int s = 0; s < kUnitSlots; ++s)
      if ((used >> s) & 1u) {
        const glm::dvec3 chord =
            glm::dvec3(decodeNormalUnit(unit, s)) - glm::normalize(glm::dvec3(normals[s]));
        squares += glm::dot(chord, chord);
      }
    EXPECT_NEAR(reported, squares, 1e-5 + 1e-4 * squares) << t;
  }
  EXPECT_GT(zeroAxes, 50);  // the zero-axis case was met
}

TEST(AttributeUnits, NormalDeterministicAndDontCares) {
  std::mt19937_64 rng(10);
  for (int t = 0; t < 100; ++t) {
    const Normals normals = spherePatch(rng, 1.0 + double(rng() % 40));
    const std::uint16_t used = randomMask(rng, 1 + int(rng() % 16));
    const NormalUnit unit = encodeNormalUnit(normals, used);
    EXPECT_EQ(encodeNormalUnit(normals, used), unit);
    Normals changed = normals;
    for (int s = 0; s < kUnitSlots; ++s)
      if (!((used >> s) & 1u)) changed[s] = glm::vec3(randomUnit(rng));
    const NormalUnit other = encodeNormalUnit(changed, used);
    for (int s = 0; s < kUnitSlots; ++s) {
      if ((used >> s) & 1u) {
        EXPECT_EQ(decodeNormalUnit(other, s), decodeNormalUnit(unit, s));
      }
      if (!((used >> s) & 1u)) {
        EXPECT_EQ((unit.words[2 + s / 8] >> (4 * (s % 8))) & 15u, 0u);
      }
    }
  }
}

}  // namespace svo
