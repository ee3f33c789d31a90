// Compressed normals (ESVO paper sec. 5.5): decoding as attribute_units.hpp documents, and an encoder that
// searches for the least-error unit. Deterministic: it uses only + - * / sqrt and floor, which IEEE platforms
// round alike, without fused multiply-adds (store/CMakeLists.txt builds with -ffp-contract=off). No heap
// allocation.
#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>

#include <immintrin.h>

#include <glm/geometric.hpp>
#include <glm/mat3x3.hpp>
#include <glm/matrix.hpp>

#include "svo/store/attribute_units.hpp"
#include "svo/store/format.hpp"
#include "unit_fit.hpp"

namespace svo {
namespace {

using unit_fit::dominantAxis;

// The encoder minimises the sum over used slots of 1 - cos(angle), as half the squared chord
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

NormalUnit encodeNormalUnit(const std::array<glm::vec3, kUnitSlots>& normals, std::uint16_t used,
                            float* squaredError) {
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
  if (squaredError) *squaredError = 0.0f;
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
    if (squaredError) *squaredError = std::numeric_limits<float>::infinity();
    return unit;
  }
  if (squaredError) *squaredError = best.error;
  unit.words[0] = best.base;
  // A zero n_u with exponent 0 (its exponent scales nothing), so that no grid unit reads as an exact one.
  unit.words[1] = (best.axes & 0x0FFFu) == 0 ? best.axes & ~0xF000u : best.axes;
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
