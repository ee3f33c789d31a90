// Pinhole camera, Phong shading with one directional light, multi-threaded rendering, image output.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <glm/geometric.hpp>
#include <glm/vec3.hpp>
#include <glm/vec4.hpp>

#include "svo/client/beam.hpp"
#include "svo/client/raycast.hpp"
#include "svo/store/format.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

struct Camera {
  glm::dvec3 eye{0.0, 0.0, 3.0};
  glm::dvec3 target{0.0};
  glm::dvec3 up{0.0, 1.0, 0.0};
  double fovYDegrees = 45.0;
  int width = 512, height = 512;

  // World-space ray through pixel centre (x + 0.5, y + 0.5); direction unit length.
  void pixelRay(double x, double y, glm::dvec3& origin, glm::dvec3& direction) const;
  // The look-at basis and image-plane scale, computed once per frame for pixelRay-equivalent rays.
  struct Basis {
    glm::dvec3 forward, right, up;
    double tanHalf = 0.0, aspect = 1.0;
    // Image-plane coordinates of column x's and row y's pixel centres (along right and up, at distance 1
    // along forward); image rows grow downwards, so row 0 is the top of the view (+up).
    double across(double x, int width) const {
      return (2.0 * (x + 0.5) / double(width) - 1.0) * tanHalf * aspect;
    }
    double down(double y, int height) const { return (1.0 - 2.0 * (y + 0.5) / double(height)) * tanHalf; }
  };
  Basis basis() const;
  static void pixelRay(const Camera& camera, const Basis& basis, double x, double y, glm::dvec3& direction);
  // Angle subtended by one pixel (radians), for the level-of-detail footprint.
  double pixelAngle() const;
  // Throws std::runtime_error when eye == target, up is parallel to the view, fov out of (0, 180) or a size
  // is not in [1, 16384].
  void validate() const;
  // A camera looking at the whole scene cube from the given direction.
  static Camera framing(const SceneTransform& scene, glm::dvec3 viewDirection, int width, int height);
  // A camera looking along viewDirection at the box [lo, hi] from just far enough that all its corners
  // project into the image: the box fills the frame's width or height (no bounding sphere's slack).
  static Camera framingBox(glm::dvec3 lo, glm::dvec3 hi, glm::dvec3 viewDirection, int width, int height);
};
// The direction the commands look at a whole scene from when given no camera: from the front, slightly
// above and to the right, so that no face of the scene cube is seen edge-on.
inline const glm::dvec3 kDefaultViewDirection{-0.35, -0.25, -1.0};

// A world-space box: what a default view frames.
struct WorldBox {
  glm::dvec3 lo, hi;
};
// The scene cube.
WorldBox sceneBox(const SceneTransform& scene);
// How deep occupiedBox looks at most: cubes of 1/64 of the scene, a box at most 1.6% of the scene wider than
// the geometry on each side, from at most a few tens of thousands of voxels.
inline constexpr int kFramingLevels = 6;
// The box of what the octree holds: its voxels down to min(kFramingLevels, trunkLevels) below the root, as
// whole cubes (so at most one cube of that level wider than the geometry on each side; a stub, whose
// children are elsewhere, counts whole). trunkLevels: the store's (StoreIndex::trunkLevels), so that a
// pager's trunk and the whole octree give the same box. A default view frames this box rather than the
// scene cube, whose bounding sphere leaves an elongated model a few percent of the pixels. The scene cube
// for an octree without voxels.
WorldBox occupiedBox(const BlockView& root, const SceneTransform& scene, int trunkLevels);

// Camera from a JSON file: {"eye":[x,y,z], "target":[..], "up":[..], "fov":deg, "width":w, "height":h}.
Camera loadCamera(const std::filesystem::path& path);
// The same from JSON text; `where` names it in messages.
Camera parseCamera(const std::string& jsonText, const std::string& where);
// A camera path: a JSON array of such objects, one per frame.
std::vector<Camera> loadCameraPath(const std::filesystem::path& path);

// The post-process filter's blur radius, as a multiple of the hit voxel's width on screen (sec. 6.3 derives
// the radius from that width). `svo bench quality --filter-radius 0.5,...,4` against the triangle reference:
// below 1 the kernel's few inner samples change nothing; on the bunny (normals only) PSNR grows with the
// radius up to 4, on the colored 2 M terrain it falls past 1.5; at 1 it gains or holds on both at every
// level of detail, and a smooth image seen through 16-pixel voxels is still not blurred past its detail.
inline constexpr float kPostFilterRadiusPerVoxel = 1.0f;

