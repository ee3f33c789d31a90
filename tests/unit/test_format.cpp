// Bit packing of the ESVO encodings (store/format.hpp) checked against the documented bit layouts, decoded
// here by hand (shifts and sign extension written out), and against analytic bounds for the quantized
// encodings.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <random>
#include <set>

#include <glm/geometric.hpp>

#include "svo/store/format.hpp"

namespace {

// Sign-extends the low `bits` bits of v.
int signExtend(std::uint32_t v, int bits) {
  const std::uint32_t m = 1u << (bits - 1);
  v &= (1u << bits) - 1u;
  return int(v ^ m) - int(m);
}

// Angle between two vectors, accurate near zero (atan2 of |cross| and dot), radians.
double angleBetween(const glm::dvec3& a, const glm::dvec3& b) {
  return std::atan2(glm::length(glm::cross(a, b)), glm::dot(a, b));
}

glm::dvec3 randomUnit(std::mt19937_64& rng) {
  std::normal_distribution<double> g;
  for (;;) {
    const glm::dvec3 v(g(rng), g(rng), g(rng));
    const double l = glm::length(v);
    if (l > 1e-6) return v / l;
  }
}

// Largest angle the cube-point normal encoding can lose: a face coordinate in [-1, 1] stored with 15 (u) or
// 14 (v) bits has a step of 2 / (2^bits - 1), so rounding moves it by at most half a step. The point on the
// face is at distance >= 1 from the origin, so the direction moves by at most |displacement| radians. A few
// float ulps (1e-6) cover the float arithmetic of the encoder and decoder.
const double kNormalAngleBound =
    std::sqrt(std::pow(1.0 / ((1 << 15) - 1), 2) + std::pow(1.0 / ((1 << 14) - 1), 2)) + 1e-6;

}  // namespace

// ---------------------------------------------------------------------------------------------------------
// Constants

TEST(Format, Constants) {
  EXPECT_EQ(svo::kPageBytes, 8192u);
  EXPECT_EQ(svo::kSlotBytes, 8u);
  EXPECT_EQ(svo::kSlotsPerPage, 1024u);
  EXPECT_EQ(svo::kMaxNearPointer, 0x7FFFu);
  EXPECT_EQ(svo::kMaxWordPointer, 0xFFFFFFu);
  EXPECT_EQ(sizeof(svo::ChildDescriptor), 8u);
  EXPECT_EQ(sizeof(svo::AttributeLookup), 4u);
}

// ---------------------------------------------------------------------------------------------------------
// Child descriptor (Fig. 2): word 0 = [31:17] child pointer, [16] far, [15:8] valid, [7:0] leaf;
// word 1 = [31:8] contour pointer, [7:0] contour mask.

namespace {
void checkDescriptor(std::uint32_t ptr, bool far, std::uint8_t valid, std::uint8_t leaf, std::uint32_t cptr,
                     std::uint8_t cmask) {
  const svo::ChildDescriptor d = svo::ChildDescriptor::make(ptr, far, valid, leaf, cptr, cmask);
  // Independent reading of the two words, bit by bit.
  EXPECT_EQ((d.topology >> 17) & 0x7FFFu, ptr);
  EXPECT_EQ((d.topology >> 16) & 1u, far ? 1u : 0u);
  EXPECT_EQ((d.topology >> 8) & 0xFFu, valid);
  EXPECT_EQ(d.topology & 0xFFu, leaf);
  EXPECT_EQ(d.contour >> 8, cptr);
  EXPECT_EQ(d.contour & 0xFFu, cmask);
  // Accessors.
  EXPECT_EQ(d.childPointer(), ptr);
  EXPECT_EQ(d.far(), far);
  EXPECT_EQ(d.validMask(), valid);
  EXPECT_EQ(d.leafMask(), leaf);
  EXPECT_EQ(d.nonLeafMask(), std::uint8_t(valid & ~leaf));
  EXPECT_EQ(d.contourPointer(), cptr);
  EXPECT_EQ(d.contourMask(), cmask);
  // In memory: word 0 first (the descriptor is two 32-bit words, topology then contour).
  std::uint32_t words[2];
  std::memcpy(words, &d, sizeof words);
  EXPECT_EQ(words[0], d.topology);
  EXPECT_EQ(words[1], d.contour);
}
}  // namespace

