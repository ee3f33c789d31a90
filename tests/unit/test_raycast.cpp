// The ESVO ray caster (client/raycast.hpp) against a brute-force double-precision reference (reference.hpp
// (c)) over the leaf voxels read from the block (reference.hpp (d)): random rays, stiff rays, contours, level
// of detail.
//
// Tolerances. The caster works in float in [1,2]^3, where one ulp is 2^-23 ~ 1.2e-7; its t values come from a
// few multiply-adds on such positions, and it clamps direction components below 2^-23 to +-2^-23, which moves
// a ray by at most 2^-23 per unit of t. So its hit t is good to ~1e-5 (t <= ~4 here); we allow
//   kTolT = 1e-4 x scene size (the octree cube has size 1 in octree units; rays have unit direction),
// and treat a ray as ambiguous when shifting its origin by kDelta = 1e-5 (well above the float error, far
// below the finest voxel of 2^-7) along any combination of axes changes the reference's first hit, or when
// that hit is only a touch (the ray crosses the shape for less than kDelta, e.g. exactly through a corner).
// Ambiguous rays must still be explained by the reference: a miss only if some shifted ray misses or every
// contact is a touch, a hit on its voxel grown by kDelta and no later than the latest of those alternatives.
// Every other ray must match exactly (same voxel or a tie, same t).
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>
#include <string>

#include <tbb/parallel_for.h>
#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/raycast.hpp"
#include "svo/client/render.hpp"

namespace {

constexpr double kTolT = 1e-4;
constexpr double kDelta = 1e-5;

struct Scene {
  std::string name;
  int levels = 0;
  svo::Octree octree;
  std::vector<svotest::LeafVoxel> leaves;
  std::map<std::pair<int, std::uint64_t>, int> index;  // (level, packed coord) -> leaf
  std::unique_ptr<svotest::RefCaster> cubes, contoured;
  std::size_t contourCount = 0;
  // Every voxel's resolved (color, normal), from readBlock: what hitAttribute must return for it.
  std::map<std::pair<int, std::uint64_t>, std::pair<std::uint32_t, std::uint32_t>> attributes;
};

void collectAttributes(const svo::VoxelTree& t, std::uint32_t i, const glm::ivec3& c, int level, Scene& s) {
  const svo::VoxelRecord& r = t.voxels.at(i);
  if (level > 0) s.attributes[{level, svotest::packCoord(c)}] = {r.color, r.normal};
  for (int slot = 0, k = 0; slot < 8; ++slot)
    if ((r.childMask >> slot) & 1)
      collectAttributes(t, r.firstChild + k++, c * 2 + glm::ivec3(slot & 1, (slot >> 1) & 1, (slot >> 2) & 1),
                        level + 1, s);
}

std::unique_ptr<Scene> makeScene(const std::string& name, const svo::Mesh& mesh, int levels) {
  auto s = std::make_unique<Scene>();
  s->name = name;
  s->levels = levels;
  svo::BuildOptions options;
  options.levels = levels;
  options.contours = true;
  s->octree = svo::buildOctree(mesh, options);
  s->leaves = svotest::walkLeaves(s->octree.block.view());
  std::vector<svotest::Shape> cubes, contoured;
  for (int i = 0; i < int(s->leaves.size()); ++i) {
    const auto& v = s->leaves[i];
    s->index[{v.level, svotest::packCoord(v.coord)}] = i;
    cubes.push_back(svotest::shapeOf(v, false));
    contoured.push_back(svotest::shapeOf(v, true));
    s->contourCount += !v.contours.empty();
  }
  collectAttributes(svo::readBlock(s->octree.block.view()), 0, glm::ivec3(0), 0, *s);
  s->cubes = std::make_unique<svotest::RefCaster>(std::move(cubes));
  s->contoured = std::make_unique<svotest::RefCaster>(std::move(contoured));
  return s;
}

// Meshes: a sphere of ~2k triangles, random triangles, an axis-aligned box, a flat quad exactly in a plane.
const Scene& sphereScene() {
  static const auto s = makeScene("sphere", svotest::makeSphere({0.3, -0.2, 0.1}, 1.0, 32, 32), 7);
  return *s;
}
const Scene& randomScene() {
  static const auto s = [] {
    svo::Mesh m = svotest::makeRandomTriangles(21, 150, {-1, -1, -1}, {1, 1, 1}, 0.4);
    std::mt19937 rng(22);  // vertex colors, so the block has a color attachment too
    for (std::size_t i = 0; i < m.positions.size(); ++i)
      m.colors.emplace_back(float(rng() % 256) / 255.0f, float(rng() % 256) / 255.0f, float(rng() % 4) / 3.0f,
                            1.0f);
    return makeScene("random", m, 6);
  }();
  return *s;
}
const Scene& boxScene() {
  static const auto s = [] {
    svo::Mesh m = svotest::makeBox({-1, -1, -1}, {1, 1, 1});
    svotest::appendMesh(m, svotest::makeBox({-0.4, -0.3, -0.2}, {0.2, 0.5, 0.35}));  // a box inside, off-grid
    return makeScene("box", m, 6);
  }();
  return *s;
}
const Scene& quadScene() {
  static const auto s = [] {
    // A quad in the plane y = 0, which the scene cube maps to the grid plane y = 1.5 of every level, a second
    // one in y = 0.25 (off the grid), and a tilted triangle so the scene cube is not flat.
    svo::Mesh m;
    m.positions = {{-1, 0, -1}, {1, 0, -1},    {1, 0, 1},    {-1, 0, 1},   {-1, -1, -1}, {1, 1, 1},
                   {0, -1, 1},  {-1, 0.25, 0}, {0, 0.25, 0}, {0, 0.25, 1}, {-1, 0.25, 1}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}, {4, 5, 6}, {7, 8, 9}, {7, 9, 10}};
    return makeScene("quad", m, 5);
  }();
  return *s;
}