struct RenderOptions {
  float lodPixels = 1.0f;  // stop at voxels no larger than this many pixels; 0 = finest level
  // Beam optimization (sec. 6.2): pixels per edge of the tile one coarse pass serves (the paper uses 4x4 or
  // 8x8); 0 casts every ray from the eye. 16: `svo bench raycast`'s depth frames at 8, 16 and 32 on the
  // bunny, city, terrain and hairball, 1 thread: 16 is fastest or within 5% of 32 in every view (a smaller
  // tile's coarse pass costs more than the start distance it buys, since packets descend together).
  int beamTile = 16;
  CastOptions cast;
  glm::vec3 lightDirection{-0.4f, -0.8f, -0.45f};  // towards the scene
  glm::vec3 background{0.08f, 0.09f, 0.11f};
  int threads = 0;           // 0 = all cores
  bool diagnostics = false;  // fill Frame::iterations and Frame::lodStopped (the viewer's false colors)
  // The post-process filter (sec. 6.3, post_filter.hpp) over the cast frame: blurs the blocks of voxels wider
  // than a pixel, each pixel within filterRadius voxel widths.
  bool filter = false;
  float filterRadius = kPostFilterRadiusPerVoxel;
  // Request each hit's color and normal look-up a few packets before the hit is shaded (AttributePrefetcher),
  // so that the cache misses of many hits overlap instead of following one another; pays only in an octree
  // larger than the caches (attributePrefetchPays).
  bool prefetchAttributes = false;
};

// Octrees above this many bytes shade faster with RenderOptions::prefetchAttributes: the bench's shaded whole
// views, 1 thread, interleaved with and without: the 1 M hairball (397 MB) and city (238 MB) faster, the
// bunny (20 MB), whose octree the caches hold, 5% slower.
inline constexpr std::size_t kPrefetchAttributesAboveBytes = std::size_t(64) << 20;
inline bool attributePrefetchPays(std::size_t octreeBytes) {
  return octreeBytes > kPrefetchAttributesAboveBytes;
}

// One frame. Depth is the world distance along the ray (infinity for a miss); voxelPixels is the hit voxel's
// size in pixels at its distance (0 for a miss).
struct Frame {
  int width = 0, height = 0;
  std::vector<glm::vec4> color;  // linear RGB + alpha (1 = hit)
  std::vector<float> depth;
  std::vector<float> voxelPixels;
  // Only with RenderOptions::diagnostics, else empty: ray-loop iterations per pixel, saturating (0 where the
  // beam pass skipped the tile), and 1 where the ray stopped at its level-of-detail target rather than at
  // the deepest voxel it found.
  std::vector<std::uint16_t> iterations;
  std::vector<std::uint8_t> lodStopped;
  double seconds = 0.0;        // clearing, casting and shading, and filtering when on
  double filterSeconds = 0.0;  // of which the post-process filter
  double deviceSeconds = 0.0;  // GPU caster: its dispatches alone (GPU timestamps), no read-back; 0 on CPU
  double meanIterations = 0.0;
  double mraysPerSecond() const { return double(width) * height / seconds * 1e-6; }
};

Frame render(const Octree& octree, const Camera& camera, const RenderOptions& options = {});
// The same over any block (a block pool's trunk: the octree as far as it is resident).
Frame render(const BlockView& block, const SceneTransform& scene, const Camera& camera,
             const RenderOptions& options = {});
// The same into `frame`, whose buffers keep their storage where the size is unchanged: a viewer or a
// benchmark rendering frame after frame allocates (and page-faults) them once.
void render(const BlockView& block, const SceneTransform& scene, const Camera& camera,
            const RenderOptions& options, Frame& frame);

// The post-process filter as `options` asks (filterRadius, threads), timed into frame.filterSeconds (what
// render does with RenderOptions::filter; other casters call it on their frames).
void applyFilter(Frame& frame, const RenderOptions& options);

// The octree level of the voxel a pixel hit (0 = the root cube), from its depth and size in pixels;
// nullopt for a miss.
std::optional<int> hitLevel(const Frame& frame, std::size_t pixel, double pixelAngle, double sceneSize);

