// castPacket's loop for one instruction set: raycast_packet.cpp includes this file once per target, inside a
// namespace of its own that defines kLanes and kAloneLanes, under that target's pragma. Work done once per
// iteration (the loop's control, a shared descent's descriptor and contour) is shared by every lane, so 16
// lanes cast more rays per instruction than 8, and 32 (two 16-lane halves, packet_halves.inl) more than 16,
// where neighbouring pixels stay together. Lane-wise choices go through select(), which both vector kinds
// define. The loop reads the octree through a lane descent (BlockLanes: a block's descriptors; LevelLanes:
// level arrays), as castRay's loop does through BlockDescent or LevelDescent. No includes here other than
// packet_halves.inl.
constexpr int N = kLanes;
#ifdef SVO_PACKET_HALVES
#include "packet_halves.inl"
#else  // one register's lanes
using Floats = float __attribute__((vector_size(sizeof(float) * N)));
using Ints = std::int32_t __attribute__((vector_size(sizeof(std::int32_t) * N)));
template <class V>
[[gnu::always_inline]] inline V select(Ints mask, V a, V b) {
  return mask ? a : b;
}
[[gnu::always_inline]] inline Floats toFloats(Ints a) {
  return __builtin_convertvector(a, Floats);
}
[[gnu::always_inline]] inline Ints bitsOf(Floats a) {
  return (Ints)a;
}
[[gnu::always_inline]] inline Floats floatsOf(Ints a) {
  return (Floats)a;
}
// The lanes of a mask as the bits of an integer, lane l as bit l: loops over them visit only the set lanes,
// one branch a set lane instead of an unpredictable one for every lane.
inline unsigned lanesOf(Ints mask) {
#ifdef SVO_PACKET_AVX512
  return unsigned(_mm512_movepi32_mask(__m512i(mask)));
#else
  return unsigned(_mm256_movemask_ps(__m256(mask)));
#endif
}
#endif

// std::min(a, b) and std::max(a, b) lane by lane, NaN handling included ((b < a) ? b : a; (a < b) ? b : a).
inline Floats minOf(Floats a, Floats b) {
  return select(b < a, b, a);
}
inline Floats maxOf(Floats a, Floats b) {
  return select(a < b, b, a);
}
inline Floats absOf(Floats a) {
  return select(a < Floats{}, -a, a);
}
inline bool any(Ints mask) {
  return lanesOf(mask) != 0;
}

// castRay's state, one lane per ray (names as in castRay), over the octree lane descent D reads. No member
// initializers: start() sets every one (GCC 12 fails to compile the implicit constructor of 256-bit members
// at -O0).
template <class D>
struct Lanes {
  // The mirrored rays' constants.
  Floats tx_coef, ty_coef, tz_coef, tx_bias, ty_bias, tz_bias, dx, dy, dz, slope, origin;
  Ints octantMask;
  // The loop's state.
  Floats t_min, t_max, scale_exp2, px, py, pz;
  Ints idx, scale, iterations, active, found;
  typename D::Node parent[N];
  // Each lane's parent's words (D::Words), reloaded where it changes: its valid mask in topology's [15:8];
  // in contourWord's [7:0] its children with a contour, by slot, and in [31:8] where their contours start
  // past the lane's contour base.
  Ints topology, contourWord;
  typename D::Extra extra;  // what else D keeps per lane
  RayStackEntryOf<typename D::Node> stack[N][kScaleMax + 1];
};

// Lane l's parent becomes `node`, with its words `w`.
template <class D>
[[gnu::always_inline]] inline void setParent(Lanes<D>& s, int l, typename D::Node node,
                                             const typename D::Words& w) {
  s.parent[l] = node;
  s.topology[l] = w.topology, s.contourWord[l] = w.contour;
  D::setExtra(s.extra, l, w);
}