// ---------------------------------------------------------------------------------------------------------
// Judging one cast against the reference.

enum class Verdict { Exact, Ambiguous, Fail };

struct Judged {
  Verdict verdict = Verdict::Fail;
  std::string why;
};

int leafOf(const Scene& s, const svo::CastHit& hit, std::string* why) {
  const int level = svo::kMaxLevels - hit.scale;
  if (level < 1 || level > svo::kMaxLevels) return *why = "bad scale " + std::to_string(hit.scale), -1;
  const glm::dvec3 g = (glm::dvec3(hit.cubeMin) - 1.0) * std::ldexp(1.0, level);
  const glm::dvec3 r = glm::round(g);
  if (glm::length(g - r) > 1e-3) return *why = "cubeMin not on the grid of its scale", -1;
  const auto it = s.index.find({level, svotest::packCoord(glm::ivec3(r))});
  if (it == s.index.end()) {
    std::ostringstream o;
    o << "hit voxel (" << r.x << "," << r.y << "," << r.z << ") level " << level << " is not a leaf";
    return *why = o.str(), -1;
  }
  return it->second;
}

std::string describe(const glm::vec3& o, const glm::vec3& d) {
  std::ostringstream s;
  s.precision(9);
  s << "ray o=(" << o.x << "," << o.y << "," << o.z << ") d=(" << d.x << "," << d.y << "," << d.z << ")";
  return s.str();
}

// The hit position lies in the hit voxel's cube, at the ray point of the hit t up to the clamping; the hit's
// attributes (walked up the path by hitAttribute) equal readBlock's resolved values for that voxel.
std::string checkHitDetails(const Scene& s, const svo::OctreeRay& ray, const svo::CastHit& hit) {
  if (!hit.hit) return "";
  const double size = hit.voxelSize();
  const glm::dvec3 lo(hit.cubeMin), p(hit.position);
  const glm::dvec3 onRay = glm::dvec3(ray.origin) + double(hit.t) * glm::dvec3(ray.direction);
  if (std::abs(size - std::ldexp(1.0, hit.scale - svo::kMaxLevels)) > 0.0)
    return "voxelSize() disagrees with scale";
  for (int i = 0; i < 3; ++i)
    if (p[i] < lo[i] || p[i] > lo[i] + size) return "hit position outside the hit voxel's cube";
  if (glm::length(p - onRay) > kTolT) return "hit position far from the ray point at t";
  const int level = svo::kMaxLevels - hit.scale;
  const glm::ivec3 c(glm::round((lo - 1.0) / size));
  const auto it = s.attributes.find({level, svotest::packCoord(c)});
  if (it == s.attributes.end()) return "hit voxel not in the block";
  const svo::BlockView view = s.octree.block.view();
  if (svo::hitAttribute(view, hit, svo::AttachmentType::Normal) != it->second.second)
    return "hitAttribute(Normal) differs from readBlock's value";
  if (view.attachment(svo::AttachmentType::Color) &&
      svo::hitAttribute(view, hit, svo::AttachmentType::Color) != it->second.first)
    return "hitAttribute(Color) differs from readBlock's value";
  return "";
}

