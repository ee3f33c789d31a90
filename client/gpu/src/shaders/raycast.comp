// The ESVO ray caster (paper sec. 6, Fig. 15) as an OpenGL 4.5 compute shader: the CPU caster of
// client/src/raycast.cpp line for line (the octree in [1,2]^3 so that a position's mantissa bits are its path,
// directions mirrored to be negative, the (parent, t_max) stack indexed by scale, POP from the highest
// differing position bit, contour slabs, the level-of-detail stop), the beam pass of client/src/beam.cpp once
// per 8 x 8 tile, and the renderer's Phong shading with attributes found through page header, info section
// and attachment (Fig. 8). The traversal's float expressions are `precise`, so no multiply-add is fused that
// the CPU does not fuse, and its depths equal the CPU's bit for bit.
#version 450
layout(local_size_x = 8, local_size_y = 8) in;

// The block pool's arena (or one block) as 32-bit words; a descriptor at slot s is words 2s and 2s + 1.
layout(std430, binding = 0) readonly buffer Pool { uint words[]; };

struct PixelOut {
  vec4 color;        // linear RGB + alpha (1 = hit)
  float depth;       // world distance along the ray; +inf for a miss
  float voxelPixels; // the hit voxel's size in pixels at its distance
  uint hitSlot;      // descriptor slot of the hit voxel's parent * 8 + child slot; 0xffffffff for a miss
  uint scaleIterations;  // hit scale (bits 0-7), 1 when stopped by LOD (bit 8), iterations (bits 16-31)
};
layout(std430, binding = 1) writeonly buffer Frame { PixelOut pixels[]; };

layout(std140, binding = 2) uniform Params {
  // The camera basis in double precision, as the CPU renderer computes pixel rays (Camera::pixelRay).
  dvec4 forward;
  dvec4 right;
  dvec4 up;
  double tanHalf, aspect, sceneSize, pixelAngle;
  vec4 origin;      // the eye in octree space (xyz)
  vec4 light;       // unit, towards the scene
  vec4 background;  // rgb
  uint rootSlot;
  uint width, height;
  uint flags;  // 1: contours, 2: colors, 4: normals, 8: the beam pass
  float footprintSlope;
  int maxIterations;
} P;

const int kScaleMax = 23;
const float kMinDirection = 1.0 / 8388608.0;
const float kParallelContour = 1e-20;
const uint kColor = 1u, kNormal = 2u, kColorUnits = 3u, kNormalUnits = 4u;
const uint kSlotsPerPage = 1024u;
const uint kShownByBlockRoot = 0xFFFFFFu;  // AttributeLookup::kShownByBlockRoot
const float kAmbient = 0.15, kDiffuse = 0.75, kSpecular = 0.25;
const int kShininessLog2 = 5;  // specular exponent 32, raised by squaring as on the CPU
const float kNeutralGreyAlbedo = 0.8;

uint topology(uint slot) { return words[2u * slot]; }
uint contourWord(uint slot) { return words[2u * slot + 1u]; }
uint validMask(uint t) { return (t >> 8) & 255u; }
uint nonLeafMask(uint t) { return validMask(t) & ~t & 255u; }
bool isFar(uint t) { return ((t >> 16) & 1u) != 0u; }
bool isStub(uint slot) { uint t = topology(slot); return validMask(t) == 0u && !isFar(t); }
int childRank(uint mask, uint slot) { return bitCount(mask & ((1u << slot) - 1u)); }

// A link's target (format.hpp: a descriptor with no valid children and the far bit, `contour` slots away).
// Links chain where regions share an entry voxel (a run of sub-cubes, then one sub-cube on its own); the loop
// is bounded, as an unbounded one here is miscompiled by Mesa 22's llvmpipe (it skips the link).
const int kMaxLinkChain = 8;
uint followLink(uint from) {
  uint at = from;
  for (int i = 0; i < kMaxLinkChain; ++i) {
    uint t = topology(at);
    if (validMask(t) != 0u || !isFar(t)) break;
    at = uint(int(at) + int(contourWord(at)));
  }
  return at;
}

