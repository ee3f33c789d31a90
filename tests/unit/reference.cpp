#include "reference.hpp"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <stdexcept>
#include <tuple>

#include <gtest/gtest.h>
#include <glm/geometric.hpp>

#include "svo/builder/build.hpp"
#include "svo/store/store_reader.hpp"

namespace svotest {

TempFile::TempFile(const std::string& stem, const std::string& extension)
    : path(std::filesystem::temp_directory_path() / (stem + "_" + std::to_string(::getpid()) + extension)) {}

TempDir::TempDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  path_ = std::filesystem::temp_directory_path() /
          (std::string("svo-test-") + info->test_suite_name() + "-" + info->name() + "-" +
           std::to_string(::getpid()) + "-" + std::to_string(std::random_device{}()));
  std::filesystem::remove_all(path_);
  std::filesystem::create_directories(path_);
}

TempDir::~TempDir() {
  std::error_code ignored;
  std::filesystem::remove_all(path_, ignored);
}

std::filesystem::path TempDir::file(const std::string& name, const std::string& bytes) const {
  const std::filesystem::path p = path_ / name;
  std::ofstream(p, std::ios::binary) << bytes;
  return p;
}

void writeSphereAndBoxStore(const std::filesystem::path& path, std::uint32_t sliceBytes) {
  svo::Mesh mesh = makeSphere({0, 0, 0}, 1.0, 24, 24);
  appendMesh(mesh, makeBox({-1.2, -1.2, -0.2}, {0.3, -0.9, 0.9}));
  for (const glm::dvec3& p : mesh.positions)
    mesh.colors.push_back(glm::vec4(0.5 + 0.4 * p.x, 0.5 + 0.4 * p.y, 0.5 - 0.4 * p.z, 1.0));
  svo::BuildOptions options;
  options.levels = 8;
  svo::StoreWriteOptions write;
  write.sliceBytes = sliceBytes;
  svo::writeOctree(path, svo::buildOctree(mesh, options), write);
}

std::size_t differingVoxels(const svo::VoxelTree& a, const svo::VoxelTree& b) {
  std::size_t differing = 0;
  for (std::size_t i = 0; i < std::min(a.voxels.size(), b.voxels.size()); ++i) {
    const svo::VoxelRecord &x = a.voxels[i], &y = b.voxels[i];
    differing += x.childMask != y.childMask || x.firstChild != y.firstChild || x.hasContour != y.hasContour ||
                 (x.hasContour && x.contour != y.contour) || x.color != y.color || x.normal != y.normal;
  }
  return differing;
}

TempFile::~TempFile() {
  std::error_code ignored;
  if (!path.empty()) std::filesystem::remove(path, ignored);
}

// ---------------------------------------------------------------------------------------------------------
// (a)
namespace {

// Polygon of at most 3 + 6 vertices (each plane adds at most one).
struct Polygon {
  std::array<glm::dvec3, 12> v;
  int n = 0;
};

// Keeps the part of `in` with sign * (x[axis] - bound) >= 0. A vertex on the plane is kept; crossing points
// get their clipped coordinate set to the bound exactly.
void clipPlane(const Polygon& in, int axis, double bound, double sign, Polygon& out) {
  out.n = 0;
  if (in.n == 0) return;
  const auto inside = [&](const glm::dvec3& p) { return sign * (p[axis] - bound) >= 0.0; };
  if (in.n == 1) {
    if (inside(in.v[0])) out.v[out.n++] = in.v[0];
    return;
  }
  for (int i = 0; i < in.n; ++i) {
    const glm::dvec3& p = in.v[i];
    const glm::dvec3& q = in.v[(i + 1) % in.n];
    const bool pin = inside(p), qin = inside(q);
    if (pin) out.v[out.n++] = p;
    if (pin != qin) {
      const double s = (bound - p[axis]) / (q[axis] - p[axis]);
      glm::dvec3 r = p + s * (q - p);
      r[axis] = bound;
      out.v[out.n++] = r;
    }
  }
}

}  // namespace

