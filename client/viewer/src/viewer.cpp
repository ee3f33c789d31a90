#include "svo/viewer/viewer.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <future>

#include <spdlog/spdlog.h>

#include "overlay_ui.hpp"
#include "script_player.hpp"
#include "svo/client/streaming.hpp"
#include "svo/gpu/gpu_caster.hpp"
#include "svo/gpu/gpu_pool.hpp"
#include "svo/viewer/fly_camera.hpp"
#include "window.hpp"

namespace svo::viewer {
namespace {

using Clock = std::chrono::steady_clock;

// A camera still for less than this still counts as moving: the gap between a key's repeats or a pause of
// the mouse should not bring a full-resolution frame in between.
constexpr double kMovingHoldSeconds = 0.15;
// Frame time a moving camera aims for (30 frames/s, the usual floor of an interactive viewer); the
// resolution scales to meet it.
constexpr double kMovingFrameSeconds = 1.0 / 30.0;
// The lowest moving resolution against the window's (an eighth of each side); below it the image is blocks.
constexpr double kMinMovingScale = 0.125;
// How far one frame may change the resolution scale (a factor per frame), so one slow frame does not halve
// it.
constexpr double kMaxScaleStep = 1.5;
// While nothing needs a frame: how long to wait for input, between the pager's updates (20 a second commit
// loads while they come).
constexpr double kIdleWaitSeconds = 0.05;
// While a still view streams, between frames: the pager's updates come this often.
constexpr double kStreamingWaitSeconds = 0.01;

double secondsBetween(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// svo-view-DATE-TIME-N.png: N counts the screenshots of the run, so two in one second do not collide.
std::string screenshotName(int n) {
  const std::time_t now = std::time(nullptr);
  char name[64];
  std::strftime(name, sizeof name, "svo-view-%Y%m%d-%H%M%S", std::localtime(&now));
  return std::string(name) + "-" + std::to_string(n) + ".png";
}

}  // namespace

class Viewer {
 public:
  explicit Viewer(const ViewerOptions& options);
  ViewerSummary run();

 private:
  struct FrameRecord {
    double ms, scale;
    bool moving;
  };

  void open();
  bool opened();
  void press(Action action);
  bool moveCamera(double seconds);
  bool wantsFrame(Clock::time_point now, bool moving) const;
  void renderFrame(Clock::time_point now, bool moving);
  void frameShown(Clock::time_point start, bool moving);
  void updateOnly(Clock::time_point now);
  void saveScreenshotIfDue();
  void fillStats();
  void changeSettings(const ViewSettings& settings);
  void draw();
  ViewerSummary summary() const;

  ViewerOptions options_;
  Window window_;
  ScriptPlayer script_;
  ViewSettings settings_;
  OverlayWidgets widgets_;
  OverlayStats stats_;
  struct Opened {
    std::shared_ptr<const SliceSource> source;
    std::unique_ptr<Pager> pager;
  };
  std::future<Opened> opening_;
  std::shared_ptr<const SliceSource> source_;  // kept to reopen the pool at another budget
  std::optional<std::size_t> budgetBefore_;    // while reopening: the budget of the pool that worked
  std::unique_ptr<Pager> pager_;
  std::unique_ptr<gpu::GpuCaster> caster_;  // with --device gpu, in the window's context
  std::unique_ptr<gpu::GpuPool> gpuPool_;   // the pager's pool mirrored in the caster's buffer
  std::optional<FlyCamera> fly_;

  // The frame on screen and what it showed.
  Frame frame_;
  std::vector<std::uint8_t> rgba_;
  bool frameCurrent_ = false;  // rendered at full resolution from the current camera and settings
  bool poolChanged_ = true;    // loads or evictions since the frame was rendered
  PagerStats lastUpdate_;
  Clock::time_point lastRender_{}, lastRenderEnd_{}, lastMove_{};
  double lastRenderSeconds_ = 0.0;
  double movingScale_ = 0.5;  // the first moving frames at half the window's size; frame times steer it after
  std::optional<std::filesystem::path> screenshotDue_;
  int screenshots_ = 0;
  std::vector<Clock::time_point> recentFrames_;