// The info section of the block holding `slot`, as a word index (page header: words from the page).
uint infoWord(uint slot) {
  uint page = slot & ~(kSlotsPerPage - 1u);
  return uint(int(2u * page) + int(words[2u * page]));
}

// Sec. 5.4 / Fig. 8: the value of child `child` of the descriptor at `slot`, or false when it inherits from
// further up. An entry without values (mask 0) may name the value all its children show (AttributeLookup).
bool shownAttribute(uint slot, uint child, uint type, out uint value) {
  uint info = infoWord(slot);
  int slotsPointer = int(words[info + 1u]);
  uint attachments = words[info + 5u];
  uint index = uint(int(slot) - (int(info) + slotsPointer) / 2);
  for (uint a = 0u; a < attachments; ++a) {
    uint entry = info + 6u + 4u * a;
    if (words[entry] != type) continue;
    uint start = uint(int(info) + int(words[entry + 1u]));
    uint lookup = words[start + index];
    uint mask = lookup & 255u;
    uint pointer = lookup >> 8;
    if (mask == 0u && pointer != 0u) {
      value = pointer == kShownByBlockRoot ? words[entry + 2u] : words[start + pointer];
      return true;
    }
    if (((mask >> child) & 1u) == 0u) return false;
    value = words[start + (lookup >> 8) + uint(childRank(mask, child))];
    return true;
  }
  return false;
}

uint rootValue(uint slot, uint type) {
  uint info = infoWord(slot);
  uint attachments = words[info + 5u];
  for (uint a = 0u; a < attachments; ++a) {
    uint entry = info + 6u + 4u * a;
    if (words[entry] == type) return words[entry + 2u];
  }
  return 0u;
}

// GLSL lets a float division be off by 2.5 ulps (NVIDIA's is a reciprocal and a multiply); a double quotient
// rounded once to float is the correctly rounded float quotient (p' >= 2p + 2 makes the double rounding
// innocuous), so the traversal divides as the CPU does.
float exactQuotient(float a, float b) { return float(double(a) / double(b)); }

vec3 decodeContourNormal(uint bits) {
  int s = int(bits);
  return vec3(exactQuotient(float(s >> 26), 31.0), exactQuotient(float((s << 6) >> 26), 31.0),
              exactQuotient(float((s << 12) >> 26), 31.0));
}
const float kContourPositionStep = float(1.5lf / 63.0lf), kContourThicknessStep = float(3.0lf / 127.0lf);
float contourPosition(uint bits) { return float((int(bits) << 18) >> 25) * kContourPositionStep; }
float contourThickness(uint bits) { return float(bits & 127u) * kContourThicknessStep; }

vec3 decodeColor(uint abgr) {
  return vec3(float(abgr & 255u), float((abgr >> 8) & 255u), float((abgr >> 16) & 255u)) / 255.0;
}
// The cube-point encoding's point on the unit cube (format.hpp's normalDirection).
vec3 cubePoint(uint bits) {
  uint face = bits >> 29;
  int axis = (face >> 1) < 2u ? int(face >> 1) : 2;
  float u = float((bits >> 14) & 32767u) / 32767.0 * 2.0 - 1.0;
  float v = float(bits & 16383u) / 16383.0 * 2.0 - 1.0;
  float w = (face & 1u) != 0u ? -1.0 : 1.0;
  return axis == 0 ? vec3(w, u, v) : axis == 1 ? vec3(u, w, v) : vec3(u, v, w);
}
vec3 decodeNormal(uint bits) { return normalize(cubePoint(bits)); }

struct Hit {
  bool hit, leaf;
  float t;
  vec3 position, cubeMin;
  uint parent, childSlot;
  int scale, iterations;
};

// The path's descriptors and slots by scale, for attribute inheritance (CastHit::pathParent).
uint pathParent[kScaleMax];
uint pathSlot[kScaleMax];