// The renderer's Phong model (one white directional light, `lightDirection` unit and pointing into the scene,
// `viewDirection` unit from the eye); the normal is flipped to face the viewer. Shared with reference
// renders. Inline: out of line, its vector arguments went through memory once per shaded hit.
inline glm::vec3 shadePhong(glm::vec3 albedo, glm::vec3 normal, glm::vec3 viewDirection,
                            glm::vec3 lightDirection) {
  // Phong terms.
  constexpr float kAmbient = 0.15f, kDiffuse = 0.75f, kSpecular = 0.25f;
  // Specular exponent 2^kShininessLog2 = 32, raised by five squarings instead of a std::pow call per hit.
  constexpr int kShininessLog2 = 5;
  // Thin surfaces are voxelized from both sides: light the side the viewer sees.
  if (glm::dot(normal, viewDirection) > 0.0f) normal = -normal;
  const float diffuse = std::max(0.0f, glm::dot(normal, -lightDirection));
  const glm::vec3 reflected = glm::reflect(lightDirection, normal);
  float specular = std::max(0.0f, glm::dot(reflected, -viewDirection));
  for (int i = 0; i < kShininessLog2; ++i) specular *= specular;
  return albedo * (kAmbient + kDiffuse * diffuse) + glm::vec3(kSpecular * specular);
}

// The world-space ray of a pixel mapped into octree space with its level-of-detail footprint.
OctreeRay octreeRay(const SceneTransform& scene, const Camera& camera, double px, double py, float lodPixels);

// The same rays with the per-frame constants computed once (what render uses).
class PixelRays {
 public:
  PixelRays(const SceneTransform& scene, const Camera& camera, float lodPixels);
  OctreeRay operator()(double px, double py) const { return at(across(px), down(py)); }
  // The same in two steps, so that a block of pixels computes each column's and row's image-plane
  // coordinate once: across(px) and down(py) (Camera::pixelRay's), then the ray through them.
  double across(double px) const { return basis_.across(px, camera_.width); }
  double down(double py) const { return basis_.down(py, camera_.height); }
  OctreeRay at(double across, double down) const {
    OctreeRay ray;
    ray.origin = origin_;
    ray.direction = directionAt(across, down);
    ray.footprintSlope = footprintSlope_;
    return ray;
  }
  // The octree direction of the ray through image-plane point (across, down).
  glm::vec3 directionAt(double across, double down) const {
    const glm::dvec3 v = basis_.forward + across * basis_.right + down * basis_.up;
    // The unit direction scaled by 1 / size keeps t in world units: octree point at t = toOctree(world
    // point at t). One division for both.
    return glm::vec3(v * (1.0 / (std::sqrt(glm::dot(v, v)) * scene_.size)));
  }

  // at(across[k], down[k]) for k < count (<= kPacketLanes), each starting at tMin: a packet's rays, computed
  // side by side in SIMD lanes with the same doubles as one by one.
  void packet(const double* across, const double* down, int count, float tMin, OctreeRay* out) const;

  // Unit world (= octree, up to scale) direction of the ray through (px + 0.5, py + 0.5).
  glm::dvec3 direction(double px, double py) const;
  const glm::vec3& origin() const { return origin_; }  // the eye in octree space, as every ray has it
  const Camera& camera() const { return camera_; }
  double sceneSize() const { return scene_.size; }
  float footprintSlope() const { return footprintSlope_; }

 private:
  const SceneTransform& scene_;
  const Camera& camera_;
  Camera::Basis basis_;
  glm::vec3 origin_;
  float footprintSlope_ = 0.0f;
};

// Pixels per edge of the tiles render casts: the beam tile, else the paper's 8x8.
int renderTileSize(const RenderOptions& options);

// Runs `trace` over the image in tiles of `tileSize` pixels on `threads` threads (0 = the calling task
// arena's: all cores, unless called inside an arena of fewer).
void forEachTile(int width, int height, int tileSize, int threads,
                 const std::function<void(const PixelTile&)>& trace);

