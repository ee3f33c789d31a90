#include "svo/viewer/script.hpp"

#include <cmath>
#include <fstream>
#include <set>
#include <stdexcept>

#include <nlohmann/json.hpp>

#include "svo/client/pager.hpp"

namespace svo::viewer {
namespace {

using Json = nlohmann::json;

// A step longer than this is a typo (seconds taken for milliseconds): a day.
constexpr double kLongestStepSeconds = 86400.0;

[[noreturn]] void fail(const std::string& where, const std::string& what) {
  throw std::runtime_error(where + ": " + what);
}

void onlyKeys(const Json& step, const std::string& where, const std::set<std::string>& allowed) {
  for (const auto& item : step.items())
    if (!allowed.contains(item.key()))
      fail(where, "'" + item.key() +
                      "' is not known here (a step is one of camera, hold, look, key, sleep, "
                      "wait, screenshot, set, print, mark)");
}

double seconds(const Json& step, const std::string& where, const char* key, std::optional<double> fallback) {
  const auto it = step.find(key);
  if (it == step.end()) {
    if (fallback) return *fallback;
    fail(where, std::string("'") + key + "' is missing (seconds)");
  }
  const double value = it->is_number() ? it->get<double>() : std::nan("");
  if (!(value >= 0.0 && value <= kLongestStepSeconds))
    fail(where, std::string("'") + key + "' must be a number of seconds in [0, 86400]");
  return value;
}

std::string text(const Json& step, const std::string& where, const char* key) {
  const auto it = step.find(key);
  if (it == step.end() || !it->is_string() || it->get<std::string>().empty())
    fail(where, std::string("'") + key + "' must be a non-empty string");
  return it->get<std::string>();
}

Action keyAction(const Json& step, const std::string& where, const char* key) {
  const std::string name = text(step, where, key);
  const std::optional<Action> action = actionOfKeyName(name);
  if (!action) fail(where, "'" + name + "' is not a key the viewer knows (" + key + ")");
  return *action;
}

// The smallest budget a script may set: one slice of the default size (a smaller pool holds no trunk).
constexpr double kMinScriptBudgetBytes = 1 << 20;
// The coarsest level of detail a script may set, as `svo render --lod-pixels` allows.
constexpr double kMaxLodPixels = 64.0;

void parseSettings(const Json& set, const std::string& where, ScriptStep& out) {
  if (!set.is_object() || set.empty()) fail(where, "must be an object of budget, lod, contours and colors");
  for (const auto& item : set.items()) {
    const std::string& key = item.key();
    const Json& value = item.value();
    if (key == "budget") {
      const double bytes = value.is_number() ? value.get<double>() : std::nan("");
      if (!(bytes >= kMinScriptBudgetBytes && bytes <= double(kMaxBudgetBytes)) || bytes != std::floor(bytes))
        fail(where, "'budget' must be a whole number of bytes from 1 MiB to 16 GiB");
      out.budgetBytes = std::size_t(bytes);
    } else if (key == "lod") {
      const double lod = value.is_number() ? value.get<double>() : std::nan("");
      if (!(lod >= 0.0 && lod <= kMaxLodPixels)) fail(where, "'lod' must be a number of pixels in [0, 64]");
      out.lodPixels = float(lod);
    } else if (key == "contours") {
      if (!value.is_boolean()) fail(where, "'contours' must be true or false");
      out.contours = value.get<bool>();
    } else if (key == "colors") {
      const std::string name = value.is_string() ? value.get<std::string>() : "";
      for (FalseColor mode : kFalseColors)
        if (name == nameOf(mode)) out.falseColor = mode;
      if (!out.falseColor)
        fail(where,
             "'colors' must be one of: shaded, octree level, iterations per pixel, resident vs wanted");
    } else {
      fail(where, "'" + key + "' is not a setting (budget, lod, contours, colors)");
    }
  }
}

ScriptStep parseStep(const Json& step, const std::string& where) {
  if (!step.is_object()) fail(where, "a step must be a JSON object");
  ScriptStep out;
  out.where = where;
  using K = ScriptStep::Kind;
  if (step.contains("camera")) {
    onlyKeys(step, where, {"camera"});
    out.kind = K::Camera;
    Json camera = step["camera"];
    if (camera.is_object()) {
      if (camera.contains("width") || camera.contains("height"))
        fail(where, "a script's camera takes the window's size: leave out width and height");
      camera["width"] = 1;  // validated below; the window's size replaces it
      camera["height"] = 1;
    }
    out.camera = parseCamera(camera.dump(), where + ": camera");
  } else if (step.contains("hold")) {
    onlyKeys(step, where, {"hold", "seconds"});
    out.kind = K::Hold;
    out.action = keyAction(step, where, "hold");
    if (!isHeld(out.action))
      fail(where, "'hold' takes a movement key (W, A, S, D, Q, E); use 'key' for the others");
    out.seconds = seconds(step, where, "seconds", std::nullopt);
  } else if (step.contains("look")) {
    onlyKeys(step, where, {"look", "seconds"});
    out.kind = K::Look;
    const Json& look = step["look"];
    if (!look.is_array() || look.size() != 2 || !look[0].is_number() || !look[1].is_number() ||
        !std::isfinite(look[0].get<double>()) || !std::isfinite(look[1].get<double>()))
      fail(where, "'look' must be [dx, dy] in pixels");
    out.dx = look[0].get<double>(), out.dy = look[1].get<double>();
    out.seconds = seconds(step, where, "seconds", 0.0);
  } else if (step.contains("key")) {
    onlyKeys(step, where, {"key"});
    out.kind = K::Key;
    out.action = keyAction(step, where, "key");
  } else if (step.contains("sleep")) {
    onlyKeys(step, where, {"sleep"});
    out.kind = K::Sleep;
    out.seconds = seconds(step, where, "sleep", std::nullopt);
  } else if (step.contains("wait")) {
    const std::string what = text(step, where, "wait");
    if (what == "converged") {
      onlyKeys(step, where, {"wait", "timeout"});
      out.kind = K::WaitConverged;
    } else if (what == "file") {
      onlyKeys(step, where, {"wait", "path", "timeout"});
      out.kind = K::WaitFile;
      out.path = text(step, where, "path");
    } else {
      fail(where, "'wait' must be \"converged\" or \"file\"");
    }
    out.seconds = seconds(step, where, "timeout", kDefaultWaitSeconds);
  } else if (step.contains("screenshot")) {
    onlyKeys(step, where, {"screenshot"});
    out.kind = K::Screenshot;
    out.path = text(step, where, "screenshot");
    if (out.path.extension() != ".png") fail(where, "'screenshot' must name a .png file");
  } else if (step.contains("set")) {
    onlyKeys(step, where, {"set"});
    out.kind = K::Set;
    parseSettings(step["set"], where + ": set", out);
  } else if (step.contains("print")) {
    onlyKeys(step, where, {"print"});
    if (text(step, where, "print") != "overlay") fail(where, "'print' must be \"overlay\"");
    out.kind = K::PrintOverlay;
  } else if (step.contains("mark")) {
    onlyKeys(step, where, {"mark"});
    out.kind = K::Mark;
    out.text = text(step, where, "mark");
  } else {
    onlyKeys(step, where, {});
    fail(where, "an empty step");
  }
  return out;
}

}  // namespace

std::vector<ScriptStep> loadScript(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw std::runtime_error(file.string() + ": cannot open the script");
  Json json;
  try {
    json = Json::parse(in);
  } catch (const Json::exception& e) {
    throw std::runtime_error(file.string() + ": not valid JSON (" + e.what() + ")");
  }
  if (!json.is_array()) throw std::runtime_error(file.string() + ": a script must be a JSON array of steps");
  std::vector<ScriptStep> steps;
  for (std::size_t i = 0; i < json.size(); ++i)
    steps.push_back(parseStep(json[i], file.string() + ": step " + std::to_string(i + 1)));
  return steps;
}

std::string describe(const ScriptStep& s) {
  using K = ScriptStep::Kind;
  const auto secs = [](double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%.3g s", v);
    return std::string(b);
  };
  switch (s.kind) {
    case K::Camera:
      return "camera jump";
    case K::Hold:
      return "hold a movement key for " + secs(s.seconds);
    case K::Look:
      return "look (" + std::to_string(int(s.dx)) + ", " + std::to_string(int(s.dy)) + ") px";
    case K::Key:
      return "key press";
    case K::Sleep:
      return "sleep " + secs(s.seconds);
    case K::WaitConverged:
      return "wait until converged";
    case K::WaitFile:
      return "wait for " + s.path.string();
    case K::Screenshot:
      return "screenshot " + s.path.string();
    case K::Set:
      return "change settings";
    case K::PrintOverlay:
      return "print the overlay";
    case K::Mark:
      return "mark " + s.text;
  }
  return "step";
}

}  // namespace svo::viewer