Judged judge(const Scene& s, const svotest::RefCaster& ref, const svo::OctreeRay& ray,
             const svo::CastHit& hit, const svo::CastOptions& options) {
  const glm::dvec3 o(ray.origin), d(ray.direction);
  Judged j;
  std::ostringstream why;
  why.precision(9);
  why << describe(ray.origin, ray.direction) << ": ";
  if (!std::isfinite(hit.t) || !std::isfinite(hit.position.x) || !std::isfinite(hit.position.y) ||
      !std::isfinite(hit.position.z))
    return {Verdict::Fail, why.str() + "non-finite t or position"};
  if (hit.iterations > options.maxIterations) return {Verdict::Fail, why.str() + "iterations exceed the cap"};
  if (const std::string details = checkHitDetails(s, ray, hit); !details.empty())
    return {Verdict::Fail, why.str() + details};
  const svotest::RefHit r = ref.first(o, d, 0.0);
  int v = -1;
  std::string leafWhy;
  if (hit.hit) {
    v = leafOf(s, hit, &leafWhy);
    if (v < 0) return {Verdict::Fail, why.str() + leafWhy};
  }
  // Exact agreement: both miss, or the hit voxel is entered (grown by kDelta, for hits on its boundary)
  // within kTolT of the reference's first entry, and the t agrees.
  if (!hit.hit && !r.hit()) return {Verdict::Exact, ""};
  if (hit.hit && r.hit()) {
    // The hit voxel's own entry (or, if the ray only touches it within rounding, its entry grown by kDelta).
    double t0, t1;
    const bool onRay = svotest::clipRay(ref.shapes()[v], o, d, 0.0, t0, t1) ||
                       svotest::clipRay(ref.shapes()[v], o, d, kDelta, t0, t1);
    if (onRay && std::abs(t0 - r.t0) <= kTolT && std::abs(double(hit.t) - r.t0) <= kTolT)
      return {Verdict::Exact, ""};
  }
  // Is the reference itself ambiguous for this ray? Two ways it can be: (1) shifting the origin by kDelta
  // along some combination of axes (27 rays, the unshifted one included) changes the first hit: the ray runs
  // along or within kDelta of a face, edge or corner; (2) the first hit is a touching contact, the ray
  // crossing the shape for less than kDelta (through a corner or along an edge of it), which float rounding
  // may skip.
  double latest = -svotest::kInf;  // the latest first hit among the shifted rays (inf: one of them misses)
  bool ambiguous = false;
  for (int k = 0; k < 27; ++k) {
    const glm::dvec3 shift = kDelta * glm::dvec3(k % 3 - 1, (k / 3) % 3 - 1, k / 9 - 1);
    const svotest::RefHit rp = ref.first(o + shift, d, 0.0);
    latest = std::max(latest, rp.hit() ? rp.t0 : svotest::kInf);
    ambiguous |= rp.hit() != r.hit() || (rp.hit() && std::abs(rp.t0 - r.t0) > kTolT);
  }
  const svotest::RefHit crossing = ref.first(o, d, 0.0, kDelta);  // first shape crossed for >= kDelta
  ambiguous |= crossing.hit() != r.hit() || (crossing.hit() && crossing.t0 - r.t0 > kTolT);
  latest = std::max(latest, crossing.hit() ? crossing.t0 : svotest::kInf);
  why << "caster " << (hit.hit ? "hit" : "miss");
  if (hit.hit) why << " t=" << hit.t << " scale " << hit.scale << " iterations " << hit.iterations;
  why << "; reference " << (r.hit() ? "hit" : "miss");
  if (r.hit())
    why << " t=" << r.t0 << " voxel (" << s.leaves[r.voxel].coord.x << "," << s.leaves[r.voxel].coord.y << ","
        << s.leaves[r.voxel].coord.z << ")";
  if (!ambiguous) return {Verdict::Fail, why.str() + " (unambiguous)"};
  // Ambiguous: a miss needs a shifted ray that misses, or only touching contacts on the ray; a hit must be on
  // its voxel (grown by kDelta) and no later than the latest of those alternatives.
  if (!hit.hit) {
    if (latest < svotest::kInf) return {Verdict::Fail, why.str() + " (every alternative hits)"};
    return {Verdict::Ambiguous, ""};
  }
  double t0, t1;
  if (!svotest::clipRay(ref.shapes()[v], o, d, kDelta, t0, t1))
    return {Verdict::Fail, why.str() + " (hit voxel not on the ray even grown)"};
  if (hit.t < t0 - kTolT || hit.t > t1 + kTolT) return {Verdict::Fail, why.str() + " (t outside the voxel)"};
  if (hit.t > latest + kTolT) return {Verdict::Fail, why.str() + " (later than every alternative)"};
  return {Verdict::Ambiguous, ""};
}

