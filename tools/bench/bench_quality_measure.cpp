// The quality bench's exact reference, its images and the errors of a voxel image against it
// (bench_quality.hpp).
#include <algorithm>
#include <cmath>
#include <limits>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <spdlog/spdlog.h>
#include <glm/geometric.hpp>

#include "bench_quality.hpp"
#include "mesh_shading.hpp"

namespace svo::tools::bench {
namespace {

// Tail quantile of the depth error.
constexpr double kDepthQuantile = 0.99;
// A reference pixel is on an edge when a 4-neighbour misses or its depth jumps by more than this fraction of
// the pixel's depth: there a voxel and a triangle may hit different surfaces (tower and ground), and the
// depth tail measures the edge, not the surface. 2% still counts surfaces up to ~4 degrees from grazing at
// 512 pixels and 40 degrees as surface.
constexpr double kEdgeDepthJump = 0.02;

OIIO::ImageBuf toImageBuf(const Image& image) {
  OIIO::ImageBuf buf(OIIO::ImageSpec(image.width, image.height, 3, OIIO::TypeDesc::FLOAT));
  std::vector<float> pixels(image.color.size() * 3);
  for (std::size_t i = 0; i < image.color.size(); ++i)
    for (int c = 0; c < 3; ++c) pixels[3 * i + c] = std::clamp(image.color[i][c], 0.0f, 1.0f);
  buf.set_pixels(OIIO::ROI::All(), OIIO::TypeDesc::FLOAT, pixels.data());
  return buf;
}

}  // namespace

std::unique_ptr<accel::Accel> buildReference(const Mesh& mesh) {
  spdlog::info("reference: kd-tree over {} triangles ...", mesh.triangles.size());
  return accel::buildByName("kd-binned", accel::trianglesOf(mesh));
}

// The mesh ray cast through the kd-tree, shaded like svo::render with interpolated normals and colors.
Image renderReference(const Mesh& mesh, const accel::Accel& kd, const Camera& camera,
                      const RenderOptions& options, int threads) {
  const MeshShading shading(mesh, options);
  Image image;
  image.width = camera.width, image.height = camera.height;
  image.color.assign(std::size_t(camera.width) * camera.height, shading.background());
  image.depth.assign(image.color.size(), std::numeric_limits<float>::infinity());
  const Camera::Basis basis = camera.basis();
  const double pixelAngle = camera.pixelAngle();
  forEachTile(camera.width, camera.height, 8, threads, [&](const PixelTile& tile) {
    for (int y = tile.y0; y < tile.y1; ++y)
      for (int x = tile.x0; x < tile.x1; ++x) {
        accel::Ray ray;
        ray.origin = camera.eye;
        Camera::pixelRay(camera, basis, x, y, ray.direction);
        const accel::Hit hit = kd.closestHit(ray);
        if (!hit.hit()) continue;
        const std::size_t i = std::size_t(y) * camera.width + x;
        image.color[i] = shading.shade(hit.triangle, hit.u, hit.v, ray.direction,
                                       PixelFootprint::at(basis, hit.t, pixelAngle));
        image.depth[i] = float(hit.t);
      }
  });
  return image;
}

void writePng(const std::filesystem::path& path, const Image& image) {
  OIIO::ImageBuf srgb = OIIO::ImageBufAlgo::colorconvert(toImageBuf(image), "linear", "sRGB");
  if (!srgb.write(path.string(), OIIO::TypeDesc::UINT8))
    throw std::runtime_error(path.string() + ": cannot write (" + srgb.geterror() + ")");
}

Image imageOf(Frame&& frame) {
  Image image;
  image.width = frame.width, image.height = frame.height;
  image.color.resize(frame.color.size());
  for (std::size_t i = 0; i < frame.color.size(); ++i) image.color[i] = glm::vec3(frame.color[i]);
  image.depth = std::move(frame.depth);
  return image;
}

void compare(const Image& reference, const Image& voxels, double finestVoxel, Measured& m) {
  const OIIO::ImageBufAlgo::CompareResults r =
      OIIO::ImageBufAlgo::compare(toImageBuf(voxels), toImageBuf(reference), 1.0f, 1.0f);
  m.rmse = r.rms_error;
  m.psnr = r.PSNR;
  const auto onEdge = [&](int x, int y) {
    const float d = reference.depth[std::size_t(y) * std::size_t(reference.width) + std::size_t(x)];
    for (const auto& [dx, dy] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
      const int nx = x + dx, ny = y + dy;
      if (nx < 0 || ny < 0 || nx >= reference.width || ny >= reference.height) continue;
      const float n = reference.depth[std::size_t(ny) * std::size_t(reference.width) + std::size_t(nx)];
      if (!std::isfinite(n) || std::abs(double(n) - double(d)) > kEdgeDepthJump * double(d)) return true;
    }
    return false;
  };
  std::vector<double> depth, offEdges;
  std::size_t mismatch = 0;
  for (int y = 0; y < reference.height; ++y)
    for (int x = 0; x < reference.width; ++x) {
      const std::size_t i = std::size_t(y) * std::size_t(reference.width) + std::size_t(x);
      const bool a = std::isfinite(reference.depth[i]), b = std::isfinite(voxels.depth[i]);
      mismatch += a != b;
      if (!a || !b) continue;
      depth.push_back(std::abs(double(voxels.depth[i]) - double(reference.depth[i])) / finestVoxel);
      if (!onEdge(x, y)) offEdges.push_back(depth.back());
    }
  m.silhouettePercent = 100.0 * double(mismatch) / double(reference.depth.size());
  const auto tail = [](std::vector<double>& v) {
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, std::size_t(kDepthQuantile * double(v.size())))];
  };
  if (!depth.empty()) {
    double sum = 0.0;
    for (const double d : depth) sum += d;
    m.depthMean = sum / double(depth.size());
    m.depthTail = tail(depth);
  }
  if (!offEdges.empty()) m.depthTailOffEdges = tail(offEdges);
}

void buildLevel(const Mesh& mesh, const BuildOptions& build, const std::filesystem::path& out, bool withRoot,
                LevelScene& s, const std::vector<float>& exactNormals) {
  const int levels = build.levels;
  spdlog::info("building {} levels, contour cut {} ...", levels, build.leafContourMinReduction);
  s.transform = fitSceneCube(mesh);
  VoxelTree tree;
  s.buildSeconds = timeSeconds([&] { tree = voxelize(mesh, s.transform, build); });
  s.store = out / fmt::format("L{}-cut{}.svo", levels, build.leafContourMinReduction);
  const BuildParameters parameters = storedParameters(build);
  writeStore(s.store, tree, s.transform, parameters);
  s.storeBytes = std::filesystem::file_size(s.store);
  if (!withRoot) return;
  s.buildSeconds +=
      timeSeconds([&] { s.scene.emplace(wholeSceneOf(tree, s.transform, parameters, s.store)); });
  if (!tree.hasColors && !tree.hasNormals) return;
  for (const float degrees : exactNormals)
    s.compressed.emplace_back(degrees, wholeSceneOf(tree, s.transform, parameters, s.store, nullptr,
                                                    {AttributeLayout::Compressed, degrees}));
}

}  // namespace svo::tools::bench
