// Frames from level arrays (level_raycast.hpp): castPacket over the renderer's tiles, each tile's rays
// started where its beam pass (beam.hpp) says, and shaded as a block's frame is (frame_shading.hpp), so that
// the same hits give the same pixels.
#include <atomic>
#include <chrono>

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
      ShadingBatch batch(frame, shading, scene.size, pixelAngle, shading.hasColor, shading.hasNormal);
      const auto index = [&](int x, int y) {
        return std::size_t(y) * std::size_t(camera.width) + std::size_t(x);
      };
      const auto keepIterations = [&](int x, int y, const LevelCastHit& hit) {
        if (!frame.iterations.empty())
          frame.iterations[index(x, y)] = std::uint16_t(std::min(hit.iterations, 0xFFFF));
      };
      const auto onHit = [&](int x, int y, const OctreeRay& ray, const LevelCastHit& hit) {
        const std::size_t i = index(x, y);
        keepIterations(x, y, hit);
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
      };
      const std::uint64_t tileIterations =
          castTile(root, rays, tile, options.beamTile > 0, options.cast, onHit, keepIterations);
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