struct Tally {
  std::size_t exact = 0, ambiguous = 0, hits = 0;
  std::vector<std::string> failures;
};

Tally castAll(const Scene& s, const std::vector<svo::OctreeRay>& rays, bool contours) {
  svo::CastOptions options;
  options.contours = contours;
  const svotest::RefCaster& ref = contours ? *s.contoured : *s.cubes;
  const svo::BlockView view = s.octree.block.view();
  std::vector<Judged> results(rays.size());
  std::vector<char> hits(rays.size());
  tbb::parallel_for(std::size_t(0), rays.size(), [&](std::size_t i) {
    const svo::CastHit hit = svo::castRay(view, rays[i], options);
    hits[i] = hit.hit;
    results[i] = judge(s, ref, rays[i], hit, options);
  });
  Tally t;
  for (std::size_t i = 0; i < rays.size(); ++i) {
    t.hits += hits[i];
    if (results[i].verdict == Verdict::Exact) ++t.exact;
    if (results[i].verdict == Verdict::Ambiguous) ++t.ambiguous;
    if (results[i].verdict == Verdict::Fail) t.failures.push_back(results[i].why);
  }
  return t;
}

void expectNoFailures(const Tally& t, const std::string& what) {
  EXPECT_TRUE(t.failures.empty()) << what << ": " << t.failures.size()
                                  << " failures; first: " << t.failures[0]
                                  << (t.failures.size() > 1 ? "\n second: " + t.failures[1] : "")
                                  << (t.failures.size() > 2 ? "\n third: " + t.failures[2] : "");
}

glm::dvec3 randomUnit(std::mt19937_64& rng) {
  std::normal_distribution<double> g;
  for (;;) {
    const glm::dvec3 v(g(rng), g(rng), g(rng));
    if (glm::length(v) > 1e-6) return glm::normalize(v);
  }
}

// Half from outside towards a random point of the cube, half from anywhere near the cube in any direction.
std::vector<svo::OctreeRay> randomRays(std::uint64_t seed, int count) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::vector<svo::OctreeRay> rays(count);
  for (int i = 0; i < count; ++i) {
    glm::dvec3 o, d;
    if (i % 2 == 0) {
      o = glm::dvec3(1.5) + 1.5 * randomUnit(rng);
      d = glm::normalize(1.0 + glm::dvec3(uni(rng), uni(rng), uni(rng)) - o);
    } else {
      o = 0.9 + 1.2 * glm::dvec3(uni(rng), uni(rng), uni(rng));
      d = randomUnit(rng);
    }
    rays[i].origin = glm::vec3(o);
    rays[i].direction = glm::vec3(d);
  }
  return rays;
}

