// Compressed colors (ESVO paper sec. 5.5): decoding as attribute_units.hpp documents, and an encoder that
// searches for the least-error unit. Deterministic: colors are integers throughout. No heap allocation.
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include <glm/geometric.hpp>
#include <glm/mat3x3.hpp>
#include <glm/matrix.hpp>

#include "svo/store/attribute_units.hpp"
#include "svo/store/format.hpp"
#include "unit_fit.hpp"

namespace svo {
namespace {

using unit_fit::dominantAxis;

// Bound on the lattice climbs; from a rounded continuous optimum they move a step or two in practice.
constexpr int kMaxClimbSteps = 16;

// The minimum of f over integer pairs in [lo, hi]^2 from `m`: every pair within `radius` of it, then a
// climb over the eight neighbours until none is better. m becomes the minimiser.
template <class F>
auto climb(const F& f, int lo, int hi, int radius, int m[2]) {
  auto best = f(m[0], m[1]);
  for (int step = 0; step < kMaxClimbSteps; ++step, radius = 1) {
    const int c0 = m[0], c1 = m[1];
    for (int a = std::max(c0 - radius, lo); a <= std::min(c0 + radius, hi); ++a)
      for (int b = std::max(c1 - radius, lo); b <= std::min(c1 + radius, hi); ++b) {
        const auto e = f(a, b);
        if (e < best) best = e, m[0] = a, m[1] = b;
      }
    if (m[0] == c0 && m[1] == c1) break;
  }
  return best;
}

// A channel's endpoint is a lattice value (5 bits red and blue, 6 bits green) expanded to 8 bits by
// bit replication; the palette's thirds are (2 a + b + 1) / 3 and (a + 2 b + 1) / 3 in integers (a GLSL
// port computes the same in uint arithmetic). The encoder's errors are exact integers.

constexpr int kChannelBits[3] = {5, 6, 5};    // red, green, blue
constexpr int kChannelShift[3] = {11, 5, 0};  // within an RGB565 endpoint

constexpr int expandChannel(int q, int bits) {
  return bits == 5 ? (q << 3) | (q >> 2) : (q << 2) | (q >> 4);
}

// The lattice value whose expansion is nearest x (the lower on ties).
int nearestLattice(int x, int bits) {
  const int maxQ = (1 << bits) - 1, q = (x * maxQ + 127) / 255;
  int best = std::max(q - 1, 0);
  for (int c = best + 1; c <= std::min(q + 1, maxQ); ++c)
    best = std::abs(expandChannel(c, bits) - x) < std::abs(expandChannel(best, bits) - x) ? c : best;
  return best;
}

// Palette entry `index` from the expanded endpoints a (c0) and b (c1): a, b, (2 a + b + 1) / 3 and
// (a + 2 b + 1) / 3 as one expression ((3 a + 1) / 3 is a).
constexpr int kWeightA[4] = {3, 0, 2, 1};
constexpr int paletteValue(int a, int b, int index) {
  return (kWeightA[index] * a + (3 - kWeightA[index]) * b + 1) / 3;
}

// The used slots' distinct colors by channel, weighted by slot count. Loops over all kUnitSlots points
// vectorize; points past `count` weigh nothing.
struct ColorPoints {
  int count = 0;
  alignas(16) int x[3][kUnitSlots] = {};
  alignas(16) int weight[kUnitSlots] = {};
  std::array<int, kUnitSlots> ofSlot{};  // point of each used slot
};

ColorPoints gatherColors(const std::array<std::uint32_t, kUnitSlots>& abgr, std::uint16_t used) {
  ColorPoints p;
  std::array<std::uint32_t, kUnitSlots> key{};
  for (int s = 0; s < kUnitSlots; ++s) {
    if (!((used >> s) & 1u)) continue;
    const std::uint32_t k = abgr[s] & 0xFFFFFFu;
    int i = 0;
    while (i < p.count && key[i] != k) ++i;
    if (i == p.count) {
      key[p.count++] = k;
      for (int c = 0; c < 3; ++c) p.x[c][i] = int((k >> (8 * c)) & 255u);
    }
    ++p.weight[i];
    p.ofSlot[s] = i;
  }
  return p;
}

struct ChannelPair {
  int a = 0, b = 0;  // lattice values of c0 and c1
};
using Ends = std::array<ChannelPair, 3>;
using Indices = std::array<int, kUnitSlots>;  // palette entry of each point

struct ColorFit {
  Ends ends{};
  Indices index{};
  long error = std::numeric_limits<long>::max();
};

// One channel's points by palette entry: weight, sum and sum of squares. With the entries fixed the
// channel's error is sum_k (w_k v_k^2 - 2 v_k s_k + q_k) for entry values v_k.
struct ChannelSums {
  int w[4] = {}, s[4] = {}, q[4] = {};
};

ChannelSums channelSums(const ColorPoints& p, const Indices& index, int c) {
  ChannelSums sums;
  for (int i = 0; i < p.count; ++i) {
    const int k = index[i], x = p.x[c][i], w = p.weight[i];
    sums.w[k] += w, sums.s[k] += w * x, sums.q[k] += w * x * x;
  }
  return sums;
}

long channelError(const ChannelSums& sums, int bits, ChannelPair q) {
  const int a = expandChannel(q.a, bits), b = expandChannel(q.b, bits);
  long e = 0;
  for (int k = 0; k < 4; ++k) {
    const long v = paletteValue(a, b, k);
    e += (sums.w[k] * v - 2 * sums.s[k]) * v + sums.q[k];
  }
  return e;
}

// Every point on entry 2: per channel the pair whose mix lands nearest the weighted mean m (each c0's best
// c1 is next to 3 m - 2 c0). Mixes reach every endpoint value too ((3 a + 1) / 3 = a), so for one color
// this is the best unit.
ColorFit fitOneEntry(const ColorPoints& p) {
  ColorFit fit;
  fit.index.fill(2);
  fit.error = 0;
  for (int c = 0; c < 3; ++c) {
    const int bits = kChannelBits[c], maxQ = (1 << bits) - 1;
    const ChannelSums sums = channelSums(p, fit.index, c);
    const long w = sums.w[2], s = sums.s[2];
    long nearest = std::numeric_limits<long>::max();
    const float target = 3.0f * float(s) / float(w);  // 2 c0 + c1, 8-bit values
    for (int a = 0; a <= maxQ; ++a) {
      const int ea = expandChannel(a, bits);
      if (2 * ea > target + 2 || 2 * ea + 258 < target) continue;  // no c1 brings the mix near the mean
      const int b = std::clamp(int(std::floor((target - 2.0f * float(ea)) * float(maxQ) / 255.0f)), 0, maxQ);
      for (int q = std::max(b - 1, 0); q <= std::min(b + 2, maxQ); ++q) {
        const long d = std::abs(w * paletteValue(ea, expandChannel(q, bits), 2) - s);
        if (d < nearest) nearest = d, fit.ends[c] = {a, q};
      }
    }
    fit.error += channelError(sums, bits, fit.ends[c]);
  }
  return fit;
}

// One channel's least-squares endpoints for fixed entries, rounded onto the lattice.
ChannelPair leastSquaresPair(const ChannelSums& sums, int bits) {
  float aa = 0, bb = 0, ab = 0, ax = 0, bx = 0, w = 0, sx = 0;
  for (int k = 0; k < 4; ++k) {  // al: the weight of c0 in entry k
    const float al = float(kWeightA[k]) / 3.0f, be = 1.0f - al, wk = float(sums.w[k]), sk = float(sums.s[k]);
    aa += wk * al * al, bb += wk * be * be, ab += wk * al * be, ax += al * sk, bx += be * sk, w += wk,
        sx += sk;
  }
  // det is 0 with one entry in use (then both endpoints at the mean), else >= (w - 1) / 9 > 1e-3 w^2.
  const float det = aa * bb - ab * ab;
  const bool single = !(det > 1e-3f * w * w);
  const float a = single ? sx / w : (ax * bb - bx * ab) / det,
              b = single ? sx / w : (bx * aa - ax * ab) / det;
  const int maxQ = (1 << bits) - 1;
  const auto lattice = [&](float v) {
    return std::clamp(int(std::floor(v * float(maxQ) / 255.0f + 0.5f)), 0, maxQ);
  };
  return {lattice(a), lattice(b)};
}

// Endpoints for fixed entries (channels are independent then), each pair climbing from the rounded least
// squares pair; returns the fixed-entry error.
long fitEndpoints(const ColorPoints& p, const Indices& index, int radius, Ends& ends) {
  long total = 0;
  for (int c = 0; c < 3; ++c) {
    const ChannelSums sums = channelSums(p, index, c);
    const auto error = [&](int a, int b) { return channelError(sums, kChannelBits[c], {a, b}); };
    const ChannelPair start = leastSquaresPair(sums, kChannelBits[c]);
    int m[2] = {start.a, start.b};
    total += climb(error, 0, (1 << kChannelBits[c]) - 1, radius, m);
    ends[c] = {m[0], m[1]};
  }
  return total;
}

// The total error with each point on its nearest palette entry, and with `index` that entry (the lowest on
// ties). Branch-free loops over a fixed number of points, half or all kUnitSlots, so that they vectorize.
template <bool kWithIndex, int kPoints>
long nearestEntries(const ColorPoints& p, const Ends& ends, Indices* index) {
  int palette[4][3];
  for (int c = 0; c < 3; ++c) {
    const int a = expandChannel(ends[c].a, kChannelBits[c]), b = expandChannel(ends[c].b, kChannelBits[c]);
    for (int k = 0; k < 4; ++k) palette[k][c] = paletteValue(a, b, k);
  }
  const auto error = [&](int k, int i) {
    const int d0 = palette[k][0] - p.x[0][i], d1 = palette[k][1] - p.x[1][i], d2 = palette[k][2] - p.x[2][i];
    return d0 * d0 + d1 * d1 + d2 * d2;
  };
  alignas(16) int best[kPoints], bestIndex[kPoints] = {};
  for (int i = 0; i < kPoints; ++i) best[i] = error(0, i);
  for (int k = 1; k < 4; ++k)
    for (int i = 0; i < kPoints; ++i) {
      const int e = error(k, i);
      if constexpr (kWithIndex) bestIndex[i] = e < best[i] ? k : bestIndex[i];
      best[i] = e < best[i] ? e : best[i];
    }
  int total = 0;
  for (int i = 0; i < kPoints; ++i) total += best[i] * p.weight[i];
  if constexpr (kWithIndex) std::copy(bestIndex, bestIndex + kPoints, index->begin());
  return total;
}

template <bool kWithIndex = true>
long assignIndices(const ColorPoints& p, const Ends& ends, Indices* index) {
  return p.count <= kUnitSlots / 2 ? nearestEntries<kWithIndex, kUnitSlots / 2>(p, ends, index)
                                   : nearestEntries<kWithIndex, kUnitSlots>(p, ends, index);
}

// Two colors: every pair of distinct entries up to swapping the endpoints (0 <-> 1, 2 <-> 3), and both on
// entry 2 (which covers both on any one entry).
constexpr int kTwoColorPatterns[6][2] = {{0, 1}, {0, 2}, {0, 3}, {2, 0}, {2, 1}, {2, 3}};
// Two colors' fixed-entry error is a narrow valley in the lattice (two equations, two unknowns): the fit
// scans this far around the rounded optimum before climbing.
constexpr int kTwoColorRadius = 2;

ColorFit fitTwoColors(const ColorPoints& p) {
  ColorFit best = fitOneEntry(p);
  for (const auto& pattern : kTwoColorPatterns) {
    ColorFit fit;
    fit.index[0] = pattern[0], fit.index[1] = pattern[1], fit.error = 0;
    for (int c = 0; c < 3; ++c) {  // as fitEndpoints, with the error of the two points directly
      const int bits = kChannelBits[c];
      const auto error = [&](int a, int b) {
        const int ea = expandChannel(a, bits), eb = expandChannel(b, bits);
        const long d0 = paletteValue(ea, eb, pattern[0]) - p.x[c][0],
                   d1 = paletteValue(ea, eb, pattern[1]) - p.x[c][1];
        return p.weight[0] * d0 * d0 + p.weight[1] * d1 * d1;
      };
      const ChannelPair start = leastSquaresPair(channelSums(p, fit.index, c), bits);
      int m[2] = {start.a, start.b};
      fit.error += climb(error, 0, (1 << bits) - 1, kTwoColorRadius, m);
      fit.ends[c] = {m[0], m[1]};
    }
    if (fit.error < best.error) best = fit;
  }
  return best;
}

// Bound on the alternations below; each lowers the error, and they settle in two or three.
constexpr int kMaxColorRounds = 4;
// Passes of the joint moves that end the fit; a second pass rarely finds one.
constexpr int kPolishPasses = 2;

// Alternates endpoint fits for fixed entries with entry choices for fixed endpoints (from a fit whose
// entries are the nearest), then tries each endpoint channel one step either way with the entries
// re-chosen: joint moves the per-channel fits cannot see.
void refineColors(const ColorPoints& p, ColorFit& fit) {
  for (int round = 0; round < kMaxColorRounds; ++round) {
    Ends ends;
    if (fitEndpoints(p, fit.index, 1, ends) >= fit.error) break;
    Indices index{};
    fit.ends = ends;
    fit.error = assignIndices(p, ends, &index);
    if (index == fit.index) break;
    fit.index = index;
  }
  for (int pass = 0; pass < kPolishPasses; ++pass) {
    bool improved = false;
    for (int move = 0; move < 12; ++move) {
      Ends ends = fit.ends;
      int& q = (move / 2) % 2 ? ends[move / 4].b : ends[move / 4].a;
      q += move % 2 ? 1 : -1;
      if (q < 0 || q > (1 << kChannelBits[move / 4]) - 1) continue;
      const long e = assignIndices<false>(p, ends, nullptr);
      if (e < fit.error) fit.ends = ends, fit.error = e, improved = true;
    }
    if (!improved) break;
  }
  assignIndices(p, fit.ends, &fit.index);
}

// Splits the cluster fit keeps for a look after quantization; more add little on measured sets.
constexpr int kKeptSplits = 4;

struct Split {
  int i0 = 0, i1 = 0, i2 = 0;  // clusters [0, i0), [i0, i1), [i1, i2), [i2, n) of the sorted points
  float score = -1;            // squared error the least-squares endpoints explain (larger is better)
};

// Cluster fit (libsquish's ClusterFit) on the projections: splits of the sorted points into four ordered
// clusters, ranked by the error their least-squares endpoints leave. Only splits that nearest-entry
// assignment can produce are tried (boundaries b0 < b1 < b2 evenly spaced, each in a gap): the best split
// is one for its own endpoints, and there are O(n^2) of them, not O(n^3). With prefix sums S (projections)
// and W (weights), 3 alpha.s = S[i0] + S[i1] + S[i2] = a, 3 beta.s = 3 S[n] - a, and 9 alpha^2, 9 beta^2,
// 9 alpha beta and det are exact in float.
std::array<Split, kKeptSplits> clusterFit(const ColorPoints& p, const int* order, const float* sorted) {
  const int n = p.count;
  float W[kUnitSlots + 1] = {}, S[kUnitSlots + 1] = {}, mean = 0;
  for (int i = 0; i < n; ++i)
    W[i + 1] = W[i] + float(p.weight[order[i]]), mean += float(p.weight[order[i]]) * sorted[i];
  mean /= W[n];
  for (int i = 0; i < n; ++i) S[i + 1] = S[i] + float(p.weight[order[i]]) * (sorted[i] - mean);
  std::array<Split, kKeptSplits> kept{};
  for (int i0 = 0; i0 <= n; ++i0) {
    int first = i0;  // the lowest i1 for i2; it only grows with i2
    for (int i2 = i0; i2 <= n; ++i2) {
      // b1 = (b0 + b2) / 2 with b0 in (sorted[i0 - 1], sorted[i0]] and b2 in (sorted[i2 - 1], sorted[i2]].
      while (i0 > 0 && first < i2 && sorted[first] <= 0.5f * (sorted[i0 - 1] + sorted[i2 - 1])) ++first;
      const float hi = i2 < n ? 0.5f * (sorted[i0] + sorted[i2]) : std::numeric_limits<float>::infinity();
      const float alpha0 = 5 * W[i0] + W[i2], beta0 = 9 * W[n] - W[i0] - 5 * W[i2],
                  alphaBeta = 2 * (W[i2] - W[i0]);
      const float a0 = S[i0] + S[i2], b0 = 3 * S[n] - a0;
      for (int i1 = first; i1 <= i2; ++i1) {
        const float alpha2 = alpha0 + 3 * W[i1], beta2 = beta0 - 3 * W[i1];
        const float det = alpha2 * beta2 - alphaBeta * alphaBeta, a = a0 + S[i1], b = b0 - S[i1];
        // Explained error times det (0 for one cluster: its endpoints are undetermined).
        const float explained = (beta2 * a - 2 * alphaBeta * b) * a + alpha2 * b * b;
        if (det > 0 && explained > kept[kKeptSplits - 1].score * det) {
          int k = kKeptSplits - 1;
          for (; k > 0 && explained / det > kept[k - 1].score; --k) kept[k] = kept[k - 1];
          kept[k] = {i0, i1, i2, explained / det};
        }
        if (i1 < i2 && !(sorted[i1] < hi)) break;
      }
    }
  }
  return kept;
}

// Pairs of the points' rounded colors as starts (least-squares endpoints miss solutions that endpoints on
// the data find): every pair up to this many colors, so that the unit is at least as good as any two used
// colors as endpoints (28 pairs cost ~1 us)...
constexpr int kAllPairsColors = 8;
// ...and beyond it, pairs of this many points from either end of the order.
constexpr int kExtremePoints = 2;

// Three or more colors: order along the principal axis; the kept splits' rounded least-squares endpoints
// and the pairs as starts, screened by their error with the entries re-chosen; the best refined (refining
// the second best too lowers the total error by 0.03% on measured sets, for 25% more time).
ColorFit fitColors(const ColorPoints& p) {
  glm::dvec3 mean(0.0), point[kUnitSlots];
  glm::dmat3 cov(0.0);
  for (int i = 0; i < p.count; ++i) point[i] = glm::dvec3(p.x[0][i], p.x[1][i], p.x[2][i]);
  for (int i = 0; i < p.count; ++i) mean += double(p.weight[i]) * point[i];
  mean /= double(std::accumulate(p.weight, p.weight + p.count, 0));
  for (int i = 0; i < p.count; ++i)
    cov += double(p.weight[i]) * glm::outerProduct(point[i] - mean, point[i] - mean);
  const glm::vec3 axis(dominantAxis(cov));
  alignas(16) float key[kUnitSlots];
  for (int i = 0; i < kUnitSlots; ++i)
    key[i] = i < p.count ? glm::dot(axis, glm::vec3(point[i])) : std::numeric_limits<float>::infinity();
  int order[kUnitSlots];
  float sorted[kUnitSlots];
  for (int i = 0; i < p.count; ++i) {  // ranks by counting (vectorized); equal keys keep point order
    int rank = 0;
    for (int j = 0; j < kUnitSlots; ++j) rank += int(key[j] < key[i]) | (int(key[j] == key[i]) & int(j < i));
    order[rank] = i, sorted[rank] = key[i];
  }
  ColorFit best;
  const auto keep = [&](const Ends& ends) {
    const long error = assignIndices<false>(p, ends, nullptr);
    if (error < best.error) best.ends = ends, best.error = error;
  };
  constexpr int kClusterIndex[4] = {0, 2, 3, 1};  // palette entry of each cluster, c0 to c1
  for (const Split& s : clusterFit(p, order, sorted)) {
    if (s.score < 0) break;
    Indices index{};
    for (int i = 0; i < p.count; ++i)
      index[order[i]] = kClusterIndex[(i >= s.i0) + (i >= s.i1) + (i >= s.i2)];
    Ends ends;
    for (int c = 0; c < 3; ++c) ends[c] = leastSquaresPair(channelSums(p, index, c), kChannelBits[c]);
    keep(ends);
  }
  int rounded[3][kUnitSlots];  // for the points that pair up
  for (int i = 0; i < p.count; ++i)
    for (int c = 0;
         c < 3 && (p.count <= kAllPairsColors || i < kExtremePoints || i >= p.count - kExtremePoints); ++c)
      rounded[c][order[i]] = nearestLattice(p.x[c][order[i]], kChannelBits[c]);
  const auto pair = [&](int i, int j) {
    keep({ChannelPair{rounded[0][i], rounded[0][j]},
          {rounded[1][i], rounded[1][j]},
          {rounded[2][i], rounded[2][j]}});
  };
  for (int i = 0; i < p.count && p.count <= kAllPairsColors; ++i)
    for (int j = i + 1; j < p.count; ++j) pair(i, j);
  for (int e = 0; e < kExtremePoints * kExtremePoints && p.count > kAllPairsColors; ++e)
    pair(order[e / kExtremePoints], order[p.count - 1 - e % kExtremePoints]);
  assignIndices(p, best.ends, &best.index);
  refineColors(p, best);
  return best;
}

}  // namespace

ColorUnit encodeColorUnit(const std::array<std::uint32_t, kUnitSlots>& abgr, std::uint16_t used) {
  const ColorPoints p = gatherColors(abgr, used);
  if (p.count == 0) return ColorUnit{};
  const ColorFit fit = p.count == 1 ? fitOneEntry(p) : p.count == 2 ? fitTwoColors(p) : fitColors(p);
  std::uint32_t endpoints = 0, indices = 0;
  for (int c = 0; c < 3; ++c)
    endpoints |= std::uint32_t(fit.ends[c].a | fit.ends[c].b << 16) << kChannelShift[c];
  for (int s = 0; s < kUnitSlots; ++s)
    if ((used >> s) & 1u) indices |= std::uint32_t(fit.index[p.ofSlot[s]]) << (2 * s);
  return ColorUnit{{endpoints, indices}};
}

std::uint32_t decodeColorUnit(const ColorUnit& unit, int slot) {
  const int index = int((unit.words[1] >> (2 * slot)) & 3u);
  int rgb[3];
  for (int c = 0; c < 3; ++c) {
    const int mask = (1 << kChannelBits[c]) - 1;
    const int a = expandChannel(int(unit.words[0] >> kChannelShift[c]) & mask, kChannelBits[c]);
    const int b = expandChannel(int(unit.words[0] >> (16 + kChannelShift[c])) & mask, kChannelBits[c]);
    rgb[c] = paletteValue(a, b, index);
  }
  return packABGR(std::uint8_t(rgb[0]), std::uint8_t(rgb[1]), std::uint8_t(rgb[2]));
}

}  // namespace svo
