// castPacket: castRay's loop (raycast.cpp) run for up to kPacketLanes rays at once, one ray per SIMD lane, on
// a block or on level arrays (level_raycast.hpp).
// The loop is bound by the latency of each iteration's chain (corner t-values, contour division, the
// decision), so a single ray leaves most of the core idle; lanes fill it. Every lane performs castRay's float
// operations in castRay's order (no fused multiply-add) and takes castRay's decisions, so each hit is the
// same bit for bit; the integer work of the decisions (child pointers, the stack) runs lane by lane. The loop
// (packet_loop.inl) is compiled once per instruction set and chosen at run time, so one binary runs
// everywhere: 32 lanes in pairs of AVX-512 registers (16 in one for a packet of at most 16 rays), 8 in AVX2
// ones, else castRay one ray at a time.
#include <algorithm>
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <new>

#include <immintrin.h>

#include "level_descent.hpp"
#include "ray_setup.hpp"
#include "svo/client/level_raycast.hpp"
#include "svo/client/raycast.hpp"

namespace svo {

using namespace ray_setup;

namespace {

// Each copy sits in its own namespace under its target pragma. Neither lets the compiler fuse multiplies
// and adds, which would round castRay's floats differently. kAloneLanes: once no more lanes than this are
// left, each finishes alone in castRay's loop, which steps one ray faster than a vector step of mostly idle
// lanes (sweep of 0-6 on the 1 M hairball's whole view, 1024^2, Xeon: 2-4 lanes of 32 and 2 of 8 cast it
// 4-7% faster; the bunny's close-up, whose packets stay full, within noise).
namespace avx2 {
#pragma GCC push_options
#pragma GCC target("avx2,popcnt,bmi2")
constexpr int kLanes = 8;
constexpr int kAloneLanes = 2;
#include "packet_loop.inl"
#pragma GCC pop_options
}  // namespace avx2

namespace avx512 {
#pragma GCC push_options
#pragma GCC target("avx2,popcnt,bmi2,avx512f,avx512vl,avx512dq,avx512bw")
#pragma GCC optimize("fp-contract=off")
constexpr int kLanes = 16;
constexpr int kAloneLanes = 2;
#define SVO_PACKET_AVX512 1  // target pragmas do not define __AVX512F__ and its kin
#include "packet_loop.inl"
#undef SVO_PACKET_AVX512
#pragma GCC pop_options
}  // namespace avx512

// 32 lanes as two 16-lane halves (packet_halves.inl): the loop's control, its branches and each shared step
// serve twice the rays, and twice the lanes' loads are in flight at once.
namespace avx512x2 {
#pragma GCC push_options
#pragma GCC target("avx2,popcnt,bmi2,avx512f,avx512vl,avx512dq,avx512bw")
#pragma GCC optimize("fp-contract=off")
constexpr int kLanes = 32;
constexpr int kAloneLanes = 3;
#define SVO_PACKET_AVX512 1
#define SVO_PACKET_HALVES 1
#include "packet_loop.inl"
#undef SVO_PACKET_HALVES
#undef SVO_PACKET_AVX512
#pragma GCC pop_options
}  // namespace avx512x2
static_assert(avx512x2::kLanes == kPacketLanes);

}  // namespace

const char* nameOf(PacketSimd simd) {
  switch (simd) {
    case PacketSimd::Widest:
      return "widest";
    case PacketSimd::Avx512:
      return "avx512";
    case PacketSimd::Avx2:
      return "avx2";
    case PacketSimd::None:
      return "none";
  }
  return "?";
}

bool cpuHas(PacketSimd simd) {
  static const bool avx2 =
      __builtin_cpu_supports("avx2") && __builtin_cpu_supports("popcnt") && __builtin_cpu_supports("bmi2");
  static const bool avx512 = avx2 && __builtin_cpu_supports("avx512f") &&
                             __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512dq") &&
                             __builtin_cpu_supports("avx512bw");
  switch (simd) {
    case PacketSimd::Avx512:
      return avx512;
    case PacketSimd::Avx2:
      return avx2;
    case PacketSimd::Widest:
    case PacketSimd::None:
      return true;
  }
  return false;
}

PacketSimd packetSimdUsed(PacketSimd requested) {
  bool allowed = requested == PacketSimd::Widest;
  for (const PacketSimd simd : {PacketSimd::Avx512, PacketSimd::Avx2}) {  // widest first
    allowed |= simd == requested;
    if (allowed && cpuHas(simd)) return simd;
  }
  return PacketSimd::None;
}

namespace {

// castPacket on either octree: the widest loop this CPU has that `options` allows (`castAll`: two AVX-512
// registers' lanes, `cast16`: one's, `cast8`: AVX2's), else castRay ray by ray.
template <class Root, class Hit, class CastLanes>
void castPacketWith(const Root& root, const OctreeRay* rays, int count, const CastOptions& options, Hit* hits,
                    CastLanes castAll, CastLanes cast16, CastLanes cast8) {
  switch (packetSimdUsed(options.simd)) {
    case PacketSimd::Avx512:
      if (count > avx512::kLanes)
        castAll(root, rays, count, options, hits);
      else  // a packet at a tile's edge: one register's lanes do
        cast16(root, rays, count, options, hits);
      return;
    case PacketSimd::Avx2:
      for (int first = 0; first < count; first += avx2::kLanes)
        cast8(root, rays + first, std::min(count - first, avx2::kLanes), options, hits + first);
      return;
    default:
      for (int l = 0; l < count; ++l) hits[l] = castRay(root, rays[l], options);
  }
}

}  // namespace

void castPacket(const BlockView& block, const OctreeRay* rays, int count, const CastOptions& options,
                CastHit* hits) {
  castPacketWith(block, rays, count, options, hits, avx512x2::castBlockLanes, avx512::castBlockLanes,
                 avx2::castBlockLanes);
}

void castPacket(const LevelRegion& root, const OctreeRay* rays, int count, const CastOptions& options,
                LevelCastHit* hits) {
  if (!root.hasChildren()) {  // no hit
    std::fill_n(hits, count, LevelCastHit{});
    return;
  }
  castPacketWith(root, rays, count, options, hits, avx512x2::castLevelLanes, avx512::castLevelLanes,
                 avx2::castLevelLanes);
}

}  // namespace svo
