// The voxelizers' kernels, shared by the in-core and the out-of-core build: triangles in octree space, pieces
// clipped to a voxel, contour candidates and fits (sec. 5.2-5.3), attribute sums, the error-driven stop and
// the pruning of dead voxels.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include <glm/geometric.hpp>

#include "geometry.hpp"
#include "svo/builder/build.hpp"

namespace svo::voxel {

using glm::dvec3;
using glm::dvec4;

// the triangles in the voxel); the largest clipped pieces go first.
inline constexpr int kMaxContourCandidates = 8;
// Candidates closer than this (cosine) to one already tried add nothing.
inline constexpr double kSameDirectionCos = 0.999;
// relative to the voxel's face area: keeps such voxels' attributes defined without biasing others.
inline constexpr double kTouchWeight = 1e-9;

struct Triangle {
  dvec3 p[3];    // octree space
  dvec3 normal;  // unit
  std::uint32_t source;
};

void checkLevels(const BuildOptions& options);

// A voxel whose exact overlap test passed but none of whose children's did (rounding on a shared face or
// edge) has no finest descendant: it is marked dead and pruned, so every leaf sits at the finest level.
constexpr std::uint32_t kDeadVoxel = 0xFFFFFFFFu;

struct Aggregate {
  double weight = 0.0;  // zero only for a dead subtree
  dvec4 color{0.0};
  dvec3 normal{0.0};
  void add(const Aggregate& o) {
    weight += o.weight;
    color += o.color;
    normal += o.normal;
  }
};

struct Node {
  int level = 0;
  glm::ivec3 coord{0};
  std::vector<std::uint32_t> triangles;
  std::vector<geom::Slab> slabs;  // ancestor contours that cut this cube
};

// What a voxel decided before its children are built.
struct Prepared {
  VoxelRecord record;
  bool leaf = false;
  Aggregate leafAttributes;    // leaves only
  std::vector<Node> children;  // slot order, non-empty ones
};

struct Piece {
  geom::Polygon polygon;
  double area = 0.0;
  dvec3 centroid{0.0};
  std::uint32_t triangle = 0;
};

// Frees a vector's memory (`v = {}` assigns an empty initializer list and keeps the capacity).
template <class T>
void release(std::vector<T>& v) {
  std::vector<T>().swap(v);
}

// The octree-space triangle of world corners, or nullopt when it is degenerate after the transform (a
// sub-ulp triangle); both voxelizers skip those.
std::optional<Triangle> makeTriangle(const std::array<dvec3, 3>& world, const SceneTransform& transform,
                                     std::uint32_t source);

geom::Cube cubeAt(int level, glm::ivec3 coord);

glm::ivec3 childCoordOf(glm::ivec3 coord, int slot);

// The children of `cube` the triangle overlaps, as a slot mask: bounding-box candidates, then the exact test.
std::uint8_t overlappedChildren(const Triangle& t, const geom::Cube& cube);

Piece clipPiece(const Triangle& t, std::uint32_t index, const geom::Cube& cube);

// A piece's weight in its voxel's averages.
double pieceWeight(const Piece& p, const geom::Cube& cube);

// Color of the source triangle at the piece (barycentric vertex colors), times its material and texture.
// `colors` and `uvs` are the three corners' or null when the mesh has none.
dvec4 pieceColor(const Piece& piece, const Triangle& t, const glm::vec4* colors, const glm::vec2* uvs,
                 const Material& material, const std::vector<std::shared_ptr<const TextureImage>>& textures);

// Shading normal of the source triangle at the piece: its corner normals (`corners`) interpolated at the
// piece's area centroid, as a renderer interpolates them across the triangle (so the area-weighted sum over
// the piece is exact), then normalized; the triangle's own normal where they cancel.
dvec3 pieceNormal(const Piece& piece, const Triangle& t, const std::array<glm::vec3, 3>& corners);

// Attribute sums and spreads (the error-driven stop's measures) over a voxel's pieces.
void accumulate(Aggregate& a, double weight, const dvec3& normal, const dvec4* color);
dvec3 meanNormal(const Aggregate& a);
struct Spread {
  double color = 0.0;      // 8-bit steps from the mean color, max over the pieces
  double normalCos = 1.0;  // cosine to the mean normal, min over the pieces
  void add(const Aggregate& sums, const dvec3& normal, const dvec4* pieceColor) {
    if (pieceColor) {
      const dvec4 d = glm::abs(*pieceColor - sums.color / sums.weight) * 255.0;
      color = std::max({color, d.r, d.g, d.b, d.a});
    }
    normalCos = std::min(normalCos, glm::dot(meanNormal(sums), normal));
  }
};

// A contour direction: the candidate normal and its 6-bit quantization.
struct Direction {
  glm::ivec3 quantized;
  dvec3 normal;  // the quantized normal, as the slab uses it
};
// Where a voxel's pieces lie along a direction, in voxel units from its centre.
struct Extent {
  double lo = 1e300, hi = -1e300;
};

// Contour direction candidates (sec. 5.2): the area-weighted mean normal, then the normals of the largest
// pieces, skipping near-duplicates. Fed piece by piece, so a voxel's pieces need not exist all at once.
class ContourCandidates {
 public:
  void add(const Piece& p, const dvec3& normal, double weight) {
    mean_ += normal * weight;
    largest_.push_back({p.area, p.triangle, normal});
    std::push_heap(largest_.begin(), largest_.end(), ranksBefore);
    if (largest_.size() > kLargestKept) {
      std::pop_heap(largest_.begin(), largest_.end(), ranksBefore);  // the smallest kept goes
      largest_.pop_back();
    }
  }
  std::vector<Direction> directions() const {
    std::vector<dvec3> candidates;
    if (glm::length(mean_) > 0.0) candidates.push_back(glm::normalize(mean_));
    std::vector<Entry> largest = largest_;
    std::sort_heap(largest.begin(), largest.end(), ranksBefore);  // largest first
    for (std::size_t i = 0; i < largest.size() && int(candidates.size()) <= kMaxContourCandidates; ++i) {
      const dvec3 n = largest[i].normal;
      const bool seen = std::any_of(candidates.begin(), candidates.end(), [&](const dvec3& c) {
        return std::abs(glm::dot(c, n)) > kSameDirectionCos;
      });
      if (!seen) candidates.push_back(n);
    }
    std::vector<Direction> out;
    for (const dvec3& c : candidates) {
      const glm::ivec3 q = quantizeContourNormal(c);
      out.push_back({q, dvec3(q) / double(kContourNormalScale)});
    }
    return out;
  }