Hit castRay(vec3 o, vec3 d, float tStart, float footprintSlope, bool contours) {
  Hit hit;
  hit.hit = false, hit.leaf = false, hit.iterations = 0;
  vec3 d0 = d;
  // A power of two below the largest component (ilogb, read from the float's exponent bits).
  float largest = max(max(abs(d.x), abs(d.y)), abs(d.z));
  precise float minComponent = ldexp(kMinDirection, int((floatBitsToUint(largest) >> 23) & 255u) - 127);
  if (abs(d.x) < minComponent) d.x = d.x < 0.0 ? -minComponent : minComponent;
  if (abs(d.y) < minComponent) d.y = d.y < 0.0 ? -minComponent : minComponent;
  if (abs(d.z) < minComponent) d.z = d.z < 0.0 ? -minComponent : minComponent;

  precise float tx_coef = exactQuotient(1.0, -abs(d.x)), ty_coef = exactQuotient(1.0, -abs(d.y)),
                tz_coef = exactQuotient(1.0, -abs(d.z));
  precise float tx_bias = tx_coef * o.x, ty_bias = ty_coef * o.y, tz_bias = tz_coef * o.z;
  int octant_mask = 7;
  if (d.x > 0.0) octant_mask ^= 1, tx_bias = 3.0 * tx_coef - tx_bias;
  if (d.y > 0.0) octant_mask ^= 2, ty_bias = 3.0 * ty_coef - ty_bias;
  if (d.z > 0.0) octant_mask ^= 4, tz_bias = 3.0 * tz_coef - tz_bias;

  precise float t_min = max(max(2.0 * tx_coef - tx_bias, 2.0 * ty_coef - ty_bias), 2.0 * tz_coef - tz_bias);
  precise float t_max = min(min(tx_coef - tx_bias, ty_coef - ty_bias), tz_coef - tz_bias);
  t_min = max(t_min, max(tStart, 0.0));
  if (!(t_min <= t_max)) return hit;

  uint stackParent[kScaleMax + 1];
  float stackTmax[kScaleMax + 1];

  uint parent = P.rootSlot;
  uint topo = 0u, contourBits = 0u;
  bool cached = false;
  int idx = 0;
  precise vec3 pos = vec3(1.0);
  int scale = kScaleMax - 1;
  precise float scale_exp2 = 0.5;
  if (1.5 * tx_coef - tx_bias > t_min) idx ^= 1, pos.x = 1.5;
  if (1.5 * ty_coef - ty_bias > t_min) idx ^= 2, pos.y = 1.5;
  if (1.5 * tz_coef - tz_bias > t_min) idx ^= 4, pos.z = 1.5;

  int iterations = 0;
  bool found = false;
  while (scale < kScaleMax) {
    if (++iterations > P.maxIterations) break;
    if (!cached) {
      topo = topology(parent);
      contourBits = contourWord(parent);
      cached = true;
    }
    precise float tx_corner = pos.x * tx_coef - tx_bias;
    precise float ty_corner = pos.y * ty_coef - ty_bias;
    precise float tz_corner = pos.z * tz_coef - tz_bias;
    precise float tc_max = min(min(tx_corner, ty_corner), tz_corner);

    uint slot = uint(idx ^ octant_mask ^ 7);
    if (((validMask(topo) >> slot) & 1u) != 0u && t_min <= t_max) {
      if (tc_max * footprintSlope + 0.0 >= scale_exp2) {
        found = true;
        break;
      }
      precise float tv_max = min(t_max, tc_max);
      precise float half_ = scale_exp2 * 0.5;
      precise float tx_center = half_ * tx_coef + tx_corner;
      precise float ty_center = half_ * ty_coef + ty_corner;
      precise float tz_center = half_ * tz_coef + tz_corner;
      uint contourMask = contourBits & 255u;
      if (contours && ((contourMask >> slot) & 1u) != 0u) {
        uint c = words[2u * parent + (contourBits >> 8) + uint(childRank(contourMask, slot))];
        vec3 n = decodeContourNormal(c);
        precise float den = n.x * d.x + n.y * d.y + n.z * d.z;
        precise float num = n.x * d.x * tx_center + n.y * d.y * ty_center + n.z * d.z * tz_center +
                            scale_exp2 * contourPosition(c);
        precise float halfWidth = 0.5 * scale_exp2 * contourThickness(c);
        if (abs(den) > kParallelContour) {
          precise float inv = exactQuotient(1.0, den);
          precise float tmid = num * inv, tdiff = abs(halfWidth * inv);
          t_min = max(t_min, tmid - tdiff);
          tv_max = min(tv_max, tmid + tdiff);
        } else if (abs(num) > halfWidth) {
          tv_max = -1.0;
        }
      }
      if (t_min <= tv_max) {
        bool hasChild = false;
        uint child = 0u;
        if (((nonLeafMask(topo) >> slot) & 1u) != 0u) {
          uint run = parent + (topo >> 17);
          if (isFar(topo)) run = uint(int(run) + int(words[2u * run]));
          child = followLink(run + uint(childRank(nonLeafMask(topo), slot)));
          hasChild = !isStub(child);
        }
        if (!hasChild) {
          found = true;
          hit.leaf = true;
          break;
        }
        stackParent[scale] = parent;
        stackTmax[scale] = t_max;
        pathParent[scale] = parent;
        pathSlot[scale] = slot;
        parent = child;
        idx = 0;
        --scale;
        scale_exp2 = half_;
        if (tx_center > t_min) idx ^= 1, pos.x += scale_exp2;
        if (ty_center > t_min) idx ^= 2, pos.y += scale_exp2;
        if (tz_center > t_min) idx ^= 4, pos.z += scale_exp2;
        t_max = tv_max;
        cached = false;
        continue;
      }
    }

    int step_mask = 0;
    if (tx_corner <= tc_max) step_mask ^= 1, pos.x -= scale_exp2;
    if (ty_corner <= tc_max) step_mask ^= 2, pos.y -= scale_exp2;
    if (tz_corner <= tc_max) step_mask ^= 4, pos.z -= scale_exp2;
    t_min = tc_max;
    idx ^= step_mask;

    if ((idx & step_mask) != 0) {
      uint differing_bits = 0u;
      if ((step_mask & 1) != 0) differing_bits |= floatBitsToUint(pos.x) ^ floatBitsToUint(pos.x + scale_exp2);
      if ((step_mask & 2) != 0) differing_bits |= floatBitsToUint(pos.y) ^ floatBitsToUint(pos.y + scale_exp2);
      if ((step_mask & 4) != 0) differing_bits |= floatBitsToUint(pos.z) ^ floatBitsToUint(pos.z + scale_exp2);
      scale = findMSB(differing_bits);
      if (scale >= kScaleMax) break;
      scale_exp2 = uintBitsToFloat(uint(scale - kScaleMax + 127) << 23);
      parent = stackParent[scale];
      t_max = stackTmax[scale];
      uint shx = floatBitsToUint(pos.x) >> scale, shy = floatBitsToUint(pos.y) >> scale,
           shz = floatBitsToUint(pos.z) >> scale;
      pos = vec3(uintBitsToFloat(shx << scale), uintBitsToFloat(shy << scale), uintBitsToFloat(shz << scale));
      idx = int((shx & 1u) | ((shy & 1u) << 1) | ((shz & 1u) << 2));
      cached = false;
    }
  }
  hit.iterations = iterations;
  if (!found) return hit;
  if ((octant_mask & 1) == 0) pos.x = 3.0 - scale_exp2 - pos.x;
  if ((octant_mask & 2) == 0) pos.y = 3.0 - scale_exp2 - pos.y;
  if ((octant_mask & 4) == 0) pos.z = 3.0 - scale_exp2 - pos.z;
  hit.hit = true;
  hit.t = t_min;
  hit.scale = scale;
  hit.parent = parent;
  hit.childSlot = uint(idx ^ octant_mask ^ 7);
  hit.cubeMin = pos;
  precise float inset = min(kMinDirection, 0.25 * scale_exp2);
  precise vec3 p = o + t_min * d0;
  hit.position = min(max(p, pos + inset), pos + scale_exp2 - inset);
  return hit;
}

