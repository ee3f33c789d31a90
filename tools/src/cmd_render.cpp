// `svo render IN.svo -o frame.png`: ray casts the octree on all cores and writes PNG or EXR.
#include <cmath>
#include <filesystem>

#include <spdlog/spdlog.h>

#include "commands.hpp"
#include "svo/client/render.hpp"

namespace svo::tools {

namespace {
glm::dvec3 vec3Of(const std::vector<double>& v) {
  return {v[0], v[1], v[2]};
}
}  // namespace

void addRenderCommand(CLI::App& app) {
  struct Args {
    std::string in, out, cameraFile;
    std::vector<double> eye, target, up{0.0, 1.0, 0.0}, view{-0.35, -0.25, -1.0};
    double fov = 40.0;
    int width = 1024, height = 1024;
    RenderOptions options;
    bool noContours = false, aux = false;
  };
  auto args = std::make_shared<Args>();
  auto* cmd = app.add_subcommand("render", "ray cast a .svo octree to PNG or EXR");
  cmd->add_option("input", args->in, "input .svo file")->required();
  cmd->add_option("-o,--output", args->out, "output image (.png or .exr)")->required();
  cmd->add_option("--camera", args->cameraFile, "camera JSON {eye, target, up, fov, width, height}");
  cmd->add_option("--eye", args->eye, "camera position x,y,z (world)")->expected(3)->delimiter(',');
  cmd->add_option("--target", args->target, "point looked at x,y,z (world)")->expected(3)->delimiter(',');
  cmd->add_option("--up", args->up, "up vector x,y,z")->expected(3)->delimiter(',')->capture_default_str();
  cmd->add_option("--view", args->view, "without --eye: look along this direction at the whole scene")
      ->expected(3)
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--fov", args->fov, "vertical field of view, degrees")
      ->check(CLI::Range(1.0, 179.0))
      ->capture_default_str();
  cmd->add_option("--width", args->width, "image width")->check(CLI::Range(1, 16384))->capture_default_str();
  cmd->add_option("--height", args->height, "image height")
      ->check(CLI::Range(1, 16384))
      ->capture_default_str();
  cmd->add_option("--lod-pixels", args->options.lodPixels,
                  "stop at voxels this many pixels across (0 = finest)")
      ->check(CLI::Range(0.0, 64.0))
      ->capture_default_str();
  cmd->add_option("--beam-tile", args->options.beamTile,
                  "beam optimization (sec. 6.2): pixels per tile edge of one coarse pass (0 = off)")
      ->check(CLI::Range(0, 64))
      ->capture_default_str();
  cmd->add_flag("--no-contours", args->noContours, "ignore contours: cube voxels");
  cmd->add_flag("--aux", args->aux, "EXR only: add depth (Z) and voxel-size-in-pixels channels");
  cmd->add_option("--threads", args->options.threads, "threads (0 = all cores)")
      ->check(CLI::NonNegativeNumber);
  cmd->callback([args] {
    const std::filesystem::path out = args->out;
    const std::string ext = out.extension().string();
    if (ext != ".png" && ext != ".exr") throw UsageError(args->out + ": output must end in .png or .exr");
    if (args->aux && ext != ".exr")
      throw UsageError("--aux needs an .exr output (PNG has no float channels)");
    checkWritableOutput(out);
    const Octree octree = readOctree(args->in);
    Camera camera;
    if (!args->cameraFile.empty()) {
      camera = loadCamera(args->cameraFile);
    } else if (!args->eye.empty()) {
      if (args->target.empty()) throw UsageError("--eye needs --target");
      camera.eye = vec3Of(args->eye);
      camera.target = vec3Of(args->target);
      camera.up = vec3Of(args->up);
      camera.fovYDegrees = args->fov;
      camera.width = args->width, camera.height = args->height;
    } else {
      camera = Camera::framing(octree.transform, vec3Of(args->view), args->width, args->height);
      camera.up = vec3Of(args->up);
    }
    camera.validate();
    RenderOptions options = args->options;
    options.cast.contours = !args->noContours && octree.parameters.contours;
    const Frame frame = render(octree, camera, options);
    writeFrame(out, frame, args->aux);
    std::printf("wrote %s (%dx%d): %.3f s, %.2f Mrays/s, %.1f iterations/ray\n", args->out.c_str(),
                frame.width, frame.height, frame.seconds, frame.mraysPerSecond(), frame.meanIterations);
  });
}

}  // namespace svo::tools
