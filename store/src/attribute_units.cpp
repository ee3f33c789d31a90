// Compressed shading attributes (ESVO paper sec. 5.5): decoding as the header documents, and encoders that
// search for the least-error unit. The encoders are deterministic: colors are integers throughout, and
// normals use only + - * / sqrt and floor, which IEEE platforms round alike, without fused multiply-adds
// (store/CMakeLists.txt builds with -ffp-contract=off). No heap allocation.
#include "svo/store/attribute_units.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <numeric>

#include <immintrin.h>

#include <glm/geometric.hpp>
#include <glm/mat3x3.hpp>
#include <glm/matrix.hpp>

#include "svo/store/format.hpp"

namespace svo {
namespace {

// Power iterations for a dominant eigenvector: enough to order points along it and to start fits. They stop
// early once the unit vector moves less than 1e-6 (squared: kPowerConvergence) in an iteration: the fits
// only start from it (the 2M terrain's units: the same mean error to 1e-4 degrees, 0.03% of their bytes
// differ).
constexpr int kPowerIterations = 16;
constexpr double kPowerConvergence = 1e-12;
// Bound on the lattice climbs; from a rounded continuous optimum they move a step or two in practice.
constexpr int kMaxClimbSteps = 16;

// The dominant eigenvector of a covariance matrix (unit length; zero where the matrix is), by power
// iteration from its largest column, which lies in its range.
glm::dvec3 dominantAxis(const glm::dmat3& c) {
  int column = 0;
  for (int k = 1; k < 3; ++k) column = glm::dot(c[k], c[k]) > glm::dot(c[column], c[column]) ? k : column;
  double length = glm::length(c[column]);
  if (!(length > 0.0)) return glm::dvec3(0.0);
  glm::dvec3 v = c[column] / length;
  for (int it = 0; it < kPowerIterations; ++it) {
    const glm::dvec3 w = c * v;
    length = glm::length(w);
    if (!(length > 0.0)) return glm::dvec3(0.0);
    const glm::dvec3 next = w / length, moved = next - v;
    v = next;
    if (glm::dot(moved, moved) < kPowerConvergence) break;
  }
  return v;
}

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

// ---------------------------------------------------------------------------------------------------------
// Colors. A channel's endpoint is a lattice value (5 bits red and blue, 6 bits green) expanded to 8 bits by
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

// ---------------------------------------------------------------------------------------------------------
// Normals. The encoder minimises the sum over used slots of 1 - cos(angle), as half the squared chord
// |decoded - target|^2 (precise in float at small angles). Fits work on points whose directions are the
// targets: the grid n_b + c_u n_u + c_v n_v is linear in its vectors, and decoding keeps only directions.

constexpr float kSelectorValue[4] = {-1.0f, -1.0f / 3.0f, 1.0f / 3.0f, 1.0f};  // c_u, c_v by 2-bit code
constexpr int kMantissaMin = -8, kMantissaMax = 7;                             // signed 4 bits
constexpr int kExponentMax = 15;                                               // 4 bits

// 2^(e - kNormalAxisExponentBias), exact in float.
constexpr float axisScale(int e) {
  return e >= kNormalAxisExponentBias ? float(1 << (e - kNormalAxisExponentBias))
                                      : 1.0f / float(1 << (kNormalAxisExponentBias - e));
}

// An axis vector from its 16 bits: signed 4-bit mantissas times the exponent's scale, exact in float.
glm::vec3 axisVector(std::uint32_t bits) {
  const float scale = axisScale(int((bits >> 12) & 15u));
  const auto mantissa = [&](int shift) { return float(std::int32_t(bits << (28 - shift)) >> 28); };
  return glm::vec3(mantissa(0) * scale, mantissa(4) * scale, mantissa(8) * scale);
}

// The decoded normal, in this order of float operations (a GLSL port keeps it, `precise` against fused
// multiply-adds): n = (n_b + c_u * n_u) + c_v * n_v per component, then n * (1 / sqrt((n.x * n.x + n.y *
// n.y) + n.z * n.z)) (glm::normalize); n_b alone, normalized, where the sum is zero or not finite.
glm::vec3 gridNormal(const glm::vec3& nb, const glm::vec3& nu, const glm::vec3& nv, unsigned selector) {
  const glm::vec3 n = nb + kSelectorValue[selector & 3u] * nu + kSelectorValue[selector >> 2] * nv;
  const float length2 = glm::dot(n, n);
  return !(length2 > 0.0f) || !std::isfinite(length2) ? glm::normalize(nb) : glm::normalize(n);
}

using Selectors = std::array<std::uint8_t, kUnitSlots>;  // per target

struct NormalTargets {  // the used slots' normals, unit length
  int count = 0;
  std::array<int, kUnitSlots> slot{};
  std::array<glm::dvec3, kUnitSlots> dir{};
};

struct Grid {  // continuous, in the scale of the fit's points
  static double cu(unsigned selector) { return kSelectorValue[selector & 3u]; }
  static double cv(unsigned selector) { return kSelectorValue[selector >> 2]; }
  glm::dvec3 nb{0.0}, nu{0.0}, nv{0.0};
  glm::dvec3 point(unsigned selector) const { return nb + cu(selector) * nu + cv(selector) * nv; }
};

// Ridge on the axes per point: an axis its selectors do not vary along stays at zero, and a determined
// axis moves by ~1e-7 of its length.
constexpr double kAxisRidge = 1e-7;

// A quantized unit: its words, the decoded vectors, the targets' selectors and their error.
struct QuantizedGrid {
  std::uint32_t base = 0, axes = 0;
  glm::vec3 nb{0.0f}, nu{0.0f}, nv{0.0f};
  Selectors selector{};
  float error = std::numeric_limits<float>::infinity();
};

// Each target's best selector among the 16 decoded normals (the lowest on ties), and the total error. The
// candidates are kept by coordinate, four to an SSE register (register k: c_v = kSelectorValue[k] and the
// four c_u, as selector 4 k + j), so that a target's 16 errors and their least take a few vector operations
// and no branch; each is glm::dot's (dx * dx + dy * dy) + dz * dz, as the scalar operations round.
void evaluate(QuantizedGrid& q, const NormalTargets& t) {
  constexpr int kCandidates = 16, kRegisters = kCandidates / 4;
  __m128 cx[kRegisters], cy[kRegisters], cz[kRegisters];
  const __m128 cu = _mm_setr_ps(kSelectorValue[0], kSelectorValue[1], kSelectorValue[2], kSelectorValue[3]);
  bool degenerate = false;
  for (int k = 0; k < kRegisters; ++k) {  // gridNormal's operations, by coordinate
    const __m128 cv = _mm_set1_ps(kSelectorValue[k]);
    const auto coordinate = [&](float b, float u, float v) {
      return _mm_add_ps(_mm_add_ps(_mm_set1_ps(b), _mm_mul_ps(cu, _mm_set1_ps(u))),
                        _mm_mul_ps(cv, _mm_set1_ps(v)));
    };
    const __m128 x = coordinate(q.nb.x, q.nu.x, q.nv.x), y = coordinate(q.nb.y, q.nu.y, q.nv.y),
                 z = coordinate(q.nb.z, q.nu.z, q.nv.z);
    const __m128 length2 = _mm_add_ps(_mm_add_ps(_mm_mul_ps(x, x), _mm_mul_ps(y, y)), _mm_mul_ps(z, z));
    const __m128 scale = _mm_div_ps(_mm_set1_ps(1.0f), _mm_sqrt_ps(length2));
    const __m128 finite = _mm_and_ps(_mm_cmpgt_ps(length2, _mm_setzero_ps()),  // false for NaN
                                     _mm_cmple_ps(length2, _mm_set1_ps(std::numeric_limits<float>::max())));
    degenerate |= _mm_movemask_ps(finite) != 15;
    cx[k] = _mm_mul_ps(x, scale), cy[k] = _mm_mul_ps(y, scale), cz[k] = _mm_mul_ps(z, scale);
  }
  if (degenerate) {
    alignas(16) float x[kCandidates], y[kCandidates], z[kCandidates];
    for (unsigned s = 0; s < kCandidates; ++s) {
      const glm::vec3 c = gridNormal(q.nb, q.nu, q.nv, s);
      x[s] = c.x, y[s] = c.y, z[s] = c.z;
    }
    for (int k = 0; k < kRegisters; ++k)
      cx[k] = _mm_load_ps(x + 4 * k), cy[k] = _mm_load_ps(y + 4 * k), cz[k] = _mm_load_ps(z + 4 * k);
  }
  q.error = 0.0f;
  for (int i = 0; i < t.count; ++i) {
    const glm::vec3 target(t.dir[i]);
    const __m128 tx = _mm_set1_ps(target.x), ty = _mm_set1_ps(target.y), tz = _mm_set1_ps(target.z);
    __m128 e[kRegisters];
    for (int k = 0; k < kRegisters; ++k) {
      const __m128 dx = _mm_sub_ps(cx[k], tx), dy = _mm_sub_ps(cy[k], ty), dz = _mm_sub_ps(cz[k], tz);
      e[k] = _mm_add_ps(_mm_add_ps(_mm_mul_ps(dx, dx), _mm_mul_ps(dy, dy)), _mm_mul_ps(dz, dz));
    }
    __m128 least = _mm_min_ps(_mm_min_ps(e[0], e[1]), _mm_min_ps(e[2], e[3]));
    least = _mm_min_ps(least, _mm_shuffle_ps(least, least, _MM_SHUFFLE(2, 3, 0, 1)));
    least = _mm_min_ps(least, _mm_shuffle_ps(least, least, _MM_SHUFFLE(1, 0, 3, 2)));
    unsigned withLeast = 0;
    for (int k = 0; k < kRegisters; ++k)
      withLeast |= unsigned(_mm_movemask_ps(_mm_cmpeq_ps(e[k], least))) << (4 * k);
    q.selector[i] = std::uint8_t(std::countr_zero(withLeast));
    q.error += _mm_cvtss_f32(least);
  }
}

// The quantized unit nearest the points for fixed selectors (n_b fixed where `base` is given). With n_b
// eliminated the squared distance is one quadratic per coordinate in its two mantissas; for each axis's
// finest fitting exponent or one coarser, each coordinate searches from its rounded continuous optimum. n_b
// is then the mean residual. False where n_b has no direction.
bool quantizedFit(const glm::dvec3* points, const Selectors& sel, int n, const glm::dvec3* base,
                  QuantizedGrid& q) {
  // The axes' normal equations: with n_b free, selectors and points centred (n_b is the mean residual);
  // with n_b fixed, points relative to it.
  double meanU = 0, meanV = 0, uu = kAxisRidge * n, uv = 0, vv = kAxisRidge * n;
  glm::dvec3 origin = base ? *base : glm::dvec3(0.0), bu(0.0), bv(0.0);
  for (int i = 0; i < n && !base; ++i)
    meanU += Grid::cu(sel[i]) / n, meanV += Grid::cv(sel[i]) / n, origin += points[i] / double(n);
  for (int i = 0; i < n; ++i) {
    const double cu = Grid::cu(sel[i]) - meanU, cv = Grid::cv(sel[i]) - meanV;
    uu += cu * cu, uv += cu * cv, vv += cv * cv, bu += cu * (points[i] - origin),
        bv += cv * (points[i] - origin);
  }
  const glm::dvec3 u = (bu * vv - bv * uv) / (uu * vv - uv * uv),
                   v = (bv * uu - bu * uv) / (uu * vv - uv * uv);
  const auto mantissa = [](double x, int e) {
    return int(std::clamp(std::floor(x / axisScale(e) + 0.5), double(kMantissaMin), double(kMantissaMax)));
  };
  const auto finest = [](const glm::dvec3& a) {  // the smallest exponent whose mantissas fit
    int e = 0;
    while (e < kExponentMax && (std::max({a.x, a.y, a.z}) >= (kMantissaMax + 0.5) * axisScale(e) ||
                                std::min({a.x, a.y, a.z}) < (kMantissaMin - 0.5) * axisScale(e)))
      ++e;
    return e;
  };
  const int eu0 = finest(u), ev0 = finest(v);
  // A coarser exponent adds only values beyond the finer one's range (its others are the finer one's even
  // mantissas), so an axis tries it only where its finest fit holds a mantissa at an end of the range.
  bool coarserU = false, coarserV = false;
  const auto atEnd = [](int m) { return m == kMantissaMin || m == kMantissaMax; };
  double best = std::numeric_limits<double>::infinity();
  for (int eu = eu0; eu <= std::min(eu0 + 1, kExponentMax); ++eu)
    for (int ev = ev0; ev <= std::min(ev0 + 1, kExponentMax); ++ev) {
      if ((eu > eu0 && !coarserU) || (ev > ev0 && !coarserV)) continue;
      const double su = axisScale(eu), sv = axisScale(ev), h[3] = {uu * su * su, uv * su * sv, vv * sv * sv};
      const double inverseH2 = 1.0 / h[2];
      std::uint32_t axes = std::uint32_t(eu) << 12 | std::uint32_t(ev) << 28;
      double total = 0.0;
      for (int k = 0; k < 3; ++k) {
        const double d[2] = {bu[k] * su, bv[k] * sv};
        const auto f = [&](int mu, int mv) {  // m^T H m - 2 d.m
          return (h[0] * mu + 2.0 * h[1] * mv) * mu + h[2] * mv * mv - 2.0 * (d[0] * mu + d[1] * mv);
        };
        // For a given m_u, f is a convex quadratic in m_v: its best m_v is the real minimiser, rounded
        // and clamped. From the rounded continuous optimum's m_u, m_u moves while a neighbour's best pair
        // is better.
        const auto bestV = [&](int mu) {
          return int(std::clamp(std::floor((d[1] - h[1] * mu) * inverseH2 + 0.5), double(kMantissaMin),
                                double(kMantissaMax)));
        };
        int m[2] = {mantissa(u[k], eu), 0};
        m[1] = bestV(m[0]);
        double least = f(m[0], m[1]);
        for (const int direction : {-1, 1})
          for (int mu = m[0] + direction; mu >= kMantissaMin && mu <= kMantissaMax; mu += direction) {
            const int mv = bestV(mu);
            const double e = f(mu, mv);
            if (!(e < least)) break;
            least = e, m[0] = mu, m[1] = mv;
          }
        total += least;
        axes |= std::uint32_t(m[0] & 15) << (4 * k) | std::uint32_t(m[1] & 15) << (16 + 4 * k);
        if (eu == eu0 && ev == ev0) coarserU |= atEnd(m[0]), coarserV |= atEnd(m[1]);
      }
      if (total < best) best = total, q.axes = axes;
    }
  q.nu = axisVector(q.axes & 0xFFFFu), q.nv = axisVector(q.axes >> 16);
  const glm::dvec3 nb = origin - meanU * glm::dvec3(q.nu) - meanV * glm::dvec3(q.nv);
  const double big = std::max({std::abs(nb.x), std::abs(nb.y), std::abs(nb.z)});
  if (!(big > 0.0) || !std::isfinite(big)) return false;
  q.base = encodeNormal(glm::vec3(nb / big));
  q.nb = normalDirection(q.base);
  return true;
}

// Rounds of quantized refits to the decoded unit, kept while its decoded error drops.
constexpr int kQuantizedRounds = 3;

// From a starting grid: the targets' best selectors on it, their quantized fit, then refits to the decoded
// unit's selectors with each target's point on its ray nearest the decoded grid point (the fit then
// measures distances across rays). With `fixedBase` n_b stays.
QuantizedGrid refineGrid(const Grid& g, const glm::dvec3* points, const NormalTargets& t, bool fixedBase) {
  const int n = t.count;
  QuantizedGrid best;
  const double big = std::max({std::abs(g.nb.x), std::abs(g.nb.y), std::abs(g.nb.z)});
  if (!(big > 0.0) || !std::isfinite(big)) return best;
  const glm::dvec3 base = g.nb / big;  // n_b on the unit cube, as the quantized unit's
  glm::dvec3 scaled[kUnitSlots];
  for (int i = 0; i < n; ++i) scaled[i] = points[i] / big;
  QuantizedGrid start;
  start.nb = glm::vec3(base), start.nu = glm::vec3(g.nu / big), start.nv = glm::vec3(g.nv / big);
  evaluate(start, t);
  if (!quantizedFit(scaled, start.selector, n, fixedBase ? &base : nullptr, best)) return best;
  evaluate(best, t);
  for (int round = 0; round < kQuantizedRounds; ++round) {
    const Grid decoded{glm::dvec3(best.nb), glm::dvec3(best.nu), glm::dvec3(best.nv)};
    for (int i = 0; i < n; ++i) {
      const glm::dvec3 p = decoded.point(best.selector[i]);
      const double along = glm::dot(p, t.dir[i]);
      scaled[i] = t.dir[i] * (along > 0.0 ? along : glm::length(p));
    }
    QuantizedGrid q;
    if (!quantizedFit(scaled, best.selector, n, fixedBase ? &decoded.nb : nullptr, q)) break;
    evaluate(q, t);
    if (!(q.error < best.error)) break;
    best = q;
  }
  return best;
}

// Targets within 60 degrees of the mean go onto the plane through it (angles stretch by 1 / cos^2 <= 4);
// wider sets are fitted on the unit sphere, also around one target.
constexpr double kPlanarMinCos = 0.5;

// The grid spanning the points' bounding box in their principal frame (selectors +-1 at its faces), or
// around point `pivot` >= 0 reaching the farthest (the paper's normals in very different directions: one
// of them as n_b, the axes reaching the others).
Grid startGrid(const glm::dvec3* points, int n, int pivot) {
  glm::dvec3 centre(0.0);
  for (int i = 0; i < n; ++i) centre += points[i] / double(n);
  glm::dmat3 c(0.0);
  for (int i = 0; i < n; ++i) c += glm::outerProduct(points[i] - centre, points[i] - centre);
  const glm::dvec3 e1 = dominantAxis(c);
  glm::dvec3 e2 = dominantAxis(c - glm::dot(e1, c * e1) * glm::outerProduct(e1, e1));
  e2 -= glm::dot(e2, e1) * e1;
  e2 = glm::length(e2) > 0.0 ? glm::normalize(e2) : glm::dvec3(0.0);
  double lo[2] = {0.0, 0.0}, hi[2] = {0.0, 0.0};
  const glm::dvec3 origin = pivot >= 0 ? points[pivot] : centre;
  for (int i = 0; i < n; ++i)
    for (int k = 0; k < 2; ++k) {
      const double s = glm::dot(points[i] - origin, k == 0 ? e1 : e2);
      lo[k] = std::min(lo[k], s), hi[k] = std::max(hi[k], s);
    }
  if (pivot >= 0) return {origin, std::max(-lo[0], hi[0]) * e1, std::max(-lo[1], hi[1]) * e2};
  return {origin + 0.5 * (lo[0] + hi[0]) * e1 + 0.5 * (lo[1] + hi[1]) * e2, 0.5 * (hi[0] - lo[0]) * e1,
          0.5 * (hi[1] - lo[1]) * e2};
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

NormalUnit encodeNormalUnit(const std::array<glm::vec3, kUnitSlots>& normals, std::uint16_t used) {
  NormalTargets t;
  glm::dvec3 sum(0.0);
  for (int s = 0; s < kUnitSlots; ++s) {
    if (!((used >> s) & 1u)) continue;
    glm::dvec3 n(normals[s]);  // divided by its largest component first: tiny vectors do not underflow
    const double big = std::max({std::abs(n.x), std::abs(n.y), std::abs(n.z)});
    n = big > 0.0 && std::isfinite(big) ? glm::normalize(n / big) : glm::dvec3(0.0, 0.0, 1.0);
    t.slot[t.count] = s, t.dir[t.count++] = n, sum += n;
  }
  NormalUnit unit;
  unit.words[0] = encodeNormal(glm::vec3(0.0f, 0.0f, 1.0f));
  if (t.count == 0) return unit;
  // Directions that cancel (an antipodal pair) have no mean: the first stands in.
  const glm::dvec3 mean = glm::length(sum) > 0.0 ? glm::normalize(sum) : t.dir[0];
  double minCos = 1.0;
  int pivot = 0;
  for (int i = 0; i < t.count; ++i) {
    minCos = std::min(minCos, glm::dot(t.dir[i], mean));
    if (glm::dot(t.dir[i], mean) > glm::dot(t.dir[pivot], mean)) pivot = i;
  }
  glm::dvec3 points[kUnitSlots];
  const bool planar = minCos >= kPlanarMinCos;
  for (int i = 0; i < t.count; ++i) points[i] = planar ? t.dir[i] / glm::dot(t.dir[i], mean) : t.dir[i];
  QuantizedGrid best = refineGrid(startGrid(points, t.count, -1), points, t, false);
  if (!planar) {
    const QuantizedGrid pivoted = refineGrid(startGrid(points, t.count, pivot), points, t, true);
    if (pivoted.error < best.error) best = pivoted;
  }
  if (!(best.error < std::numeric_limits<float>::infinity())) {  // no fit had a base direction
    unit.words[0] = encodeNormal(glm::vec3(mean));
    return unit;
  }
  unit.words[0] = best.base;
  unit.words[1] = best.axes;
  for (int i = 0; i < t.count; ++i)
    unit.words[2 + t.slot[i] / 8] |= std::uint32_t(best.selector[i]) << (4 * (t.slot[i] % 8));
  return unit;
}

glm::vec3 decodeNormalUnit(const NormalUnit& unit, int slot) {
  const unsigned selector = (unit.words[2 + slot / 8] >> (4 * (slot % 8))) & 15u;
  return gridNormal(normalDirection(unit.words[0]), axisVector(unit.words[1] & 0xFFFFu),
                    axisVector(unit.words[1] >> 16), selector);
}

}  // namespace svo
