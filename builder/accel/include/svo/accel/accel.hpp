// Triangle acceleration structures behind one interface: build from triangles, closest hit, any hit, box
// query, statistics. Every structure answers exactly what the brute-force reference answers: the same
// triangle (ties on t broken by the smaller triangle id) and the same t, because all of them run the same
// double-precision ray/triangle kernel and the same triangle/box test; the structures only choose which
// triangles to test. Specification: the kd-tree (Qian, Liang & Zhang 2012), ORG grid (Li & Wang 2011) and
// OAVM octree (Yuan et al. 2017) papers.
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

namespace svo {
struct Mesh;
}

namespace svo::accel {

inline constexpr std::uint32_t kNoTriangle = 0xffffffffu;
inline constexpr double kInfinity = std::numeric_limits<double>::infinity();

// Indexed triangles in double precision (svo::Mesh's layout). Triangle ids are indices into `indices`.
struct Triangles {
  std::span<const glm::dvec3> positions;
  std::span<const glm::uvec3> indices;
};
Triangles trianglesOf(const Mesh& mesh);

// A ray o + t·d, t in [tMin, tMax] (closed). `direction` need not be unit length; t is in its units.
struct Ray {
  glm::dvec3 origin{0.0};
  glm::dvec3 direction{0.0, 0.0, 1.0};
  double tMin = 0.0;
  double tMax = kInfinity;
};

struct Hit {
  std::uint32_t triangle = kNoTriangle;
  double t = kInfinity;
  double u = 0.0, v = 0.0;  // barycentrics of vertices 1 and 2
  bool hit() const { return triangle != kNoTriangle; }
};

// A closed axis-aligned box.
struct Box {
  glm::dvec3 lo{kInfinity};
  glm::dvec3 hi{-kInfinity};
  bool empty() const { return lo.x > hi.x || lo.y > hi.y || lo.z > hi.z; }
  void extend(const glm::dvec3& p);
  void extend(const Box& b);
  glm::dvec3 extent() const { return empty() ? glm::dvec3(0.0) : hi - lo; }
};

// Counts as the papers tabulate them. `cells` is kd-tree nodes, grid cells (all levels) or octree nodes;
// `references` is triangle references stored in leaves; `pointers` is what the OAVM paper counts (pointer
// fields stored: child/parent pointers, leaf list and volume pointers); `bytes` is the memory of the
// structure.
struct Stats {
  std::size_t triangles = 0;    // valid (finite, non-degenerate) triangles indexed
  std::size_t cells = 0;        // nodes or cells
  std::size_t leaves = 0;       // leaves (kd, octree) or leaf cells (grids)
  std::size_t emptyLeaves = 0;  // leaves without triangles
  std::size_t references = 0;   // triangle references
  std::size_t pointers = 0;     // pointer fields (see above)
  std::size_t volumes = 0;      // OAVM merged empty volumes; grids: sub-grids
  std::size_t maxDepth = 0;     // deepest level (root = 0)
  std::size_t bytes = 0;
};

class Accel {
 public:
  virtual ~Accel() = default;
  virtual std::string name() const = 0;
  // Nearest hit with t in [ray.tMin, ray.tMax]; equal t resolves to the smaller triangle id.
  virtual Hit closestHit(const Ray& ray) const = 0;
  // Whether any triangle is hit with t in [ray.tMin, ray.tMax].
  virtual bool anyHit(const Ray& ray) const = 0;
  // Ids of the triangles that overlap the closed box (separating-axis test), ascending.
  virtual std::vector<std::uint32_t> boxQuery(const Box& box) const = 0;
  virtual Stats stats() const = 0;
  // The axis-aligned planes the structure cuts space at (kd split planes, grid cell walls, octree node
  // walls), at most `limit` of them; for stiff-case tests that shoot rays exactly along them.
  struct Plane {
    int axis = 0;
    double pos = 0.0;
  };
  virtual std::vector<Plane> planes(std::size_t limit) const { return {}; }
};

// ----- brute force: every triangle, the reference the others are tested against ----------------------
std::unique_ptr<Accel> buildBruteForce(const Triangles& triangles);

// ----- kd-tree (Qian, Liang & Zhang 2012) --------------------------------------------------------------
enum class KdBuild {
  kBinnedAnalytic,  // Sec. 2: bins along the longest axis, Algorithms 1 and 2, Eqs. 5/6
  kExactSah,        // Wald & Havran 2006: event sorting, O(N log N), every axis and candidate
};
enum class BinPolicy {
  kLinear,      // Sec. 3.2: c·n bins (quality; paper's Table 1 uses 0.4·n)
  kLogSquared,  // Sec. 3.2: c·log2²n bins (build speed on uneven scenes)
  kNLogN,       // Sec. 3.2: c·n·log2 n bins (total time on even static scenes)
};
struct KdParams {
  KdBuild build = KdBuild::kBinnedAnalytic;
  BinPolicy binPolicy = BinPolicy::kLinear;
  double binCoefficient = 0.4;  // Sec. 3.1: 0.4·n in Tables 1 and 2; tested 1.0, 0.4, 0.3, 0.1
  double traversalCost = 1.0;   // C_T of Eq. 2
  // C_I of Eq. 2. The paper gives no value (Wald & Havran use K_I/K_T = 20/15); 0.5 renders fastest of
  // 0.3 ... 3.0 on the 1e4 ... 2e6-triangle spheres of svo bench accel.
  double intersectionCost = 0.5;
  std::size_t leafSize = 1;  // Sec. 3: "node split threshold 1"
  double depthBase = 8.0;    // Sec. 2.2.3: max depth 8 + 1.3·log2 N
  double depthSlope = 1.3;
  // Exact SAH build only: Wald & Havran 2006 scale the cost of a plane that cuts off empty space by
  // λ(p) = 0.8 (their SAH cost function), favouring empty leaves that rays skip without a triangle test.
  // The binned build keeps the Qian et al. cost (Eq. 2), which has no such factor.
  double emptySpaceBonus = 0.8;
  void validate() const;  // throws std::invalid_argument naming the bad field
};
std::unique_ptr<Accel> buildKdTree(const Triangles& triangles, const KdParams& params = {});

// ----- grids (Li & Wang 2011) ---------------------------------------------------------------------------
enum class GridKind {
  kUniform,    // UG: Eq. 1 with λ = 5 (Table 1's UG, rc ≈ 5)
  kRecursive,  // RG (Jevans & Wyvill): cells with > threshold triangles get a λ·N_i sub-grid
  kTwoLevel,   // RG-2 (Ize et al.): M1 = (8N)^0.6 top cells, M2 = 8·N2 in each sub-grid
  kOrg,        // ORG: Eq. 1 + Algorithm 1 + Algorithm 2, hierarchy with β, γ, MAXDEPTH
};
struct GridParams {
  GridKind kind = GridKind::kOrg;
  double lambda = 1.0;           // Sec. 3: λ = 1 (ORG, RG); UG uses uniformLambda
  double alpha = 2.0;            // Sec. 3: α = 2, cell / mean primitive size ratio (Algorithm 2)
  double gamma = 16.0;           // Sec. 3: γ = 16, sub-grids below this many cells are not built
  int maxDepth = 8;              // Sec. 2: MAXDEPTH = 4 × 2 = 8 levels (ORG)
  double uniformLambda = 5.0;    // Table 1: UG has rc ≈ 5
  std::size_t rgThreshold = 16;  // Sec. 3: RG subdivides cells with more than β = 16 triangles
  int rgMaxDepth = 3;            // Sec. 3: RG depth had to be forced to 2..4; 3 here
  double rg2TopExponent = 0.6;   // Sec. 3: RG-2 M1 = (8N)^0.6
  double rg2Density = 8.0;       // Sec. 3: RG-2 factor 8 in M1 = (8N)^0.6 and M2 = 8·N2
  void validate() const;
};
std::unique_ptr<Accel> buildGrid(const Triangles& triangles, const GridParams& params = {});

// Algorithm 1 (+ Eq. 1) of the ORG paper: per-axis resolutions for a box with extents L holding n
// primitives, about λ·n cells, flat and thin boxes handled (cases 1-4). Exposed for tests.
glm::ivec3 orgResolution(const glm::dvec3& extent, double n, double lambda);

// ----- octrees (Yuan et al. 2017) -----------------------------------------------------------------------
struct OctreeParams {
  std::size_t leafSize = 8;  // more triangles: subdivide (no value in the OAVM paper)
  int maxLevel = -1;  // deepest level; -1: round((8 + 1.3·log2 N) / 3), the kd-tree rule per octree level
  double maxGrowth = 4.0;  // ours: no subdivision when the children would hold > 4× the node's references
  void validate() const;
};

// Classic octree: nodes with 8 child pointers and a parent pointer, recursive front-to-back traversal.
std::unique_ptr<Accel> buildClassicOctree(const Triangles& triangles, const OctreeParams& params = {});

// OAVM: nodes addressed by (level, Morton code), empty leaves merged into shared boxes, Liang-Barsky
// clipping, neighbour lookup from the code; supports local updates.
class OavmOctree : public Accel {
 public:
  // Triangles inserted later must lie inside the root cube given here (the scene box of `triangles` and
  // `bounds`); a triangle reaching outside throws std::invalid_argument.
  static std::unique_ptr<OavmOctree> build(const Triangles& triangles, const OctreeParams& params = {},
                                           const Box& bounds = {});
  // Adds triangle `id` of `triangles` (the same position/index arrays, possibly grown) to the leaves it
  // overlaps; full leaves over leafSize are subdivided; leaves that turn full leave their merged volume and
  // the merge is redone up to the first type-2 node (Sec. 3, step 3).
  virtual void insert(const Triangles& triangles, std::uint32_t id) = 0;
  // Removes triangle `id`; leaves that turn empty are merged with their empty siblings, and upwards while
  // all eight children are empty (Sec. 3, step 2). Throws std::invalid_argument for an unknown id.
  virtual void remove(std::uint32_t id) = 0;
  // Checks every invariant (volumes contain their leaves and no full leaf, codes consistent); throws
  // std::logic_error describing the first violation. For tests.
  virtual void checkInvariants() const = 0;
};

// Builds the structure a bench or the builder names: "brute", "kd-binned", "kd-sah", "ug", "rg", "rg2",
// "org", "octree", "oavm". Throws std::invalid_argument for an unknown name.
std::unique_ptr<Accel> buildByName(const std::string& name, const Triangles& triangles);
std::vector<std::string> structureNames();

}  // namespace svo::accel