struct IgnoreMiss {
  template <class Hit>
  void operator()(int, int, const Hit&) const {}
};
struct IgnorePacket {
  template <class Hit>
  void operator()(const Hit*, int) const {}
};
// Casts the rays of one tile, starting each at the tile's beam bound when `beam` (tiles whose beam meets
// nothing cast no ray), and calls onHit(x, y, ray, hit) for each hit and onMiss(x, y, hit) for each ray cast
// that missed. onPacket(hits, count) sees each packet's hits and misses at once, kLag packets before they
// are handed out (for prefetching; after the last packet, one onPacket(nullptr, 0) before each of the last
// kLag is). Returns the ray-loop iterations. `octree` is a block (BlockView) or level arrays (a LevelRegion,
// level_raycast.hpp), whose castBeam, castRay and castPacket it calls.
template <int kLag = 0, class Octree, class OnHit, class OnMiss = IgnoreMiss, class OnPacket = IgnorePacket>
std::uint64_t castTile(const Octree& octree, const PixelRays& rays, const PixelTile& tile, bool beam,
                       const CastOptions& options, OnHit&& onHit, OnMiss&& onMiss = OnMiss{},
                       OnPacket&& onPacket = OnPacket{}) {
  static_assert(kLag >= 0);
  using Hit = decltype(castRay(octree, OctreeRay{}, options));
  float tStart = 0.0f;
  if (beam) {
    tStart = castBeam(octree, rays, tile).tStart;
    if (!(tStart < std::numeric_limits<float>::infinity())) return 0;
  }
  struct Packet {
    OctreeRay rays[kPacketLanes];
    Hit hits[kPacketLanes];
    int x[kPacketLanes], y[kPacketLanes];
    int count = 0;
  };
  Packet packets[kLag + 1];  // a ring: the newest and the kLag before it, not yet handed out
  std::uint64_t cast = 0, iterations = 0;
  const auto handOut = [&](const Packet& p) {
    for (int i = 0; i < p.count; ++i) {
      iterations += std::uint64_t(p.hits[i].iterations);
      if (p.hits[i].hit) {
        onHit(p.x[i], p.y[i], p.rays[i], p.hits[i]);
      } else {
        onMiss(p.x[i], p.y[i], p.hits[i]);
      }
    }
  };
  // 8x4 pixel blocks cast together (castPacket): two 4x4 blocks side by side, each in the order of one
  // register's lanes, so that a packet's halves and quarters are squares and rows of neighbours.
  static_assert(kPacketLanes == 32);
  for (int y = tile.y0; y < tile.y1; y += 4) {
    for (int x = tile.x0; x < tile.x1; x += 8) {
      double across[8], down[4];
      for (int i = 0; i < 8; ++i) across[i] = rays.across(x + i);
      for (int i = 0; i < 4; ++i) down[i] = rays.down(y + i);
      Packet& p = packets[cast % (kLag + 1)];
      p.count = 0;
      double rayAcross[kPacketLanes], rayDown[kPacketLanes];
      for (int x0 = x; x0 < x + 8 && x0 < tile.x1; x0 += 4)
        for (int dy = 0; dy < 4 && y + dy < tile.y1; ++dy)
          for (int dx = 0; dx < 4 && x0 + dx < tile.x1; ++dx) {
            p.x[p.count] = x0 + dx, p.y[p.count] = y + dy;
            rayAcross[p.count] = across[x0 + dx - x], rayDown[p.count++] = down[dy];
          }
      rays.packet(rayAcross, rayDown, p.count, tStart, p.rays);
      castPacket(octree, p.rays, p.count, options, p.hits);
      onPacket(p.hits, p.count);
      if (++cast > std::uint64_t(kLag)) handOut(packets[(cast - 1 - kLag) % (kLag + 1)]);
    }
  }
  for (std::uint64_t k = cast > std::uint64_t(kLag) ? cast - kLag : 0; k < cast; ++k) {
    onPacket(static_cast<const Hit*>(nullptr), 0);
    handOut(packets[k % (kLag + 1)]);
  }
  return iterations;
}

// The frame's colors as 8-bit sRGB, 4 bytes a pixel with alpha 255 (what a PNG of the frame holds, for
// display), row by row from the top.
void encodeSrgb8(const Frame& frame, std::vector<std::uint8_t>& rgba);

// Writes PNG (8-bit sRGB) or EXR (float, with Z and voxelPixels channels when `withAux`) by extension.
// Writes to a temporary name and renames; throws std::runtime_error naming the path on failure.
void writeFrame(const std::filesystem::path& path, const Frame& frame, bool withAux);

}  // namespace svo
