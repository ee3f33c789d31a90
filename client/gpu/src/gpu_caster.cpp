#include "svo/gpu/gpu_caster.hpp"

#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <stdexcept>
#include <string>

#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <tbb/task_arena.h>
#include <glm/geometric.hpp>

#include "raycast_shader.hpp"

namespace svo::gpu {
namespace {

// The shader's work group: 8 x 8 pixels, the paper's beam tile (sec. 6.2).
constexpr int kGroupSide = 8;
// Pixels a read-back task unpacks at least: 64 KiB of the mapped frame, far more than a task costs to schedule
// (set so, not swept; 1080p makes at most 1,013 tasks).
constexpr std::size_t kUnpackGrain = 2048;

struct PixelOut {  // std430, as the shader's PixelOut
  float color[4];
  float depth, voxelPixels;
  std::uint32_t hitSlot, scaleIterations;
};
static_assert(sizeof(PixelOut) == 32);

struct Params {  // std140, as the shader's Params
  double forward[4], right[4], up[4];
  double tanHalf, aspect, sceneSize, pixelAngle;
  float origin[4], light[4], background[4];
  std::uint32_t rootSlot, width, height, flags;
  float footprintSlope;
  std::int32_t maxIterations;
  std::uint32_t padding[2];
};

void copy3(double* to, glm::dvec3 v) {
  to[0] = v.x, to[1] = v.y, to[2] = v.z, to[3] = 0.0;
}
void copy3(float* to, glm::vec3 v) {
  to[0] = v.x, to[1] = v.y, to[2] = v.z, to[3] = 0.0f;
}

unsigned compile(const char* source) {
  const GLuint shader = glCreateShader(GL_COMPUTE_SHADER);
  glShaderSource(shader, 1, &source, nullptr);
  glCompileShader(shader);
  GLint ok = 0;
  glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[4096] = {};
    glGetShaderInfoLog(shader, sizeof log, nullptr, log);
    glDeleteShader(shader);
    throw GpuUnavailable(std::string("the ray casting shader does not compile here: ") + log);
  }
  const GLuint program = glCreateProgram();
  glAttachShader(program, shader);
  glLinkProgram(program);
  glDeleteShader(shader);
  glGetProgramiv(program, GL_LINK_STATUS, &ok);
  if (!ok) {
    char log[4096] = {};
    glGetProgramInfoLog(program, sizeof log, nullptr, log);
    glDeleteProgram(program);
    throw GpuUnavailable(std::string("the ray casting shader does not link here: ") + log);
  }
  return program;
}

}  // namespace

GpuCaster::GpuCaster() {
  GLint major = 0, minor = 0;
  glGetIntegerv(GL_MAJOR_VERSION, &major);
  glGetIntegerv(GL_MINOR_VERSION, &minor);
  if (major * 10 + minor < 45)
    throw GpuUnavailable("OpenGL " + std::to_string(major) + "." + std::to_string(minor) +
                         " here; the GPU caster needs 4.5 (compute shaders, storage buffers)");
  program_ = compile(kRaycastShader);
  // The beam pass is the same source with SVO_BEAM_PASS defined right after its #version line.
  std::string beamSource = kRaycastShader;
  const std::string version = "#version 450\n";
  beamSource.insert(beamSource.find(version) + version.size(), "#define SVO_BEAM_PASS\n");
  beamProgram_ = compile(beamSource.c_str());
  GLuint buffers[4];
  glCreateBuffers(4, buffers);
  pool_ = buffers[0], pixels_ = buffers[1], params_ = buffers[2], tileStarts_ = buffers[3];
  glNamedBufferStorage(params_, sizeof(Params), nullptr, GL_DYNAMIC_STORAGE_BIT);
  glCreateQueries(GL_TIMESTAMP, 2, timers_);
}

GpuCaster::~GpuCaster() {
  const GLuint buffers[4] = {pool_, pixels_, params_, tileStarts_};
  glDeleteBuffers(4, buffers);
  glDeleteProgram(program_);
  glDeleteProgram(beamProgram_);
  glDeleteQueries(2, timers_);
}

std::size_t GpuCaster::maxBufferBytes() const {
  GLint64 bytes = 0;
  glGetInteger64v(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &bytes);
  return std::size_t(bytes);
}

void GpuCaster::reserve(std::size_t bytes) {
  if (bytes > maxBufferBytes())
    throw std::runtime_error(
        "the GPU caster's buffer takes at most " + std::to_string(maxBufferBytes() >> 20) +
        " MiB here (GL_MAX_SHADER_STORAGE_BLOCK_SIZE); asked for " + std::to_string(bytes >> 20) + " MiB");
  if (bytes == capacity_) return;
  glDeleteBuffers(1, &pool_);
  glCreateBuffers(1, &pool_);
  glNamedBufferStorage(pool_, GLsizeiptr(std::max<std::size_t>(bytes, 4)), nullptr, GL_DYNAMIC_STORAGE_BIT);
  capacity_ = bytes;
}

void GpuCaster::upload(std::size_t offset, std::span<const std::byte> bytes) {
  if (offset + bytes.size() > capacity_) throw std::logic_error("GPU caster: upload past the buffer");
  glNamedBufferSubData(pool_, GLintptr(offset), GLsizeiptr(bytes.size()), bytes.data());
  uploadedBytes_ += bytes.size();
}