// Sec. 5.5: the first word of the unit holding the children of the descriptor at `slot` in attachment `type`
// (kColorUnits or kNormalUnits, `unitWords` words per unit) and the half they take (pairHalf), through the
// attachment's unit directory (block.hpp: kUnitGroup pairs of slots per entry, a presence mask and the
// index of the entry's first unit). kNoUnit: the pair holds none, its children inherit their parent's
// value; kNoAttachment: the block has no such attachment (the raw layout).
const int kNoAttachment = 0, kNoUnit = 1, kUnit = 2;
const uint kUnitGroup = 32u;
int unitOf(uint slot, uint type, uint unitWords, out uint start, out uint pairHalf) {
  uint info = infoWord(slot);
  int slotsPointer = int(words[info + 1u]);
  uint slotCount = words[info + 2u];
  uint attachments = words[info + 5u];
  uint index = uint(int(slot) - (int(info) + slotsPointer) / 2);
  for (uint a = 0u; a < attachments; ++a) {
    uint entry = info + 6u + 4u * a;
    if (words[entry] != type) continue;
    uint directory = uint(int(info) + int(words[entry + 1u]));
    uint pair = index / 2u, bit = pair % kUnitGroup;
    uint group = directory + 2u * (pair / kUnitGroup);
    pairHalf = index & 1u;
    if (((words[group] >> bit) & 1u) == 0u) return kNoUnit;
    uint rank = words[group + 1u] + uint(bitCount(words[group] & ((1u << bit) - 1u)));
    uint directoryWords = 2u * (((slotCount + 1u) / 2u + kUnitGroup - 1u) / kUnitGroup);
    start = directory + directoryWords + rank * unitWords;
    return kUnit;
  }
  return kNoAttachment;
}