bool triangleBoxOverlap(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c,
                        const glm::dvec3& boxMin, const glm::dvec3& boxMax) {
  Polygon p, q;
  p.v[0] = a;
  p.v[1] = b;
  p.v[2] = c;
  p.n = 3;
  for (int axis = 0; axis < 3; ++axis) {
    clipPlane(p, axis, boxMin[axis], 1.0, q);
    clipPlane(q, axis, boxMax[axis], -1.0, p);
    if (p.n == 0) return false;
  }
  return p.n > 0;
}

// ---------------------------------------------------------------------------------------------------------
// (b)
void sortUnique(std::vector<glm::ivec3>& coords) {
  std::sort(coords.begin(), coords.end(),
            [](const glm::ivec3& a, const glm::ivec3& b) { return packCoord(a) < packCoord(b); });
  coords.erase(std::unique(coords.begin(), coords.end()), coords.end());
}

std::vector<glm::ivec3> referenceLeafVoxels(const svo::Mesh& mesh, const svo::SceneTransform& transform,
                                            int levels, double margin) {
  if (levels < 0 || levels > 20) throw std::invalid_argument("referenceLeafVoxels: levels out of range");
  const double cells = std::ldexp(1.0, levels);
  const int maxIndex = (1 << levels) - 1;
  const double m = margin * cells;  // margin in cube units
  std::vector<glm::ivec3> out;
  for (const glm::uvec3& tri : mesh.triangles) {
    // Grid coordinates: (p - 1) * 2^levels; the scaling is exact.
    glm::dvec3 g[3];
    for (int k = 0; k < 3; ++k) g[k] = (transform.toOctree(mesh.positions[tri[k]]) - 1.0) * cells;
    const glm::dvec3 lo = glm::min(glm::min(g[0], g[1]), g[2]);
    const glm::dvec3 hi = glm::max(glm::max(g[0], g[1]), g[2]);
    glm::ivec3 first, last;
    bool empty = false;
    for (int axis = 0; axis < 3; ++axis) {
      // Cube i spans [i - m, i + 1 + m]; it can touch the triangle when i - m <= hi and i + 1 + m >= lo.
      const double f = std::floor(lo[axis] - m - 1.0), l = std::ceil(hi[axis] + m);
      first[axis] = int(std::clamp(f, 0.0, double(maxIndex)));
      last[axis] = int(std::clamp(l, -1.0, double(maxIndex)));
      if (l < 0.0 || f > maxIndex) empty = true;
    }
    if (empty) continue;
    for (int z = first.z; z <= last.z; ++z)
      for (int y = first.y; y <= last.y; ++y)
        for (int x = first.x; x <= last.x; ++x) {
          const glm::dvec3 boxMin = glm::dvec3(x, y, z) - m, boxMax = glm::dvec3(x, y, z) + 1.0 + m;
          if (triangleBoxOverlap(g[0], g[1], g[2], boxMin, boxMax)) out.emplace_back(x, y, z);
        }
  }
  sortUnique(out);
  return out;
}