Frame GpuCaster::render(std::uint32_t rootSlot, bool hasColors, bool hasNormals, const SceneTransform& scene,
                        const Camera& camera, const RenderOptions& options, GpuHits* hits) {
  camera.validate();
  const auto start = std::chrono::steady_clock::now();
  const std::size_t pixels = std::size_t(camera.width) * std::size_t(camera.height);
  if (pixels * sizeof(PixelOut) != pixelBytes_) {
    glDeleteBuffers(1, &pixels_);
    glCreateBuffers(1, &pixels_);
    pixelBytes_ = pixels * sizeof(PixelOut);
    glNamedBufferStorage(pixels_, GLsizeiptr(pixelBytes_), nullptr, GL_MAP_READ_BIT);
  }
  const Camera::Basis basis = camera.basis();
  const PixelRays rays(scene, camera, options.lodPixels);
  Params p{};
  copy3(p.forward, basis.forward), copy3(p.right, basis.right), copy3(p.up, basis.up);
  p.tanHalf = basis.tanHalf, p.aspect = basis.aspect, p.sceneSize = scene.size,
  p.pixelAngle = camera.pixelAngle();
  copy3(p.origin, rays.origin());
  copy3(p.light, glm::normalize(options.lightDirection));
  copy3(p.background, options.background);
  p.rootSlot = rootSlot, p.width = std::uint32_t(camera.width), p.height = std::uint32_t(camera.height);
  p.flags = (options.cast.contours ? 1u : 0u) | (hasColors ? 2u : 0u) | (hasNormals ? 4u : 0u) |
            (options.beamTile > 0 ? 8u : 0u);
  p.footprintSlope = rays.footprintSlope();
  p.maxIterations = options.cast.maxIterations;
  glNamedBufferSubData(params_, 0, sizeof p, &p);

  const GLuint tilesX = GLuint((camera.width + kGroupSide - 1) / kGroupSide);
  const GLuint tilesY = GLuint((camera.height + kGroupSide - 1) / kGroupSide);
  if (std::size_t(tilesX) * tilesY * sizeof(float) > tileStartBytes_) {
    glDeleteBuffers(1, &tileStarts_);
    glCreateBuffers(1, &tileStarts_);
    tileStartBytes_ = std::size_t(tilesX) * tilesY * sizeof(float);
    glNamedBufferStorage(tileStarts_, GLsizeiptr(tileStartBytes_), nullptr, 0);
  }
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, pool_);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, pixels_);
  glBindBufferBase(GL_UNIFORM_BUFFER, 2, params_);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, tileStarts_);
  glQueryCounter(timers_[0], GL_TIMESTAMP);
  if (options.beamTile > 0) {
    // One invocation per tile, 8 x 8 tiles per work group.
    glUseProgram(beamProgram_);
    glDispatchCompute((tilesX + kGroupSide - 1) / kGroupSide, (tilesY + kGroupSide - 1) / kGroupSide, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  }
  glUseProgram(program_);
  glDispatchCompute(tilesX, tilesY, 1);
  glQueryCounter(timers_[1], GL_TIMESTAMP);
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT | GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT);
  const auto* out = static_cast<const PixelOut*>(
      glMapNamedBufferRange(pixels_, 0, GLsizeiptr(pixelBytes_), GL_MAP_READ_BIT));
  if (!out) throw std::runtime_error("GPU caster: cannot read the frame back");

  Frame frame;
  frame.width = camera.width, frame.height = camera.height;
  frame.color.resize(pixels);
  frame.depth.resize(pixels);
  frame.voxelPixels.resize(pixels);
  if (options.diagnostics) frame.iterations.resize(pixels), frame.lodStopped.resize(pixels);
  if (hits) hits->voxel.resize(pixels), hits->scale.resize(pixels);
  // Unpacked on all the threads asked for: on a GPU the read-back, not the dispatch, takes most of a frame.
  const auto unpack = [&](const tbb::blocked_range<std::size_t>& range, std::uint64_t iterations) {
    for (std::size_t i = range.begin(); i != range.end(); ++i) {
      const PixelOut& o = out[i];
      frame.color[i] = glm::vec4(o.color[0], o.color[1], o.color[2], o.color[3]);
      frame.depth[i] = o.depth;
      frame.voxelPixels[i] = o.voxelPixels;
      const std::uint32_t n = o.scaleIterations >> 16;
      iterations += n;
      if (options.diagnostics)
        frame.iterations[i] = std::uint16_t(n), frame.lodStopped[i] = (o.scaleIterations >> 8) & 1u;
      if (hits) hits->voxel[i] = o.hitSlot, hits->scale[i] = std::uint8_t(o.scaleIterations & 255u);
    }
    return iterations;
  };
  const auto unpackAll = [&] {
    return tbb::parallel_reduce(tbb::blocked_range<std::size_t>(0, pixels, kUnpackGrain), std::uint64_t(0),
                                unpack, std::plus<>());
  };
  std::uint64_t iterations = 0;
  if (options.threads > 0) {
    tbb::task_arena arena(options.threads);
    iterations = arena.execute(unpackAll);
  } else {
    iterations = unpackAll();
  }
  glUnmapNamedBuffer(pixels_);
  GLuint64 dispatchStart = 0, dispatchEnd = 0;
  glGetQueryObjectui64v(timers_[0], GL_QUERY_RESULT, &dispatchStart);
  glGetQueryObjectui64v(timers_[1], GL_QUERY_RESULT, &dispatchEnd);
  frame.deviceSeconds = double(dispatchEnd - dispatchStart) * 1e-9;
  // The filter runs on the CPU over the frame read back.
  if (options.filter) applyFilter(frame, options);
  frame.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  frame.meanIterations = double(iterations) / double(pixels);
  return frame;
}

Frame renderBlock(GpuCaster& caster, const BlockView& block, const SceneTransform& scene,
                  const Camera& camera, const RenderOptions& options, GpuHits* hits) {
  caster.reserve(block.size());
  caster.upload(0, std::span<const std::byte>(block.base(), block.size()));
  return caster.render(block.info().rootSlot, block.hasColors(), block.hasNormals(), scene, camera, options,
                       hits);
}

}  // namespace svo::gpu