TEST(Format, ChildDescriptorLimits) {
  for (std::uint32_t ptr : {0u, 1u, 2u, 0x4000u, 0x7FFEu, 0x7FFFu})
    for (bool far : {false, true})
      for (std::uint32_t cptr : {0u, 1u, 0x800000u, 0xFFFFFEu, 0xFFFFFFu})
        checkDescriptor(ptr, far, 0xFF, 0x00, cptr, 0xFF);
  // Every valid / leaf / contour mask (leaf mask a subset of valid, as a well-formed tree has it; any bits
  // are carried unchanged anyway).
  for (int valid = 0; valid < 256; ++valid)
    for (int leaf = 0; leaf < 256; leaf += 17) checkDescriptor(0x7FFF, true, valid, leaf, 0xFFFFFF, valid);
  // All-ones and all-zeros words.
  const svo::ChildDescriptor ones = svo::ChildDescriptor::make(0x7FFF, true, 0xFF, 0xFF, 0xFFFFFF, 0xFF);
  EXPECT_EQ(ones.topology, 0xFFFFFFFFu);
  EXPECT_EQ(ones.contour, 0xFFFFFFFFu);
  const svo::ChildDescriptor zero = svo::ChildDescriptor::make(0, false, 0, 0, 0, 0);
  EXPECT_EQ(zero.topology, 0u);
  EXPECT_EQ(zero.contour, 0u);
}

TEST(Format, ChildDescriptorRandom) {
  std::mt19937_64 rng(1);
  for (int i = 0; i < 100000; ++i) {
    const std::uint64_t r = rng();
    checkDescriptor(std::uint32_t(r & 0x7FFF), (r >> 15) & 1, std::uint8_t(r >> 16), std::uint8_t(r >> 24),
                    std::uint32_t((r >> 32) & 0xFFFFFF), std::uint8_t(r >> 56));
    if (HasFailure()) break;
  }
}

TEST(Format, ChildRank) {
  for (int mask = 0; mask < 256; ++mask)
    for (int slot = 0; slot < 8; ++slot) {
      int count = 0;
      for (int s = 0; s < slot; ++s) count += (mask >> s) & 1;
      ASSERT_EQ(svo::childRank(std::uint8_t(mask), slot), count) << "mask " << mask << " slot " << slot;
    }
}

// ---------------------------------------------------------------------------------------------------------
// Contours (Fig. 4): [6:0] thickness (unsigned), [13:7] position (signed), [19:14] nz, [25:20] ny, [31:26]
// nx.

namespace {
void checkContourDecode(std::uint32_t bits) {
  const int nx = signExtend(bits >> 26, 6), ny = signExtend(bits >> 20, 6), nz = signExtend(bits >> 14, 6);
  const int pos = signExtend(bits >> 7, 7);
  const int th = int(bits & 127u);
  const svo::Contour c = svo::decodeContour(bits);
  // Decoded values vs. the integer fields scaled by the documented steps; 1e-6 is a few float ulps.
  EXPECT_NEAR(c.normal.x, nx / 31.0, 1e-6) << std::hex << bits;
  EXPECT_NEAR(c.normal.y, ny / 31.0, 1e-6) << std::hex << bits;
  EXPECT_NEAR(c.normal.z, nz / 31.0, 1e-6) << std::hex << bits;
  EXPECT_NEAR(c.position, pos * (1.5 / 63.0), 1e-6) << std::hex << bits;
  EXPECT_NEAR(c.thickness, th * (3.0 / 127.0), 1e-6) << std::hex << bits;
  // Packing the fields again gives the same bits.
  EXPECT_EQ(svo::packContourBits(nx, ny, nz, pos, th), bits);
}
}  // namespace