// ---------------------------------------------------------------------------------------------------------
// (d)
namespace {

glm::ivec3 childCoord(const glm::ivec3& parent, int slot) {
  return parent * 2 + glm::ivec3(slot & 1, (slot >> 1) & 1, (slot >> 2) & 1);
}

void walkBlock(const svo::ChildDescriptor* desc, const glm::ivec3& coord, int level,
               std::vector<ChainContour>& chain, std::vector<LeafVoxel>& out) {
  if (level >= svo::kMaxLevels) throw std::runtime_error("walkLeaves: block deeper than kMaxLevels");
  for (int slot = 0; slot < 8; ++slot) {
    if (!((desc->validMask() >> slot) & 1)) continue;
    const glm::ivec3 c = childCoord(coord, slot);
    const std::optional<std::uint32_t> contour = svo::BlockView::contour(desc, slot);
    if (contour) chain.push_back({level + 1, c, *contour});
    if ((desc->leafMask() >> slot) & 1) {
      out.push_back({c, level + 1, chain});
    } else {
      walkBlock(svo::BlockView::child(desc, slot), c, level + 1, chain, out);
    }
    if (contour) chain.pop_back();
  }
}

void walkTree(const svo::VoxelTree& tree, std::uint32_t index, const glm::ivec3& coord, int level,
              std::vector<ChainContour>& chain, std::vector<LeafVoxel>& out) {
  if (level >= svo::kMaxLevels) throw std::runtime_error("walkLeaves: tree deeper than kMaxLevels");
  const svo::VoxelRecord& r = tree.voxels.at(index);
  std::uint32_t next = r.firstChild;
  for (int slot = 0; slot < 8; ++slot) {
    if (!((r.childMask >> slot) & 1)) continue;
    const std::uint32_t ci = next++;
    const svo::VoxelRecord& child = tree.voxels.at(ci);
    const glm::ivec3 c = childCoord(coord, slot);
    if (child.hasContour) chain.push_back({level + 1, c, child.contour});
    if (child.childMask == 0) {
      out.push_back({c, level + 1, chain});
    } else {
      walkTree(tree, ci, c, level + 1, chain, out);
    }
    if (child.hasContour) chain.pop_back();
  }
}

}  // namespace

std::vector<LeafVoxel> walkLeaves(const svo::BlockView& block) {
  std::vector<LeafVoxel> out;
  std::vector<ChainContour> chain;
  walkBlock(block.root(), glm::ivec3(0), 0, chain, out);
  return out;
}

std::uint64_t exactNormalUnits(const svo::BlockView& block) {
  std::uint64_t exact = 0;
  std::vector<const svo::ChildDescriptor*> stack{block.root()};
  while (!stack.empty()) {
    const svo::ChildDescriptor* d = stack.back();
    stack.pop_back();
    if (d->isStub()) continue;
    const auto unit = svo::BlockView::unit(d, svo::AttachmentType::NormalUnits);
    exact += unit && unit->half == 0 && unit->words[1] == svo::kExactNormalAxes;  // once per pair
    for (int slot = 0; slot < 8; ++slot)
      if (d->nonLeafMask() >> slot & 1u) stack.push_back(svo::BlockView::child(d, slot));
  }
  return exact;
}

// The root's own contour is not part of the chain: a block has no parent descriptor to hold it.
std::vector<LeafVoxel> walkLeaves(const svo::VoxelTree& tree) {
  std::vector<LeafVoxel> out;
  if (tree.voxels.empty()) return out;
  std::vector<ChainContour> chain;
  walkTree(tree, 0, glm::ivec3(0), 0, chain, out);
  return out;
}

std::vector<glm::ivec3> leafCoords(const std::vector<LeafVoxel>& leaves, int level,
                                   std::size_t* otherLevels) {
  std::vector<glm::ivec3> out;
  std::size_t other = 0;
  for (const LeafVoxel& v : leaves) {
    if (v.level == level)
      out.push_back(v.coord);
    else
      ++other;
  }
  if (otherLevels) *otherLevels = other;
  sortUnique(out);
  return out;
}

// ---------------------------------------------------------------------------------------------------------
// (c)
Shape cubeShape(const glm::ivec3& coord, int level) {
  const double h = std::ldexp(1.0, -level);
  Shape s;
  s.lo = 1.0 + glm::dvec3(coord) * h;
  s.hi = 1.0 + (glm::dvec3(coord) + 1.0) * h;
  return s;
}

Shape shapeOf(const LeafVoxel& voxel, bool withContours) {
  Shape s = cubeShape(voxel.coord, voxel.level);
  if (!withContours) return s;
  for (const ChainContour& cc : voxel.contours) {
    const svo::Contour c = svo::decodeContour(cc.bits);
    const double size = std::ldexp(1.0, -cc.level);
    const glm::dvec3 centre = 1.0 + (glm::dvec3(cc.coord) + 0.5) * size;
    // n = q / 31 with q integral: recover q exactly from the decoded float.
    const glm::dvec3 q = glm::round(glm::dvec3(c.normal) * double(svo::kContourNormalScale));
    // |n.u - p| <= th/2, u = (x - centre) / size  <=>  q.x in q.centre + 31 size [p - th/2, p + th/2].
    const double k = double(svo::kContourNormalScale) * size;
    const double p = double(c.position), half = 0.5 * double(c.thickness);
    Slab slab;
    slab.q = q;
    slab.lo = glm::dot(q, centre) + k * (p - half);
    slab.hi = glm::dot(q, centre) + k * (p + half);
    s.slabs.push_back(slab);
  }
  return s;
}

