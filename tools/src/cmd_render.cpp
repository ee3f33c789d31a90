// `svo render IN.svo -o frame.png`: ray casts the octree on all cores and writes PNG or EXR. IN.svo is a file
// or an http(s):// URL of one (range requests). A store that fits one block and the machine's memory is read
// whole; any other streams through a block pool (--budget, or
// a share of the machine's memory): one view refines until it has converged, or with --path a camera path
// renders frame by frame while the scene streams in, with a CSV row per frame and a plot of the error
// against the converged frames over time.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "commands.hpp"
#include "machine.hpp"
#include "measure.hpp"
#include "number_checks.hpp"
#include "pager_flags.hpp"
#include "plot.hpp"
#include "remote.hpp"
#include "report.hpp"
#include "svo/client/locator.hpp"
#include "svo/client/pager.hpp"
#include "svo/client/render.hpp"
#include "svo/client/streaming.hpp"
#include "svo/client/whole_scene.hpp"
#include "svo/gpu/headless_gpu.hpp"
#include "view_flags.hpp"

namespace svo::tools {

namespace {
struct RenderArgs {
  std::string in, out, token;
  bool rangeOnly = false;
  CameraFlags camera;
  RenderOptions options;
  bool noContours = false, aux = false;
  std::size_t budget = 0, referenceBudget = std::size_t(1) << 30;
  std::string pathFile;
  PagerOptions pager;  // threads; the budget is chosen per run
  double timeout = 300.0;
  std::string device = "cpu";
  std::shared_ptr<gpu::HeadlessGpu> gpu;  // with --device gpu, made before the store is read
};

// The frames of `pager` on the device --device names (nullptr: svo::render on the CPU).
PoolRenderer poolRendererOf(const RenderArgs& args, Pager& pager) {
  return args.gpu ? args.gpu->poolRenderer(pager) : nullptr;
}

Camera cameraOf(const RenderArgs& args, const BlockView& root, const SceneTransform& scene,
                const StoreIndex& index) {
  return cameraOf(args.camera, root, scene, index);
}

// How --pool holds the stream, after its size in the messages.
const char* poolName(const RenderArgs& args) {
  return args.pager.layout == PoolLayout::Levels ? " pool of level arrays" : " block pool";
}

PagerOptions pagerOptions(std::size_t budget, const RenderArgs& args) {
  PagerOptions options = args.pager;
  options.budgetBytes = budget;
  options.fetchThreads = resolvedFetchThreads(options.fetchThreads, args.in);
  return options;
}

// One view streamed from `source` until it has converged; `how` says why it streams and with which budget.
void renderConverged(const RenderArgs& args, std::shared_ptr<const SliceSource> source, RenderOptions options,
                     std::size_t budget, const std::string& how) {
  const std::filesystem::path out = args.out;
  const auto start = std::chrono::steady_clock::now();
  Pager pager(std::move(source), pagerOptions(budget, args));
  const Camera camera = cameraOf(args, TrunkBlock(pager).view(), pager.transform(), pager.index());
  options.cast.contours = options.cast.contours && pager.index().header().parameters.contours;
  const PoolRenderer renderer = poolRendererOf(args, pager);
  const Frame first = renderer ? renderer(pager, camera, options) : render(pager, camera, options);
  const double firstSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  StreamedFrame last;
  const Convergence c = convergeView(pager, camera, options, args.timeout, &last, nullptr, renderer);
  if (!c.converged())
    throw std::runtime_error(args.in + ": the view did not converge within " + std::to_string(args.timeout) +
                             " s (budget " + formatBytes(pager.budgetBytes()) + ")");
  writeFrame(out, last.frame, args.aux);
  std::printf("first coarse image %.1f ms after opening (%d x %d, %.1f ms to render)\n", firstSeconds * 1e3,
              first.width, first.height, first.seconds * 1e3);
  std::printf("view converged in %.3f s after the first image (%s read; final image after %.3f s)\n",
              c.viewSeconds, formatBytes(c.viewBytesRead).c_str(), c.imageFinalSeconds);
  std::printf("with the slices around it in %.3f s: %zu slices resident (%s of %s), %s read\n", c.seconds,
              pager.residentSlices().size(), formatBytes(pager.residentBytes()).c_str(),
              formatBytes(pager.budgetBytes()).c_str(), formatBytes(pager.bytesRead()).c_str());
  for (const std::string& e : pager.takeErrors()) spdlog::warn("{}", e);
  std::printf("wrote %s, %s\n", args.out.c_str(), how.c_str());
}

// A camera path while streaming from `source`: frames, frames.csv, error.png.
void renderPath(const RenderArgs& args, const std::shared_ptr<const SliceSource>& source,
                RenderOptions options, std::size_t budget, const std::string& how) {
  const std::vector<Camera> cameras = loadCameraPath(args.pathFile);
  const std::filesystem::path folder = args.out;
  std::error_code ec;
  std::filesystem::create_directories(folder, ec);
  if (ec || !std::filesystem::is_directory(folder))
    throw UsageError(args.out + ": cannot create the output folder");
  checkWritableOutput(folder / "frames.csv");
  Pager pager(source, pagerOptions(budget, args));
  options.cast.contours = options.cast.contours && pager.index().header().parameters.contours;
  const PoolRenderer renderer = poolRendererOf(args, pager);

  std::vector<StreamedFrame> frames;
  std::vector<double> elapsed;
  const auto start = std::chrono::steady_clock::now();
  spdlog::info("streaming {} frames through a {} pool ...", cameras.size(), formatBytes(pager.budgetBytes()));
  for (std::size_t i = 0; i < cameras.size(); ++i) {
    frames.push_back(streamFrame(pager, cameras[i], options, renderer));
    if (frames.back().stats.residentBytes > pager.budgetBytes())
      throw std::logic_error("resident bytes exceed the budget at frame " + std::to_string(i));
    elapsed.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    char name[32];
    std::snprintf(name, sizeof name, "frame_%04zu.png", i);
    writeFrame(folder / name, frames.back().frame, false);
    for (const std::string& e : pager.takeErrors()) spdlog::warn("{}", e);
  }
  // The converged frame of each camera, from a pool large enough to hold everything the view wants (on the
  // CPU: such a pool is larger than one GPU buffer may be, and both devices give the same frame).
  spdlog::info("converging the reference frames ({} pool) ...", formatBytes(args.referenceBudget));
  Pager reference(source, pagerOptions(args.referenceBudget, args));
  std::ofstream csv(folder / "frames.csv");
  csv << "frame,elapsed_s,frame_ms,update_ms,resident_bytes,loaded,evicted,requested,cancelled,denied,failed,"
         "wanted,in_flight,rmse,silhouette_pct,reference_converged\n";
  plot::Series rmse{"RMSE vs converged", {}}, silhouette{"silhouette mismatch %", {}};
  std::vector<double> frameMs;
  std::size_t maxResident = 0;
  for (std::size_t i = 0; i < cameras.size(); ++i) {
    maxResident = std::max(maxResident, frames[i].stats.residentBytes);
    StreamedFrame converged;
    const bool ok = convergeView(reference, cameras[i], options, args.timeout, &converged).converged();
    const FrameError error = frameError(frames[i].frame, converged.frame);
    const StreamedFrame& f = frames[i];
    const PagerStats& s = f.stats;
    frameMs.push_back(f.seconds() * 1e3);
    csv << i << ',' << elapsed[i] << ',' << f.seconds() * 1e3 << ',' << f.updateSeconds * 1e3 << ','
        << s.residentBytes << ',' << s.loaded << ',' << s.evicted << ',' << s.requested << ',' << s.cancelled
        << ',' << s.denied << ',' << s.failed << ',' << s.wanted << ',' << s.inFlight << ',' << error.rmse
        << ',' << error.silhouettePercent << ',' << int(ok) << '\n';
    rmse.points.push_back({elapsed[i], error.rmse});
    silhouette.points.push_back({elapsed[i], error.silhouettePercent});
  }
  csv.close();
  if (!csv) throw std::runtime_error((folder / "frames.csv").string() + ": cannot write");
  plot::writeLogLogPlot(folder / "error.png",
                        {{"error against the converged frame while streaming", {rmse}},
                         {"silhouette mismatch while streaming", {silhouette}}},
                        "elapsed seconds", "error", 1400, 600);
  const Summary ms = summarize(frameMs);
  const double p99 = percentile(frameMs, 0.99);
  std::printf("%zu frames in %.2f s: frame time median %.1f ms, p99 %.1f ms; resident at most %s of %s\n",
              cameras.size(), elapsed.back(), ms.median, p99, formatBytes(maxResident).c_str(),
              formatBytes(pager.budgetBytes()).c_str());
  std::printf("wrote %s: frame_NNNN.png, frames.csv, error.png, %s\n", folder.c_str(), how.c_str());
}

void renderStreaming(const RenderArgs& args, std::shared_ptr<const SliceSource> source, std::size_t budget,
                     const std::string& how) {
  keepFreedMemoryForReuse();
  RenderOptions options = args.options;
  options.cast.contours = !args.noContours;
  options.prefetchAttributes = attributePrefetchPays(budget);
  if (args.pathFile.empty()) {
    renderConverged(args, std::move(source), options, budget, how);
  } else {
    renderPath(args, source, options, budget, how);
  }
}

// The whole octree as one block, one frame.
void renderWhole(const RenderArgs& args, const Octree& octree, const StoreIndex& index) {
  const Camera camera = cameraOf(args, octree.block.view(), octree.transform, index);
  RenderOptions options = args.options;
  options.cast.contours = !args.noContours && octree.parameters.contours;
  options.prefetchAttributes = attributePrefetchPays(octree.block.bytes().size());
  const Frame frame =
      args.gpu ? gpu::renderBlock(args.gpu->caster(), octree.block.view(), octree.transform, camera, options)
               : render(octree, camera, options);
  writeFrame(args.out, frame, args.aux);
  std::printf(
      "wrote %s (%dx%d), read whole as one block of %s: %.3f s, %.2f Mrays/s, %.1f iterations/ray%s%s\n",
      args.out.c_str(), frame.width, frame.height, formatBytes(octree.block.bytes().size()).c_str(),
      frame.seconds, frame.mraysPerSecond(), frame.meanIterations,
      args.gpu ? (" on " + args.gpu->renderer()).c_str() : "",
      options.filter ? fmt::format(", of which the filter {:.1f} ms", frame.filterSeconds * 1e3).c_str()
                     : "");
}

void checkImageOutput(const RenderArgs& args) {
  const std::filesystem::path out = args.out;
  const std::string ext = out.extension().string();
  if (ext != ".png" && ext != ".exr") throw UsageError(args.out + ": output must end in .png or .exr");
  if (args.aux && ext != ".exr") throw UsageError("--aux needs an .exr output (PNG has no float channels)");
  checkWritableOutput(out);
}

// Without --budget: the store whole when it fits one block and the machine's memory, else streamed through
// a pool of a share of the machine's memory (never more than the whole store takes).
void renderDefault(const RenderArgs& args) {
  const std::uint64_t share = defaultMemoryShare(machineMemory());
  const RemoteOptions remote = remoteOptions(args.token, args.rangeOnly);
  const std::shared_ptr<const ByteSource> bytes = openByteSource(args.in, remote);
  std::size_t storeBudget = 0;
  std::string why;
  {
    const StoreReader store(bytes);
    const StoreFootprint footprint = footprintOf(store.slices());
    storeBudget = wholeStoreBudget(store.slices());
    if (!footprint.mayFitOneBlock()) {
      why = "the octree is too large for one block";
    } else if (footprint.wholeLoadBytes() > share) {
      why = "reading it whole would take about " + formatBytes(footprint.wholeLoadBytes()) + ", more than " +
            formatBytes(share) + " (the default share of memory)";
    }
    if (why.empty() && args.pathFile.empty()) {
      try {
        return renderWhole(args, readOctree(store, args.pager.attributes), store.index());
      } catch (const BlockTooLarge&) {
        why = "the octree is too large for one block";
      }
    }
  }
  if (why.empty()) why = "a camera path streams";
  std::size_t budget = std::size_t(std::min<std::uint64_t>({share, storeBudget, kMaxBudgetBytes}));
  if (args.gpu) budget = std::min(budget, args.gpu->caster().maxBufferBytes());  // the pool is one buffer
  renderStreaming(args, sliceSourceOver(bytes, args.in, remote), budget,
                  "streamed through a " + formatBytes(budget) + poolName(args) + " (default: " + why +
                      "; --budget sets the pool)");
}

}  // namespace

void addRenderCommand(CLI::App& app) {
  using Args = RenderArgs;
  auto args = std::make_shared<Args>();
  auto* cmd = app.add_subcommand("render", "ray cast a .svo octree to PNG or EXR");
  cmd->add_option("input", args->in, "input .svo store: a file, or its http(s):// URL on a static server")
      ->required();
  addTokenOption(cmd, args->token);
  addRangeOnlyFlag(cmd, args->rangeOnly);
  cmd->add_option("-o,--output", args->out, "output image (.png or .exr)")->required();
  addCameraFlags(*cmd, args->camera);
  addRenderFlags(*cmd, args->options, args->noContours);
  cmd->add_flag("--aux", args->aux, "EXR only: add depth (Z) and voxel-size-in-pixels channels");
  cmd->add_option(
         "--budget", args->budget,
         "stream the store through a block pool of this many bytes (64M, 1G): frames render from what "
         "is resident (default: the store is read whole when it fits one block and half the available "
         "memory, else streamed through a pool of that half)")
      ->transform(CLI::AsSizeValue(false));
  cmd->add_option("--path", args->pathFile,
                  "stream along a camera path (JSON array of cameras); -o is then a folder for the frames, "
                  "frames.csv and error.png");
  cmd->add_option("--reference-budget", args->referenceBudget,
                  "with --path: pool for the converged reference frames")
      ->transform(CLI::AsSizeValue(false))
      ->capture_default_str();
  addPagerThreadFlags(*cmd, args->pager);
  addAttributeLayoutFlag(*cmd, args->pager.attributes);
  addPoolLayoutFlag(*cmd, args->pager.layout);
  cmd->add_option("--timeout", args->timeout, "when streaming: seconds a view may take to converge")
      ->check(finitePositive())
      ->capture_default_str();
  cmd->add_option("--device", args->device,
                  "cpu: the ray caster on all cores; gpu: the OpenGL 4.5 compute caster (headless EGL; the "
                  "pool in one storage buffer, so --budget at most its size)")
      ->check(CLI::IsMember({"cpu", "gpu"}))
      ->capture_default_str();
  cmd->callback([args, cmd] {
    if (args->pathFile.empty()) checkImageOutput(*args);
    applyDeviceBeamDefault(*cmd, args->device, args->options);
    if (args->pager.layout == PoolLayout::Levels && args->device == "gpu")
      throw UsageError("--pool levels: a pool of level arrays renders on the CPU only (--device cpu)");
    if (args->device == "gpu") {
      try {
        args->gpu = std::make_shared<gpu::HeadlessGpu>();
      } catch (const gpu::GpuUnavailable& e) {
        throw std::runtime_error(std::string("--device gpu: ") + e.what());
      }
    }
    if (args->budget == 0) return renderDefault(*args);
    renderStreaming(*args, openSliceSource(args->in, remoteOptions(args->token, args->rangeOnly)),
                    args->budget, "streamed through a " + formatBytes(args->budget) + poolName(*args));
  });
}

}  // namespace svo::tools