TEST(Format, ContourFieldsRoundTrip) {
  // Extremes of every field: normals -32..31, position -64..63, thickness 0..127.
  for (int n : {-32, -31, -1, 0, 1, 31})
    for (int pos : {-64, -63, -1, 0, 1, 63})
      for (int th : {0, 1, 126, 127}) {
        const std::uint32_t bits = svo::packContourBits(n, -n - 1, n / 2, pos, th);
        EXPECT_EQ(signExtend(bits >> 26, 6), n);
        EXPECT_EQ(signExtend(bits >> 20, 6), -n - 1);
        EXPECT_EQ(signExtend(bits >> 14, 6), n / 2);
        EXPECT_EQ(signExtend(bits >> 7, 7), pos);
        EXPECT_EQ(int(bits & 127u), th);
        checkContourDecode(bits);
      }
  for (std::uint32_t bits : {0u, 0xFFFFFFFFu, 0x80000000u, 0x7FFFFFFFu, 0x00002000u, 0x0000007Fu, 0xFC000000u,
                             0x02000000u, 0x00080000u})
    checkContourDecode(bits);
  std::mt19937 rng(2);
  for (int i = 0; i < 100000 && !HasFailure(); ++i) checkContourDecode(std::uint32_t(rng()));
}

TEST(Format, QuantizeContourNormal) {
  std::mt19937_64 rng(3);
  std::vector<glm::dvec3> normals = {{1, 0, 0},  {-1, 0, 0},           {0, 1, 0},    {0, -1, 0},
                                     {0, 0, 1},  {0, 0, -1},           {1, 1, 1},    {-1, 1, -1},
                                     {1, -1, 0}, {1e-300, 0, -1e-300}, {3, 1e-9, 0}, {1e6, -2e6, 5e5}};
  for (int i = 0; i < 100000; ++i)
    normals.push_back(randomUnit(rng) * std::exp2(double(int(rng() % 40) - 20)));
  for (const glm::dvec3& n : normals) {
    const glm::ivec3 q = svo::quantizeContourNormal(n);
    const glm::dvec3 a = glm::abs(n);
    const double largest = std::max({a.x, a.y, a.z});
    // Largest component at +-31, with the sign of the input's largest component.
    EXPECT_EQ(std::max({std::abs(q.x), std::abs(q.y), std::abs(q.z)}), 31) << n.x << " " << n.y << " " << n.z;
    for (int k = 0; k < 3; ++k) {
      // Each component is the nearest integer to n * 31 / largest (0.5 + rounding slack).
      EXPECT_LE(std::abs(q[k] - n[k] * 31.0 / largest), 0.5 + 1e-9) << n.x << " " << n.y << " " << n.z;
      if (a[k] == largest) {
        EXPECT_EQ(q[k], n[k] > 0 ? 31 : -31);
      }
    }
    if (HasFailure()) break;
  }
}

