#include "stability.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <random>

#include <fmt/format.h>
#include <glm/geometric.hpp>

#include "svo/accel/accel.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/raycast.hpp"
#include "svo/client/render.hpp"

namespace svo::tools {
namespace {

using glm::dvec3;

// Camera rays per stiff camera: a small image, enough to sweep the scene.
constexpr int kCameraPixels = 24;
// Structure the surface-distance queries use (any structure answers box queries exactly).
constexpr const char* kQueryStructure = "kd-binned";
// Direction components that stress the caster's clamp to +-2^-23 (released code) and its mirroring.
constexpr double kTinyComponents[] = {0.0, -0.0, 1e-30, -1e-30, 1e-40 /* float denormal */, 1e-300};

std::uint32_t addVertex(Mesh& m, const dvec3& p) {
  m.positions.push_back(p);
  return std::uint32_t(m.positions.size() - 1);
}
void addTriangle(Mesh& m, const dvec3& a, const dvec3& b, const dvec3& c) {
  m.triangles.emplace_back(addVertex(m, a), addVertex(m, b), addVertex(m, c));
}

// UV sphere with shared vertices.
Mesh sphere(const dvec3& centre, double radius, int stacks, int slices) {
  Mesh m;
  const auto at = [&](int i, int j) {
    const double theta = std::numbers::pi * i / stacks, phi = 2.0 * std::numbers::pi * j / slices;
    return centre +
           radius * dvec3(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
  };
  for (int i = 0; i < stacks; ++i)
    for (int j = 0; j < slices; ++j) {
      if (i > 0) addTriangle(m, at(i, j), at(i + 1, j), at(i + 1, j + 1));
      if (i + 1 < stacks) addTriangle(m, at(i, j), at(i + 1, j + 1), at(i, j + 1));
    }
  return m;
}

// Rays of a pinhole camera through every pixel of a small image.
void addCamera(std::vector<StiffRay>& rays, const dvec3& eye, const dvec3& target, double fov) {
  Camera camera;
  camera.eye = eye, camera.target = target, camera.fovYDegrees = fov;
  camera.width = camera.height = kCameraPixels;
  if (std::abs(glm::dot(glm::normalize(target - eye), camera.up)) > 0.99) camera.up = dvec3(1, 0, 0);
  const Camera::Basis basis = camera.basis();
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x) {
      StiffRay r;
      r.origin = eye;
      Camera::pixelRay(camera, basis, x, y, r.direction);
      rays.push_back(r);
    }
}

// Cameras around and inside the scene's bounds.
void addCameras(std::vector<StiffRay>& rays, const Mesh& mesh) {
  const SceneTransform t = fitSceneCube(mesh);
  const dvec3 centre = t.toWorld(dvec3(1.5));
  addCamera(rays, centre + t.size * dvec3(1.3, 0.9, 1.7), centre, 50.0);  // outside
  addCamera(rays, centre + t.size * dvec3(0.05, 0.02, -0.03), centre + dvec3(t.size, 0, 0), 120.0);  // inside
  addCamera(rays, centre + dvec3(0, 0, 2.0 * t.size), centre, 40.0);  // straight down the z axis
}

// Rays exactly along the finest voxel grid: axis-parallel through faces, edges and corners, with the other
// components +-0, tiny or denormal, and diagonals through grid vertices.
void addGridRays(std::vector<StiffRay>& rays, const Mesh& mesh, int levels, std::mt19937_64& rng) {
  const SceneTransform t = fitSceneCube(mesh);
  const int cells = 1 << std::min(levels, 12);
  std::uniform_int_distribution<int> cell(0, cells);
  const auto grid = [&](int i) { return 1.0 + double(i) / double(cells); };  // octree coordinate on the grid
  for (int k = 0; k < 48; ++k) {
    for (int axis = 0; axis < 3; ++axis) {
      dvec3 p(grid(cell(rng)), grid(cell(rng)), grid(cell(rng)));
      dvec3 d(0.0);
      d[axis] = k % 2 ? 1.0 : -1.0;
      p[axis] = d[axis] > 0 ? 0.5 : 2.5;  // start outside the octree
      const double tiny = kTinyComponents[k % std::size(kTinyComponents)];
      d[(axis + 1) % 3] = tiny;
      d[(axis + 2) % 3] = k % 3 ? -tiny : tiny;
      rays.push_back({t.toWorld(p), d});
    }
    // Through a grid vertex along a diagonal, and from a point exactly on a face.
    const dvec3 vertex(grid(cell(rng)), grid(cell(rng)), grid(cell(rng)));
    const dvec3 diagonal(k & 1 ? 1 : -1, k & 2 ? 1 : -1, k & 4 ? 1 : -1);
    rays.push_back({t.toWorld(vertex - 0.75 * diagonal), diagonal});
    rays.push_back({t.toWorld(dvec3(vertex.x, vertex.y, 1.5)), dvec3(0.3, -0.2, k & 1 ? 1.0 : -1.0)});
  }
}

// Rays from inside a voxel: just off a surface point, in random directions.
void addInsideRays(std::vector<StiffRay>& rays, const Mesh& mesh, std::mt19937_64& rng) {
  std::uniform_int_distribution<std::size_t> pick(0, mesh.triangles.size() - 1);
  std::normal_distribution<double> g;
  for (int k = 0; k < 64; ++k) {
    const glm::uvec3 tri = mesh.triangles[pick(rng)];
    const dvec3 c = (mesh.positions[tri.x] + mesh.positions[tri.y] + mesh.positions[tri.z]) / 3.0;
    rays.push_back({c, dvec3(g(rng), g(rng), g(rng))});
  }
}

StiffCase makeCase(std::string name, std::string what, Mesh mesh, int levels, std::uint64_t seed) {
  StiffCase c{std::move(name), std::move(what), std::move(mesh), levels, true, {}};
  std::mt19937_64 rng(seed);
  addCameras(c.rays, c.mesh);
  addGridRays(c.rays, c.mesh, levels, rng);
  addInsideRays(c.rays, c.mesh, rng);
  return c;
}

// Distance from p to triangle abc: to the plane where p projects inside, else to the nearest edge.
double pointTriangleDistance(const dvec3& p, const dvec3& a, const dvec3& b, const dvec3& c) {
  const auto segment = [&](const dvec3& u, const dvec3& v) {
    const dvec3 e = v - u;
    const double len2 = glm::dot(e, e);
    const double s = len2 > 0.0 ? std::clamp(glm::dot(p - u, e) / len2, 0.0, 1.0) : 0.0;
    return glm::length(p - (u + s * e));
  };
  const dvec3 n = glm::cross(b - a, c - a);
  const double n2 = glm::dot(n, n);
  if (n2 > 0.0) {
    const dvec3 q = p - n * (glm::dot(p - a, n) / n2);  // projection onto the plane
    const bool inside = glm::dot(glm::cross(b - a, q - a), n) >= 0.0 &&
                        glm::dot(glm::cross(c - b, q - b), n) >= 0.0 &&
                        glm::dot(glm::cross(a - c, q - c), n) >= 0.0;
    if (inside) return glm::length(p - q);
  }
  return std::min({segment(a, b), segment(b, c), segment(c, a)});
}

bool finite(const glm::vec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

// Two tiny triangles (1e-6 of the scene) at opposite corners: 23 levels stay small.
StiffCase fullDepthCase() {
  Mesh m;
  addTriangle(m, dvec3(0.0), dvec3(1e-6, 0, 0), dvec3(0, 1e-6, 0.3e-6));
  addTriangle(m, dvec3(1.0), dvec3(1.0 - 1e-6, 1.0, 1.0), dvec3(1.0, 1.0 - 0.7e-6, 1.0 - 1e-6));
  StiffCase c = makeCase("23 levels",
                         "the full 23 levels: voxels of 2^-23, the float mantissa's last bit; cube voxels (a "
                         "float ray is itself only known to half a finest voxel there)",
                         m, 23, 2);
  // Aim at the tiny triangles from several sides, from ~500 finest voxels away: the caster's t is a float,
  // so a voxel of 2^-23 is only resolved where t itself is small (t's ulp is t x 2^-24).
  for (const glm::uvec3& t : m.triangles) {
    const dvec3 centroid = (m.positions[t.x] + m.positions[t.y] + m.positions[t.z]) / 3.0;
    for (const dvec3 d : {dvec3(0, 0, -1), dvec3(0, 0, 1), dvec3(1, 1, 1), dvec3(-0.3, 0.2, -1)})
      c.rays.push_back({centroid - 1e-4 * d, d});
  }
  c.contours = false;
  return c;
}

// The ORG paper's worst case: two huge triangles among many tiny ones.
StiffCase hugeAmongTinyCase(int detail) {
  Mesh m;
  addTriangle(m, dvec3(-1, -1, -1), dvec3(1, -1, -1), dvec3(0, 1, 1));
  addTriangle(m, dvec3(-1, 1, -1), dvec3(1, 1, -1), dvec3(0, -1, 1));
  std::mt19937_64 rng(10);
  std::uniform_real_distribution<double> u(-1.0, 1.0), small(-1e-3, 1e-3);
  for (int k = 0; k < 10000 * detail * detail; ++k) {
    const dvec3 p(u(rng), u(rng), u(rng));
    addTriangle(m, p, p + dvec3(small(rng), small(rng), small(rng)),
                p + dvec3(small(rng), small(rng), small(rng)));
  }
  return makeCase("huge among tiny", "2 scene-sized triangles among 10^4 x detail^2 tiny ones", std::move(m),
                  8, 10);
}

// A field of thin grass blades on the ground.
StiffCase grassCase(int detail) {
  Mesh m;
  addTriangle(m, dvec3(-1, 0, -1), dvec3(1, 0, -1), dvec3(1, 0, 1));
  addTriangle(m, dvec3(-1, 0, -1), dvec3(1, 0, 1), dvec3(-1, 0, 1));
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0), lean(-0.1, 0.1);
  for (int k = 0; k < 2000 * detail; ++k) {
    const dvec3 base(u(rng), 0.0, u(rng));
    addTriangle(m, base, base + dvec3(2e-3, 0, 0), base + dvec3(lean(rng), 0.2 + 0.1 * lean(rng), lean(rng)));
  }
  return makeCase("grass", "thin blades (2e-3 wide, 0.2 tall) on a ground plane", std::move(m), 9, 11);
}

}  // namespace

std::vector<StiffCase> stiffCases(int detail) {
  detail = std::max(detail, 1);
  std::vector<StiffCase> cases;
  const Mesh ball = sphere(dvec3(0.2, -0.1, 0.3), 1.0, 10, 14);
  cases.push_back(makeCase(
      "grid rays", "axis-parallel rays along voxel faces, edges, corners; +-0, 1e-30, denormal components",
      ball, 8, 1));
  cases.push_back(fullDepthCase());
  for (const auto& [name, offset, scale] :
       {std::tuple{"offset 1e6", 1e6, 1.0}, std::tuple{"offset 1e-6", 1e-6, 1.0},
        std::tuple{"scale 1e6", 0.0, 1e6}, std::tuple{"scale 1e-6", 0.0, 1e-6}}) {
    Mesh m = ball;
    for (dvec3& p : m.positions) p = p * scale + dvec3(offset, -offset, offset);
    cases.push_back(
        makeCase(name, "a sphere moved or scaled far from unit size and the origin", std::move(m), 8, 3));
  }
  {
    Mesh m;  // z = 0 exactly: one bounding-box extent is zero
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j)
        addTriangle(m, dvec3(i, j, 0), dvec3(i + 1, j, 0), dvec3(i + 1, j + 1, 0)),
            addTriangle(m, dvec3(i, j, 0), dvec3(i + 1, j + 1, 0), dvec3(i, j + 1, 0));
    StiffCase c =
        makeCase("flat", "every triangle in z = 0: a zero bounding-box extent; grazing rays", m, 8, 4);
    for (int k = 0; k < 64; ++k)  // grazing: nearly in the plane
      c.rays.push_back({dvec3(-1.0, 0.1 + 0.06 * k, 1e-3), dvec3(1.0, 0.01 * (k % 7), -1e-3 * (1 + k % 5))});
    cases.push_back(std::move(c));
  }
  {
    Mesh m;
    addTriangle(m, dvec3(-1, -1, 0.2), dvec3(1, -0.8, -0.1), dvec3(0.1, 1, 0.4));
    cases.push_back(makeCase("single triangle", "one triangle", m, 9, 5));
  }
  {
    Mesh m;
    addTriangle(m, dvec3(0, 0, 0), dvec3(1, 0.2, 0.1), dvec3(0.5, 0.1 + 1e-6, 0.05));
    addTriangle(m, dvec3(0, 0.3, 0), dvec3(0.2, 0.5, 0.4), dvec3(0.1, 0.3, 0.2));
    cases.push_back(makeCase("needle", "a triangle a million times longer than wide", m, 10, 6));
  }
  {
    Mesh m;
    for (int k = 0; k < 5; ++k)
      addTriangle(m, dvec3(-1 + 0.1 * k, -1, 0.25), dvec3(1, -0.9 + 0.1 * k, 0.25),
                  dvec3(0, 1 - 0.05 * k, 0.25));
    addTriangle(m, dvec3(-1, -1, -1), dvec3(1, 0, 1), dvec3(0, 1, -0.5));
    cases.push_back(makeCase("coplanar overlap", "five overlapping triangles in one plane", m, 8, 7));
  }
  {
    Mesh m = ball;
    const std::size_t n = m.positions.size();
    for (std::size_t i = 0; i + 2 < n; i += 7) {
      m.triangles.emplace_back(std::uint32_t(i), std::uint32_t(i), std::uint32_t(i + 1));  // repeated vertex
      const dvec3 a = m.positions[i], b = m.positions[i + 1];
      m.triangles.emplace_back(addVertex(m, a), addVertex(m, b), addVertex(m, 0.5 * (a + b)));  // zero area
      m.triangles.push_back(m.triangles[i / 7]);  // an exact duplicate
    }
    cases.push_back(makeCase(
        "degenerate", "zero-area, repeated-vertex and duplicated triangles among valid ones", m, 8, 8));
  }
  {
    // A plane tilted 1e-3 rad from z = 0: contour normals nearly parallel to a face, thin slabs.
    Mesh m;
    const double tilt = 1e-3;
    addTriangle(m, dvec3(-1, -1, -tilt), dvec3(1, -1, tilt), dvec3(1, 1, tilt));
    addTriangle(m, dvec3(-1, -1, -tilt), dvec3(1, 1, tilt), dvec3(-1, 1, -tilt));
    addTriangle(m, dvec3(-0.2, -0.2, -0.5), dvec3(0.3, -0.1, 0.5), dvec3(0.0, 0.4, 0.1));  // not flat
    StiffCase c = makeCase("grazing contours",
                           "a plane 1e-3 rad off a face: grazing slabs; rays at grazing angles", m, 9, 9);
    for (int k = 0; k < 64; ++k)
      c.rays.push_back(
          {dvec3(-2.0, -0.9 + 0.028 * k, 0.01), dvec3(1.0, 0.001 * (k % 5), -0.004 - 0.001 * (k % 3))});
    cases.push_back(std::move(c));
  }
  cases.push_back(hugeAmongTinyCase(detail));
  cases.push_back(grassCase(detail));
  return cases;
}

