// The Embree 3 peer of `svo bench raycast` and `svo bench accel`: a BVH over the source triangles and
// rtcIntersect1 per camera pixel over the renderer's 8x8 pixel tiles (svo::forEachTile). Embree's headers
// stay behind SVO_BENCH_PEERS; only bench_*.cpp files include this.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#ifdef SVO_BENCH_PEERS
#include <embree3/rtcore.h>
#include <pmmintrin.h>
#include <xmmintrin.h>
#endif

#include "bench_common.hpp"
#include "mesh_shading.hpp"
#include "svo/client/render.hpp"

namespace svo::tools::bench {

inline constexpr float kInfinity = std::numeric_limits<float>::infinity();

// Pixels per tile edge for every method: the renderer's (and the beam's) 8x8 tiles (sec. 6.2).
inline constexpr int kTileSize = 8;
inline constexpr std::uint32_t kNoPrimitive = 0xffffffffu;

// Depth per pixel (world distance, infinity for a miss) and the work it took.
struct TraceResult {
  std::vector<float> depth;
  std::uint64_t hits = 0;
  double meanIterations = 0.0;           // ESVO only
  std::vector<std::uint32_t> primitive;  // Embree: primID per pixel (kNoPrimitive for a miss)
  std::vector<glm::vec3> color;          // shaded traces only: linear RGB, the background for a miss
};

inline std::uint64_t countHits(const std::vector<float>& depth) {
  return std::uint64_t(std::count_if(depth.begin(), depth.end(), [](float d) { return std::isfinite(d); }));
}

#ifdef SVO_BENCH_PEERS
// Embree 3 scene over the source triangles, vertices as floats relative to the scene centre so that
// far-from-origin coordinates keep their precision.
class EmbreePeer {
 public:
  EmbreePeer(const Mesh& mesh, glm::dvec3 centre) : centre_(centre) {
    device_ = rtcNewDevice(nullptr);
    if (!device_)
      throw std::runtime_error(
          fmt::format("embree: rtcNewDevice failed ({})", errorName(rtcGetDeviceError(nullptr))));
    rtcSetDeviceErrorFunction(device_, &EmbreePeer::onError, this);
    scene_ = rtcNewScene(device_);
    rtcSetSceneBuildQuality(scene_, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry geometry = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(geometry, RTC_BUILD_QUALITY_HIGH);
    auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(
        geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), mesh.positions.size()));
    auto* indices = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
        geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), mesh.triangles.size()));
    check("allocating buffers");
    for (std::size_t i = 0; i < mesh.positions.size(); ++i) {
      const glm::dvec3 p = mesh.positions[i] - centre_;
      vertices[3 * i + 0] = float(p.x);
      vertices[3 * i + 1] = float(p.y);
      vertices[3 * i + 2] = float(p.z);
    }
    for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
      indices[3 * i + 0] = mesh.triangles[i].x;
      indices[3 * i + 1] = mesh.triangles[i].y;
      indices[3 * i + 2] = mesh.triangles[i].z;
    }
    rtcCommitGeometry(geometry);
    rtcAttachGeometry(scene_, geometry);
    rtcReleaseGeometry(geometry);
    buildSeconds_ = timeSeconds([&] { rtcCommitScene(scene_); });
    check("building the BVH");
  }
  ~EmbreePeer() {
    if (scene_) rtcReleaseScene(scene_);
    if (device_) rtcReleaseDevice(device_);
  }
  EmbreePeer(const EmbreePeer&) = delete;
  EmbreePeer& operator=(const EmbreePeer&) = delete;

  double buildSeconds() const { return buildSeconds_; }

  // rtcIntersect1 for every camera pixel ray; flush-to-zero and denormals-are-zero set in each task (and the
  // thread's previous mode restored afterwards, so the ESVO runs on the same workers are not affected). With
  // `shading`, each hit is also shaded as svo::render shades a voxel (the like-for-like peer of a frame).
  TraceResult trace(const Camera& camera, int threads, const MeshShading* shading = nullptr) const {
    TraceResult result;
    trace(camera, threads, shading, result);
    return result;
  }
  // The same into `result`, its storage reused where the size is unchanged (as svo::render's frame).
  void trace(const Camera& camera, int threads, const MeshShading* shading, TraceResult& result) const {
    // Each pixel is written once, hit or miss, in its tile's task, as a renderer built on Embree does (no
    // clear of the frame first, which would be a pass on one thread).
    const std::size_t pixels = std::size_t(camera.width) * camera.height;
    result.depth.resize(pixels);
    result.primitive.resize(pixels);
    result.color.resize(shading ? pixels : 0);
    const glm::vec3 background = shading ? shading->background() : glm::vec3();
    // Per-frame constants computed once, as svo::render does: the look-at basis and the eye relative to the
    // scene centre.
    const Camera::Basis basis = camera.basis();
    const glm::vec3 origin(camera.eye - centre_);
    const double pixelAngle = camera.pixelAngle();
    forEachTile(camera.width, camera.height, kTileSize, threads, [&](const PixelTile& tile) {
      const unsigned savedCsr = _mm_getcsr();
      _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
      _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
      RTCIntersectContext context;
      rtcInitIntersectContext(&context);
      for (int y = tile.y0; y < tile.y1; ++y) {
        for (int x = tile.x0; x < tile.x1; ++x) {
          glm::dvec3 direction;
          Camera::pixelRay(camera, basis, x, y, direction);
          RTCRayHit rayHit;
          rayHit.ray.org_x = float(origin.x);
          rayHit.ray.org_y = float(origin.y);
          rayHit.ray.org_z = float(origin.z);
          rayHit.ray.dir_x = float(direction.x);
          rayHit.ray.dir_y = float(direction.y);
          rayHit.ray.dir_z = float(direction.z);
          rayHit.ray.tnear = 0.0f;
          rayHit.ray.tfar = kInfinity;
          rayHit.ray.time = 0.0f;
          rayHit.ray.mask = ~0u;
          rayHit.ray.id = 0;
          rayHit.ray.flags = 0;
          rayHit.hit.geomID = RTC_INVALID_GEOMETRY_ID;
          rayHit.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
          rtcIntersect1(scene_, &context, &rayHit);
          const std::size_t pixel = std::size_t(y) * camera.width + x;
          if (rayHit.hit.geomID != RTC_INVALID_GEOMETRY_ID) {
            result.depth[pixel] = rayHit.ray.tfar;
            result.primitive[pixel] = rayHit.hit.primID;
            if (shading)
              result.color[pixel] = shading->shade(rayHit.hit.primID, rayHit.hit.u, rayHit.hit.v, direction,
                                                   PixelFootprint::at(basis, rayHit.ray.tfar, pixelAngle));
          } else {
            result.depth[pixel] = kInfinity;
            result.primitive[pixel] = kNoPrimitive;
            if (shading) result.color[pixel] = background;
          }
        }
      }
      _mm_setcsr(savedCsr);
    });
    check("tracing");
    result.hits = countHits(result.depth);
  }

 private:
  static const char* errorName(RTCError error) {
    switch (error) {
      case RTC_ERROR_NONE:
        return "no error";
      case RTC_ERROR_INVALID_ARGUMENT:
        return "invalid argument";
      case RTC_ERROR_INVALID_OPERATION:
        return "invalid operation";
      case RTC_ERROR_OUT_OF_MEMORY:
        return "out of memory";
      case RTC_ERROR_UNSUPPORTED_CPU:
        return "unsupported CPU";
      case RTC_ERROR_CANCELLED:
        return "cancelled";
      default:
        return "unknown error";
    }
  }
  static void onError(void* self, RTCError error, const char* message) {
    auto* peer = static_cast<EmbreePeer*>(self);
    if (peer->error_.empty()) peer->error_ = fmt::format("{}: {}", errorName(error), message ? message : "");
  }
  void check(const char* what) const {
    if (!error_.empty()) throw std::runtime_error(fmt::format("embree failed while {}: {}", what, error_));
  }

  glm::dvec3 centre_;
  RTCDevice device_ = nullptr;
  RTCScene scene_ = nullptr;
  double buildSeconds_ = 0.0;
  std::string error_;
};
#endif

}  // namespace svo::tools::bench