// color_units.cpp's decodeColorUnit: RGB565 endpoints widened by bit replication, thirds in integers.
uint paletteChannel(uint word0, uint shift, uint bits, uint index) {
  uint mask = (1u << bits) - 1u;
  uint qa = (word0 >> shift) & mask, qb = (word0 >> (16u + shift)) & mask;
  uint a = bits == 5u ? (qa << 3) | (qa >> 2) : (qa << 2) | (qa >> 4);
  uint b = bits == 5u ? (qb << 3) | (qb >> 2) : (qb << 2) | (qb >> 4);
  return index == 0u ? a : index == 1u ? b : index == 2u ? (2u * a + b + 1u) / 3u : (a + 2u * b + 1u) / 3u;
}
vec3 unitColor(uint start, uint unitSlot) {
  uint index = (words[start + 1u] >> (2u * unitSlot)) & 3u;
  uint c = words[start];
  return vec3(float(paletteChannel(c, 11u, 5u, index)), float(paletteChannel(c, 5u, 6u, index)),
              float(paletteChannel(c, 0u, 5u, index))) / 255.0;
}

// normal_units.cpp's decodeNormalUnit, in its order of float operations.
vec3 axisVector(uint bits) {
  float scale = ldexp(1.0, int((bits >> 12) & 15u) - 16);
  return vec3(float(int(bits << 28) >> 28), float(int(bits << 24) >> 28), float(int(bits << 20) >> 28)) * scale;
}
// An exact unit (attribute_units.hpp: word 1 kExactNormalAxes) holds its slots' values behind the units.
const uint kExactNormalAxes = 61440u;
vec3 unitNormal(uint start, uint unitSlot) {
  if (words[start + 1u] == kExactNormalAxes)
    return decodeNormal(words[start + words[start] + uint(bitCount(words[start + 2u] & ((1u << unitSlot) - 1u)))]);
  const float selectorValue[4] = float[4](-1.0, -1.0 / 3.0, 1.0 / 3.0, 1.0);
  uint selector = (words[start + 2u + unitSlot / 8u] >> (4u * (unitSlot % 8u))) & 15u;
  vec3 nb = cubePoint(words[start]);
  precise vec3 n = nb + selectorValue[selector & 3u] * axisVector(words[start + 1u] & 65535u) +
                   selectorValue[selector >> 2] * axisVector(words[start + 1u] >> 16);
  float length2 = dot(n, n);
  if (!(length2 > 0.0) || isinf(length2) || isnan(length2)) return normalize(nb);
  return normalize(n);
}

uint hitAttribute(Hit hit, uint type) {
  uint value;
  if (shownAttribute(hit.parent, hit.childSlot, type, value)) return value;
  for (int s = hit.scale + 1; s < kScaleMax; ++s)
    if (shownAttribute(pathParent[s], pathSlot[s], type, value)) return value;
  return rootValue(P.rootSlot, type);
}

