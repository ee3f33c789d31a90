// Procedural scenes for `svo gen` and their binary PLY output. Every random number comes from a counter-based
// hash of (seed, stream, index), so each row, building or tube is generated independently of the others:
// the mesh is the same for any thread count and the work parallelizes without coordination.
#include "svo/builder/gen.hpp"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <vector>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <glm/geometric.hpp>
#include <glm/vec4.hpp>

namespace svo {

namespace {

// ----- deterministic randomness ----------------------------------------------------------------------------

// SplitMix64's finalizer (Steele, Lea & Flood 2014): a bijective 64-bit mix with full avalanche.
std::uint64_t mix(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

std::uint64_t hash(std::uint64_t seed, std::uint64_t a, std::uint64_t b = 0, std::uint64_t c = 0) {
  return mix(mix(mix(mix(seed) ^ a) ^ b) ^ c);
}

// [0, 1) from the top 53 bits.
double unit(std::uint64_t bits) {
  return double(bits >> 11) * 0x1.0p-53;
}

// A sequence of uniform numbers for one item (a building, a tube): item i of stream s under the seed.
class Random {
 public:
  Random(std::uint64_t seed, std::uint64_t stream, std::uint64_t item) : state_(hash(seed, stream, item)) {}
  double uniform() { return unit(mix(state_++)); }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  // Uniform direction on the unit sphere (Marsaglia's z / angle method).
  glm::dvec3 direction() {
    const double z = uniform(-1.0, 1.0), a = uniform(0.0, 2.0 * std::numbers::pi);
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    return {r * std::cos(a), r * std::sin(a), z};
  }

 private:
  std::uint64_t state_;
};

// Stream ids: different uses of the same seed draw unrelated numbers.
enum Stream : std::uint64_t { kNoiseStream = 1, kBuildingStream, kTubeStream };

// ----- fractal value noise ---------------------------------------------------------------------------------

// Value noise on the integer lattice, quintic-smoothed trilinear interpolation: in [0, 1).
double valueNoise(std::uint64_t seed, glm::dvec3 p) {
  const glm::dvec3 f = glm::floor(p);
  const glm::dvec3 t = p - f;
  const glm::dvec3 s = t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
  const auto lattice = [&](int dx, int dy, int dz) {
    return unit(hash(seed, std::uint64_t(std::int64_t(f.x) + dx), std::uint64_t(std::int64_t(f.y) + dy),
                     std::uint64_t(std::int64_t(f.z) + dz)));
  };
  const auto lerp = [](double a, double b, double w) { return a + (b - a) * w; };
  const double x00 = lerp(lattice(0, 0, 0), lattice(1, 0, 0), s.x);
  const double x10 = lerp(lattice(0, 1, 0), lattice(1, 1, 0), s.x);
  const double x01 = lerp(lattice(0, 0, 1), lattice(1, 0, 1), s.x);
  const double x11 = lerp(lattice(0, 1, 1), lattice(1, 1, 1), s.x);
  return lerp(lerp(x00, x10, s.y), lerp(x01, x11, s.y), s.z);
}

// Fractional Brownian motion: octaves of value noise, each at twice the frequency and half the amplitude
// (persistence 1/2, lacunarity 2: the usual 1/f spectrum of natural terrain), normalized into [0, 1).
double fbm(std::uint64_t seed, glm::dvec3 p, int octaves) {
  double sum = 0.0, amplitude = 1.0, total = 0.0;
  for (int o = 0; o < octaves; ++o) {
    sum += amplitude * valueNoise(hash(seed, kNoiseStream, std::uint64_t(o)), p);
    total += amplitude;
    amplitude *= 0.5;
    p *= 2.0;
  }
  return sum / total;
}

// Octaves from a base frequency (lattice cells across the scene) until one lattice cell is about one mesh
// cell: finer octaves would alias. At least one octave.
int octavesFor(double baseFrequency, double meshCells) {
  // More octaves than this add amplitude below 2^-kMaxOctaves: nothing a float coordinate keeps.
  constexpr int kMaxOctaves = 20;
  return std::clamp(int(std::floor(std::log2(std::max(1.0, meshCells / baseFrequency)))) + 1, 1, kMaxOctaves);
}

// ----- small helpers ---------------------------------------------------------------------------------------

// What a float PLY stores: positions are rounded to float once, here, so the mesh equals its file. Through
// volatile floats: g++ 12's SLP vectorizer at -O2 and above drops a plain double -> float -> double round
// trip of a vector's components (seen in gen.cpp's sphere; tests/unit/test_gen.cpp catches it).
glm::dvec3 floatExact(glm::dvec3 p) {
  volatile float x = static_cast<float>(p.x), y = static_cast<float>(p.y), z = static_cast<float>(p.z);
  return {double(x), double(y), double(z)};
}

glm::vec4 rgb(double r, double g, double b) {
  return {float(r), float(g), float(b), 1.0f};
}

glm::vec4 mixColor(glm::vec4 a, glm::vec4 b, double t) {
  return a + (b - a) * float(std::clamp(t, 0.0, 1.0));
}

// Reports progress from worker threads every `step` items.
class Progress {
 public:
  Progress(const std::function<void(double)>& report, std::uint64_t total)
      : report_(report), total_(std::max<std::uint64_t>(total, 1)) {}
  void add(std::uint64_t items) {
    if (!report_) return;
    const std::uint64_t done = done_.fetch_add(items) + items;
    report_(double(done) / double(total_));
  }

 private:
  const std::function<void(double)>& report_;
  std::uint64_t total_;
  std::atomic<std::uint64_t> done_{0};
};

// Rows, buildings or tubes handed to the workers together: enough work per task to hide scheduling.
constexpr std::size_t kGrain = 64;

template <class F>
void parallelItems(std::uint64_t count, Progress& progress, F&& item) {
  tbb::parallel_for(tbb::blocked_range<std::uint64_t>(0, count, kGrain),
                    [&](const tbb::blocked_range<std::uint64_t>& r) {
                      for (std::uint64_t i = r.begin(); i != r.end(); ++i) item(i);
                      progress.add(r.size());
                    });
}

// ----- terrain: an fBm heightfield over a square grid ------------------------------------------------------

// Lattice cells across the terrain at the first octave: a few hills and valleys.
constexpr double kTerrainBaseFrequency = 4.0;

Mesh terrain(const GenOptions& o) {
  // 2 c^2 triangles for c x c cells.
  const std::uint64_t c = std::max<std::uint64_t>(1, std::llround(std::sqrt(double(o.triangles) / 2.0)));
  const std::uint64_t n = c + 1;
  Mesh mesh;
  mesh.positions.resize(n * n);
  mesh.colors.resize(n * n);
  mesh.triangles.resize(2 * c * c);
  const int octaves = octavesFor(kTerrainBaseFrequency, double(c));
  Progress progress(o.progress, 2 * n);
  std::vector<double> rowMin(n), rowMax(n);
  parallelItems(n, progress, [&](std::uint64_t j) {
    double lo = 1.0, hi = 0.0;
    for (std::uint64_t i = 0; i < n; ++i) {
      const double x = -1.0 + 2.0 * double(i) / double(c), z = -1.0 + 2.0 * double(j) / double(c);
      // Squaring the noise flattens the valleys and sharpens the peaks, like eroded terrain.
      const double f = fbm(
          o.seed,
          glm::dvec3((x + 1.0) * 0.5 * kTerrainBaseFrequency, (z + 1.0) * 0.5 * kTerrainBaseFrequency, 0.5),
          octaves);
      const double h = f * f;
      mesh.positions[j * n + i] = glm::dvec3(x, h, z);
      lo = std::min(lo, h), hi = std::max(hi, h);
    }
    rowMin[j] = lo, rowMax[j] = hi;
  });
  const double lo = *std::min_element(rowMin.begin(), rowMin.end());
  const double hi = *std::max_element(rowMax.begin(), rowMax.end());
  const double scale = hi > lo ? kTerrainHeight / (hi - lo) : 0.0;
  const glm::vec4 grass = rgb(0.10, 0.30, 0.05), rock = rgb(0.30, 0.22, 0.15), snow = rgb(0.90, 0.90, 0.95);
  parallelItems(n, progress, [&](std::uint64_t j) {
    for (std::uint64_t i = 0; i < n; ++i) {
      glm::dvec3& p = mesh.positions[j * n + i];
      // Normalized so that the lowest point is at 0 and the highest at kTerrainHeight exactly.
      p.y = p.y == hi ? kTerrainHeight : std::min(kTerrainHeight, (p.y - lo) * scale);
      p = floatExact(p);
      const double t = p.y / kTerrainHeight;
      mesh.colors[j * n + i] =
          t < 0.6 ? mixColor(grass, rock, t / 0.6) : mixColor(rock, snow, (t - 0.6) / 0.4);
    }
    if (j == c) return;
    for (std::uint64_t i = 0; i < c; ++i) {
      const auto v = [&](std::uint64_t di, std::uint64_t dj) { return std::uint32_t((j + dj) * n + i + di); };
      glm::uvec3* t = &mesh.triangles[2 * (j * c + i)];
      t[0] = {v(0, 0), v(0, 1), v(1, 0)};
      t[1] = {v(1, 0), v(0, 1), v(1, 1)};
    }
  });
  return mesh;
}

// ----- city: boxes of random heights on a ground plane -----------------------------------------------------

// Triangles per building: four walls and a roof, two triangles each (the floor is the ground plane).
constexpr std::uint64_t kBuildingTriangles = 10;
// Footprint as a fraction of the building's grid cell: the rest is street.
constexpr double kMinFootprint = 0.5, kMaxFootprint = 0.85;
// Heights in cell widths: low houses to towers, skewed towards low (cubed uniform) as in real skylines.
constexpr double kMinStoreys = 0.5, kMaxStoreys = 12.0;
// Downtown: heights up to (1 + kDowntownBoost) times taller at the centre, within about kDowntownRadius of it
// (a third of the city's half-width: a visible skyline, suburbs around it).
constexpr double kDowntownBoost = 3.0, kDowntownRadius = 0.35;

Mesh city(const GenOptions& o) {
  const std::uint64_t buildings =
      std::max<std::uint64_t>(1, std::llround(double(o.triangles - 2) / double(kBuildingTriangles)));
  const std::uint64_t g = std::uint64_t(std::ceil(std::sqrt(double(buildings))));
  const double cell = 2.0 / double(g);
  Mesh mesh;
  mesh.positions.resize(4 + 8 * buildings);
  mesh.colors.resize(mesh.positions.size());
  mesh.triangles.resize(2 + kBuildingTriangles * buildings);
  const glm::vec4 asphalt = rgb(0.05, 0.05, 0.06);
  for (int k = 0; k < 4; ++k) {
    mesh.positions[k] = glm::dvec3(k & 1 ? 1.0 : -1.0, 0.0, k & 2 ? 1.0 : -1.0);
    mesh.colors[k] = asphalt;
  }
  mesh.triangles[0] = {0, 2, 1};
  mesh.triangles[1] = {1, 2, 3};
  Progress progress(o.progress, buildings);
  parallelItems(buildings, progress, [&](std::uint64_t b) {
    Random r(o.seed, kBuildingStream, b);
    const double x0 = -1.0 + cell * double(b % g), z0 = -1.0 + cell * double(b / g);
    const double w = cell * r.uniform(kMinFootprint, kMaxFootprint);
    const double d = cell * r.uniform(kMinFootprint, kMaxFootprint);
    const double left = x0 + r.uniform(0.0, cell - w), front = z0 + r.uniform(0.0, cell - d);
    const double u = r.uniform();
    // Downtown: towers grow towards the centre, falling off with a Gaussian of kDowntownRadius.
    const double cx = left + 0.5 * w, cz = front + 0.5 * d;
    const double downtown =
        1.0 + kDowntownBoost * std::exp(-(cx * cx + cz * cz) / (kDowntownRadius * kDowntownRadius));
    const double storeys = (kMinStoreys + (kMaxStoreys - kMinStoreys) * u * u * u) * downtown;
    const double h = std::min(kCityMaxHeight, cell * storeys);
    // Concrete greys to glass blues, roofs darker than the street level.
    const double shade = r.uniform(0.25, 0.75), blue = r.uniform(0.0, 0.25);
    const glm::vec4 wall = rgb(shade, shade, std::min(1.0, shade + blue));
    const glm::vec4 roof = rgb(0.6 * wall.r, 0.6 * wall.g, 0.6 * wall.b);
    const std::uint32_t base = std::uint32_t(4 + 8 * b);
    for (int k = 0; k < 8; ++k) {
      // Corner k: x from bit 0, z from bit 1, top from bit 2.
      mesh.positions[base + k] =
          floatExact({k & 1 ? left + w : left, k & 4 ? h : 0.0, k & 2 ? front + d : front});
      mesh.colors[base + k] = k & 4 ? roof : wall;
    }
    // Outward-facing quads (a, b, c, d counter-clockwise seen from outside), two triangles each.
    static constexpr std::array<std::array<std::uint32_t, 4>, 5> kFaces = {
        {{0, 4, 5, 1}, {1, 5, 7, 3}, {3, 7, 6, 2}, {2, 6, 4, 0}, {4, 6, 7, 5}}};
    glm::uvec3* t = &mesh.triangles[2 + kBuildingTriangles * b];
    for (const auto& f : kFaces) {
      *t++ = {base + f[0], base + f[1], base + f[2]};
      *t++ = {base + f[0], base + f[2], base + f[3]};
    }
  });
  return mesh;
}

// ----- hairball: thin tubes along random smooth curves -----------------------------------------------------

// Sides of a tube's cross-section: a hexagon is the fewest that still reads as round.
constexpr std::uint64_t kTubeSides = 6;
// Segments per tube for large targets: enough rings to follow the curve's bends smoothly.
constexpr std::uint64_t kSegmentsPerTube = 128;
// Tube radius: thin against the unit ball (a 1024^3 grid over the scene has voxels of ~0.002).
constexpr double kTubeRadius = 0.003;
// Harmonics of a tube's closed Fourier curve, and the part of the loop a tube follows.
constexpr int kHarmonics = 3;
constexpr double kTubeSpan = 0.8;
// Dense samples per ring for the arc-length parametrization: rings end up equally spaced along the curve.
constexpr std::uint64_t kSamplesPerRing = 8;
// Kept from promised bounds so that rounding positions to float cannot cross them.
constexpr double kFloatMargin = 1e-6;

struct Frame {
  glm::dvec3 normal, binormal;
};

// Any unit vector perpendicular to the unit vector t.
glm::dvec3 perpendicular(glm::dvec3 t) {
  const glm::dvec3 axis = std::abs(t.x) < 0.6 ? glm::dvec3(1, 0, 0) : glm::dvec3(0, 1, 0);
  return glm::normalize(glm::cross(t, axis));
}

void tube(const GenOptions& o, std::uint64_t index, std::uint64_t segments, Mesh& mesh) {
  Random r(o.seed, kTubeStream, index);
  // c(t) = centre + sum_k a_k cos(2 pi k t) + b_k sin(2 pi k t), amplitudes falling as 1/k; scaled so that
  // |centre| + sum |a_k| + |b_k| <= 1 - radius: the whole tube stays in the unit ball.
  std::array<glm::dvec3, 2 * kHarmonics> coefficients;
  double reach = 0.0;
  for (int k = 0; k < kHarmonics; ++k)
    for (int j = 0; j < 2; ++j) {
      coefficients[2 * k + j] = r.direction() * (r.uniform(0.5, 1.0) / (k + 1));
      reach += glm::length(coefficients[2 * k + j]);
    }
  const glm::dvec3 centre = r.direction() * r.uniform(0.0, 0.3);
  const double scale = (1.0 - kTubeRadius - kFloatMargin - glm::length(centre)) / reach;
  const double start = r.uniform();
  const auto curve = [&](double s) {
    const double t = start + kTubeSpan * s;
    glm::dvec3 p = centre;
    for (int k = 0; k < kHarmonics; ++k) {
      const double a = 2.0 * std::numbers::pi * (k + 1) * t;
      p += scale * (coefficients[2 * k] * std::cos(a) + coefficients[2 * k + 1] * std::sin(a));
    }
    return p;
  };
  // Arc-length parametrization from dense samples.
  const std::uint64_t samples = segments * kSamplesPerRing;
  std::vector<glm::dvec3> dense(samples + 1);
  std::vector<double> length(samples + 1, 0.0);
  for (std::uint64_t i = 0; i <= samples; ++i) {
    dense[i] = curve(double(i) / double(samples));
    if (i) length[i] = length[i - 1] + glm::distance(dense[i], dense[i - 1]);
  }
  std::vector<glm::dvec3> rings(segments + 1);
  std::uint64_t k = 0;
  for (std::uint64_t i = 0; i <= segments; ++i) {
    const double target = length.back() * double(i) / double(segments);
    while (k + 1 < samples && length[k + 1] < target) ++k;
    const double span = length[k + 1] - length[k];
    const double w = span > 0.0 ? std::clamp((target - length[k]) / span, 0.0, 1.0) : 0.0;
    rings[i] = dense[k] + (dense[k + 1] - dense[k]) * w;
  }
  // Rotation-minimizing frames by parallel transport: the previous normal projected onto the new ring plane.
  const std::uint64_t firstVertex = index * (segments + 1) * kTubeSides;
  const glm::vec4 color = [&] {
    const double hue = r.uniform(0.0, 6.0);
    const auto channel = [&](double offset) {
      return std::clamp(std::abs(std::fmod(hue + offset, 6.0) - 3.0) - 1.0, 0.0, 1.0);
    };
    return mixColor(rgb(channel(0.0), channel(4.0), channel(2.0)), rgb(1, 1, 1), 0.2);
  }();
  Frame frame{};
  for (std::uint64_t i = 0; i <= segments; ++i) {
    const glm::dvec3 t = glm::normalize(rings[std::min(i + 1, segments)] - rings[i == 0 ? 0 : i - 1]);
    glm::dvec3 normal = i == 0 ? perpendicular(t) : frame.normal - t * glm::dot(frame.normal, t);
    // A tangent that turned by ~180 degrees in one step leaves nothing to project: start afresh.
    normal = glm::length(normal) > 1e-3 ? glm::normalize(normal) : perpendicular(t);
    frame = {normal, glm::cross(t, normal)};
    for (std::uint64_t s = 0; s < kTubeSides; ++s) {
      const double a = 2.0 * std::numbers::pi * double(s) / double(kTubeSides);
      const std::uint64_t v = firstVertex + i * kTubeSides + s;
      mesh.positions[v] =
          floatExact(rings[i] + kTubeRadius * (std::cos(a) * frame.normal + std::sin(a) * frame.binormal));
      mesh.colors[v] = color;
    }
  }
  glm::uvec3* out = &mesh.triangles[index * segments * kTubeSides * 2];
  for (std::uint64_t i = 0; i < segments; ++i)
    for (std::uint64_t s = 0; s < kTubeSides; ++s) {
      const auto v = [&](std::uint64_t di, std::uint64_t ds) {
        return std::uint32_t(firstVertex + (i + di) * kTubeSides + (s + ds) % kTubeSides);
      };
      *out++ = {v(0, 0), v(0, 1), v(1, 0)};
      *out++ = {v(0, 1), v(1, 1), v(1, 0)};
    }
}

Mesh hairball(const GenOptions& o) {
  const double perRing = 2.0 * double(kTubeSides);
  const std::uint64_t tubes =
      std::max<std::uint64_t>(1, std::llround(double(o.triangles) / (perRing * double(kSegmentsPerTube))));
  const std::uint64_t segments =
      std::max<std::uint64_t>(1, std::llround(double(o.triangles) / (perRing * double(tubes))));
  Mesh mesh;
  mesh.positions.resize(tubes * (segments + 1) * kTubeSides);
  mesh.colors.resize(mesh.positions.size());
  mesh.triangles.resize(tubes * segments * kTubeSides * 2);
  Progress progress(o.progress, tubes);
  parallelItems(tubes, progress, [&](std::uint64_t t) { tube(o, t, segments, mesh); });
  return mesh;
}

// ----- sphere: a UV sphere with fBm bumps ------------------------------------------------------------------

// Lattice cells across the sphere's diameter at the first octave: a few large bumps.
constexpr double kSphereBaseFrequency = 3.0;

Mesh sphere(const GenOptions& o) {
  // `rings` latitude bands: polar fans of `sides` triangles and 2 * sides per band between them, so
  // 2 * sides * (rings - 1) triangles; sides ~ 2 * rings keeps the cells near the equator square.
  const std::uint64_t rings = std::max<std::uint64_t>(3, std::llround(std::sqrt(double(o.triangles) / 4.0)));
  const std::uint64_t sides =
      std::max<std::uint64_t>(3, std::llround(double(o.triangles) / (2.0 * double(rings - 1))));
  const int octaves = octavesFor(kSphereBaseFrequency, double(rings));
  Mesh mesh;
  const std::uint64_t vertices = 2 + (rings - 1) * sides;
  mesh.positions.resize(vertices);
  mesh.colors.resize(vertices);
  mesh.triangles.resize(2 * sides * (rings - 1));
  const glm::vec4 low = rgb(0.05, 0.15, 0.45), high = rgb(0.85, 0.55, 0.20);
  const auto place = [&](std::uint64_t v, glm::dvec3 dir) {
    const double f = fbm(o.seed, (dir + 1.0) * (0.5 * kSphereBaseFrequency), octaves);
    // Radii in [kSphereMinRadius, 1], inside by the float margin at both ends.
    const double radius = 1.0 - kFloatMargin - (1.0 - kSphereMinRadius - 2.0 * kFloatMargin) * f;
    mesh.positions[v] = floatExact(dir * radius);
    mesh.colors[v] = mixColor(low, high, f);
  };
  const std::uint64_t south = vertices - 1;
  place(0, {0, 1, 0});
  place(south, {0, -1, 0});
  // Vertex of latitude ring `ring` (1 .. rings - 1, north to south) and side `s`.
  const auto vertex = [&](std::uint64_t ring, std::uint64_t s) {
    return std::uint32_t(1 + (ring - 1) * sides + s % sides);
  };
  Progress progress(o.progress, rings - 1);
  parallelItems(rings - 1, progress, [&](std::uint64_t band) {
    const std::uint64_t ring = band + 1;
    const double polar = std::numbers::pi * double(ring) / double(rings);
    for (std::uint64_t s = 0; s < sides; ++s) {
      const double azimuth = 2.0 * std::numbers::pi * double(s) / double(sides);
      place(vertex(ring, s),
            {std::sin(polar) * std::cos(azimuth), std::cos(polar), std::sin(polar) * std::sin(azimuth)});
    }
    // Band `band` lies between ring `band` and ring `band + 1` (ring 0 is the north pole): the north fan
    // (sides triangles) for band 0, 2 * sides for the others; the last band also gets the south fan.
    glm::uvec3* t = &mesh.triangles[band == 0 ? 0 : sides * (2 * band - 1)];
    if (band == 0) {
      for (std::uint64_t s = 0; s < sides; ++s) *t++ = {0, vertex(1, s + 1), vertex(1, s)};
    } else {
      for (std::uint64_t s = 0; s < sides; ++s) {
        *t++ = {vertex(ring - 1, s), vertex(ring - 1, s + 1), vertex(ring, s)};
        *t++ = {vertex(ring - 1, s + 1), vertex(ring, s + 1), vertex(ring, s)};
      }
    }
    if (ring == rings - 1)
      for (std::uint64_t s = 0; s < sides; ++s)
        *t++ = {std::uint32_t(south), vertex(ring, s), vertex(ring, s + 1)};
  });
  return mesh;
}

// ----- PLY and GLB output ----------------------------------------------------------------------------------

// Linear [0, 1] to 8-bit sRGB (IEC 61966-2-1), the inverse of what loadMesh applies to PLY colors.
std::uint8_t toSrgb8(float linear) {
  const double c = std::clamp(double(linear), 0.0, 1.0);
  const double s = c <= 0.0031308 ? 12.92 * c : 1.055 * std::pow(c, 1.0 / 2.4) - 0.055;
  return std::uint8_t(std::lround(s * 255.0));
}

// Bytes gathered before each write: large enough for full-speed sequential writes, small next to a mesh.
constexpr std::size_t kWriteBuffer = std::size_t(1) << 20;

// A file written under a temporary name in the target's folder and renamed over the target on commit();
// destroyed without commit() it removes the temporary and leaves the target alone.
class AtomicOutput {
 public:
  explicit AtomicOutput(const std::filesystem::path& path)
      : path_(path), temp_(path.string() + ".tmp." + std::to_string(::getpid())) {
    file_ = std::fopen(temp_.c_str(), "wb");
    if (!file_) fail("cannot write");
    buffer_.reserve(kWriteBuffer);
  }
  ~AtomicOutput() {
    if (!file_) return;
    std::fclose(file_);
    std::error_code ignored;
    std::filesystem::remove(temp_, ignored);
  }
  AtomicOutput(const AtomicOutput&) = delete;
  AtomicOutput& operator=(const AtomicOutput&) = delete;

  template <class T>
  void put(const T& value) {
    static_assert(std::endian::native == std::endian::little, "PLY output is written little endian");
    const auto* bytes = reinterpret_cast<const char*>(&value);
    buffer_.insert(buffer_.end(), bytes, bytes + sizeof(T));
    if (buffer_.size() >= kWriteBuffer) flush();
  }
  void text(const std::string& s) { buffer_.insert(buffer_.end(), s.begin(), s.end()); }
  void commit() {
    flush();
    if (std::fflush(file_) != 0 || ::fsync(::fileno(file_)) != 0) fail("cannot write");
    const int closed = std::fclose(file_);
    file_ = nullptr;
    if (closed != 0) fail("cannot write");
    std::error_code ec;
    std::filesystem::rename(temp_, path_, ec);
    if (ec) {
      std::filesystem::remove(temp_, ec);
      throw std::runtime_error(path_.string() + ": cannot rename into place (" + ec.message() + ")");
    }
  }

 private:
  void flush() {
    if (std::fwrite(buffer_.data(), 1, buffer_.size(), file_) != buffer_.size()) fail("cannot write");
    buffer_.clear();
  }
  [[noreturn]] void fail(const char* what) const {
    throw std::runtime_error(path_.string() + ": " + what + " (" + std::strerror(errno) + ")");
  }

  std::filesystem::path path_, temp_;
  std::FILE* file_ = nullptr;
  std::vector<char> buffer_;
};

// ----- the kinds -------------------------------------------------------------------------------------------

struct KindEntry {
  SceneKind kind;
  std::string_view name;
  Mesh (*generate)(const GenOptions&);
  GenBounds bounds;  // what gen.hpp promises
};
const KindEntry kKindTable[] = {
    {SceneKind::Terrain, "terrain", terrain, {{-1.0, 0.0, -1.0}, {1.0, kTerrainHeight, 1.0}}},
    {SceneKind::City, "city", city, {{-1.0, 0.0, -1.0}, {1.0, kCityMaxHeight, 1.0}}},
    {SceneKind::Hairball, "hairball", hairball, {glm::dvec3(-1.0), glm::dvec3(1.0)}},
    {SceneKind::Sphere, "sphere", sphere, {glm::dvec3(-1.0), glm::dvec3(1.0)}},
};

const KindEntry& entry(SceneKind kind) {
  for (const KindEntry& e : kKindTable)
    if (e.kind == kind) return e;
  throw std::invalid_argument("unknown scene kind " + std::to_string(int(kind)));
}

// Progress of a writer in records (vertices, faces), reported about every write buffer's worth.
class RecordProgress {
 public:
  RecordProgress(const std::function<void(double)>& report, std::uint64_t total)
      : report_(report), total_(std::max<std::uint64_t>(total, 1)) {}
  void tick() {
    if (report_ && ++done_ % kReportEvery == 0) report_(double(done_) / double(total_));
  }

 private:
  static constexpr std::uint64_t kReportEvery = kWriteBuffer / 16;
  const std::function<void(double)>& report_;
  std::uint64_t total_, done_ = 0;
};

}  // namespace

std::optional<SceneKind> parseSceneKind(std::string_view name) {
  for (const KindEntry& e : kKindTable)
    if (name == e.name) return e.kind;
  return std::nullopt;
}

std::string_view sceneKindName(SceneKind kind) {
  return entry(kind).name;
}

std::string sceneKindList() {
  std::string list;
  for (const KindEntry& e : kKindTable) list += (list.empty() ? "" : ", ") + std::string(e.name);
  return list;
}

GenBounds sceneBounds(SceneKind kind) {
  return entry(kind).bounds;
}

Mesh generateScene(const GenOptions& options) {
  if (options.triangles < kMinGenTriangles || options.triangles > kMaxGenTriangles)
    throw std::invalid_argument("triangle target " + std::to_string(options.triangles) + " is outside [" +
                                std::to_string(kMinGenTriangles) + ", " + std::to_string(kMaxGenTriangles) +
                                "]");
  Mesh mesh = entry(options.kind).generate(options);
  if (options.progress) options.progress(1.0);
  return mesh;
}

void writePly(const std::filesystem::path& path, const Mesh& mesh, const std::string& comment,
              const std::function<void(double)>& progress) {
  const bool colors = !mesh.colors.empty();
  if (colors && mesh.colors.size() != mesh.positions.size())
    throw std::invalid_argument("writePly: colors and positions differ in count");
  AtomicOutput out(path);
  std::string header = "ply\nformat binary_little_endian 1.0\n";
  if (!comment.empty()) header += "comment " + comment + "\n";
  header += "element vertex " + std::to_string(mesh.positions.size()) +
            "\nproperty float x\nproperty float y\nproperty float z\n";
  if (colors) header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  header += "element face " + std::to_string(mesh.triangles.size()) +
            "\nproperty list uchar int vertex_indices\nend_header\n";
  out.text(header);
  RecordProgress records(progress, mesh.positions.size() + mesh.triangles.size());
  for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
    out.put(glm::vec3(mesh.positions[v]));
    if (colors)
      for (int k = 0; k < 3; ++k) out.put(toSrgb8(mesh.colors[v][k]));
    records.tick();
  }
  for (const glm::uvec3& t : mesh.triangles) {
    out.put(std::uint8_t(3));
    out.put(glm::ivec3(t));
    records.tick();
  }
  out.commit();
  if (progress) progress(1.0);
}

void writeGlb(const std::filesystem::path& path, const Mesh& mesh, const std::string& generator,
              const std::function<void(double)>& progress) {
  const bool colors = !mesh.colors.empty();
  if (colors && mesh.colors.size() != mesh.positions.size())
    throw std::invalid_argument("writeGlb: colors and positions differ in count");
  const std::uint64_t nv = mesh.positions.size(), nt = mesh.triangles.size();
  // Binary chunk: float positions, then RGBA8 colors, then uint32 indices; every part 4-byte aligned.
  const std::uint64_t positionBytes = 12 * nv, colorBytes = colors ? 4 * nv : 0, indexBytes = 12 * nt;
  const std::uint64_t binBytes = positionBytes + colorBytes + indexBytes;
  glm::vec3 lo(std::numeric_limits<float>::max()), hi(-std::numeric_limits<float>::max());
  for (const glm::dvec3& p : mesh.positions) lo = glm::min(lo, glm::vec3(p)), hi = glm::max(hi, glm::vec3(p));
  std::string name;
  for (const char c : generator)
    if (c != '"' && c != '\\' && static_cast<unsigned char>(c) >= 0x20) name += c;  // a JSON-safe string
  // glTF 2.0 codes: ARRAY_BUFFER 34962, ELEMENT_ARRAY_BUFFER 34963, FLOAT 5126, UNSIGNED_BYTE 5121,
  // UNSIGNED_INT 5125, mode TRIANGLES 4. Accessor 0 positions, 1 indices, 2 colors; views alike.
  std::string json = fmt::format(
      R"({{"asset":{{"version":"2.0","generator":"{}"}},"scene":0,"scenes":[{{"nodes":[0]}}],)"
      R"("nodes":[{{"mesh":0}}],"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0{}}},"indices":1,)"
      R"("mode":4}}]}}],"buffers":[{{"byteLength":{}}}],"bufferViews":[)"
      R"({{"buffer":0,"byteOffset":0,"byteLength":{},"target":34962}},)"
      R"({{"buffer":0,"byteOffset":{},"byteLength":{},"target":34963}})",
      name, colors ? R"(,"COLOR_0":2)" : "", binBytes, positionBytes, positionBytes + colorBytes, indexBytes);
  if (colors)
    json += fmt::format(R"(,{{"buffer":0,"byteOffset":{},"byteLength":{},"target":34962}})", positionBytes,
                        colorBytes);
  json += fmt::format(R"(],"accessors":[{{"bufferView":0,"componentType":5126,"count":{},"type":"VEC3",)"
                      R"("min":[{:.9g},{:.9g},{:.9g}],"max":[{:.9g},{:.9g},{:.9g}]}},)"
                      R"({{"bufferView":1,"componentType":5125,"count":{},"type":"SCALAR"}})",
                      nv, lo.x, lo.y, lo.z, hi.x, hi.y, hi.z, 3 * nt);
  if (colors)
    json += fmt::format(
        R"(,{{"bufferView":2,"componentType":5121,"normalized":true,"count":{},"type":"VEC4"}})", nv);
  json += "]}";
  json.append((4 - json.size() % 4) % 4, ' ');  // chunks are 4-byte aligned; JSON pads with spaces
  const std::uint64_t total = 12 + 8 + json.size() + 8 + binBytes;
  if (total > 0xFFFFFFFFull)
    throw std::runtime_error(path.string() + ": " + std::to_string(total) +
                             " bytes exceed the 4 GiB a GLB file can hold (write .ply instead)");
  AtomicOutput out(path);
  out.put(std::uint32_t(0x46546C67));  // "glTF"
  out.put(std::uint32_t(2));
  out.put(std::uint32_t(total));
  out.put(std::uint32_t(json.size()));
  out.put(std::uint32_t(0x4E4F534A));  // "JSON"
  out.text(json);
  out.put(std::uint32_t(binBytes));
  out.put(std::uint32_t(0x004E4942));  // "BIN\0"
  RecordProgress records(progress, 2 * nv + nt);
  for (const glm::dvec3& p : mesh.positions) {
    out.put(glm::vec3(p));
    records.tick();
  }
  if (colors)
    for (const glm::vec4& c : mesh.colors) {
      // glTF vertex colors are linear.
      for (int k = 0; k < 4; ++k) out.put(std::uint8_t(std::lround(std::clamp(c[k], 0.0f, 1.0f) * 255.0f)));
      records.tick();
    }
  for (const glm::uvec3& t : mesh.triangles) {
    out.put(t);
    records.tick();
  }
  out.commit();
  if (progress) progress(1.0);
}

}  // namespace svo