void randomRayTest(const Scene& s, int count, bool contours) {
  const Tally t = castAll(s, randomRays(100 + s.levels, count), contours);
  const std::string what = s.name + (contours ? " with contours" : " cubes");
  std::printf(
      "[ RAYS     ] %s L%d: %d rays, %zu hits, %zu exact, %zu ambiguous (within %.0e of a boundary)\n",
      what.c_str(), s.levels, count, t.hits, t.exact, t.ambiguous, kDelta);
  expectNoFailures(t, what);
  EXPECT_GT(t.hits, std::size_t(count / 20)) << what << ": too few hits to test anything";
  // Random rays are almost never within kDelta of an edge: the exact comparison covers nearly all of them.
  EXPECT_GE(double(t.exact), 0.995 * count) << what << ": " << t.ambiguous << " ambiguous rays";
  if (contours) EXPECT_GT(s.contourCount, 0u) << what << ": no contours to test";
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------
// Random rays.

TEST(Raycast, RandomRaysSphereCubes) {
  randomRayTest(sphereScene(), 100000, false);
}
TEST(Raycast, RandomRaysSphereContours) {
  randomRayTest(sphereScene(), 100000, true);
}
TEST(Raycast, RandomRaysTrianglesCubes) {
  randomRayTest(randomScene(), 20000, false);
}
TEST(Raycast, RandomRaysTrianglesContours) {
  randomRayTest(randomScene(), 20000, true);
}
TEST(Raycast, RandomRaysBoxCubes) {
  randomRayTest(boxScene(), 20000, false);
}
TEST(Raycast, RandomRaysBoxContours) {
  randomRayTest(boxScene(), 20000, true);
}
TEST(Raycast, RandomRaysQuadCubes) {
  randomRayTest(quadScene(), 20000, false);
}
TEST(Raycast, RandomRaysQuadContours) {
  randomRayTest(quadScene(), 20000, true);
}

// ---------------------------------------------------------------------------------------------------------
// Stiff rays.

namespace {

std::vector<svo::OctreeRay> stiffRays(const Scene& s, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const int cells = 1 << s.levels;
  const double h = 1.0 / cells;
  const auto gridPlane = [&] { return 1.0 + double(rng() % (cells + 1)) * h; };
  const float tiny[] = {0.0f,
                        -0.0f,
                        1e-30f,
                        -1e-30f,
                        std::numeric_limits<float>::denorm_min(),
                        -std::numeric_limits<float>::denorm_min(),
                        1e-40f,
                        -1e-40f,
                        1e-8f,
                        -1e-8f};
  std::vector<svo::OctreeRay> rays;
  const auto add = [&](const glm::dvec3& o, const glm::vec3& d) {
    svo::OctreeRay r;
    r.origin = glm::vec3(o);
    r.direction = d;
    rays.push_back(r);
  };
  for (int axis = 0; axis < 3; ++axis)
    for (int sign : {-1, 1})
      for (int i = 0; i < 300; ++i) {
        const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
        glm::dvec3 o;
        o[axis] = sign > 0 ? 0.5 : 2.5;
        // 0: axis-parallel; 1: along a grid plane (cube faces); 2: along a grid line (cube edges); 3: along
        // the octree's own faces; 4: grazing a grid plane at +-1e-7.
        const int kind = i % 5;
        o[a1] = kind == 1 || kind == 2 ? gridPlane() : kind == 3 ? (i % 2 ? 1.0 : 2.0) : 1.0 + uni(rng);
        o[a2] = kind == 2 ? gridPlane() : 1.0 + uni(rng);
        if (kind == 4) o[a1] = gridPlane() + (i % 2 ? 1e-7 : -1e-7);
        glm::vec3 d(0.0f);
        d[axis] = float(sign);
        d[a1] = tiny[rng() % 10];
        d[a2] = tiny[rng() % 10];
        add(o, d);
        if (i % 5 == 4) add(o, glm::normalize(glm::vec3(d[axis], 1e-4f * float(sign), d[a2])));
      }
  // Through grid corners of leaf voxels, from outside and from inside.
  for (int i = 0; i < 1000; ++i) {
    const auto& v = s.leaves[rng() % s.leaves.size()];
    const double hv = std::ldexp(1.0, -v.level);
    const glm::dvec3 corner = 1.0 + (glm::dvec3(v.coord) + glm::dvec3(rng() % 2, rng() % 2, rng() % 2)) * hv;
    const glm::dvec3 o =
        i % 2 ? glm::dvec3(1.5) + 1.5 * randomUnit(rng)
              : 1.0 + glm::dvec3(rng() % (cells + 1), rng() % (cells + 1), rng() % (cells + 1)) * h;
    if (glm::length(corner - o) < 1e-9) continue;
    add(o, glm::vec3(glm::normalize(corner - o)));
    // Diagonal through the corner: equal components.
    add(corner - 0.75 * glm::dvec3(1, i % 3 ? 1 : -1, 1),
        glm::vec3(glm::normalize(glm::dvec3(1, i % 3 ? 1 : -1, 1))));
  }
  // Origins on the octree boundary, pointing in and out.
  for (int i = 0; i < 300; ++i) {
    glm::dvec3 o(1.0 + uni(rng), 1.0 + uni(rng), 1.0 + uni(rng));
    o[i % 3] = i % 2 ? 1.0 : 2.0;
    add(o, glm::vec3(randomUnit(rng)));
  }
  // Tiny, zero, negative-zero and denormal components on random rays.
  for (int i = 0; i < 600; ++i) {
    glm::dvec3 o = glm::dvec3(1.5) + 1.5 * randomUnit(rng);
    glm::vec3 d = glm::vec3(glm::normalize(1.0 + glm::dvec3(uni(rng), uni(rng), uni(rng)) - o));
    d[i % 3] = tiny[rng() % 10];
    if (i % 7 == 0) d[(i + 1) % 3] = tiny[rng() % 10];
    if (glm::length(glm::dvec3(d)) < 0.1) continue;
    add(o, d);
  }
  return rays;
}

// Origins inside leaf voxels (cube voxels): the hit is at t = 0, in that voxel (or a tie sharing the origin).
// With `corners`, origins exactly at voxel corners, where the ray may just touch the voxel and leave.
std::vector<svo::OctreeRay> insideRays(const Scene& s, std::uint64_t seed, bool corners) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.01, 0.99);
  std::vector<svo::OctreeRay> rays;
  for (int i = 0; i < 2000; ++i) {
    const auto& v = s.leaves[rng() % s.leaves.size()];
    const double hv = std::ldexp(1.0, -v.level);
    glm::dvec3 f(uni(rng), uni(rng), uni(rng));
    if (i % 2 == 1) f = glm::dvec3(0.5);
    if (corners) f = glm::dvec3(rng() % 2, rng() % 2, rng() % 2);
    svo::OctreeRay r;
    r.origin = glm::vec3(1.0 + (glm::dvec3(v.coord) + f) * hv);
    r.direction = glm::vec3(randomUnit(rng));
    rays.push_back(r);
  }
  return rays;
}

