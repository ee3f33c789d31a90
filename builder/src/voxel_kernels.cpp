#include "voxel_kernels.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace svo::voxel {

void checkLevels(const BuildOptions& options) {
  if (options.levels < 1 || options.levels > kMaxLevels)
    throw std::invalid_argument("levels must be in [1, " + std::to_string(kMaxLevels) + "], got " +
                                std::to_string(options.levels));
}

std::optional<Triangle> makeTriangle(const std::array<dvec3, 3>& world, const SceneTransform& transform,
                                     std::uint32_t source) {
  Triangle t;
  for (int k = 0; k < 3; ++k) t.p[k] = transform.toOctree(world[k]);
  const dvec3 n = glm::cross(t.p[1] - t.p[0], t.p[2] - t.p[0]);
  const double length = glm::length(n);
  if (!(length > 0.0)) return std::nullopt;
  t.normal = n / length;
  t.source = source;
  return t;
}

geom::Cube cubeAt(int level, glm::ivec3 coord) {
  const double size = std::ldexp(1.0, -level);
  return {dvec3(1.0) + dvec3(coord) * size, size};
}

glm::ivec3 childCoordOf(glm::ivec3 coord, int slot) {
  return coord * 2 + glm::ivec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1);
}

std::uint8_t overlappedChildren(const Triangle& t, const geom::Cube& cube) {
  const dvec3 mid = cube.centre();
  const double half = 0.5 * cube.size;
  const dvec3 lo = glm::min(glm::min(t.p[0], t.p[1]), t.p[2]),
              hi = glm::max(glm::max(t.p[0], t.p[1]), t.p[2]);
  std::uint8_t mask = 0;
  for (int slot = 0; slot < 8; ++slot) {
    geom::Cube child{cube.lo + dvec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1) * half, half};
    bool candidate = true, inside = true;
    for (int a = 0; a < 3; ++a) {
      const bool upper = slot >> a & 1;
      if (upper ? hi[a] < mid[a] : lo[a] > mid[a]) candidate = false;
      if (lo[a] < child.lo[a] || hi[a] > child.lo[a] + half) inside = false;
    }
    if (candidate && (inside || geom::triangleOverlapsCube(t.p[0], t.p[1], t.p[2], child)))
      mask |= std::uint8_t(1u << slot);
  }
  return mask;
}

Piece clipPiece(const Triangle& t, std::uint32_t index, const geom::Cube& cube) {
  Piece p;
  p.triangle = index;
  p.polygon = geom::clipTriangleToCube(t.p[0], t.p[1], t.p[2], cube);
  if (p.polygon.n == 0) {
    // The SAT says the closed cube touches the triangle; clipping lost it to rounding. Keep the triangle's
    // closest vertex so the voxel still has a defined piece.
    p.polygon.n = 1;
    p.polygon.v[0] = glm::clamp(t.p[0], cube.lo, cube.lo + cube.size);
  }
  p.area = geom::polygonArea(p.polygon, &p.centroid);
  return p;
}

double pieceWeight(const Piece& p, const geom::Cube& cube) {
  return p.area + kTouchWeight * cube.size * cube.size;
}

namespace {

// Barycentric coordinates of x (in the triangle's plane) in t.
dvec3 barycentricIn(const Triangle& t, const dvec3& x) {
  const dvec3 e0 = t.p[1] - t.p[0], e1 = t.p[2] - t.p[0], r = x - t.p[0];
  const double d00 = glm::dot(e0, e0), d01 = glm::dot(e0, e1), d11 = glm::dot(e1, e1);
  const double d20 = glm::dot(r, e0), d21 = glm::dot(r, e1), den = d00 * d11 - d01 * d01;
  const double v = (d11 * d20 - d01 * d21) / den, w = (d00 * d21 - d01 * d20) / den;
  return dvec3(1.0 - v - w, v, w);
}

}  // namespace

dvec3 pieceNormal(const Piece& piece, const Triangle& t, const std::array<glm::vec3, 3>& corners) {
  const dvec3 b = barycentricIn(t, piece.centroid);
  const dvec3 n = b.x * dvec3(corners[0]) + b.y * dvec3(corners[1]) + b.z * dvec3(corners[2]);
  const double length = glm::length(n);
  return length > 0.0 && std::isfinite(length) ? n / length : t.normal;
}

dvec4 pieceColor(const Piece& piece, const Triangle& t, const glm::vec4* colors, const glm::vec2* uvs,
                 const Material& material, const std::vector<std::shared_ptr<const TextureImage>>& textures) {
  dvec4 color(material.baseColor);
  if (colors) {
    const dvec3 b = barycentricIn(t, piece.centroid);
    color *= b.x * dvec4(colors[0]) + b.y * dvec4(colors[1]) + b.z * dvec4(colors[2]);
  }
  if (material.texture >= 0 && uvs) {
    glm::vec2 uv[geom::kMaxClippedVertices + 3];
    for (int k = 0; k < piece.polygon.n; ++k) {
      const dvec3 b = barycentricIn(t, piece.polygon.v[k]);
      uv[k] = glm::vec2(b.x * glm::dvec2(uvs[0]) + b.y * glm::dvec2(uvs[1]) + b.z * glm::dvec2(uvs[2]));
    }
    color *= dvec4(textures[material.texture]->average({uv, std::size_t(piece.polygon.n)}));
  }
  return color;
}

void accumulate(Aggregate& a, double weight, const dvec3& normal, const dvec4* color) {
  a.weight += weight;
  a.normal += weight * normal;
  if (color) a.color += weight * *color;
}