namespace {

// Narrows [t0, t1] to the t where lo <= o + t d <= hi (scalar); d == 0 exactly means "inside or not".
inline bool clipInterval(double o, double d, double lo, double hi, double& t0, double& t1) {
  if (d == 0.0) return lo <= o && o <= hi;
  double ta = (lo - o) / d, tb = (hi - o) / d;
  if (ta > tb) std::swap(ta, tb);
  t0 = std::max(t0, ta);
  t1 = std::min(t1, tb);
  return t0 <= t1;
}

}  // namespace

bool clipBox(const glm::dvec3& lo, const glm::dvec3& hi, const glm::dvec3& origin,
             const glm::dvec3& direction, double margin, double& t0, double& t1) {
  t0 = 0.0;
  t1 = kInf;
  for (int axis = 0; axis < 3; ++axis)
    if (!clipInterval(origin[axis], direction[axis], lo[axis] - margin, hi[axis] + margin, t0, t1))
      return false;
  return t0 <= t1;
}

bool clipRay(const Shape& shape, const glm::dvec3& origin, const glm::dvec3& direction, double margin,
             double& t0, double& t1) {
  if (!clipBox(shape.lo, shape.hi, origin, direction, margin, t0, t1)) return false;
  for (const Slab& s : shape.slabs) {
    const double grow = margin * glm::length(s.q);
    if (!clipInterval(glm::dot(s.q, origin), glm::dot(s.q, direction), s.lo - grow, s.hi + grow, t0, t1))
      return false;
  }
  return t0 <= t1;
}

RefCaster::RefCaster(std::vector<Shape> shapes) : shapes_(std::move(shapes)) {
  std::map<std::uint64_t, int> index;  // level-3 cube -> bucket
  for (int i = 0; i < int(shapes_.size()); ++i) {
    const Shape& s = shapes_[i];
    const glm::dvec3 size = s.hi - s.lo;
    if (std::max({size.x, size.y, size.z}) > 0.125) {  // coarser than level 3: a bucket of its own
      buckets_.push_back({s.lo, s.hi, {i}});
      continue;
    }
    const glm::ivec3 key = glm::ivec3(glm::floor((0.5 * (s.lo + s.hi) - 1.0) * 8.0));
    auto [it, fresh] = index.try_emplace((std::uint64_t(1) << 63) | packCoord(key), int(buckets_.size()));
    if (fresh) {
      const Shape cube = cubeShape(key, 3);
      buckets_.push_back({cube.lo, cube.hi, {}});
    }
    buckets_[it->second].members.push_back(i);
  }
}

RefHit RefCaster::first(const glm::dvec3& origin, const glm::dvec3& direction, double margin,
                        double minLength) const {
  std::vector<std::pair<double, int>> order;
  order.reserve(buckets_.size());
  for (int b = 0; b < int(buckets_.size()); ++b) {
    double t0, t1;
    if (clipBox(buckets_[b].lo, buckets_[b].hi, origin, direction, std::max(margin, 0.0), t0, t1))
      order.emplace_back(t0, b);
  }
  std::sort(order.begin(), order.end());
  RefHit best;
  for (const auto& [tb, b] : order) {
    if (tb > best.t0) break;  // every member is entered at or after its bucket
    for (int i : buckets_[b].members) {
      double t0, t1;
      if (!clipRay(shapes_[i], origin, direction, margin, t0, t1) || t1 - t0 < minLength) continue;
      if (t0 < best.t0 || (t0 == best.t0 && i < best.voxel)) best = {i, t0, t1};
    }
  }
  return best;
}