// Conservative encoding: the decoded slab (as the ray caster decodes it, floats) contains [lo, hi].
TEST(Format, EncodeContourIsConservative) {
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const double ps = 1.5 / 63.0, ts = 3.0 / 127.0;
  int accepted = 0, rejected = 0;
  for (int i = 0; i < 100000; ++i) {
    const glm::ivec3 q = svo::quantizeContourNormal(randomUnit(rng));
    // Projections of the voxel cube u in [-1/2, 1/2]^3 onto n = q / 31 span [-w/2, w/2].
    const double w = (std::abs(q.x) + std::abs(q.y) + std::abs(q.z)) / 31.0;
    double lo, hi;
    switch (i % 8) {
      case 0:
        lo = hi = (uni(rng) - 0.5) * w;
        break;  // a plane
      case 1:
        lo = -0.5 * w, hi = 0.5 * w;
        break;  // the whole cube
      case 2:
        lo = hi = 0.5 * w;
        break;  // a corner plane
      case 3:
        lo = hi = -0.5 * w;
        break;
      case 4:
        lo = -0.5 * w, hi = lo + uni(rng) * 0.1 * w;
        break;  // thin, at the edge
      default: {
        double a = (uni(rng) - 0.5) * w, b = (uni(rng) - 0.5) * w;
        lo = std::min(a, b), hi = std::max(a, b);
        if (i % 8 == 5) hi = lo + (hi - lo) * 0.05;  // thin anywhere
      }
    }
    std::uint32_t bits = 0;
    if (svo::encodeContour(q, lo, hi, bits)) {
      ++accepted;
      const svo::Contour c = svo::decodeContour(bits);
      EXPECT_EQ(glm::ivec3(glm::round(glm::dvec3(c.normal) * 31.0)), q);
      const double p = c.position, half = 0.5 * double(c.thickness);
      EXPECT_LE(p - half, lo) << "slab does not contain lo; q " << q.x << " " << q.y << " " << q.z;
      EXPECT_GE(p + half, hi) << "slab does not contain hi; q " << q.x << " " << q.y << " " << q.z;
      // Narrower than the cube (else it should not be stored).
      EXPECT_LT(double(c.thickness), w);
      // Not gratuitously wide: the width can exceed hi - lo only by the rounding of the centre (one position
      // step) and of the width (one thickness step).
      EXPECT_LE(double(c.thickness), (hi - lo) + ps + ts + 1e-6);
    } else {
      ++rejected;
      // Rejected only when even the best quantized slab is about as wide as the cube.
      EXPECT_GE(hi - lo, w - ps - 2.0 * ts - 1e-9) << "rejected a slab much narrower than the cube";
    }
    if (HasFailure()) break;
  }
  EXPECT_GT(accepted, 0);
  EXPECT_GT(rejected, 0);
}

// ---------------------------------------------------------------------------------------------------------
// Colors: ABGR, R in the low byte.

TEST(Format, ColorBytes) {
  const std::uint32_t c = svo::packABGR(0x11, 0x22, 0x33, 0x44);
  unsigned char bytes[4];
  std::memcpy(bytes, &c, 4);  // little-endian host (x86-64, aarch64)
  EXPECT_EQ(bytes[0], 0x11);
  EXPECT_EQ(bytes[1], 0x22);
  EXPECT_EQ(bytes[2], 0x33);
  EXPECT_EQ(bytes[3], 0x44);
  EXPECT_EQ(svo::packABGR(1, 2, 3), 0xFF030201u);  // default alpha 255
}

TEST(Format, ColorRoundTrip) {
  // Every 8-bit value in every channel decodes to value / 255 and encodes back to itself.
  for (int v = 0; v < 256; ++v) {
    for (int ch = 0; ch < 4; ++ch) {
      std::uint8_t rgba[4] = {7, 100, 200, 255};
      rgba[ch] = std::uint8_t(v);
      const std::uint32_t bits = svo::packABGR(rgba[0], rgba[1], rgba[2], rgba[3]);
      const glm::vec4 d = svo::decodeColor(bits);
      for (int k = 0; k < 4; ++k) EXPECT_NEAR(d[k], rgba[k] / 255.0, 1e-7);
      EXPECT_EQ(svo::encodeColor(d), bits);
    }
  }
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  for (int i = 0; i < 100000; ++i) {
    const std::uint32_t bits = std::uint32_t(rng());
    ASSERT_EQ(svo::encodeColor(svo::decodeColor(bits)), bits);
    const glm::vec4 c(uni(rng), uni(rng), uni(rng), uni(rng));
    const glm::vec4 d = svo::decodeColor(svo::encodeColor(c));
    // Rounding to the nearest of 256 levels: half a step (plus float slack).
    for (int k = 0; k < 4; ++k) ASSERT_LE(std::abs(d[k] - c[k]), 0.5 / 255.0 + 1e-6);
  }
  // Out of range clamps.
  EXPECT_EQ(svo::encodeColor(glm::vec4(-0.5f, 1.5f, -1e30f, 1e30f)), svo::packABGR(0, 255, 0, 255));
  EXPECT_EQ(svo::encodeColor(glm::vec4(0.0f, 1.0f, 0.5f / 255.0f - 1e-4f, 254.5f / 255.0f + 1e-4f)),
            svo::packABGR(0, 255, 0, 255));
}

