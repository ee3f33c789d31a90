// The camera and the renderer's options as command-line flags, for every command that looks at a scene
// (`svo render`, `svo view`).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "svo/client/render.hpp"
#include "svo/store/store_index.hpp"

namespace svo::tools {

struct CameraFlags {
  std::string cameraFile;
  std::vector<double> eye, target, up{0.0, 1.0, 0.0},
      view{kDefaultViewDirection.x, kDefaultViewDirection.y, kDefaultViewDirection.z};
  double fov = 40.0;
  int width = 1024, height = 1024;
};

// Adds --camera, --eye, --target, --up, --view, --fov, --width and --height; `flags` holds the defaults
// shown.
void addCameraFlags(CLI::App& cmd, CameraFlags& flags);
// The camera the flags name: --camera's file, else --eye and --target, else nullopt (the scene framed).
std::optional<Camera> explicitCamera(const CameraFlags& flags);
// That camera, or what the octree under `root` holds (occupiedBox; `index` the store's) seen along --view at
// --width x --height.
Camera cameraOf(const CameraFlags& flags, const BlockView& root, const SceneTransform& scene,
                const StoreIndex& index);
glm::dvec3 viewDirectionOf(const CameraFlags& flags);

// Adds --lod-pixels, --beam-tile, --filter, --threads (bound to `options`) and --no-contours.
void addRenderFlags(CLI::App& cmd, RenderOptions& options, bool& noContours);
// On `--device gpu` the beam pass is off unless --beam-tile was given: on llvmpipe it costs 1.8x in a
// close-up and saves nothing in a whole view (`svo render --device gpu --beam-tile 0|8`, 1280x720); no real
// GPU was there to measure.
void applyDeviceBeamDefault(const CLI::App& cmd, const std::string& device, RenderOptions& options);

}  // namespace svo::tools