// A pair without a unit shows its children with their parent's value: that of the nearest ancestor whose
// pair holds a unit (its first word and the ancestor's unit slot), else the root's (false)
// (SiblingAttribute::inheritedFromUnits).
bool ancestorUnit(Hit hit, uint type, uint unitWords, out uint start, out uint unitSlot) {
  uint pairHalf;
  for (int s = hit.scale + 1; s < kScaleMax; ++s) {
    if (unitOf(pathParent[s], type, unitWords, start, pairHalf) == kUnit) {
      unitSlot = pairHalf * 8u + pathSlot[s];
      return true;
    }
  }
  return false;
}

vec3 hitColor(Hit hit) {
  uint start, pairHalf, unitSlot;
  int found = unitOf(hit.parent, kColorUnits, 2u, start, pairHalf);
  if (found == kUnit) return unitColor(start, pairHalf * 8u + hit.childSlot);
  if (found == kNoAttachment) return decodeColor(hitAttribute(hit, kColor));
  if (ancestorUnit(hit, kColorUnits, 2u, start, unitSlot)) return unitColor(start, unitSlot);
  return decodeColor(rootValue(P.rootSlot, kColorUnits));
}
vec3 hitNormal(Hit hit) {
  uint start, pairHalf, unitSlot;
  int found = unitOf(hit.parent, kNormalUnits, 4u, start, pairHalf);
  if (found == kUnit) return unitNormal(start, pairHalf * 8u + hit.childSlot);
  if (found == kNoAttachment) return decodeNormal(hitAttribute(hit, kNormal));
  if (ancestorUnit(hit, kNormalUnits, 4u, start, unitSlot)) return unitNormal(start, unitSlot);
  return decodeNormal(rootValue(P.rootSlot, kNormalUnits));
}

// The renderer's estimateNormal: the nearest cube face, or the contour slab when nearer.
vec3 estimateNormal(Hit hit, bool contours) {
  precise float size = ldexp(1.0, hit.scale - kScaleMax);
  precise vec3 rel = (hit.position - hit.cubeMin) / size;
  int axis = 0;
  precise float faceDistance = 1.0 / 0.0;
  float sgn = 1.0;
  for (int i = 0; i < 3; ++i) {
    precise float low = rel[i], high = 1.0 - rel[i];
    if (low < faceDistance) faceDistance = low, axis = i, sgn = -1.0;
    if (high < faceDistance) faceDistance = high, axis = i, sgn = 1.0;
  }
  vec3 normal = vec3(0.0);
  normal[axis] = sgn;
  uint contourBits = contourWord(hit.parent);
  uint mask = contourBits & 255u;
  if (contours && ((mask >> hit.childSlot) & 1u) != 0u) {
    uint c = words[2u * hit.parent + (contourBits >> 8) + uint(childRank(mask, hit.childSlot))];
    vec3 n = decodeContourNormal(c);
    precise float len = length(n);
    if (len > 0.0) {
      precise float offset = dot(n, rel - 0.5) - contourPosition(c);
      precise float slabDistance = abs(abs(offset) - 0.5 * contourThickness(c)) / len;
      if (slabDistance < faceDistance) normal = n / len * (offset < 0.0 ? -1.0 : 1.0);
    }
  }
  return normal;
}

vec3 shadePhong(vec3 albedo, vec3 n, vec3 viewDirection, vec3 lightDirection) {
  if (dot(n, viewDirection) > 0.0) n = -n;
  precise float diffuse = max(0.0, dot(n, -lightDirection));
  precise vec3 reflected = reflect(lightDirection, n);
  precise float specular = max(0.0, dot(reflected, -viewDirection));
  for (int i = 0; i < kShininessLog2; ++i) specular *= specular;
  return albedo * (kAmbient + kDiffuse * diffuse) + vec3(kSpecular * specular);
}

// ---------------------------------------------------------------------------------------------------------
// The beam pass (sec. 6.2) of client/src/beam.cpp, once per 8 x 8 tile (the ray pass's work group): a
// front-to-back walk keeping the cubes that meet the tile's beam, in double precision, whose nearest stop
// bounds every ray of the tile from below.
const double kEdgeMarginPixels = 1.0lf / 64.0lf;
const double kCubeMargin = 1.0lf / 1048576.0lf;
const double kStartMargin = 1.0lf / 1024.0lf;
const double kLodSafety = 2.0lf;