// castRay's set-up for each ray from `root` (whose children are at scale kScaleMax - 1); lanes past `count`
// and rays that cannot hit start inactive.
template <class D>
[[gnu::always_inline]] inline void start(Lanes<D>& s, typename D::Node root, const OctreeRay* rays, int count,
                                         typename D::Hit* hits) {
  const Floats zero{};
  s.tx_coef = s.ty_coef = s.tz_coef = s.tx_bias = s.ty_bias = s.tz_bias = zero;
  s.dx = s.dy = s.dz = s.slope = s.origin = s.t_min = s.t_max = s.scale_exp2 = s.px = s.py = s.pz = zero;
  s.octantMask = s.idx = s.scale = s.iterations = s.active = s.found = Ints{};
  const typename D::Words rootWords = D::wordsOf(root, kScaleMax - 1);
  s.topology = Ints{} + rootWords.topology;
  s.contourWord = Ints{} + rootWords.contour;
  for (int l = 0; l < N; ++l) {
    s.parent[l] = root;
    D::setExtra(s.extra, l, rootWords);
    if (l < count) new (&hits[l]) typename D::Hit;  // as castRay's: the path arrays are written by each PUSH
    MirroredRay m;
    if (l >= count || !mirrorRay(rays[l], m)) continue;
    s.active[l] = -1;
    s.tx_coef[l] = m.tx_coef, s.ty_coef[l] = m.ty_coef, s.tz_coef[l] = m.tz_coef;
    s.tx_bias[l] = m.tx_bias, s.ty_bias[l] = m.ty_bias, s.tz_bias[l] = m.tz_bias;
    s.dx[l] = m.d.x, s.dy[l] = m.d.y, s.dz[l] = m.d.z;
    s.slope[l] = rays[l].footprintSlope, s.origin[l] = rays[l].footprintOrigin;
    s.octantMask[l] = m.octant_mask;
    s.t_min[l] = m.t_min, s.t_max[l] = m.t_max;
    s.idx[l] = m.idx;
    s.px[l] = m.pos.x, s.py[l] = m.pos.y, s.pz[l] = m.pos.z;
    s.scale[l] = kScaleMax - 1;
    s.scale_exp2[l] = 0.5f;
  }
}

// childRank for every lane: the set bits of the 8-bit `mask` below `slot` (a population count in lanes).
[[gnu::always_inline]] inline Ints childRanks(Ints mask, Ints slot) {
  Ints rank = mask & (((Ints{} + 1) << slot) - 1);
  rank = rank - ((rank >> 1) & 0x55);
  rank = (rank & 0x33) + ((rank >> 2) & 0x33);
  return (rank + (rank >> 4)) & 0x0F;
}

// clipToContour for the `clip` lanes, given each lane's decoded contour: raises t_min, lowers tv_max.
template <class D>
[[gnu::always_inline]] inline void clipLanes(const Lanes<D>& s, Ints clip, Floats nx, Floats ny, Floats nz,
                                             Floats position, Floats thickness, Floats tx_center,
                                             Floats ty_center, Floats tz_center, Floats& t_min,
                                             Floats& tv_max) {
  const Floats den = nx * s.dx + ny * s.dy + nz * s.dz;
  const Floats num =
      nx * s.dx * tx_center + ny * s.dy * ty_center + nz * s.dz * tz_center + s.scale_exp2 * position;
  const Floats halfWidth = 0.5f * s.scale_exp2 * thickness;
  const Ints crossing = clip & (absOf(den) > kParallelContour);
  const Floats inv = 1.0f / select(crossing, den, Floats{} + 1.0f);
  const Floats tmid = num * inv, tdiff = absOf(halfWidth * inv);
  t_min = select(crossing, maxOf(t_min, tmid - tdiff), t_min);
  tv_max = select(crossing, minOf(tv_max, tmid + tdiff), tv_max);
  const Ints outside = clip & ~crossing & (absOf(num) > halfWidth);
  // Parallel and outside: the voxel's shape is not on this ray.
  tv_max = select(outside, Floats{} - 1.0f, tv_max);
}