CaseResult evaluateCase(const StiffCase& stiff, const StabilityBounds& bounds) {
  const auto start = std::chrono::steady_clock::now();
  // As `svo build` does: degenerate triangles (zero area, repeated vertices) are dropped first, so the
  // builder and the structures index the same triangles.
  StiffCase c = stiff;
  const std::size_t dropped = validateMesh(c.mesh, c.name);
  CaseResult r;
  r.droppedTriangles = dropped;
  r.name = c.name;
  r.what = c.what;
  r.triangles = c.mesh.triangles.size();
  r.rays = c.rays.size();
  const accel::Triangles triangles = accel::trianglesOf(c.mesh);
  const std::unique_ptr<accel::Accel> reference = accel::buildBruteForce(triangles);
  std::vector<std::unique_ptr<accel::Accel>> structures;
  const accel::Accel* query = nullptr;
  for (const std::string& name : accel::structureNames()) {
    if (name == "brute") continue;
    structures.push_back(accel::buildByName(name, triangles));
    if (name == kQueryStructure) query = structures.back().get();
  }
  r.structures = structures.size();
  BuildOptions options;
  options.levels = c.levels;
  const Octree octree = buildOctree(c.mesh, options);
  const BlockView block = octree.block.view();
  const SceneTransform& scene = octree.transform;
  CastOptions cast;
  cast.contours = c.contours;

  std::size_t rayIndex = 0;
  const auto fail = [&](const std::string& why) {
    if (!r.failure.empty()) return;
    const StiffRay& ray = c.rays[rayIndex];
    r.failure =
        fmt::format("{} (ray {}: origin ({:.17g}, {:.17g}, {:.17g}), direction ({:.17g}, {:.17g}, {:.17g}))",
                    why, rayIndex, ray.origin.x, ray.origin.y, ray.origin.z, ray.direction.x, ray.direction.y,
                    ray.direction.z);
  };
  double iterationSum = 0.0, surfaceSum = 0.0;
  std::size_t surfaceCount = 0;
  for (; rayIndex < c.rays.size(); ++rayIndex) {
    const StiffRay& ray = c.rays[rayIndex];
    accel::Ray worldRay;
    worldRay.origin = ray.origin;
    worldRay.direction = ray.direction;
    const accel::Hit ref = reference->closestHit(worldRay);
    r.referenceHits += ref.hit();
    for (const auto& s : structures) {
      const accel::Hit h = s->closestHit(worldRay);
      if (h.triangle == ref.triangle) continue;
      const double error =
          h.hit() && ref.hit() ? std::abs(h.t - ref.t) / std::max(std::abs(ref.t), 1e-300) : 1.0;
      r.maxAccelError = std::max(r.maxAccelError, error);
      if (error > bounds.accelRelative) {
        ++r.accelMismatches;
        fail(s->name() + " disagrees with brute force");
      }
    }

    // The caster on the same ray: t is the same parameter (the octree direction is the world one / size).
    OctreeRay o;
    o.origin = glm::vec3(scene.toOctree(ray.origin));
    o.direction = glm::vec3(ray.direction / scene.size);
    const CastHit hit = castRay(block, o, cast);
    r.maxIterations = std::max(r.maxIterations, hit.iterations);
    iterationSum += hit.iterations;
    if (hit.iterations > cast.maxIterations) ++r.capped, fail("a ray hit the iteration cap");
    if (hit.hit && (!std::isfinite(hit.t) || !finite(hit.position))) {
      ++r.nonFinite;
      fail("a non-finite hit");
      continue;
    }
    r.casterHits += hit.hit;
    const double directionLength = glm::length(ray.direction);
    const double finestVoxelT = scene.size / double(std::int64_t(1) << c.levels) / directionLength;
    // A contact closer to the origin than the origin's own float rounding may fall on either side of it.
    const bool contactAtOrigin = ref.hit() && ref.t * directionLength / scene.size <= bounds.seeThroughOctree;
    if (ref.hit() && !contactAtOrigin) {
      const double slack =
          bounds.seeThroughOctree * scene.size / directionLength + bounds.seeThroughRelative * ref.t;
      const double excess = hit.hit ? double(hit.t) - ref.t : std::numeric_limits<double>::infinity();
      if (excess > 0.0) r.maxSeeThrough = std::max(r.maxSeeThrough, excess / finestVoxelT);
      if (excess > slack)
        ++r.seeThrough,
            fail(fmt::format("the caster saw through the surface: reference t {:.9g} (triangle {}), "
                             "caster {}",
                             ref.t, ref.triangle, hit.hit ? fmt::format("t {:.9g}", hit.t) : "miss"));
    }
    if (hit.hit) {
      const dvec3 p = scene.toWorld(dvec3(hit.position));
      const double diagonal = std::sqrt(3.0) * double(hit.voxelSize()) * scene.size;
      // Float positions in [1, 2] are good to 2^-23 per coordinate.
      const double rounding = std::sqrt(3.0) * scene.size / double(1 << 23);
      const double reach = bounds.surfaceDiagonals * diagonal + rounding;
      accel::Box box;
      box.lo = p - 2.0 * reach;
      box.hi = p + 2.0 * reach;
      double distance = 2.0 * reach;  // beyond the box: at least this far
      for (const std::uint32_t t : query->boxQuery(box)) {
        const glm::uvec3 tri = c.mesh.triangles[t];
        distance =
            std::min(distance, pointTriangleDistance(p, c.mesh.positions[tri.x], c.mesh.positions[tri.y],
                                                     c.mesh.positions[tri.z]));
      }
      const double error = distance / diagonal;
      r.maxSurfaceError = std::max(r.maxSurfaceError, error);
      surfaceSum += error, ++surfaceCount;
      if (distance > reach)
        fail(fmt::format("a hit point {:.3g} voxel diagonals from the mesh", distance / diagonal));
    }
  }
  r.meanIterations = r.rays ? iterationSum / double(r.rays) : 0.0;
  r.meanSurfaceError = surfaceCount ? surfaceSum / double(surfaceCount) : 0.0;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return r;
}

}  // namespace svo::tools
