// The viewer's flying camera: an eye and a heading (yaw about the up axis, pitch above the horizon), moved by
// held keys at a speed relative to the scene and turned by the mouse.
#pragma once

#include <glm/vec3.hpp>

#include "svo/client/render.hpp"
#include "svo/store/store_types.hpp"

namespace svo::viewer {

// Which movement keys are down.
struct MoveKeys {
  bool forward = false, back = false, left = false, right = false, down = false, up = false;
  bool any() const { return forward || back || left || right || down || up; }
};

// Flying speed when the viewer opens: the scene's cube in this many seconds (a common default of fly-through
// viewers, slow enough for a close-up and fast enough to cross the scene).
inline constexpr double kSecondsToCrossScene = 4.0;
// Each scroll step multiplies the speed by this (or divides it); 12 steps are a factor of about 15.
inline constexpr double kSpeedPerScrollStep = 1.25;
// Radians turned per pixel the mouse moves with its button down (about 0.17 degrees, as in most viewers).
inline constexpr double kLookRadiansPerPixel = 0.003;
// The heading stops this short of straight up or down (radians), where yaw about the up axis degenerates.
inline constexpr double kMaxPitch = 1.55;

class FlyCamera {
 public:
  // `contents`: the box frameScene frames (occupiedBox of the scene's octree).
  FlyCamera(const SceneTransform& scene, const WorldBox& contents, const Camera& start);

  // The camera for an image of width x height. Until the camera moves it is exactly the one it was set to.
  Camera camera(int width, int height) const;
  // Jumps to `camera` (its eye, target, up and field of view).
  void set(const Camera& camera);
  // Looks at the whole scene (its contents box) from the current heading.
  void frameScene();
  // Flies for `seconds` with `keys` down; returns whether the eye moved.
  bool move(const MoveKeys& keys, double seconds);
  // Turns by a mouse motion of (dx, dy) pixels: right and down turn right and down.
  void look(double dx, double dy);
  // Scroll steps: positive is faster.
  void scaleSpeed(double steps);

  double speed() const { return speed_; }  // world units per second
  double yaw() const { return yaw_; }
  double pitch() const { return pitch_; }

 private:
  glm::dvec3 forward() const;
  void headingFromCamera();
  void cameraFromHeading();

  SceneTransform scene_;
  WorldBox contents_;
  Camera camera_;
  glm::dvec3 up_{0.0, 1.0, 0.0};
  glm::dvec3 north_{0.0, 0.0, -1.0}, east_{1.0, 0.0, 0.0};  // the horizon's axes: yaw 0 and yaw pi/2
  double yaw_ = 0.0, pitch_ = 0.0;
  double speed_ = 1.0;
};

}  // namespace svo::viewer
