// Independent double-precision references for the unit tests. Nothing here shares code with the builder or
// the ray caster: triangle/box overlap is decided by exact polygon clipping (not by the separating-axis test
// the builder uses), leaf voxels are enumerated by brute force, and rays are clipped against convex voxel
// shapes (cube intersected with contour slabs) slab by slab, Kay-Kajiya style.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/builder/mesh.hpp"
#include "svo/store/block.hpp"
#include "svo/store/format.hpp"
#include "svo/store/store_types.hpp"

namespace svo {
class StoreReader;
}

namespace svotest {

// Voxels (records by index) that differ between two trees in children, contour or attributes; the trees
// must be the same size.
std::size_t differingVoxels(const svo::VoxelTree& a, const svo::VoxelTree& b);

// A file in the temp folder named `stem_<pid><extension>`, removed when its owner goes (moves hand it on).
struct TempFile {
  TempFile() = default;
  TempFile(const std::string& stem, const std::string& extension);
  TempFile(TempFile&& other) noexcept : path(std::exchange(other.path, {})) {}
  TempFile& operator=(TempFile&&) = delete;
  ~TempFile();
  std::filesystem::path path;
};

// A fresh folder in the temp folder, named after the running test, removed with everything in it when its
// owner goes.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::filesystem::path& path() const { return path_; }
  // Writes `bytes` to the file `name` in the folder and returns its path.
  std::filesystem::path file(const std::string& name, const std::string& bytes) const;

 private:
  std::filesystem::path path_;
};