#ifdef SVO_PACKET_AVX512
// Word offset[l] after bases[l] for the 16 `mask` lanes of one register, 0 elsewhere: hardware gathers of 8
// lanes each over the 64-bit addresses (a lane-by-lane loop would store each word and reload the vector).
using Ints16 = std::int32_t __attribute__((vector_size(64)));
using Ints8 = std::int32_t __attribute__((vector_size(32)));
using Addresses8 = std::int64_t __attribute__((vector_size(64)));
// Vector extensions and zero-masked intrinsics: those that leave lanes undefined make GCC 12 warn.
template <class P>
[[gnu::always_inline]] inline Ints16 wordsAt16(const P* const* bases, Ints16 offset, Ints16 mask) {
  const __mmask16 lanes = _mm512_movepi32_mask(__m512i(mask));
  const Ints8 offsets[2] = {__builtin_shufflevector(offset, offset, 0, 1, 2, 3, 4, 5, 6, 7),
                            __builtin_shufflevector(offset, offset, 8, 9, 10, 11, 12, 13, 14, 15)};
  Ints8 words[2];
  for (int h = 0; h < 2; ++h) {
    Addresses8 address;
    std::memcpy(&address, bases + 8 * h, sizeof address);
    address += Addresses8(_mm512_maskz_cvtepi32_epi64(0xFF, __m256i(offsets[h]))) << 2;
    words[h] = Ints8(_mm512_mask_i64gather_epi32(__m256i(Ints8{}), __mmask8(lanes >> (8 * h)),
                                                 __m512i(address), nullptr, 1));
  }
  return __builtin_shufflevector(words[0], words[1], 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
}
#endif

#ifdef SVO_PACKET_AVX512
// decodeContour's normal components, k / kContourNormalScale for the 6-bit signed k of 16 lanes: two permutes
// over a table of the 64 quotients instead of a division (whose 16-lane form issues once every 16 cycles or
// so on AVX-512 cores, three per clip); the table holds the division's own floats.
using Floats16 = float __attribute__((vector_size(64)));
[[gnu::always_inline]] inline Floats16 contourNormalComponents16(Ints16 k) {
  static constexpr auto kQuotients = [] {
    std::array<float, 64> q{};
    for (int i = 0; i < 64; ++i) q[std::size_t(i)] = float(i - 32) / kContourNormalScale;
    return q;
  }();
  const __m512i index = __m512i(k + 32);
  const __m512 below =
      _mm512_permutex2var_ps(_mm512_loadu_ps(&kQuotients[0]), index, _mm512_loadu_ps(&kQuotients[16]));
  const __m512 above =
      _mm512_permutex2var_ps(_mm512_loadu_ps(&kQuotients[32]), index, _mm512_loadu_ps(&kQuotients[48]));
  return Floats16(_mm512_mask_blend_ps(_mm512_test_epi32_mask(index, _mm512_set1_epi32(32)), below, above));
}
#endif

// k / kContourNormalScale lane by lane, as decodeContour computes a contour normal's component.
[[gnu::always_inline]] inline Floats contourNormalComponents(Ints k) {
#if defined(SVO_PACKET_HALVES)
  return {contourNormalComponents16(k.lo), contourNormalComponents16(k.hi)};
#elif defined(SVO_PACKET_AVX512)
  return contourNormalComponents16(k);
#else
  return toFloats(k) / kContourNormalScale;
#endif
}

// The 32-bit word offset[l] after the lane's base bases[l] for the `mask` lanes, 0 elsewhere.
template <class P>
[[gnu::always_inline]] inline Ints wordsAt(const P* const* bases, Ints offset, Ints mask) {
#if defined(SVO_PACKET_HALVES)
  return {wordsAt16(bases, offset.lo, mask.lo), wordsAt16(bases + 16, offset.hi, mask.hi)};
#elif defined(SVO_PACKET_AVX512)
  return wordsAt16(bases, offset, mask);
#else
  Ints words{};
  for (unsigned lanes = lanesOf(mask); lanes != 0; lanes &= lanes - 1) {
    const int l = __builtin_ctz(lanes);
    words[l] = std::int32_t(reinterpret_cast<const std::uint32_t*>(bases[l])[offset[l]]);
  }
  return words;
#endif
}

// clipToContour for the `clip` lanes: their contour words loaded and decoded as decodeContour decodes one.
template <class D>
[[gnu::always_inline]] inline void clipToContours(Lanes<D>& s, Ints clip, Ints contourWord, Ints slot,
                                                  Floats tx_center, Floats ty_center, Floats tz_center,
                                                  Floats& tv_max) {
  // Past the lane's contour base: where its children's contours start ([31:8]), then the rank among the
  // children with a contour (the mask, [7:0]).
  const Ints offset = ((contourWord >> 8) & 0xFFFFFF) + childRanks(contourWord & 0xFF, slot);
  const Ints bits = wordsAt(D::contourBases(s), offset, clip);
  const Floats nx = contourNormalComponents(bits >> 26);
  const Floats ny = contourNormalComponents((bits << 6) >> 26);
  const Floats nz = contourNormalComponents((bits << 12) >> 26);
  const Floats position = toFloats((bits << 18) >> 25) * kContourPositionStep;
  const Floats thickness = toFloats(bits & 127) * kContourThicknessStep;
  clipLanes(s, clip, nx, ny, nz, position, thickness, tx_center, ty_center, tz_center, s.t_min, tv_max);
}

// The child each `meets` lane enters: where the lane descent finds none to enter (a leaf, a stub, a voxel
// without resident children) it is the lane's hit, else PUSH. Returns the lanes that pushed.
template <class D>
[[gnu::always_inline]] inline Ints push(Lanes<D>& s, Ints meets, Ints slot, bool recordPath,
                                        typename D::Hit* hits) {
  Ints pushed{};
  for (unsigned lanes = lanesOf(meets); lanes != 0; lanes &= lanes - 1) {
    const int l = __builtin_ctz(lanes);
    typename D::Node child;
    if (!D::child(s, l, slot[l], child)) {
      s.found[l] = -1;
      s.active[l] = 0;
      hits[l].leaf = true;
      continue;
    }
    const int scale = s.scale[l];
    s.stack[l][scale] = {s.parent[l], s.t_max[l]};
    if (recordPath) D::Scalar::recordPath(hits[l], scale, s.parent[l], slot[l]);
    setParent(s, l, child, D::wordsOf(child, scale - 1));
    pushed[l] = -1;
  }
  return pushed;
}

// The rest of PUSH for the `pushed` lanes: one scale down, into the child cube holding the ray at t_min (the
// ray is past a child's centre plane on each axis where that plane's t-value is not above t_min).
template <class D>
[[gnu::always_inline]] inline void enterChildren(Lanes<D>& s, Ints pushed, Floats half, Floats tx_center,
                                                 Floats ty_center, Floats tz_center, Floats tv_max) {
  s.scale -= pushed & 1;
  s.scale_exp2 = select(pushed, half, s.scale_exp2);
  const Ints upX = pushed & (tx_center > s.t_min), upY = pushed & (ty_center > s.t_min),
             upZ = pushed & (tz_center > s.t_min);
  s.idx = select(pushed, ((upX & 1) | (upY & 2) | (upZ & 4)), s.idx);
  s.px = select(upX, s.px + s.scale_exp2, s.px);
  s.py = select(upY, s.py + s.scale_exp2, s.py);
  s.pz = select(upZ, s.pz + s.scale_exp2, s.pz);
  s.t_max = select(pushed, tv_max, s.t_max);
}

// POP for the `pop` lanes, which left their parent: the new scale from the highest differing bit. Only the
// stack is read lane by lane. Positions are positive, so no sign bit differs and the signed conversion is
// castRay's unsigned one.
template <class D>
[[gnu::always_inline]] inline void pop(Lanes<D>& s, Ints pop, Ints step_mask) {
  const Ints none{};
  const Ints differing_bits = select((step_mask & 1) != 0, bitsOf(s.px) ^ bitsOf(s.px + s.scale_exp2), none) |
                              select((step_mask & 2) != 0, bitsOf(s.py) ^ bitsOf(s.py + s.scale_exp2), none) |
                              select((step_mask & 4) != 0, bitsOf(s.pz) ^ bitsOf(s.pz + s.scale_exp2), none);
  const Ints scale = (bitsOf(toFloats(differing_bits)) >> 23) - 127;
  s.active &= ~(pop & (scale >= kScaleMax));  // left the octree
  pop &= scale < kScaleMax;
  if (!any(pop)) return;
  const Ints shift = select(pop, scale, none);  // in range on every lane
  const Ints shx = bitsOf(s.px) >> shift, shy = bitsOf(s.py) >> shift, shz = bitsOf(s.pz) >> shift;
  s.scale = select(pop, scale, s.scale);
  s.scale_exp2 = select(pop, floatsOf((scale - kScaleMax + 127) << 23), s.scale_exp2);
  s.px = select(pop, floatsOf(shx << shift), s.px);
  s.py = select(pop, floatsOf(shy << shift), s.py);
  s.pz = select(pop, floatsOf(shz << shift), s.pz);
  s.idx = select(pop, (shx & 1) | ((shy & 1) << 1) | ((shz & 1) << 2), s.idx);
  for (unsigned lanes = lanesOf(pop); lanes != 0; lanes &= lanes - 1) {
    const int l = __builtin_ctz(lanes);
    const typename D::Node parent = s.stack[l][scale[l]].parent;
    s.t_max[l] = s.stack[l][scale[l]].t_max;
    setParent(s, l, parent, D::wordsOf(parent, scale[l]));
  }
}

// The lanes that share their voxel descend together. While they are in the same child slot of the same
// parent (a packet of neighbouring pixels, a few voxels apart at most), each step is castRay's iteration for
// a lane that enters a valid voxel with resident children and pushes into it: the descriptor, contour and
// child are looked up once for all of them, and no lane's decision branches. A lane in another slot, or whose
// iteration would do anything else (advance, stop by level of detail, the iteration cap, a contour that
// misses), leaves the group with its state untouched, and the loop goes on from there.
template <class D>
[[gnu::always_inline]] inline void descendTogether(Lanes<D>& s, const CastOptions& options, bool recordPath,
                                                   typename D::Hit* hits) {
  Ints together = s.active;
  while (any(together)) {
    const int leader = __builtin_ctz(lanesOf(together));
    const Ints slots = s.idx ^ s.octantMask ^ 7;
    const int slot = slots[leader];
    const typename D::Node parent = s.parent[leader];  // every lane of the group has it
    typename D::Node child;
    // Empty, or nothing to enter: the loop's iteration decides.
    if (!(s.topology[leader] >> 8 >> slot & 1) || !D::child(s, leader, slot, child)) return;
    together &= (slots == slot) & (s.iterations < options.maxIterations) & (s.t_min <= s.t_max);
    const Floats tx_corner = s.px * s.tx_coef - s.tx_bias;
    const Floats ty_corner = s.py * s.ty_coef - s.ty_bias;
    const Floats tz_corner = s.pz * s.tz_coef - s.tz_bias;
    const Floats tc_max = minOf(minOf(tx_corner, ty_corner), tz_corner);
    together &= ~(tc_max * s.slope + s.origin >= s.scale_exp2);
    Floats tv_max = minOf(s.t_max, tc_max), t_min = s.t_min;
    const Floats half = s.scale_exp2 * 0.5f;
    const Floats tx_center = half * s.tx_coef + tx_corner;
    const Floats ty_center = half * s.ty_coef + ty_corner;
    const Floats tz_center = half * s.tz_coef + tz_corner;
    if (Contour c; options.contours && D::contour(s, leader, slot, c)) {
      const Floats none{};
      clipLanes(s, together, none + c.normal.x, none + c.normal.y, none + c.normal.z, none + c.position,
                none + c.thickness, tx_center, ty_center, tz_center, t_min, tv_max);
    }
    together &= t_min <= tv_max;
    if (!any(together)) return;
    // PUSH
    const int scale = s.scale[leader];
    const typename D::Words words = D::wordsOf(child, scale - 1);
    for (unsigned lanes = lanesOf(together); lanes != 0; lanes &= lanes - 1) {
      const int l = __builtin_ctz(lanes);
      s.stack[l][scale] = {parent, s.t_max[l]};
      if (recordPath) D::Scalar::recordPath(hits[l], scale, parent, slot);
      s.parent[l] = child;
      D::setExtra(s.extra, l, words);
    }
    s.topology = select(together, Ints{} + words.topology, s.topology);
    s.contourWord = select(together, Ints{} + words.contour, s.contourWord);
    s.iterations -= together;
    s.t_min = select(together, t_min, s.t_min);
    enterChildren(s, together, half, tx_center, ty_center, tz_center, tv_max);
  }
}

// castRay's loop for each `lanes` lane from where the lane is, one lane after another.
template <class D>
[[gnu::noinline]] void finishAlone(Lanes<D>& s, unsigned lanes, const CastOptions& options,
                                   typename D::Hit* hits) {
  for (; lanes != 0; lanes &= lanes - 1) {
    const int l = __builtin_ctz(lanes);
    MirroredRay m;
    m.d = glm::vec3(s.dx[l], s.dy[l], s.dz[l]);
    m.tx_coef = s.tx_coef[l], m.ty_coef = s.ty_coef[l], m.tz_coef = s.tz_coef[l];
    m.tx_bias = s.tx_bias[l], m.ty_bias = s.ty_bias[l], m.tz_bias = s.tz_bias[l];
    m.octant_mask = s.octantMask[l];
    RayStateOf<typename D::Node> r{.parent = s.parent[l],
                                   .pos = glm::vec3(s.px[l], s.py[l], s.pz[l]),
                                   .scale_exp2 = s.scale_exp2[l],
                                   .t_min = s.t_min[l],
                                   .t_max = s.t_max[l],
                                   .idx = s.idx[l],
                                   .scale = s.scale[l],
                                   .iterations = s.iterations[l]};
    s.found[l] =
        continueRay<typename D::Scalar>(m, s.slope[l], s.origin[l], options, r, s.stack[l], hits[l]) ? -1 : 0;
    s.active[l] = 0;
    s.parent[l] = r.parent;
    s.px[l] = r.pos.x, s.py[l] = r.pos.y, s.pz[l] = r.pos.z;
    s.scale_exp2[l] = r.scale_exp2, s.t_min[l] = r.t_min, s.t_max[l] = r.t_max;
    s.idx[l] = r.idx, s.scale[l] = r.scale, s.iterations[l] = r.iterations;
  }
}

template <class D>
void castLanes(typename D::Node root, const OctreeRay* rays, int count, const CastOptions& options,
               typename D::Hit* hits) {
  const bool recordPath = options.recordPath;  // read once: the stores into `hits` might alias `options`
  Lanes<D> s;
  start(s, root, rays, count, hits);
  descendTogether(s, options, recordPath, hits);
  while (any(s.active)) {
    if (const unsigned lanes = lanesOf(s.active); std::popcount(lanes) <= kAloneLanes) {
      finishAlone(s, lanes, options, hits);
      break;
    }
    // The iteration cap, then each lane's voxel: valid, with or without a contour, a non-leaf or not, from
    // its parent's descriptor words (kept in the lanes since the lane's last PUSH or POP).
    s.iterations -= s.active;
    s.active &= s.iterations <= options.maxIterations;
    const Ints topology = s.topology, contourWord = s.contourWord;
    const Ints slot = s.idx ^ s.octantMask ^ 7;
    const Ints valid = -((topology >> 8 >> slot) & 1);
    const Ints contoured = options.contours ? -((contourWord >> slot) & 1) : Ints{};
    const Floats tx_corner = s.px * s.tx_coef - s.tx_bias;
    const Floats ty_corner = s.py * s.ty_coef - s.ty_bias;
    const Floats tz_corner = s.pz * s.tz_coef - s.tz_bias;
    const Floats tc_max = minOf(minOf(tx_corner, ty_corner), tz_corner);

    const Ints entered = s.active & valid & (s.t_min <= s.t_max);
    // Level of detail: the voxel is no larger than the ray's footprint where the ray leaves it.
    const Ints lodStop = entered & (tc_max * s.slope + s.origin >= s.scale_exp2);
    s.found |= lodStop;
    s.active &= ~lodStop;
    const Ints intersect = entered & ~lodStop;

    // INTERSECT: the cube, then the voxel's contour slab.
    Floats tv_max = minOf(s.t_max, tc_max);
    const Floats half = s.scale_exp2 * 0.5f;
    const Floats tx_center = half * s.tx_coef + tx_corner;
    const Floats ty_center = half * s.ty_coef + ty_corner;
    const Floats tz_center = half * s.tz_coef + tz_corner;
    const Ints clip = intersect & contoured;
    if (any(clip)) clipToContours(s, clip, contourWord, slot, tx_center, ty_center, tz_center, tv_max);

    const Ints pushed = push(s, intersect & (s.t_min <= tv_max), slot, recordPath, hits);
    if (any(pushed)) enterChildren(s, pushed, half, tx_center, ty_center, tz_center, tv_max);

    // ADVANCE the others: step to the next cube of the same scale along the ray.
    const Ints advance = s.active & ~pushed;
    if (!any(advance)) continue;
    const Ints stepX = advance & (tx_corner <= tc_max), stepY = advance & (ty_corner <= tc_max),
               stepZ = advance & (tz_corner <= tc_max);
    s.px = select(stepX, s.px - s.scale_exp2, s.px);
    s.py = select(stepY, s.py - s.scale_exp2, s.py);
    s.pz = select(stepZ, s.pz - s.scale_exp2, s.pz);
    s.t_min = select(advance, tc_max, s.t_min);
    const Ints step_mask = (stepX & 1) | (stepY & 2) | (stepZ & 4);
    s.idx ^= step_mask;
    // POP when a bit flipped against the ray direction: the ray left the parent.
    pop(s, advance & ((s.idx & step_mask) != 0), step_mask);
  }

  for (int l = 0; l < count; ++l) {
    hits[l].iterations = s.iterations[l];
    if (s.found[l])
      completeHit(rays[l], s.octantMask[l], glm::vec3(s.px[l], s.py[l], s.pz[l]), s.scale_exp2[l], s.scale[l],
                  s.t_min[l], s.parent[l], s.idx[l], hits[l]);
  }
}

// A block's descriptors lane by lane: a lane's words are its parent descriptor's, whose contour pointer
// counts from the descriptor itself (BlockDescent reads them the same way one ray at a time).
struct BlockLanes {
  using Node = const ChildDescriptor*;
  using Hit = CastHit;
  using Scalar = BlockDescent;
  struct Words {
    std::int32_t topology, contour;
  };
  struct Extra {};
  static Words wordsOf(Node node, int /*scale*/) {
    return {std::int32_t(node->topology), std::int32_t(node->contour)};
  }
  static void setExtra(Extra&, int, const Words&) {}
  static const ChildDescriptor* const* contourBases(const Lanes<BlockLanes>& s) { return s.parent; }
  // The child lane l enters at `slot`; false where it is the lane's hit.
  static bool child(const Lanes<BlockLanes>& s, int l, int slot, Node& child) {
    return BlockDescent::child(s.parent[l], BlockDescent::read(s.parent[l], 0), slot, 0, child);
  }
  static bool contour(const Lanes<BlockLanes>& s, int l, int slot, Contour& c) {
    return BlockDescent::contour(s.parent[l], BlockDescent::read(s.parent[l], 0), slot, 0, c);
  }
};

// Level arrays lane by lane (LevelDescent's reading): a lane keeps its parent's LevelDescent::Parent, and
// its words are made from it: the valid mask, and the children's contour presence bits spread to their
// slots, with the first child's contour as the contour base.
struct LevelLanes {
  using Node = LevelNode;
  using Hit = LevelCastHit;
  using Scalar = LevelDescent;
  struct Words {
    std::int32_t topology, contour;
    LevelDescent::Parent parent;
    const std::uint32_t* contourBase;
  };
  static constexpr std::uint32_t kMostChildren = 8;  // a child mask's bits
  struct Extra {
    LevelDescent::Parent parent[N];
    const std::uint32_t* contourBase[N];
  };
  static Words wordsOf(Node node, int scale) {
    const LevelDescent::Parent p = LevelDescent::read(node, scale);
    const PresentValues<std::uint32_t>& contours = p.children->contours;
    // The presence bits of the children (at most 8) from the first on; PresentValues keeps a word past the
    // last voxel's, so the next word may be read.
    const std::uint32_t first = p.firstChild, shift = first % 64;
    std::uint64_t present = contours.words[first / 64] >> shift;
    if (shift > 64 - kMostChildren) present |= contours.words[first / 64 + 1] << (64 - shift);
    const unsigned bySlot = _pdep_u32(unsigned(present), p.validMask);  // the i-th child's bit to its slot
    return {std::int32_t(p.validMask) << 8, std::int32_t(bySlot), p,
            contours.values.data() + contours.rank(first)};
  }
  static void setExtra(Extra& e, int l, const Words& w) {
    e.parent[l] = w.parent;
    e.contourBase[l] = w.contourBase;
  }
  static const std::uint32_t* const* contourBases(const Lanes<LevelLanes>& s) { return s.extra.contourBase; }
  static bool child(const Lanes<LevelLanes>& s, int l, int slot, Node& child) {
    return LevelDescent::child(s.parent[l], s.extra.parent[l], slot, 0, child);
  }
  static bool contour(const Lanes<LevelLanes>& s, int l, int slot, Contour& c) {
    return LevelDescent::contour(s.parent[l], s.extra.parent[l], slot, 0, c);
  }
};

void castBlockLanes(const BlockView& block, const OctreeRay* rays, int count, const CastOptions& options,
                    CastHit* hits) {
  castLanes<BlockLanes>(block.root(), rays, count, options, hits);
}

// The root's region must have children (LevelRegion::hasChildren).
void castLevelLanes(const LevelRegion& root, const OctreeRay* rays, int count, const CastOptions& options,
                    LevelCastHit* hits) {
  castLanes<LevelLanes>(LevelNode{&root, 0}, rays, count, options, hits);
}
