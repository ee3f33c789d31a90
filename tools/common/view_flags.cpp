#include "view_flags.hpp"

#include "number_checks.hpp"
#include "pager_flags.hpp"
#include "usage.hpp"

namespace svo::tools {
namespace {

glm::dvec3 vec3Of(const std::vector<double>& v) {
  return {v[0], v[1], v[2]};
}

}  // namespace

void addCameraFlags(CLI::App& cmd, CameraFlags& flags) {
  cmd.add_option("--camera", flags.cameraFile, "camera JSON {eye, target, up, fov, width, height}");
  cmd.add_option("--eye", flags.eye, "camera position x,y,z (world)")->expected(3)->delimiter(',');
  cmd.add_option("--target", flags.target, "point looked at x,y,z (world)")->expected(3)->delimiter(',');
  cmd.add_option("--up", flags.up, "up vector x,y,z")->expected(3)->delimiter(',')->capture_default_str();
  cmd.add_option("--view", flags.view, "without --eye: look along this direction at the whole scene")
      ->expected(3)
      ->delimiter(',')
      ->check(finiteNumber())
      ->capture_default_str();
  cmd.add_option("--fov", flags.fov, "vertical field of view, degrees")
      ->check(finiteRange(1.0, 179.0))
      ->capture_default_str();
  cmd.add_option("--width", flags.width, "image width")->check(CLI::Range(1, 16384))->capture_default_str();
  cmd.add_option("--height", flags.height, "image height")
      ->check(CLI::Range(1, 16384))
      ->capture_default_str();
}

std::optional<Camera> explicitCamera(const CameraFlags& flags) {
  Camera camera;
  if (!flags.cameraFile.empty()) {
    camera = loadCamera(flags.cameraFile);
  } else if (!flags.eye.empty()) {
    if (flags.target.empty()) throw UsageError("--eye needs --target");
    camera.eye = vec3Of(flags.eye);
    camera.target = vec3Of(flags.target);
    camera.up = vec3Of(flags.up);
    camera.fovYDegrees = flags.fov;
    camera.width = flags.width, camera.height = flags.height;
  } else {
    return std::nullopt;
  }
  camera.validate();
  return camera;
}

glm::dvec3 viewDirectionOf(const CameraFlags& flags) {
  const glm::dvec3 view = vec3Of(flags.view);
  if (view == glm::dvec3(0.0)) throw UsageError("--view: the direction must not be zero");
  return view;
}

Camera cameraOf(const CameraFlags& flags, const BlockView& root, const SceneTransform& scene,
                const StoreIndex& index) {
  if (std::optional<Camera> camera = explicitCamera(flags)) return *camera;
  const WorldBox box = occupiedBox(root, scene, index.trunkLevels());
  Camera camera = Camera::framingBox(box.lo, box.hi, viewDirectionOf(flags), flags.width, flags.height);
  camera.up = vec3Of(flags.up);
  camera.validate();
  return camera;
}

void addRenderFlags(CLI::App& cmd, RenderOptions& options, bool& noContours) {
  cmd.add_option("--lod-pixels", options.lodPixels, "stop at voxels this many pixels across (0 = finest)")
      ->check(finiteRange(0.0, 64.0))
      ->capture_default_str();
  cmd.add_option("--beam-tile", options.beamTile,
                 "beam optimization (sec. 6.2): pixels per tile edge of one coarse pass (0 = off)")
      ->check(CLI::Range(0, 64))
      ->capture_default_str();
  cmd.add_flag("--no-contours", noContours, "ignore contours: cube voxels");
  cmd.add_flag("--filter", options.filter,
               "post-process filter (sec. 6.3): blur the blocks of voxels wider than a pixel");
  cmd.add_option("--threads", options.threads, "render threads (0 = all cores)")
      ->check(CLI::NonNegativeNumber);
  addPacketSimdFlag(cmd, options.cast.simd);
}

void applyDeviceBeamDefault(const CLI::App& cmd, const std::string& device, RenderOptions& options) {
  if (device == "gpu" && cmd.count("--beam-tile") == 0) options.beamTile = 0;
}

}  // namespace svo::tools
