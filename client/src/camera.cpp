// Pinhole camera: pixel rays, the level-of-detail pixel angle, validation, framing and JSON loading.
#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>

#include <glm/geometric.hpp>
#include <nlohmann/json.hpp>

#include "svo/client/render.hpp"

namespace svo {
namespace {

constexpr int kMaxImageSide = 16384;
constexpr double kDefaultFovDegrees = 45.0;
constexpr int kDefaultImageSide = 512;
// |sin| of the angle between up and the view below which the camera basis is ill-conditioned.
constexpr double kParallelSine = 1e-9;
// framingBox keeps the eye at least this fraction of the box's diagonal in front of its nearest corner.
constexpr double kNearFraction = 1e-3;

double radians(double degrees) {
  return degrees * std::numbers::pi / 180.0;
}

bool finite(glm::dvec3 v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

std::string format(glm::dvec3 v) {
  return "(" + std::to_string(v.x) + ", " + std::to_string(v.y) + ", " + std::to_string(v.z) + ")";
}

}  // namespace

// Right-handed look-at basis: forward into the scene, right to the image's +x, up to the image's top.
Camera::Basis Camera::basis() const {
  Basis b;
  b.forward = glm::normalize(target - eye);
  b.right = glm::normalize(glm::cross(b.forward, up));
  b.up = glm::cross(b.right, b.forward);
  b.tanHalf = std::tan(radians(fovYDegrees) * 0.5);
  b.aspect = double(width) / double(height);
  return b;
}

void Camera::pixelRay(const Camera& camera, const Basis& b, double x, double y, glm::dvec3& direction) {
  direction =
      glm::normalize(b.forward + b.across(x, camera.width) * b.right + b.down(y, camera.height) * b.up);
}

void Camera::pixelRay(double x, double y, glm::dvec3& origin, glm::dvec3& direction) const {
  origin = eye;
  pixelRay(*this, basis(), x, y, direction);
}

double Camera::pixelAngle() const {
  return 2.0 * std::tan(radians(fovYDegrees) * 0.5) / double(height);
}

void Camera::validate() const {
  if (!finite(eye) || !finite(target) || !finite(up) || !std::isfinite(fovYDegrees))
    throw std::runtime_error("camera: eye, target, up and fov must be finite numbers");
  if (!(fovYDegrees > 0.0 && fovYDegrees < 180.0))
    throw std::runtime_error("camera: fov must be in (0, 180) degrees (got " + std::to_string(fovYDegrees) +
                             ")");
  if (width < 1 || width > kMaxImageSide || height < 1 || height > kMaxImageSide)
    throw std::runtime_error("camera: width and height must be in [1, " + std::to_string(kMaxImageSide) +
                             "] (got " + std::to_string(width) + "x" + std::to_string(height) + ")");
  const glm::dvec3 view = target - eye;
  const double viewLength = glm::length(view);
  if (!(viewLength > 0.0) || !std::isfinite(viewLength))
    throw std::runtime_error("camera: eye and target must differ (both " + format(eye) + ")");
  const double upLength = glm::length(up);
  if (!(upLength > 0.0) || !std::isfinite(upLength) ||
      glm::length(glm::cross(view / viewLength, up / upLength)) < kParallelSine)
    throw std::runtime_error("camera: up " + format(up) +
                             " must not be zero or parallel to the view direction");
}

namespace {

// A camera of the default field of view looking along `viewDirection` (-z when it is not a direction); its
// unit forward vector is returned in `forward`. Eye and target are the caller's.
Camera lookingAlong(glm::dvec3 viewDirection, int width, int height, glm::dvec3& forward) {
  Camera camera;
  camera.width = width;
  camera.height = height;
  camera.fovYDegrees = kDefaultFovDegrees;
  const double length = glm::length(viewDirection);
  forward = (length > 0.0 && std::isfinite(length)) ? viewDirection / length : glm::dvec3(0.0, 0.0, -1.0);
  // Looking straight up or down: y cannot be up, so the image's top points along -z.
  camera.up = std::abs(forward.y) > 0.999 ? glm::dvec3(0.0, 0.0, -1.0) : glm::dvec3(0.0, 1.0, 0.0);
  return camera;
}

}  // namespace

Camera Camera::framing(const SceneTransform& scene, glm::dvec3 viewDirection, int width, int height) {
  glm::dvec3 forward;
  Camera camera = lookingAlong(viewDirection, width, height, forward);
  // The octree's [1, 2]^3 is the world cube [origin, origin + size]^3.
  const glm::dvec3 centre = scene.origin + 0.5 * scene.size;
  const double radius = 0.5 * std::sqrt(3.0) * scene.size;
  // The bounding sphere fits when its radius subtends at most the narrower half-angle of the view.
  const double tanHalfY = std::tan(radians(camera.fovYDegrees) * 0.5);
  const double tanHalfX = tanHalfY * double(std::max(width, 1)) / double(std::max(height, 1));
  const double halfAngle = std::atan(std::min(tanHalfX, tanHalfY));
  const double distance = radius / std::sin(halfAngle);
  camera.target = centre;
  camera.eye = centre - forward * distance;
  return camera;
}

WorldBox sceneBox(const SceneTransform& scene) {
  return {scene.toWorld(glm::dvec3(1.0)), scene.toWorld(glm::dvec3(2.0))};
}

WorldBox occupiedBox(const BlockView& root, const SceneTransform& scene, int trunkLevels) {
  const int levels = std::max(1, std::min(kFramingLevels, trunkLevels));
  // Octree space: the cube at `coord` of `level` is [1, 2]^3 cut into 2^level per side.
  glm::dvec3 lo(std::numeric_limits<double>::infinity()), hi(-std::numeric_limits<double>::infinity());
  const auto include = [&](const glm::ivec3& coord, int level) {
    const double side = std::ldexp(1.0, -level);
    lo = glm::min(lo, glm::dvec3(1.0) + glm::dvec3(coord) * side);
    hi = glm::max(hi, glm::dvec3(1.0) + glm::dvec3(coord + 1) * side);
  };
  struct Visit {
    const ChildDescriptor* descriptor;
    glm::ivec3 coord;
    int level;
  };
  std::vector<Visit> stack{{root.root(), glm::ivec3(0), 0}};
  while (!stack.empty()) {
    const Visit v = stack.back();
    stack.pop_back();
    const ChildDescriptor* d = v.descriptor;
    for (int slot = 0; slot < 8; ++slot) {
      if (!(d->validMask() >> slot & 1u)) continue;
      const glm::ivec3 coord = childCoord(v.coord, slot);
      const ChildDescriptor* child = (d->nonLeafMask() >> slot & 1u) ? BlockView::child(d, slot) : nullptr;
      if (v.level + 1 == levels || !child || child->isStub())
        include(coord, v.level + 1);
      else
        stack.push_back({child, coord, v.level + 1});
    }
  }
  if (!(lo.x <= hi.x)) return sceneBox(scene);
  return {scene.toWorld(lo), scene.toWorld(hi)};
}

Camera Camera::framingBox(glm::dvec3 lo, glm::dvec3 hi, glm::dvec3 viewDirection, int width, int height) {
  glm::dvec3 forward;
  Camera camera = lookingAlong(viewDirection, width, height, forward);
  const glm::dvec3 centre = 0.5 * (lo + hi);
  camera.target = centre;
  camera.eye = centre - forward;  // only the basis is wanted here: it does not depend on the distance
  const Basis basis = camera.basis();
  const double tanHalfY = basis.tanHalf, tanHalfX = basis.tanHalf * basis.aspect;
  // Each corner q (relative to the centre) projects inside the image when the eye is far enough back:
  // |q.right| <= (distance + q.forward) tanHalfX, and the same vertically.
  double distance = 0.0;
  for (int corner = 0; corner < 8; ++corner) {
    const glm::dvec3 q =
        glm::dvec3(corner & 1 ? hi.x : lo.x, corner & 2 ? hi.y : lo.y, corner & 4 ? hi.z : lo.z) - centre;
    const double along = glm::dot(q, basis.forward);
    distance = std::max({distance, std::abs(glm::dot(q, basis.right)) / tanHalfX - along,
                         std::abs(glm::dot(q, basis.up)) / tanHalfY - along});
  }
  // The eye stays in front of every corner (a box seen end-on projects to a point), and off the centre of a
  // point-like box.
  const double diagonal = glm::length(hi - lo);
  for (int corner = 0; corner < 8; ++corner) {
    const glm::dvec3 q =
        glm::dvec3(corner & 1 ? hi.x : lo.x, corner & 2 ? hi.y : lo.y, corner & 4 ? hi.z : lo.z) - centre;
    distance = std::max(distance, kNearFraction * diagonal - glm::dot(q, basis.forward));
  }
  if (!(distance > 0.0)) distance = 1.0;
  camera.eye = centre - forward * distance;
  return camera;
}

namespace {

using Json = nlohmann::json;

[[noreturn]] void keyError(const std::string& file, const std::string& key, const std::string& what) {
  throw std::runtime_error(file + ": key '" + key + "' " + what);
}

glm::dvec3 readVector(const Json& object, const std::string& file, const char* key,
                      const glm::dvec3* fallback) {
  const auto it = object.find(key);
  if (it == object.end()) {
    if (fallback) return *fallback;
    keyError(file, key, "is missing (an array of 3 numbers)");
  }
  if (!it->is_array() || it->size() != 3) keyError(file, key, "must be an array of 3 numbers");
  glm::dvec3 v;
  for (int i = 0; i < 3; ++i) {
    if (!(*it)[i].is_number()) keyError(file, key, "must be an array of 3 numbers");
    v[i] = (*it)[i].get<double>();
  }
  return v;
}

double readNumber(const Json& object, const std::string& file, const char* key, double fallback) {
  const auto it = object.find(key);
  if (it == object.end()) return fallback;
  if (!it->is_number()) keyError(file, key, "must be a number");
  return it->get<double>();
}

int readSide(const Json& object, const std::string& file, const char* key, int fallback) {
  const auto it = object.find(key);
  if (it == object.end()) return fallback;
  // Accept 512.0 as well as 512: JSON writers do not always keep the distinction.
  const double value = it->is_number() ? it->get<double>() : std::nan("");
  if (!(value >= 1.0 && value <= kMaxImageSide) || value != std::floor(value))
    keyError(file, key, "must be an integer in [1, " + std::to_string(kMaxImageSide) + "]");
  return int(value);
}

}  // namespace

namespace {

Json parseJsonFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path.string() + ": cannot open camera file");
  try {
    return Json::parse(in);
  } catch (const Json::exception& e) {
    throw std::runtime_error(path.string() + ": not valid JSON (" + e.what() + ")");
  }
}

// `where` names the camera in messages: the file, or the file and the camera's index in a path.
Camera cameraOf(const Json& json, const std::string& where) {
  if (!json.is_object()) throw std::runtime_error(where + ": a camera must be a JSON object");
  // Unknown keys are most often typos ("fovy"); silently ignoring them would render the wrong view.
  for (const auto& item : json.items()) {
    const std::string& key = item.key();
    if (key != "eye" && key != "target" && key != "up" && key != "fov" && key != "width" && key != "height")
      keyError(where, key, "is not known (expected eye, target, up, fov, width, height)");
  }
  Camera camera;
  const glm::dvec3 defaultUp(0.0, 1.0, 0.0);
  camera.eye = readVector(json, where, "eye", nullptr);
  camera.target = readVector(json, where, "target", nullptr);
  camera.up = readVector(json, where, "up", &defaultUp);
  camera.fovYDegrees = readNumber(json, where, "fov", kDefaultFovDegrees);
  camera.width = readSide(json, where, "width", kDefaultImageSide);
  camera.height = readSide(json, where, "height", kDefaultImageSide);
  try {
    camera.validate();
  } catch (const std::runtime_error& e) {
    // validate() speaks of "camera: ..."; here the file is the better subject.
    std::string what = e.what();
    if (what.starts_with("camera: ")) what.erase(0, 8);
    throw std::runtime_error(where + ": " + what);
  }
  return camera;
}

}  // namespace

Camera parseCamera(const std::string& jsonText, const std::string& where) {
  Json json;
  try {
    json = Json::parse(jsonText);
  } catch (const Json::exception& e) {
    throw std::runtime_error(where + ": not valid JSON (" + e.what() + ")");
  }
  return cameraOf(json, where);
}

Camera loadCamera(const std::filesystem::path& path) {
  return cameraOf(parseJsonFile(path), path.string());
}

std::vector<Camera> loadCameraPath(const std::filesystem::path& path) {
  const Json json = parseJsonFile(path);
  if (!json.is_array() || json.empty())
    throw std::runtime_error(path.string() + ": a camera path must be a non-empty JSON array of cameras");
  std::vector<Camera> cameras;
  for (std::size_t i = 0; i < json.size(); ++i)
    cameras.push_back(cameraOf(json[i], path.string() + ": camera " + std::to_string(i)));
  return cameras;
}

}  // namespace svo