void stiffRayTest(const Scene& s, bool contours) {
  const std::vector<svo::OctreeRay> rays = stiffRays(s, 200 + s.levels);
  const Tally t = castAll(s, rays, contours);
  std::printf("[ RAYS     ] %s stiff, contours %d: %zu rays, %zu hits, %zu exact, %zu ambiguous\n",
              s.name.c_str(), int(contours), rays.size(), t.hits, t.exact, t.ambiguous);
  expectNoFailures(t, s.name + (contours ? " stiff, contours" : " stiff, cubes"));
  EXPECT_GT(t.hits, rays.size() / 20);
}

}  // namespace

TEST(Raycast, StiffRaysSphere) {
  stiffRayTest(sphereScene(), false);
  stiffRayTest(sphereScene(), true);
}
TEST(Raycast, StiffRaysBox) {
  stiffRayTest(boxScene(), false);
  stiffRayTest(boxScene(), true);
}
TEST(Raycast, StiffRaysQuad) {
  stiffRayTest(quadScene(), false);
  stiffRayTest(quadScene(), true);
}

TEST(Raycast, OriginInsideLeafVoxel) {
  for (const Scene* s : {&sphereScene(), &boxScene()}) {
    // At a corner: whatever the caster does must be explained by the reference.
    expectNoFailures(castAll(*s, insideRays(*s, 301, true), false), s->name + " origin at a voxel corner");
    const auto rays = insideRays(*s, 300, false);
    const Tally t = castAll(*s, rays, false);
    expectNoFailures(t, s->name + " origin inside");
    EXPECT_EQ(t.hits, rays.size());
    // And the hit is at t = 0 (the reference gives t0 = 0 for the containing voxel).
    const svo::BlockView view = s->octree.block.view();
    for (const auto& r : rays) {
      const svo::CastHit hit = svo::castRay(view, r, {false, 4096});
      ASSERT_TRUE(hit.hit);
      ASSERT_LE(hit.t, kTolT) << describe(r.origin, r.direction);
    }
  }
}

// Degenerate inputs: a zero direction, NaN, infinite origin: a miss, never NaN, never a hang.
TEST(Raycast, DegenerateRaysMiss) {
  const Scene& s = sphereScene();
  const svo::BlockView view = s.octree.block.view();
  const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
  const std::vector<std::pair<glm::vec3, glm::vec3>> cases = {
      {{1.5f, 1.5f, 0.0f}, {0.0f, 0.0f, 0.0f}}, {{1.5f, 1.5f, 0.0f}, {-0.0f, 0.0f, -0.0f}},
      {{1.5f, 1.5f, 0.0f}, {nan, 0.0f, 1.0f}},  {{nan, 1.5f, 0.0f}, {0.0f, 0.0f, 1.0f}},
      {{1.5f, 1.5f, -inf}, {0.0f, 0.0f, 1.0f}}, {{1.5f, 1.5f, 0.0f}, {0.0f, inf, 1.0f}}};
  for (const auto& [o, d] : cases) {
    svo::OctreeRay r;
    r.origin = o;
    r.direction = d;
    const svo::CastHit hit = svo::castRay(view, r);
    EXPECT_FALSE(hit.hit) << describe(o, d);
    EXPECT_FALSE(std::isnan(hit.t));
    EXPECT_LE(hit.iterations, svo::CastOptions{}.maxIterations);
  }
}