 private:
  // Pieces whose normals may become candidates: enough to find kMaxContourCandidates distinct ones.
  static constexpr std::size_t kLargestKept = kMaxContourCandidates * 4;
  struct Entry {
    double area;
    std::uint32_t triangle;
    dvec3 normal;
  };
  // Larger area first, ties by triangle order: a strict order, so the kept set is what a full sort keeps.
  static bool ranksBefore(const Entry& a, const Entry& b) {
    return a.area > b.area || (a.area == b.area && a.triangle < b.triangle);
  }
  dvec3 mean_{0.0};
  std::vector<Entry> largest_;  // a heap with the smallest kept piece on top
};

void extendExtents(const std::vector<Direction>& directions, const Piece& p, const geom::Cube& cube,
                   std::vector<Extent>& extents);

// The contour fit (sec. 5.2-5.3) once the candidates' extents are known: keep the slab that cuts away most of
// the ancestor-bounded hull; store it only when the cut exceeds `minCut` voxels.
struct ContourFit {
  std::uint32_t bits = 0;
  double cut = 0.0;        // voxel units removed from the hull along the normal
  double thickness = 0.0;  // surface extent along the normal, voxel units
};
std::optional<ContourFit> chooseContour(const geom::Cube& cube, const std::vector<Direction>& directions,
                                        const std::vector<Extent>& extents,
                                        const std::vector<geom::Slab>& slabs, double minCut);

// The error-driven stop: a voxel with a contour stops refining when its surface is within the geometry error
// and its attributes within the color and normal errors.
bool stopsRefining(const BuildOptions& options, int level, const ContourFit& contour, const Spread& spread);

// The slab a contour adds to the ones its descendants are bounded by.
geom::Slab slabOf(const geom::Cube& cube, std::uint32_t contourBits);

// The slabs among `slabs` that still cut `cube`.
std::vector<geom::Slab> slabsCutting(const std::vector<geom::Slab>& slabs, const geom::Cube& cube);

void setAttributes(VoxelRecord& r, const Aggregate& a, bool colors);

// Marks `r` dead when none of its children survived; returns whether it did.
bool markIfDead(VoxelRecord& r, const Aggregate& sum);

// Drops dead records: breadth first from the root, keeping each voxel's live children contiguous.
std::vector<VoxelRecord> prune(const std::vector<VoxelRecord>& in);

std::vector<VoxelRecord> pruneIfDead(std::vector<VoxelRecord>&& records);

}  // namespace svo::voxel