dvec3 pixelDirection(double x, double y) {  // Camera::pixelRay
  double sx = (2.0lf * (x + 0.5lf) / double(P.width) - 1.0lf) * P.tanHalf * P.aspect;
  double sy = (1.0lf - 2.0lf * (y + 0.5lf) / double(P.height)) * P.tanHalf;
  dvec3 world = P.forward.xyz + sx * P.right.xyz + sy * P.up.xyz;
  return world / sqrt(dot(world, world));
}

dvec3 beamEye;
dvec3 beamInward[4];

bool meetsBeam(dvec3 lo, double size) {
  for (int i = 0; i < 4; ++i) {
    dvec3 n = beamInward[i];
    dvec3 p = dvec3(n.x > 0.0lf ? lo.x + size : lo.x, n.y > 0.0lf ? lo.y + size : lo.y,
                    n.z > 0.0lf ? lo.z + size : lo.z);
    if (dot(n, p - beamEye) < 0.0lf) return false;
  }
  return true;
}

double nearestDistance(dvec3 lo, double size) {
  dvec3 below = max(lo - beamEye, dvec3(0.0lf)), above = max(beamEye - (lo + size), dvec3(0.0lf));
  dvec3 v = below + above;
  return sqrt(dot(v, v));
}
double furthestDistance(dvec3 lo, double size) {
  dvec3 v = max(abs(beamEye - lo), abs(lo + size - beamEye));
  return sqrt(dot(v, v));
}

struct BeamEntry {
  uint descriptor;
  dvec3 lo;
  double size, nearest;
};

float castBeam(uvec2 tileMin, uvec2 tileEnd) {
  double m = 0.5lf + kEdgeMarginPixels;
  double x0 = double(tileMin.x) - m, x1 = double(tileEnd.x) - 1.0lf + m;
  double y0 = double(tileMin.y) - m, y1 = double(tileEnd.y) - 1.0lf + m;
  dvec3 corner[4] = dvec3[4](pixelDirection(x0, y0), pixelDirection(x1, y0), pixelDirection(x1, y1),
                             pixelDirection(x0, y1));
  dvec3 centre = pixelDirection(0.5lf * (x0 + x1), 0.5lf * (y0 + y1));
  beamEye = dvec3(P.origin.xyz);
  for (int i = 0; i < 4; ++i) {
    dvec3 n = cross(corner[i], corner[(i + 1) % 4]);
    if (dot(n, centre) < 0.0lf) n = -n;
    beamInward[i] = n;
  }
  double tilePixels = double(max(tileEnd.x - tileMin.x, tileEnd.y - tileMin.y));
  double stopSlope = max(tilePixels * P.pixelAngle, kLodSafety * double(P.footprintSlope) * P.sceneSize);

  BeamEntry stack[8 * kScaleMax];
  int top = 0;
  double best = 1.0lf / 0.0lf;
  dvec3 rootLo = dvec3(1.0lf - kCubeMargin);
  double rootSize = 1.0lf + 2.0lf * kCubeMargin;
  if (!meetsBeam(rootLo, rootSize)) return 1.0 / 0.0;
  stack[top++] = BeamEntry(P.rootSlot, dvec3(1.0lf), 1.0lf, nearestDistance(rootLo, rootSize));
  while (top > 0) {
    BeamEntry e = stack[--top];
    if (e.nearest >= best) continue;
    uint topo = topology(e.descriptor);
    uint valid = validMask(topo), nonLeaf = nonLeafMask(topo);
    double half_ = 0.5lf * e.size;
    BeamEntry children[8];
    int count = 0;
    for (uint slot = 0u; slot < 8u; ++slot) {
      if (((valid >> slot) & 1u) == 0u) continue;
      dvec3 lo = e.lo + half_ * dvec3(double(slot & 1u), double((slot >> 1) & 1u), double((slot >> 2) & 1u));
      dvec3 grownLo = lo - kCubeMargin;
      double grownSize = half_ + 2.0lf * kCubeMargin;
      if (!meetsBeam(grownLo, grownSize)) continue;
      double nearest = nearestDistance(grownLo, grownSize);
      if (nearest >= best) continue;
      bool leaf = true;
      uint child = 0u;
      if (((nonLeaf >> slot) & 1u) != 0u) {
        uint run = e.descriptor + (topo >> 17);
        if (isFar(topo)) run = uint(int(run) + int(words[2u * run]));
        child = followLink(run + uint(childRank(nonLeaf, slot)));
        leaf = isStub(child);
      }
      if (leaf || half_ <= stopSlope * furthestDistance(grownLo, grownSize)) {
        best = nearest;
        continue;
      }
      children[count++] = BeamEntry(child, lo, half_, nearest);
    }
    // Furthest first on the stack, so the nearest child is walked next (insertion sort of at most 8).
    for (int i = 1; i < count; ++i)
      for (int j = i; j > 0 && children[j - 1].nearest < children[j].nearest; --j) {
        BeamEntry t = children[j - 1];
        children[j - 1] = children[j];
        children[j] = t;
      }
    for (int i = 0; i < count; ++i)
      if (children[i].nearest < best) stack[top++] = children[i];
  }
  return isinf(best) ? 1.0 / 0.0 : float(best * P.sceneSize * (1.0lf - kStartMargin));
}