// The message of what `f` throws ("" when it does not).
template <class F>
std::string errorOf(F&& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

// sRGB to linear, written out from the standard (IEC 61966-2-1) rather than shared with the loader.
inline double srgbToLinearRef(double c) {
  return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
}

// The whole store's tree cut down to the voxels whose slice is in `resident`: what a pager holding those
// slices renders (the pager and GPU pool tests).
svo::VoxelTree truncatedTree(const svo::StoreReader& reader, const std::vector<std::uint32_t>& resident);

// A colored sphere and box at 8 levels with `sliceBytes` slices (4 KB: many regions, cubes that split at
// once, regions whose cube voxel is the parent's deepest level, attributes inherited across blocks), written
// to `path`. The pager, HTTP and server tests stream it.
void writeSphereAndBoxStore(const std::filesystem::path& path, std::uint32_t sliceBytes = 4096);

inline constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------------------------
// (a) Triangle / closed axis-aligned box overlap by Sutherland-Hodgman clipping of the triangle against the
// six box planes, in double. Overlap <=> the clipped polygon is non-empty. Degenerate triangles (segments,
// points) are handled the same way.
bool triangleBoxOverlap(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c,
                        const glm::dvec3& boxMin, const glm::dvec3& boxMax);

// ---------------------------------------------------------------------------------------------------------
// (b) Finest-level cubes a mesh overlaps. Cube (x, y, z) at `levels` is [1 + x h, 1 + (x+1) h] x ... in
// octree space, h = 2^-levels. `margin` (octree units) grows every cube by that much on all sides (negative
// shrinks it): a builder that is right up to rounding must lie between the shrunk and the grown sets. Brute
// force over the cubes in each triangle's bounding box. Result sorted (by packCoord) and unique.
std::vector<glm::ivec3> referenceLeafVoxels(const svo::Mesh& mesh, const svo::SceneTransform& transform,
                                            int levels, double margin = 0.0);

// Packs integer cube coordinates (each < 2^21) into one sortable key.
inline std::uint64_t packCoord(const glm::ivec3& c) {
  return (std::uint64_t(std::uint32_t(c.z)) << 42) | (std::uint64_t(std::uint32_t(c.y)) << 21) |
         std::uint64_t(std::uint32_t(c.x));
}
void sortUnique(std::vector<glm::ivec3>& coords);

// ---------------------------------------------------------------------------------------------------------
// (d) Leaf voxels of a block or of a voxel tree, with the chain of contours of the voxel and its ancestors.
struct ChainContour {
  int level = 0;           // level of the voxel that owns the contour (root = 0)
  glm::ivec3 coord{0};     // that voxel's integer coordinates at `level`
  std::uint32_t bits = 0;  // raw contour value (decode with svo::decodeContour)
};
struct LeafVoxel {
  glm::ivec3 coord{0};  // integer cube coordinates at `level`
  int level = 0;        // root = 0; the cube is [1 + coord * 2^-level, 1 + (coord + 1) * 2^-level]
  std::vector<ChainContour> contours;  // outermost ancestor first, the voxel's own contour last
};
// Walks the block with BlockView::root / child / contour only (no readBlock).
std::vector<LeafVoxel> walkLeaves(const svo::BlockView& block);
// Walks builder records (root first, children contiguous in slot order).
std::vector<LeafVoxel> walkLeaves(const svo::VoxelTree& tree);
// A compressed block's exact normal units (attribute_units.hpp), counted over its descriptor pairs.
std::uint64_t exactNormalUnits(const svo::BlockView& block);
// Coordinates of the leaves at `level`, sorted and unique; `otherLevels` counts the leaves at any other
// level.
std::vector<glm::ivec3> leafCoords(const std::vector<LeafVoxel>& leaves, int level, std::size_t* otherLevels);

// ---------------------------------------------------------------------------------------------------------
// (c) Brute-force ray caster over convex voxel shapes, double precision.
// A slab is lo <= q.x <= hi for an integer-valued normal q (the contour's 6-bit normal, unscaled), x in
// octree space. Keeping q integral makes q.d exact for axis-aligned and most quantized normals.
struct Slab {
  glm::dvec3 q{0.0};
  double lo = 0.0, hi = 0.0;
};
struct Shape {
  glm::dvec3 lo{0.0}, hi{0.0};  // cube, octree space
  std::vector<Slab> slabs;
};
// The voxel's cube, and (withContours) the slab of every contour in its chain, each in its owner's frame
// u = (x - centre) / size: |n.u - position| <= thickness / 2, n = q / 31, decoded with svo::decodeContour.
Shape shapeOf(const LeafVoxel& voxel, bool withContours);
Shape cubeShape(const glm::ivec3& coord, int level);

// Clips the ray's t >= 0 part against the shape grown by `margin` (octree units, every face and slab moved
// outwards by that distance; negative shrinks). Zero direction components are handled exactly (the ray is
// inside a slab or not). Returns false when the clipped span is empty.
bool clipRay(const Shape& shape, const glm::dvec3& origin, const glm::dvec3& direction, double margin,
             double& t0, double& t1);
bool clipBox(const glm::dvec3& lo, const glm::dvec3& hi, const glm::dvec3& origin,
             const glm::dvec3& direction, double margin, double& t0, double& t1);

struct RefHit {
  int voxel = -1;  // index into the shape list; -1 = miss
  double t0 = kInf, t1 = kInf;
  bool hit() const { return voxel >= 0; }
};

// First hit over all shapes (the smallest entry t; ties go to the lower index). Exact brute force; shapes are
// bucketed by their level-3 ancestor cube only to skip buckets whose cube the ray enters after the best hit.
// `minLength` > 0 ignores shapes the ray crosses for less than that (touching contacts).
class RefCaster {
 public:
  explicit RefCaster(std::vector<Shape> shapes);
  RefHit first(const glm::dvec3& origin, const glm::dvec3& direction, double margin = 0.0,
               double minLength = 0.0) const;
  const std::vector<Shape>& shapes() const { return shapes_; }

 private:
  struct Bucket {
    glm::dvec3 lo, hi;
    std::vector<int> members;
  };
  std::vector<Shape> shapes_;
  std::vector<Bucket> buckets_;
};

// ---------------------------------------------------------------------------------------------------------
// (e) Closest distance from a point to a triangle (Ericson, "Real-Time Collision Detection" 5.1.5), double.
double pointTriangleDistance(const glm::dvec3& p, const glm::dvec3& a, const glm::dvec3& b,
                             const glm::dvec3& c);

// ---------------------------------------------------------------------------------------------------------
// (f) Test meshes.
// UV sphere: 2 * slices * (stacks - 1) triangles, vertices exactly on the sphere.
svo::Mesh makeSphere(const glm::dvec3& centre, double radius, int stacks, int slices);
// Axis-aligned box surface, 12 triangles.
svo::Mesh makeBox(const glm::dvec3& lo, const glm::dvec3& hi);
// Random triangles with vertices in [lo, hi]: each triangle is a random point plus two random offsets of at
// most `maxEdge` (clamped into the box).
svo::Mesh makeRandomTriangles(std::uint64_t seed, int count, const glm::dvec3& lo, const glm::dvec3& hi,
                              double maxEdge);
void appendMesh(svo::Mesh& to, const svo::Mesh& from);

}  // namespace svotest
