// Frames from level arrays (level_raycast.hpp): castRay per pixel over the renderer's tiles, each tile's rays
// started where its beam pass (beam.hpp) says, and shaded as a block's frame is (frame_shading.hpp), so that
// the same hits give the same pixels.
#include <atomic>
#include <chrono>
#include <limits>

#include "frame_shading.hpp"
#include "svo/client/beam.hpp"
#include "svo/client/level_raycast.hpp"
#include "svo/client/render.hpp"

namespace svo {

using namespace frame_shading;

namespace {

// The contour bits of the voxel `hit` stopped at, where it has one.
std::optional<std::uint32_t> hitContour(const LevelCastHit& hit) {
  const LevelNode voxel = hitVoxel(hit);
  const LevelRegion& region = *voxel.region;
  std::uint32_t bits;
  if (region.levels[std::size_t(kMaxLevels - hit.scale - region.baseLevel)].contours.find(voxel.index, bits))
    return bits;
  return std::nullopt;
}

}  // namespace

Frame render(const LevelRegion& root, const StoreHeader& header, const SceneTransform& scene,
             const Camera& camera, const RenderOptions& options) {
  Frame frame;
  prepareFrame(camera, options, frame);
  const Shading shading{glm::normalize(options.lightDirection), header.hasColors, header.hasNormals,
                        options.cast.contours};
  const double pixelAngle = camera.pixelAngle();
  const PixelRays rays(scene, camera, options.lodPixels);
  std::atomic<std::uint64_t> iterations{0};
  const auto start = std::chrono::steady_clock::now();
  inArena(options.threads, [&] {
    clearFrame(frame, glm::vec4(options.background, 0.0f));
    forEachTile(camera.width, camera.height, renderTileSize(options), 0, [&](const PixelTile& tile) {
      float tStart = 0.0f;
      if (options.beamTile > 0) {
        tStart = castBeam(root, rays, tile).tStart;
        if (!(tStart < std::numeric_limits<float>::infinity())) return;  // no ray of the tile hits
      }
      ShadingBatch batch(frame, shading, scene.size, pixelAngle, shading.hasColor, shading.hasNormal);
      std::uint64_t tileIterations = 0;
      // Rays a packet's lanes at a time, as castTile makes them (PixelRays::packet computes every lane).
      double across[kPacketLanes], down[kPacketLanes];
      int xs[kPacketLanes], ys[kPacketLanes];
      OctreeRay packet[kPacketLanes];
      int count = 0;
      const auto castPacket = [&] {
        rays.packet(across, down, count, tStart, packet);
        for (int k = 0; k < count; ++k) {
          const OctreeRay& ray = packet[k];
          const LevelCastHit hit = castRay(root, ray, options.cast);
          tileIterations += std::uint64_t(hit.iterations);
          const std::size_t i = std::size_t(ys[k]) * std::size_t(camera.width) + std::size_t(xs[k]);
          if (!frame.iterations.empty())
            frame.iterations[i] = std::uint16_t(std::min(hit.iterations, 0xFFFF));
          if (!hit.hit) continue;
          if (!frame.lodStopped.empty()) frame.lodStopped[i] = std::uint8_t(!hit.leaf);
          const int b = batch.add(i, ray.direction, hit.t, hit.voxelSize());
          const LevelHitValues values = hitValues(hit, shading.hasColor, shading.hasNormal);
          if (shading.hasColor)
            batch.setColor(b, values.color);
          else
            batch.setColor(b, glm::vec3(kNeutralGreyAlbedo));
          if (shading.hasNormal)
            batch.setNormal(b, values.normal);
          else
            batch.setNormal(b, estimateNormal(hit.position, hit.cubeMin, hit.voxelSize(),
                                              shading.contours ? hitContour(hit) : std::nullopt));
        }
        count = 0;
      };
      for (int y = tile.y0; y < tile.y1; ++y)
        for (int x = tile.x0; x < tile.x1; ++x) {
          across[count] = rays.across(x), down[count] = rays.down(y), xs[count] = x, ys[count] = y;
          if (++count == kPacketLanes) castPacket();
        }
      if (count > 0) castPacket();
      batch.flush();
      iterations.fetch_add(tileIterations, std::memory_order_relaxed);
    });
  });
  if (options.filter) applyFilter(frame, options);
  frame.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  frame.meanIterations = double(iterations.load()) / double(frame.depth.size());
  return frame;
}

}  // namespace svo