// The beam pass's result per 8 x 8 tile, row by row: written by this shader compiled with SVO_BEAM_PASS (one
// invocation per tile, so the walks run side by side), read by the ray pass (one work group per tile).
layout(std430, binding = 3) buffer TileStarts { float tileStarts[]; };
const uint kTileSide = 8u;

#ifdef SVO_BEAM_PASS
void main() {
  uvec2 tile = gl_GlobalInvocationID.xy;
  uvec2 tiles = (uvec2(P.width, P.height) + kTileSide - 1u) / kTileSide;
  if (tile.x >= tiles.x || tile.y >= tiles.y) return;
  uvec2 tileMin = tile * kTileSide;
  tileStarts[tile.y * tiles.x + tile.x] = castBeam(tileMin, min(tileMin + kTileSide, uvec2(P.width, P.height)));
}
#else
void main() {
  uvec2 pixel = gl_GlobalInvocationID.xy;
  bool beam = (P.flags & 8u) != 0u;
  if (pixel.x >= P.width || pixel.y >= P.height) return;
  uint index = pixel.y * P.width + pixel.x;
  // Camera::pixelRay, in double precision; the octree direction is the world one / size (t in world units).
  vec3 direction = vec3(pixelDirection(double(pixel.x), double(pixel.y)) / P.sceneSize);
  bool contours = (P.flags & 1u) != 0u;
  Hit hit;
  hit.hit = false, hit.iterations = 0;
  uint tilesX = (P.width + kTileSide - 1u) / kTileSide;
  float tStart = beam ? tileStarts[gl_WorkGroupID.y * tilesX + gl_WorkGroupID.x] : 0.0;
  // A tile whose beam meets nothing casts no ray.
  if (!isinf(tStart)) hit = castRay(P.origin.xyz, direction, tStart, P.footprintSlope, contours);
  PixelOut out_;
  out_.color = vec4(P.background.rgb, 0.0);
  out_.depth = 1.0 / 0.0;
  out_.voxelPixels = 0.0;
  out_.hitSlot = 0xffffffffu;
  out_.scaleIterations = uint(min(hit.iterations, 65535)) << 16;
  if (hit.hit) {
    vec3 viewDirection = normalize(direction);
    vec3 albedo = (P.flags & 2u) != 0u ? hitColor(hit) : vec3(kNeutralGreyAlbedo);
    vec3 n = (P.flags & 4u) != 0u ? hitNormal(hit) : estimateNormal(hit, contours);
    out_.color = vec4(shadePhong(albedo, n, viewDirection, P.light.xyz), 1.0);
    out_.depth = hit.t;
    out_.voxelPixels = float(double(ldexp(1.0, hit.scale - kScaleMax)) * P.sceneSize /
                             (double(hit.t) * P.pixelAngle));
    out_.hitSlot = hit.parent * 8u + hit.childSlot;
    out_.scaleIterations |= uint(hit.scale) | (hit.leaf ? 0u : 256u);
  }
  pixels[index] = out_;
}
#endif