// A tiny iteration cap: the ray gives up (a miss), within the cap.
TEST(Raycast, IterationCapIsHonoured) {
  const Scene& s = sphereScene();
  const svo::BlockView view = s.octree.block.view();
  const auto rays = randomRays(400, 2000);
  for (int cap : {1, 3, 10}) {
    svo::CastOptions options;
    options.contours = false;
    options.maxIterations = cap;
    for (const auto& r : rays) {
      const svo::CastHit hit = svo::castRay(view, r, options);
      ASSERT_LE(hit.iterations, cap + 1) << describe(r.origin, r.direction);
      ASSERT_TRUE(std::isfinite(hit.t));
      if (hit.hit) {
        // Whatever it reports within the cap is still a real first hit.
        const Judged j = judge(s, *s.cubes, r, hit, options);
        ASSERT_NE(j.verdict, Verdict::Fail) << j.why;
      }
    }
  }
}

// tMax: a hit beyond tMax is a miss; before it, the same hit.
TEST(Raycast, TMaxLimitsTheRay) {
  const Scene& s = sphereScene();
  const svo::BlockView view = s.octree.block.view();
  const auto rays = randomRays(500, 5000);
  std::size_t checked = 0;
  for (auto r : rays) {
    const svotest::RefHit ref = s.cubes->first(glm::dvec3(r.origin), glm::dvec3(r.direction));
    const svotest::RefHit shrunk = s.cubes->first(glm::dvec3(r.origin), glm::dvec3(r.direction), -kDelta);
    if (!ref.hit() || !shrunk.hit() || shrunk.t0 - ref.t0 > kTolT) continue;
    r.tMax = float(ref.t0 - 10 * kTolT);
    if (r.tMax > 0.0f) {
      EXPECT_FALSE(svo::castRay(view, r, {false, 4096}).hit) << describe(r.origin, r.direction);
      ++checked;
    }
    r.tMax = float(ref.t0 + 10 * kTolT);
    const svo::CastHit hit = svo::castRay(view, r, {false, 4096});
    EXPECT_TRUE(hit.hit) << describe(r.origin, r.direction);
    EXPECT_NEAR(hit.t, ref.t0, kTolT);
  }
  EXPECT_GT(checked, 100u);
}

// ---------------------------------------------------------------------------------------------------------
// Level of detail: a non-leaf hit is a non-empty voxel no larger than the footprint where the ray leaves it,
// entered no later than the leaf the full-resolution ray hits.

TEST(Raycast, LevelOfDetail) {
  for (const Scene* s : {&sphereScene(), &randomScene()}) {
    // Every non-empty voxel: the ancestors of the leaves.
    std::map<std::pair<int, std::uint64_t>, bool> nonEmpty;
    for (const auto& v : s->leaves)
      for (int l = v.level; l >= 1; --l) nonEmpty[{l, svotest::packCoord(v.coord >> (v.level - l))}] = true;
    const svo::BlockView view = s->octree.block.view();
    const auto rays = randomRays(600, 20000);
    std::size_t lodStops = 0, strictAtHit = 0;
    std::vector<std::string> failures;
    for (double slope : {0.003, 0.02, 0.08}) {
      for (const auto& base : rays) {
        svo::OctreeRay r = base;
        r.footprintSlope = float(slope);
        r.footprintOrigin = 0.0f;
        const glm::dvec3 o(r.origin), d(r.direction);
        const svo::CastHit hit = svo::castRay(view, r, {false, 4096});
        const svotest::RefHit shrunk = s->cubes->first(o, d, -kDelta);
        std::string why = describe(r.origin, r.direction) + " slope " + std::to_string(slope) + ": ";
        if (!std::isfinite(hit.t)) {
          failures.push_back(why + "non-finite t");
          continue;
        }
        if (!hit.hit) {
          if (shrunk.hit()) failures.push_back(why + "missed a robust leaf hit");
          continue;
        }
        const int level = svo::kMaxLevels - hit.scale;
        const double size = std::ldexp(1.0, -level);
        const glm::dvec3 g = (glm::dvec3(hit.cubeMin) - 1.0) / size;
        const glm::ivec3 c(glm::round(g));
        if (level < 1 || !nonEmpty.count({level, svotest::packCoord(c)})) {
          failures.push_back(why + "hit voxel is not a non-empty voxel");
          continue;
        }
        const svotest::Shape cube = svotest::cubeShape(c, level);
        double t0, t1;
        if (!svotest::clipBox(cube.lo, cube.hi, o, d, kDelta, t0, t1) || hit.t < t0 - kTolT ||
            hit.t > t1 + kTolT) {
          failures.push_back(why + "t not on the hit voxel");
          continue;
        }
        if (shrunk.hit() && hit.t > shrunk.t0 + kTolT) failures.push_back(why + "LOD hit after the leaf hit");
        if (const std::string details = checkHitDetails(*s, r, hit); !details.empty())
          failures.push_back(why + details);
        if (hit.leaf) {
          if (level != s->levels || !s->index.count({level, svotest::packCoord(c)}))
            failures.push_back(why + "reported leaf is not a leaf");
          continue;
        }
        ++lodStops;
        // The footprint at the voxel's exit (relative float slack 1e-5).
        if (size > (r.footprintOrigin + t1 * slope) * (1.0 + 1e-5))
          failures.push_back(why + "LOD voxel larger than the footprint at its exit: size " +
                             std::to_string(size));
        strictAtHit += size <= r.footprintOrigin + hit.t * slope;
      }
    }
    EXPECT_TRUE(failures.empty()) << s->name << ": " << failures.size()
                                  << " failures; first: " << failures[0];
    EXPECT_GT(lodStops, 1000u) << s->name << ": level of detail never stopped early";
    std::printf("[ LOD      ] %s: %zu LOD stops, %zu also no larger than the footprint at the hit t\n",
                s->name.c_str(), lodStops, strictAtHit);
  }
}

