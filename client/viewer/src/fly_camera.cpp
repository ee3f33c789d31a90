#include "svo/viewer/fly_camera.hpp"

#include <algorithm>
#include <cmath>

#include <glm/geometric.hpp>

namespace svo::viewer {
namespace {

// Speed bounds in scene sizes per second: slow enough to approach the finest of 23 levels, fast enough to
// leave the scene behind.
constexpr double kMinSpeedPerSize = 1e-7;
constexpr double kMaxSpeedPerSize = 10.0;

}  // namespace

FlyCamera::FlyCamera(const SceneTransform& scene, const WorldBox& contents, const Camera& start)
    : scene_(scene), contents_(contents), speed_(scene.size / kSecondsToCrossScene) {
  set(start);
}

void FlyCamera::set(const Camera& camera) {
  camera.validate();
  camera_ = camera;
  up_ = glm::normalize(camera.up);
  // Any horizontal axis will do for yaw 0; the one nearest the view keeps yaw small and readable.
  const glm::dvec3 view = glm::normalize(camera.target - camera.eye);
  glm::dvec3 level = view - glm::dot(view, up_) * up_;
  if (glm::length(level) < 1e-9) {  // looking along up: any axis across it
    level = glm::cross(up_, std::abs(up_.x) < 0.9 ? glm::dvec3(1, 0, 0) : glm::dvec3(0, 1, 0));
  }
  north_ = glm::normalize(level);
  east_ = glm::cross(north_, up_);
  headingFromCamera();
}

void FlyCamera::headingFromCamera() {
  const glm::dvec3 view = glm::normalize(camera_.target - camera_.eye);
  pitch_ = std::clamp(std::asin(std::clamp(glm::dot(view, up_), -1.0, 1.0)), -kMaxPitch, kMaxPitch);
  yaw_ = std::atan2(glm::dot(view, east_), glm::dot(view, north_));
}

glm::dvec3 FlyCamera::forward() const {
  return std::cos(pitch_) * (std::cos(yaw_) * north_ + std::sin(yaw_) * east_) + std::sin(pitch_) * up_;
}

void FlyCamera::cameraFromHeading() {
  // The target sits one scene size ahead: only its direction matters to the image.
  camera_.target = camera_.eye + forward() * scene_.size;
  camera_.up = up_;
}

Camera FlyCamera::camera(int width, int height) const {
  Camera c = camera_;
  c.width = width;
  c.height = height;
  return c;
}

void FlyCamera::frameScene() {
  const Camera framed =
      Camera::framingBox(contents_.lo, contents_.hi, forward(), camera_.width, camera_.height);
  camera_.eye = framed.eye;
  camera_.fovYDegrees = framed.fovYDegrees;
  cameraFromHeading();
}

bool FlyCamera::move(const MoveKeys& keys, double seconds) {
  const glm::dvec3 ahead = forward();
  const glm::dvec3 right = glm::normalize(glm::cross(ahead, up_));
  glm::dvec3 step(0.0);
  step += (double(keys.forward) - double(keys.back)) * ahead;
  step += (double(keys.right) - double(keys.left)) * right;
  step += (double(keys.up) - double(keys.down)) * up_;
  if (step == glm::dvec3(0.0) || !(seconds > 0.0)) return false;
  camera_.eye += glm::normalize(step) * speed_ * seconds;
  cameraFromHeading();
  return true;
}

void FlyCamera::look(double dx, double dy) {
  if (dx == 0.0 && dy == 0.0) return;
  yaw_ += dx * kLookRadiansPerPixel;
  pitch_ = std::clamp(pitch_ - dy * kLookRadiansPerPixel, -kMaxPitch, kMaxPitch);
  cameraFromHeading();
}

void FlyCamera::scaleSpeed(double steps) {
  speed_ = std::clamp(speed_ * std::pow(kSpeedPerScrollStep, steps), kMinSpeedPerSize * scene_.size,
                      kMaxSpeedPerSize * scene_.size);
}

}  // namespace svo::viewer