// ---------------------------------------------------------------------------------------------------------
// Normals as points on the unit cube.

namespace {
void checkNormal(const glm::dvec3& n, int expectFace = -1) {
  const std::uint32_t bits = svo::encodeNormal(glm::vec3(n));
  const glm::vec3 d = svo::decodeNormal(bits);
  EXPECT_NEAR(glm::length(glm::dvec3(d)), 1.0, 1e-6);
  const double angle = angleBetween(glm::normalize(n), glm::dvec3(d));
  EXPECT_LE(angle, kNormalAngleBound)
      << "n " << n.x << " " << n.y << " " << n.z << " bits " << std::hex << bits;
  const std::uint32_t face = bits >> 29;
  EXPECT_LE(face, 5u);
  if (expectFace >= 0) {
    EXPECT_EQ(int(face), expectFace) << "n " << n.x << " " << n.y << " " << n.z;
  }
  // Decoding then encoding again is a fixed point up to one code in u and v (float rounding of the decoded
  // unit vector), on the same face unless the point sits on a cube edge.
  const std::uint32_t again = svo::encodeNormal(d);
  if ((again >> 29) == face) {
    EXPECT_LE(std::abs(int((again >> 14) & 0x7FFF) - int((bits >> 14) & 0x7FFF)), 1);
    EXPECT_LE(std::abs(int(again & 0x3FFF) - int(bits & 0x3FFF)), 1);
  }
}
}  // namespace

TEST(Format, NormalAxesAndFaces) {
  for (int axis = 0; axis < 3; ++axis)
    for (int neg = 0; neg < 2; ++neg) {
      glm::dvec3 n(0.0);
      n[axis] = neg ? -1.0 : 1.0;
      checkNormal(n, axis * 2 + neg);
      const glm::vec3 d = svo::decodeNormal(svo::encodeNormal(glm::vec3(n)));
      // The axis comes back as the dominant component with the right sign.
      EXPECT_GT(std::abs(d[axis]), 0.999999f);
      EXPECT_EQ(d[axis] < 0.0f, bool(neg));
      // Random vectors well inside each face's cone land on that face.
      std::mt19937_64 rng(6 + axis * 2 + neg);
      std::uniform_real_distribution<double> uni(-0.95, 0.95);
      for (int i = 0; i < 20000 && !HasFailure(); ++i) {
        glm::dvec3 v;
        v[axis] = neg ? -1.0 : 1.0;
        v[(axis + 1) % 3] = uni(rng);
        v[(axis + 2) % 3] = uni(rng);
        checkNormal(v * (0.5 + 4.0 * std::abs(uni(rng))), axis * 2 + neg);
      }
    }
}

TEST(Format, NormalRandomRoundTrip) {
  std::mt19937_64 rng(7);
  for (int i = 0; i < 100000 && !HasFailure(); ++i) checkNormal(randomUnit(rng));
}

TEST(Format, NormalEdgesAndCorners) {
  for (int x = -1; x <= 1; ++x)
    for (int y = -1; y <= 1; ++y)
      for (int z = -1; z <= 1; ++z) {
        if (x == 0 && y == 0 && z == 0) continue;
        checkNormal(glm::dvec3(x, y, z));
        // Just off the edge or corner, on either side.
        for (double e : {1e-7, -1e-7, 1e-4, -1e-4}) {
          checkNormal(glm::dvec3(x + e, y, z));
          checkNormal(glm::dvec3(x, y - e, z + e));
        }
      }
  // Extreme face coordinates u, v = +-1 exactly and next to it.
  checkNormal({1.0, 1.0, -1.0});
  checkNormal({1.0, 0.9999999, -0.9999999});
  checkNormal({-1.0, -1.0, 0.0});
  // Tiny and huge magnitudes give the same direction.
  checkNormal({1e-30, 2e-30, -3e-30});
  checkNormal({1e30, -2e30, 3e30});
}

