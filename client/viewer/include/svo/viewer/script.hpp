// `svo view --script FILE`: timed camera moves and key presses that drive the viewer as a person would, for
// tests under Xvfb and for measured fly-throughs. A script is a JSON array of steps run one after another:
//
//   {"camera": {"eye": [x,y,z], "target": [x,y,z], "up": [..], "fov": deg}}   jump there
//   {"hold": "W", "seconds": 1.5}        hold a key down (held keys fly the camera)
//   {"look": [dx, dy], "seconds": 1.0}   drag the mouse by (dx, dy) pixels over that time
//   {"key": "F1"}                        press and release a key (controls.hpp names them)
//   {"sleep": 0.5}                       keep viewing for that long
//   {"wait": "converged", "timeout": 60} until the view has converged and its frame is final (timeout: an
//   error)
//   {"wait": "file", "path": "p", "timeout": 60}   until the file exists (a test's signal)
//   {"screenshot": "out.png"}            save the next full-resolution frame there
//   {"set": {"budget": 16777216, "lod": 2, "contours": false, "colors": "octree level"}}
//                                        change settings as the overlay does (any of them; budget in bytes)
//   {"print": "overlay"}                 write the overlay's lines to standard output
//   {"mark": "text"}                     write "mark text" to standard output
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "svo/client/render.hpp"
#include "svo/viewer/controls.hpp"
#include "svo/viewer/false_color.hpp"

namespace svo::viewer {

struct ScriptStep {
  enum class Kind {
    Camera,
    Hold,
    Look,
    Key,
    Sleep,
    WaitConverged,
    WaitFile,
    Screenshot,
    Set,
    PrintOverlay,
    Mark
  };
  Kind kind = Kind::Sleep;
  std::string where;                // "FILE: step N", for messages
  Camera camera;                    // Camera (width and height are the window's)
  Action action = Action::Forward;  // Hold, Key
  double seconds = 0.0;             // Hold, Look, Sleep; the timeout of a wait
  double dx = 0.0, dy = 0.0;        // Look
  std::filesystem::path path;       // WaitFile, Screenshot
  std::string text;                 // Mark
  // Set: the settings it changes.
  std::optional<std::size_t> budgetBytes;
  std::optional<float> lodPixels;
  std::optional<bool> contours;
  std::optional<FalseColor> falseColor;
};

// Throws std::runtime_error naming the file, the step and the field for anything malformed.
std::vector<ScriptStep> loadScript(const std::filesystem::path& file);
// A one-line description of a step ("hold W for 1.5 s").
std::string describe(const ScriptStep& step);

// Longest a wait step may take (seconds) when it names no timeout; long enough for a cold close-up from a
// slow server, short enough that a test that cannot converge fails in bounded time.
inline constexpr double kDefaultWaitSeconds = 120.0;

}  // namespace svo::viewer