dvec3 meanNormal(const Aggregate& a) {
  return glm::length(a.normal) > 0.0 ? glm::normalize(a.normal) : dvec3(0, 0, 1);
}

void extendExtents(const std::vector<Direction>& directions, const Piece& p, const geom::Cube& cube,
                   std::vector<Extent>& extents) {
  const dvec3 centre = cube.centre();
  for (std::size_t i = 0; i < directions.size(); ++i)
    for (const dvec3& v : p.polygon.vertices()) {
      const double d = glm::dot(directions[i].normal, v - centre) / cube.size;
      extents[i].lo = std::min(extents[i].lo, d), extents[i].hi = std::max(extents[i].hi, d);
    }
}

std::optional<ContourFit> chooseContour(const geom::Cube& cube, const std::vector<Direction>& directions,
                                        const std::vector<Extent>& extents,
                                        const std::vector<geom::Slab>& slabs, double minCut) {
  const dvec3 centre = cube.centre();
  const geom::HullVertices hull = slabs.empty() ? geom::HullVertices{} : geom::hullVertices(cube, slabs);
  std::optional<ContourFit> best;
  double bestScore = 0.0;
  for (std::size_t i = 0; i < directions.size(); ++i) {
    const dvec3 n = directions[i].normal;
    const double lo = extents[i].lo, hi = extents[i].hi;
    double hullLo, hullHi;
    if (hull.empty()) {
      hullHi = 0.5 * (std::abs(n.x) + std::abs(n.y) + std::abs(n.z));
      hullLo = -hullHi;
    } else {
      hullLo = 1e300, hullHi = -1e300;
      for (const dvec3& v : hull.vertices()) {
        const double d = glm::dot(n, v - centre) / cube.size;
        hullLo = std::min(hullLo, d), hullHi = std::max(hullHi, d);
      }
    }
    std::uint32_t bits;
    if (!(hullHi > hullLo) || !encodeContour(directions[i].quantized, lo, hi, bits)) continue;
    const Contour c = decodeContour(bits);
    const double slabLo = c.position - 0.5 * c.thickness, slabHi = c.position + 0.5 * c.thickness;
    const double cut = std::max(0.0, slabLo - hullLo) + std::max(0.0, hullHi - slabHi);
    const double score = cut / (hullHi - hullLo);
    if (cut >= minCut && score > bestScore) bestScore = score, best = ContourFit{bits, cut, hi - lo};
  }
  return best;
}

bool stopsRefining(const BuildOptions& options, int level, const ContourFit& contour, const Spread& spread) {
  const double thicknessFinest = contour.thickness * std::ldexp(1.0, options.levels - level);
  return thicknessFinest <= options.geometryError &&
         (options.colorError <= 0.0f || spread.color <= options.colorError) &&
         (options.normalError <= 0.0f ||
          spread.normalCos >= std::cos(double(options.normalError) * std::numbers::pi / 180.0));
}

geom::Slab slabOf(const geom::Cube& cube, std::uint32_t contourBits) {
  const Contour c = decodeContour(contourBits);
  const dvec3 n(c.normal);
  const double base = glm::dot(n, cube.centre());
  return {n, base + cube.size * (double(c.position) - 0.5 * double(c.thickness)),
          base + cube.size * (double(c.position) + 0.5 * double(c.thickness))};
}

std::vector<geom::Slab> slabsCutting(const std::vector<geom::Slab>& slabs, const geom::Cube& cube) {
  std::vector<geom::Slab> out;
  for (const geom::Slab& s : slabs)
    if (geom::slabCutsCube(s, cube)) out.push_back(s);
  return out;
}

void setAttributes(VoxelRecord& r, const Aggregate& a, bool colors) {
  if (colors) r.color = encodeColor(glm::vec4(a.color / a.weight));
  r.normal = latticeNormal(glm::vec3(meanNormal(a)));  // the store keeps normals on its 16-bit lattice
}

bool markIfDead(VoxelRecord& r, const Aggregate& sum) {
  if (sum.weight != 0.0) return false;
  r.childMask = 0;
  r.firstChild = kDeadVoxel;
  return true;
}

std::vector<VoxelRecord> prune(const std::vector<VoxelRecord>& in) {
  std::vector<VoxelRecord> out{in[0]};
  std::vector<std::pair<std::uint32_t, std::uint32_t>> queue{{0u, 0u}};  // (input index, output index)
  for (std::size_t q = 0; q < queue.size(); ++q) {
    const auto [i, o] = queue[q];
    const VoxelRecord& r = in[i];
    if (r.childMask == 0) continue;
    std::uint8_t mask = 0;
    const std::uint32_t first = std::uint32_t(out.size());
    for (std::uint32_t c = r.firstChild, slot = 0; slot < 8; ++slot) {
      if (!(r.childMask >> slot & 1u)) continue;
      if (in[c].firstChild != kDeadVoxel) {
        mask |= std::uint8_t(1u << slot);
        queue.push_back({c, std::uint32_t(out.size())});
        out.push_back(in[c]);
      }
      ++c;
    }
    out[o].childMask = mask;
    out[o].firstChild = first;
  }
  return out;
}

std::vector<VoxelRecord> pruneIfDead(std::vector<VoxelRecord>&& records) {
  const bool dead = std::any_of(records.begin(), records.end(),
                                [](const VoxelRecord& r) { return r.firstChild == kDeadVoxel; });
  return dead ? prune(records) : std::move(records);
}

}  // namespace svo::voxel