// ---------------------------------------------------------------------------------------------------------
// The store's normal lattice: 16-bit octahedral codes.

// Every lattice point survives the store's round trip (cube bits -> code -> cube bits), so the store keeps
// normals in two bytes without loss; and the codes are unit directions.
TEST(Format, LatticeNormalsRoundTripThroughTheirCodes) {
  std::set<std::uint32_t> distinct;
  for (std::uint32_t code = 0; code < (1u << (2 * svo::kOctNormalBits)); ++code) {
    const std::uint32_t bits = svo::latticeNormalBits(std::uint16_t(code));
    ASSERT_EQ(svo::latticeNormalBits(svo::octNormalCodeOf(bits)), bits) << "code " << code;
    ASSERT_NEAR(glm::length(svo::octNormalDirection(std::uint16_t(code))), 1.0f, 1e-6f);
    distinct.insert(bits);
  }
  // -128 repeats -1 (2 * 256 - 1 codes), and the folded square's rim names some directions twice.
  EXPECT_LT(distinct.size(), (1u << 16) - 511u);
  EXPECT_GT(distinct.size(), (1u << 16) - 2 * 511u);
}

// Rounding onto the lattice moves a direction by less than a degree (the steps are 0.7 degrees at most), is
// idempotent, and keeps the axes exactly.
TEST(Format, LatticeNormalErrorIsUnderADegree) {
  std::mt19937_64 rng(8);
  double worst = 0.0;
  for (int i = 0; i < 200000; ++i) {
    const glm::dvec3 n = randomUnit(rng);
    const std::uint32_t bits = svo::latticeNormal(glm::vec3(n));
    worst = std::max(worst, angleBetween(n, glm::dvec3(svo::decodeNormal(bits))));
    ASSERT_EQ(svo::latticeNormal(svo::decodeNormal(bits)), bits);
  }
  EXPECT_LT(worst, 1.0 * 3.14159265358979 / 180.0);
  EXPECT_GT(worst, 0.5 * 3.14159265358979 / 180.0);  // it does round: 8 bits are not 29
  for (int x = -1; x <= 1; ++x)
    for (int y = -1; y <= 1; ++y)
      for (int z = -1; z <= 1; ++z) {
        if (x == 0 && y == 0 && z == 0) continue;
        const glm::dvec3 n = glm::normalize(glm::dvec3(x, y, z));
        // The axes lie on lattice points (flat walls and floors keep their normals, up to the cube
        // encoding's own half step, 7e-5 rad); the rest within a lattice step.
        const bool axis = std::abs(x) + std::abs(y) + std::abs(z) == 1;
        const double bound = axis ? 1e-4 : 0.7 * 3.14159265358979 / 180.0;
        EXPECT_LE(angleBetween(n, glm::dvec3(svo::decodeNormal(svo::latticeNormal(glm::vec3(n))))), bound)
            << x << " " << y << " " << z;
      }
}

// ---------------------------------------------------------------------------------------------------------
// Attribute lookup entries (Fig. 7c): [7:0] mask, [31:8] value pointer.

TEST(Format, AttributeLookup) {
  for (std::uint32_t vp : {0u, 1u, 0x123456u, 0xFFFFFEu, 0xFFFFFFu})
    for (int mask = 0; mask < 256; ++mask) {
      const svo::AttributeLookup a = svo::AttributeLookup::make(vp, std::uint8_t(mask));
      EXPECT_EQ(a.bits & 0xFFu, std::uint32_t(mask));
      EXPECT_EQ(a.bits >> 8, vp);
      EXPECT_EQ(a.mask(), mask);
      EXPECT_EQ(a.valuePointer(), vp);
    }
}