  std::vector<FrameRecord> records_;
  double movingSeconds_ = 0.0;
  ViewerSummary summary_;
};

Viewer::Viewer(const ViewerOptions& options)
    : options_(options),
      window_(options.width, options.height, "svo view - " + options.sourceName, options.gpu,
              Window::Input{[this](Action a) { press(a); },
                            [this](double dx, double dy) {
                              if (fly_) fly_->look(dx, dy), lastMove_ = Clock::now();
                            },
                            [this](double steps) {
                              if (fly_) fly_->scaleSpeed(steps);
                            }}),
      script_(options.script),
      settings_(options.settings) {
  summary_.windowSeconds = secondsBetween(options.launched, Clock::now());
  stats_.source = options.sourceName;
  stats_.device = "the CPU";
  settings_.budgetBytes = options.pager.budgetBytes;
  if (options.gpu) {
    caster_ = std::make_unique<gpu::GpuCaster>();  // throws GpuUnavailable where 4.5 lacks compute
    stats_.device = window_.renderer();
    if (options.defaultBudget)
      settings_.budgetBytes = std::min(settings_.budgetBytes, caster_->maxBufferBytes());
  }
  open();
}

// Opens the store and the pool on a background thread: the window keeps answering meanwhile.
void Viewer::open() {
  PagerOptions pagerOptions = options_.pager;
  pagerOptions.budgetBytes = settings_.budgetBytes;
  opening_ = std::async(std::launch::async, [this, pagerOptions, source = source_]() {
    Opened o{source ? source : options_.openSource(), nullptr};
    o.pager = std::make_unique<Pager>(o.source, pagerOptions);
    return o;
  });
  stats_.opening = true;
}

bool Viewer::opened() {
  if (pager_) return true;
  if (opening_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return false;
  Opened o;
  std::unique_ptr<gpu::GpuPool> gpuPool;
  try {
    o = opening_.get();
    if (caster_) gpuPool = std::make_unique<gpu::GpuPool>(*caster_, *o.pager);  // throws above one buffer
  } catch (const std::exception& e) {
    if (!budgetBefore_) throw;  // the store cannot be opened at all
    // A budget the overlay chose that holds no trunk (or, on the GPU, exceeds one buffer): say why and go
    // back to the last one that worked.
    spdlog::error("a {:.1f} MiB pool: {}; back to {:.1f} MiB", double(settings_.budgetBytes) / (1 << 20),
                  e.what(), double(*budgetBefore_) / (1 << 20));
    settings_.budgetBytes = *std::exchange(budgetBefore_, std::nullopt);
    open();
    return false;
  }
  budgetBefore_.reset();
  source_ = std::move(o.source);
  pager_ = std::move(o.pager);
  gpuPool_ = std::move(gpuPool);
  stats_.storeLevels = pager_->index().header().parameters.levels;
  stats_.opening = false;
  if (!fly_) {
    const glm::ivec2 size = window_.framebufferSize();
    const WorldBox contents =
        occupiedBox(pager_->trunk(), pager_->transform(), pager_->index().trunkLevels());
    fly_.emplace(pager_->transform(), contents,
                 options_.camera
                     ? *options_.camera
                     : Camera::framingBox(contents.lo, contents.hi, options_.viewDirection, size.x, size.y));
  }
  frameCurrent_ = false;
  poolChanged_ = true;
  return true;
}

void Viewer::press(Action action) {
  switch (action) {
    case Action::FrameScene:
      if (fly_) fly_->frameScene(), lastMove_ = Clock::now();
      break;
    case Action::Screenshot:
      screenshotDue_ = options_.screenshotFolder / screenshotName(++screenshots_);
      break;
    case Action::ToggleOverlay:
      settings_.overlay = !settings_.overlay;
      break;
    case Action::ToggleContours:
      settings_.contours = !settings_.contours, frameCurrent_ = false;
      break;
    case Action::ToggleFilter:
      settings_.filter = !settings_.filter, frameCurrent_ = false;
      break;
    case Action::Shaded:
      settings_.falseColor = FalseColor::Shaded, frameCurrent_ = false;
      break;
    case Action::FalseColorLevel:
      settings_.falseColor = FalseColor::OctreeLevel, frameCurrent_ = false;
      break;
    case Action::FalseColorIterations:
      settings_.falseColor = FalseColor::Iterations, frameCurrent_ = false;
      break;
    case Action::FalseColorDetail:
      settings_.falseColor = FalseColor::Detail, frameCurrent_ = false;
      break;
    case Action::Quit:
      window_.close();
      break;
    default:
      break;  // held keys move the camera in moveCamera
  }
}

bool Viewer::moveCamera(double seconds) {
  MoveKeys keys = window_.heldKeys();
  const MoveKeys scripted = script_.heldKeys();
  keys.forward |= scripted.forward, keys.back |= scripted.back, keys.left |= scripted.left;
  keys.right |= scripted.right, keys.down |= scripted.down, keys.up |= scripted.up;
  return fly_->move(keys, seconds);
}

bool Viewer::wantsFrame(Clock::time_point now, bool moving) const {
  if (moving || !frameCurrent_ || glm::ivec2(frame_.width, frame_.height) != window_.framebufferSize())
    return true;
  if (!poolChanged_) return false;
  // A still view that streams: at most kStillViewFrameSeconds apart, and as long after a frame as it took,
  // so the workers get the cores between frames.
  return secondsBetween(lastRender_, now) >= kStillViewFrameSeconds &&
         secondsBetween(lastRenderEnd_, now) >= lastRenderSeconds_ * kStillViewWaitPerRenderSecond;
}

void Viewer::renderFrame(Clock::time_point now, bool moving) {
  const glm::ivec2 window = window_.framebufferSize();
  const double scale = moving ? movingScale_ : 1.0;
  const int width = std::max(1, int(std::lround(window.x * scale)));
  const int height = std::max(1, int(std::lround(window.y * scale)));
  const Camera camera = fly_->camera(width, height);
  RenderOptions options = options_.render;
  options.lodPixels = settings_.lodPixels;
  options.cast.contours = settings_.contours && pager_->index().header().parameters.contours;
  options.filter = settings_.filter;
  options.prefetchAttributes = attributePrefetchPays(pager_->residentBytes());
  options.diagnostics =
      settings_.falseColor == FalseColor::Iterations || settings_.falseColor == FalseColor::Detail;

  const std::uint64_t uploadedBefore = gpuPool_ ? gpuPool_->uploadedBytes() : 0;
  const PoolRenderer renderer = gpuPool_
                                    ? PoolRenderer([this](Pager&, const Camera& c, const RenderOptions& o) {
                                        return gpuPool_->render(c, o);
                                      })
                                    : PoolRenderer();
  StreamedFrame streamed = streamFrame(*pager_, camera, options, renderer);
  if (gpuPool_) {
    stats_.uploadedLastFrame = gpuPool_->uploadedBytes() - uploadedBefore;
    stats_.uploadedBytes = summary_.uploadedBytes + gpuPool_->uploadedBytes();
  }
  Frame& frame = streamed.frame;
  stats_.deepestLevel = deepestLevel(frame, camera, pager_->transform().size);
  switch (settings_.falseColor) {
    case FalseColor::Shaded:
      break;
    case FalseColor::OctreeLevel:
      paintLevels(frame, camera, pager_->transform().size);
      break;
    case FalseColor::Iterations:
      paintIterations(frame);
      break;
    case FalseColor::Detail:
      paintDetail(frame, pager_->detailMap(frame, camera, options.lodPixels));
      break;
  }
  encodeSrgb8(frame, rgba_);
  window_.upload(rgba_, width, height);
  const Clock::time_point end = Clock::now();
  lastUpdate_ = streamed.stats;
  poolChanged_ = false;
  frameCurrent_ = !moving;
  frame_ = std::move(frame);
  lastRender_ = now, lastRenderEnd_ = end;
  lastRenderSeconds_ = secondsBetween(now, end);
  stats_.renderMs = frame_.seconds * 1e3;
  stats_.updateMs = streamed.updateSeconds * 1e3;
  stats_.width = width, stats_.height = height, stats_.scale = scale;
}

// After a rendered frame is on screen: its time from the pager's update to the buffer swap steers the moving
// resolution and goes into the run's numbers.
void Viewer::frameShown(Clock::time_point start, bool moving) {
  const Clock::time_point end = Clock::now();
  const double seconds = secondsBetween(start, end);
  if (moving) {
    const double step = std::sqrt(kMovingFrameSeconds / std::max(seconds, 1e-4));
    movingScale_ =
        std::clamp(movingScale_ * std::clamp(step, 1.0 / kMaxScaleStep, kMaxScaleStep), kMinMovingScale, 1.0);
  }
  stats_.frameMs = seconds * 1e3;
  records_.push_back({seconds * 1e3, stats_.scale, moving});
  recentFrames_.push_back(end);
  if (summary_.firstFrameSeconds < 0.0) summary_.firstFrameSeconds = secondsBetween(options_.launched, end);
}

// Between frames: commit what the workers finished and ask for what the view wants next.
void Viewer::updateOnly(Clock::time_point now) {
  const glm::ivec2 window = window_.framebufferSize();
  const Camera camera = fly_->camera(window.x, window.y);
  lastUpdate_ = pager_->update(viewOf(pager_->transform(), camera, settings_.lodPixels));
  if (lastUpdate_.loaded > 0 || lastUpdate_.evicted > 0) poolChanged_ = true;
}

void Viewer::saveScreenshotIfDue() {
  if (!screenshotDue_ || !frameCurrent_) return;
  const std::filesystem::path path = *std::exchange(screenshotDue_, std::nullopt);
  try {
    writeFrame(path, frame_, false);
    spdlog::info("saved {} ({} x {})", path.string(), frame_.width, frame_.height);
  } catch (const std::exception& e) {
    if (script_.running()) throw;
    spdlog::error("{}", e.what());  // a person can pick another folder; the viewer goes on
  }
}

void Viewer::fillStats() {
  stats_.residentBytes = pager_->residentBytes();
  stats_.budgetBytes = pager_->budgetBytes();
  stats_.residentSlices = pager_->residentSlices().size();
  stats_.inFlight = lastUpdate_.inFlight;
  stats_.wanted = lastUpdate_.wanted;
  stats_.bytesRead = pager_->bytesRead();
  stats_.converged = pager_->converged();
  const Clock::time_point now = Clock::now();
  std::erase_if(recentFrames_, [&](Clock::time_point t) { return secondsBetween(t, now) > 1.0; });
  stats_.framesPerSecond = double(recentFrames_.size());
  const Camera& camera = fly_->camera(1, 1);
  stats_.eye = camera.eye;
  stats_.speed = fly_->speed();
}

// From the overlay or a script: the frame shows the new settings next; a new budget is a new pool.
void Viewer::changeSettings(const ViewSettings& settings) {
  const bool reopen = settings.budgetBytes != settings_.budgetBytes;
  settings_ = settings;
  frameCurrent_ = false;
  if (reopen && pager_) {
    // A pool's arena is its budget: a new budget is a new pool, streamed afresh over the same source.
    budgetBefore_ = pager_->budgetBytes();
    if (gpuPool_) summary_.uploadedBytes += gpuPool_->uploadedBytes();
    summary_.bytesRead += pager_->bytesRead();
    gpuPool_.reset();
    pager_.reset();
    open();
  }
}

void Viewer::draw() {
  window_.draw();
  if (settings_.overlay) {
    window_.beginOverlay();
    ViewSettings edited = settings_;
    const bool changed = drawOverlay(stats_, edited, widgets_);
    window_.endOverlay();
    if (changed) changeSettings(edited);
  }
  window_.present();
}

ViewerSummary Viewer::run() {
  Clock::time_point previous = Clock::now();
  bool busy = true;
  while (!window_.closing()) {
    window_.handleEvents(busy ? 0.0
                              : (pager_ && !pager_->converged() ? kStreamingWaitSeconds : kIdleWaitSeconds));
    const Clock::time_point now = Clock::now();
    const double elapsed = secondsBetween(previous, now);
    previous = now;
    if (!opened()) {
      draw();
      busy = false;
      continue;
    }
    const ScriptPlayer::Outcome scripted =
        script_.advance(now, {*fly_, stats_, settings_, frameCurrent_, pager_->converged() && !poolChanged_,
                              screenshotDue_.has_value(), lastRenderEnd_});
    for (Action a : scripted.pressed) press(a);
    if (scripted.screenshot) screenshotDue_ = scripted.screenshot;
    if (scripted.turned) lastMove_ = now;
    if (scripted.jumped) frameCurrent_ = false;
    if (scripted.settings) changeSettings(*scripted.settings);
    if (!pager_) continue;  // a new budget: the new pool is opening
    if (script_.failed() || (!options_.script.empty() && script_.finished())) window_.close();

    if (moveCamera(elapsed)) lastMove_ = now;
    const bool moving = secondsBetween(lastMove_, now) < kMovingHoldSeconds;
    if (moving) movingSeconds_ += elapsed;
    if (moving) frameCurrent_ = false;
    const bool rendering = wantsFrame(now, moving);
    if (rendering) {
      renderFrame(now, moving);
      busy = moving || !frameCurrent_;
    } else {
      updateOnly(now);
      busy = false;
    }
    saveScreenshotIfDue();
    fillStats();
    draw();
    if (rendering) frameShown(now, moving);
  }
  if (script_.failed()) throw std::runtime_error(*script_.failed());
  return summary();
}

ViewerSummary Viewer::summary() const {
  ViewerSummary s = summary_;
  std::vector<double> moving, still, scales;
  for (const FrameRecord& r : records_) {
    (r.moving ? moving : still).push_back(r.ms);
    if (r.moving) scales.push_back(r.scale);
  }
  s.movingFrames = moving.size(), s.stillFrames = still.size();
  s.movingFrameMsMedian = median(moving), s.stillFrameMsMedian = median(still);
  s.movingScaleMedian = scales.empty() ? 1.0 : median(scales);
  s.movingFramesPerSecond = movingSeconds_ > 0.0 ? double(moving.size()) / movingSeconds_ : 0.0;
  s.sharpAfterStop = script_.sharpAfterStop();
  s.device = stats_.device;
  if (gpuPool_) s.uploadedBytes += gpuPool_->uploadedBytes();
  if (pager_) s.bytesRead += pager_->bytesRead();
  return s;
}

ViewerSummary runViewer(const ViewerOptions& options) {
  Viewer viewer(options);
  return viewer.run();
}

}  // namespace svo::viewer