// ---------------------------------------------------------------------------------------------------------
// (e)
double pointTriangleDistance(const glm::dvec3& p, const glm::dvec3& a, const glm::dvec3& b,
                             const glm::dvec3& c) {
  const glm::dvec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = glm::dot(ab, ap), d2 = glm::dot(ac, ap);
  if (d1 <= 0.0 && d2 <= 0.0) return glm::length(p - a);
  const glm::dvec3 bp = p - b;
  const double d3 = glm::dot(ab, bp), d4 = glm::dot(ac, bp);
  if (d3 >= 0.0 && d4 <= d3) return glm::length(p - b);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return glm::length(p - (a + ab * (d1 / (d1 - d3))));
  const glm::dvec3 cp = p - c;
  const double d5 = glm::dot(ab, cp), d6 = glm::dot(ac, cp);
  if (d6 >= 0.0 && d5 <= d6) return glm::length(p - c);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return glm::length(p - (a + ac * (d2 / (d2 - d6))));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0)
    return glm::length(p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))));
  const double denom = 1.0 / (va + vb + vc);
  const double v = vb * denom, w = vc * denom;
  return glm::length(p - (a + ab * v + ac * w));
}

// ---------------------------------------------------------------------------------------------------------
// (f)
svo::Mesh makeSphere(const glm::dvec3& centre, double radius, int stacks, int slices) {
  svo::Mesh m;
  const double pi = 3.14159265358979323846;
  m.positions.push_back(centre + glm::dvec3(0, 0, radius));
  for (int i = 1; i < stacks; ++i) {
    const double theta = pi * i / stacks;
    for (int j = 0; j < slices; ++j) {
      const double phi = 2.0 * pi * j / slices;
      m.positions.push_back(centre + radius * glm::dvec3(std::sin(theta) * std::cos(phi),
                                                         std::sin(theta) * std::sin(phi), std::cos(theta)));
    }
  }
  m.positions.push_back(centre - glm::dvec3(0, 0, radius));
  const auto ring = [&](int i, int j) { return std::uint32_t(1 + (i - 1) * slices + (j % slices)); };
  const std::uint32_t south = std::uint32_t(m.positions.size() - 1);
  for (int j = 0; j < slices; ++j) {
    m.triangles.emplace_back(0, ring(1, j), ring(1, j + 1));
    m.triangles.emplace_back(south, ring(stacks - 1, j + 1), ring(stacks - 1, j));
  }
  for (int i = 1; i + 1 < stacks; ++i)
    for (int j = 0; j < slices; ++j) {
      m.triangles.emplace_back(ring(i, j), ring(i + 1, j), ring(i + 1, j + 1));
      m.triangles.emplace_back(ring(i, j), ring(i + 1, j + 1), ring(i, j + 1));
    }
  return m;
}

svo::Mesh makeBox(const glm::dvec3& lo, const glm::dvec3& hi) {
  svo::Mesh m;
  for (int k = 0; k < 8; ++k)
    m.positions.emplace_back(k & 1 ? hi.x : lo.x, k & 2 ? hi.y : lo.y, k & 4 ? hi.z : lo.z);
  const int faces[6][4] = {{0, 2, 6, 4}, {1, 5, 7, 3}, {0, 4, 5, 1},
                           {2, 3, 7, 6}, {0, 1, 3, 2}, {4, 6, 7, 5}};
  for (const auto& f : faces) {
    m.triangles.emplace_back(f[0], f[1], f[2]);
    m.triangles.emplace_back(f[0], f[2], f[3]);
  }
  return m;
}

svo::Mesh makeRandomTriangles(std::uint64_t seed, int count, const glm::dvec3& lo, const glm::dvec3& hi,
                              double maxEdge) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  svo::Mesh m;
  for (int i = 0; i < count; ++i) {
    const glm::dvec3 a = lo + (hi - lo) * glm::dvec3(uni(rng), uni(rng), uni(rng));
    const auto offset = [&] {
      return glm::clamp(a + maxEdge * (2.0 * glm::dvec3(uni(rng), uni(rng), uni(rng)) - 1.0), lo, hi);
    };
    const std::uint32_t base = std::uint32_t(m.positions.size());
    m.positions.push_back(a);
    m.positions.push_back(offset());
    m.positions.push_back(offset());
    m.triangles.emplace_back(base, base + 1, base + 2);
  }
  return m;
}