// One SiblingAttribute per attribute, and one RawAttributePair for both, kept across a frame's hits in pixel
// order, as render keeps them per tile: each hit's color and normal equal readBlock's resolved values for its
// voxel, whether the hit shares the previous hit's parent (the parent's look-up reused, inherited values
// included) or not.
TEST(Raycast, SiblingAttributesKeptAcrossHitsEqualReadBlock) {
  for (const Scene* s : {&sphereScene(), &randomScene()}) {
    const svo::BlockView view = s->octree.block.view();
    // Near enough that the finest voxels are a few pixels wide and neighbouring pixels hit siblings.
    svo::Camera camera = svo::Camera::framing(s->octree.transform, svo::kDefaultViewDirection, 160, 160);
    camera.eye = camera.target + 0.5 * (camera.eye - camera.target);
    for (const float lod : {0.0f, 12.0f}) {  // the finest voxels, and coarser ones stopped by LOD
      const svo::PixelRays rays(s->octree.transform, camera, lod);
      svo::SiblingAttribute colors(view, svo::AttachmentType::Color),
          normals(view, svo::AttachmentType::Normal);
      svo::RawAttributePair both(view);
      const svo::ChildDescriptor* previous = nullptr;
      std::size_t hits = 0, shared = 0;
      for (int y = 0; y < camera.height; ++y)
        for (int x = 0; x < camera.width; ++x) {
          const svo::CastHit hit = svo::castRay(view, rays(x, y));
          if (!hit.hit) continue;
          ++hits;
          shared += hit.parent == previous;
          previous = hit.parent;
          const double size = hit.voxelSize();
          const glm::ivec3 c(glm::round((glm::dvec3(hit.cubeMin) - 1.0) / size));
          const auto it = s->attributes.find({svo::kMaxLevels - hit.scale, svotest::packCoord(c)});
          ASSERT_NE(it, s->attributes.end()) << s->name << " pixel " << x << "," << y;
          ASSERT_EQ(normals.value(hit), it->second.second)
              << s->name << " lod " << lod << " pixel " << x << "," << y;
          ASSERT_EQ(normals.normal(hit), svo::decodeNormal(it->second.second));
          ASSERT_EQ(both.normal(hit), it->second.second)
              << s->name << " lod " << lod << " pixel " << x << "," << y;
          if (view.attachment(svo::AttachmentType::Color)) {
            ASSERT_EQ(colors.value(hit), it->second.first)
                << s->name << " lod " << lod << " pixel " << x << "," << y;
            ASSERT_EQ(both.color(hit), it->second.first)
                << s->name << " lod " << lod << " pixel " << x << "," << y;
            ASSERT_EQ(colors.color(hit), glm::vec3(svo::decodeColor(it->second.first)));
          }
        }
      std::printf("[ SIBLINGS ] %s, lod %g: %zu hits, %zu on the previous hit's parent\n", s->name.c_str(),
                  lod, hits, shared);
      EXPECT_GT(hits, 5000u) << s->name;
      EXPECT_GT(shared, hits / 4) << s->name << ": too few hits on the previous hit's siblings";
      EXPECT_LT(shared, hits) << s->name;
    }
  }
}