void appendMesh(svo::Mesh& to, const svo::Mesh& from) {
  const std::uint32_t base = std::uint32_t(to.positions.size());
  to.positions.insert(to.positions.end(), from.positions.begin(), from.positions.end());
  for (const glm::uvec3& t : from.triangles) to.triangles.push_back(t + base);
}

// The whole store's tree cut down to the voxels whose slice is in `resident`.
svo::VoxelTree truncatedTree(const svo::StoreReader& reader, const std::vector<std::uint32_t>& resident) {
  const svo::VoxelTree full = reader.loadTree();
  // (voxel level, cube level, cube) -> slice; a run of sub-cubes is keyed by each sub-cube.
  std::map<std::tuple<int, int, int, int, int>, std::uint32_t> sliceAt;
  const auto& slices = reader.slices();
  for (std::uint32_t s = 0; s < slices.size(); ++s) {
    const svo::SliceInfo& i = slices[s];
    if (i.firstSlot == 0 && i.lastSlot == 7) {
      sliceAt[{i.voxelLevel, i.cubeLevel, i.cubeCoord.x, i.cubeCoord.y, i.cubeCoord.z}] = s;
      continue;
    }
    for (int slot = i.firstSlot; slot <= i.lastSlot; ++slot) {
      const glm::ivec3 sub = svo::childCoord(i.cubeCoord, slot);
      sliceAt[{i.voxelLevel, i.cubeLevel + 1, sub.x, sub.y, sub.z}] = s;
    }
  }
  const std::set<std::uint32_t> have(resident.begin(), resident.end());
  const auto kept = [&](int level, glm::ivec3 c) {
    for (int cubeLevel = 0; cubeLevel < level; ++cubeLevel) {
      const glm::ivec3 cube = c >> (level - cubeLevel);
      const auto it = sliceAt.find({level, cubeLevel, cube.x, cube.y, cube.z});
      if (it != sliceAt.end()) return have.count(it->second) != 0;
    }
    ADD_FAILURE() << "no slice holds a voxel of level " << level;
    return false;
  };
  svo::VoxelTree out;
  out.hasColors = full.hasColors, out.hasNormals = full.hasNormals;
  out.voxels.push_back(full.voxels[0]);
  // The slice each kept voxel's children come from, for the compressed layout's units.
  const bool childSlices = !full.childSlice.empty();
  if (childSlices) out.childSlice.push_back(full.childSlice[0]);
  struct Item {
    std::uint32_t from, to;
    int level;
    glm::ivec3 coord;
  };
  std::vector<Item> queue{{0, 0, 0, glm::ivec3(0)}};
  for (std::size_t q = 0; q < queue.size(); ++q) {
    const Item item = queue[q];
    const svo::VoxelRecord& r = full.voxels[item.from];
    std::uint8_t mask = 0;
    std::vector<Item> children;
    for (std::uint32_t c = r.firstChild, slot = 0; slot < 8; ++slot) {
      if (!(r.childMask >> slot & 1u)) continue;
      const glm::ivec3 coord = svo::childCoord(item.coord, int(slot));
      if (kept(item.level + 1, coord)) {
        mask |= std::uint8_t(1u << slot);
        children.push_back({c, 0, item.level + 1, coord});
      }
      ++c;
    }
    out.voxels[item.to].childMask = mask;
    out.voxels[item.to].firstChild = mask ? std::uint32_t(out.voxels.size()) : 0;
    for (Item& child : children) {
      child.to = std::uint32_t(out.voxels.size());
      svo::VoxelRecord record = full.voxels[child.from];
      record.childMask = 0, record.firstChild = 0;
      out.voxels.push_back(record);
      if (childSlices) out.childSlice.push_back(full.childSlice[child.from]);
      queue.push_back(child);
    }
  }
  return out;
}

}  // namespace svotest
