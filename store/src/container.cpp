#include "svo/store/container.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <cstring>
#include <functional>
#include <map>
#include <stdexcept>
#include <string>
#include <system_error>
#include <type_traits>
#include <vector>

#include <fcntl.h>
#include <unistd.h>
#include <xxhash.h>
#include <zstd.h>
#include <glm/common.hpp>

namespace svo {
namespace {

// zstd level for slices: fast to write, decompresses at GB/s (zstd manual: levels 1-3 are the fast range).
constexpr int kZstdLevel = 3;
// Smallest slice size accepted: below this the per-slice header and directory entry dominate.
constexpr std::uint32_t kMinSliceBytes = 256;
// Largest decoded slice a reader accepts: a cube that cannot split further may exceed the slice size, but a
// slice claims at most one level of one cube, and 1 GiB bounds what a corrupt directory can make us allocate.
constexpr std::uint64_t kMaxSliceRawBytes = std::uint64_t(1) << 30;
constexpr std::uint32_t kSliceMagic = 0x45434c53;  // "SLCE"
// Fuzz builds skip the checksum comparisons so mutated inputs reach the decoders (tests/fuzz).
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
constexpr bool kCheckChecksums = false;
#else
constexpr bool kCheckChecksums = true;
#endif

// Fixed-size header at offset 0; little-endian, as x86-64 and the GPU both are.
struct FileHeader {
  char magic[8];
  std::uint32_t version;
  std::uint32_t headerBytes;
  double origin[3];
  double size;
  std::int32_t levels;
  float geometryError, colorError, normalError;
  std::uint32_t contours;
  std::uint32_t attachmentTypes;  // bit (type - 1) set for each attachment present
  std::uint32_t rootColor, rootNormal;
  std::uint32_t sliceBytes;
  std::uint32_t sliceCount;
  std::uint64_t directoryOffset;
  std::uint64_t directoryBytes;
  std::uint64_t directoryChecksum;  // XXH3-64 of the directory
  std::uint8_t reserved[136];       // room for later fields; zero
  std::uint64_t headerChecksum;     // XXH3-64 of every byte above
};
static_assert(sizeof(FileHeader) == 256);

// One directory record on disk.
struct DirectoryEntry {
  std::uint64_t offset;
  std::uint64_t checksum;
  std::uint32_t compressedBytes, rawBytes;
  std::int32_t cubeCoord[3];
  std::uint8_t cubeLevel, voxelLevel;
  std::uint8_t firstSlot, lastSlot;
  std::uint32_t parentCount, voxelCount, contourCount, colorCount, normalCount;
  std::uint32_t parentSlice;
};
static_assert(sizeof(DirectoryEntry) == 64);

// The head of a decoded slice; the counts must agree with the directory's and with the sections' sizes.
struct SliceHead {
  std::uint32_t magic;
  std::uint32_t parentCount, splitCount, voxelCount, contourCount, colorCount, normalCount;
  std::uint32_t attachments;  // bit 0 colors, bit 1 normals
};
static_assert(sizeof(SliceHead) == 32);

// Reads up to `bytes` at `offset` (fewer only at the end of the file); -1 on a read error (errno set).
std::int64_t readAt(int fd, std::uint64_t offset, void* out, std::size_t bytes) {
  std::size_t done = 0;
  while (done < bytes) {
    const ssize_t got = ::pread(fd, static_cast<char*>(out) + done, bytes - done, off_t(offset + done));
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) return -1;
    if (got == 0) break;
    done += std::size_t(got);
  }
  return std::int64_t(done);
}

// The directory record of a slice and back: the one place that maps SliceInfo to its on-disk form.
DirectoryEntry entryOf(const SliceInfo& s) {
  return {s.offset,
          s.checksum,
          s.compressedBytes,
          s.rawBytes,
          {s.cubeCoord.x, s.cubeCoord.y, s.cubeCoord.z},
          std::uint8_t(s.cubeLevel),
          std::uint8_t(s.voxelLevel),
          s.firstSlot,
          s.lastSlot,
          s.parentCount,
          s.voxelCount,
          s.contourCount,
          s.colorCount,
          s.normalCount,
          s.parentSlice};
}
SliceInfo sliceOf(const DirectoryEntry& e) {
  SliceInfo s;
  s.offset = e.offset;
  s.compressedBytes = e.compressedBytes;
  s.rawBytes = e.rawBytes;
  s.checksum = e.checksum;
  s.cubeCoord = {e.cubeCoord[0], e.cubeCoord[1], e.cubeCoord[2]};
  s.cubeLevel = e.cubeLevel;
  s.voxelLevel = e.voxelLevel;
  s.firstSlot = e.firstSlot;
  s.lastSlot = e.lastSlot;
  s.parentCount = e.parentCount;
  s.voxelCount = e.voxelCount;
  s.contourCount = e.contourCount;
  s.colorCount = e.colorCount;
  s.normalCount = e.normalCount;
  s.parentSlice = e.parentSlice;
  return s;
}

std::uint64_t headerChecksum(const FileHeader& h) {
  return XXH3_64bits(&h, offsetof(FileHeader, headerChecksum));
}

[[noreturn]] void fail(const std::filesystem::path& path, const std::string& what) {
  throw std::runtime_error(path.string() + ": " + what);
}

std::size_t bitBytes(std::size_t bits) {
  return (bits + 7) / 8;
}

// Format v4 value encodings: byte planes of what is left after a prediction, which zstd packs far better
// than the values (2M-triangle terrain at 13 levels, on disk: 5.13 -> 2.60 B per leaf voxel in all).
// A contour: its normal's three 6-bit fields minus those its voxel's normal predicts (mod 64; exact for 83%
// on the 20M terrain), its position minus the one its parent's contour predicts (mod 128), its thickness.
constexpr std::size_t kContourBytes = 5;
// A normal: its octahedral code minus its parent's effective normal's, per coordinate (mod 256).
constexpr std::size_t kNormalBytes = 2;
constexpr std::size_t kColorBytes = 4;  // ABGR as it is

std::size_t sliceRawBytes(const SliceHead& h) {
  std::size_t bytes = sizeof(SliceHead) + bitBytes(h.parentCount) + h.splitCount + bitBytes(h.voxelCount) +
                      kContourBytes * std::size_t(h.contourCount);
  if (h.attachments & 1u) bytes += bitBytes(h.voxelCount) + kColorBytes * std::size_t(h.colorCount);
  if (h.attachments & 2u) bytes += bitBytes(h.voxelCount) + kNormalBytes * std::size_t(h.normalCount);
  return bytes;
}

using ContourResidual = std::array<std::uint8_t, kContourBytes>;
using NormalResidual = std::array<std::uint8_t, kNormalBytes>;

// The position field (bits [13:7]) a contour of the child in `slot` is predicted to have: its parent's slab
// centre plane in the child's frame. Child units are half the parent's and its centre is a quarter of the
// parent off per axis, so with the parent's fields n (/31) and p (x 1.5/63, format.hpp) the plane
// n.u = p (1.5/63) becomes n.u' = 2 p - (21/31) sum(+-n_i) in child position steps. Integers only: the
// prediction is part of the format, so no compiler's floating point may round it differently. 0 when the
// parent has no contour. (Measured on the 20M terrain's v3 slices: the position plane 0.73 -> 0.55 B per
// leaf voxel.) Set up once per parent, asked once per child.
class ContourPositionPredictor {
 public:
  ContourPositionPredictor(bool parentHasContour, std::uint32_t parentContour) : has_(parentHasContour) {
    const ContourFields f = contourFields(parentContour);
    for (int k = 0; k < 3; ++k) normal_[k] = f.normal[k];
    twicePosition_ = 62 * f.position;
  }
  std::uint32_t operator()(int slot) const {
    if (!has_) return 0;
    int reach = 0;  // sum of +-n_i, the sign from which half of the parent the child is in
    for (int k = 0; k < 3; ++k) reach += (slot >> k & 1) ? normal_[k] : -normal_[k];
    const int numerator = twicePosition_ - 21 * reach;  // 31 x the prediction
    const int rounded = (numerator >= 0 ? numerator + 15 : numerator - 15) / 31;
    return std::uint32_t(std::clamp(rounded, -64, 63) & 127) << 7;
  }

 private:
  bool has_;
  int normal_[3];
  int twicePosition_;  // 62 p: 31 x twice the parent's position field
};

// `predicted`: the normal fields predictedContourNormalBits gives for the voxel's normal (0 in a store
// without normals) and the position field ContourPositionPredictor gives.
// Fields are differences modulo their widths (packContourBits masks them).
ContourResidual contourResidual(std::uint32_t contour, std::uint32_t predicted) {
  const ContourFields c = contourFields(contour), p = contourFields(predicted);
  ContourResidual r;
  for (int k = 0; k < 3; ++k) r[k] = std::uint8_t((c.normal[k] - p.normal[k]) & 63);
  r[3] = std::uint8_t((c.position - p.position) & 127), r[4] = std::uint8_t(c.thickness);
  return r;
}
std::uint32_t contourOf(const ContourResidual& r, std::uint32_t predicted) {
  const ContourFields p = contourFields(predicted);
  return packContourBits(r[0] + p.normal[0], r[1] + p.normal[1], r[2] + p.normal[2], r[3] + p.position, r[4]);
}
NormalResidual normalResidual(std::uint16_t code, std::uint16_t parentCode) {
  return {std::uint8_t((code >> 8) - (parentCode >> 8)), std::uint8_t(code - parentCode)};
}
std::uint16_t normalCodeOf(const NormalResidual& r, std::uint16_t parentCode) {
  return std::uint16_t(std::uint8_t(r[0] + (parentCode >> 8)) << 8 | std::uint8_t(r[1] + parentCode));
}

// octNormalCodeOf, remembering the last answer: siblings share their parent's normal and often their own.
class NormalCodes {
 public:
  std::uint16_t operator()(std::uint32_t normal) {
    if (normal != normal_) normal_ = normal, code_ = octNormalCodeOf(normal);
    return code_;
  }

 private:
  std::uint32_t normal_ = 0;
  std::uint16_t code_ = octNormalCodeOf(0);
};

static_assert(std::endian::native == std::endian::little, "slices are little-endian, as written in memory");

// Bits LSB-first, as slices store them (bit i in byte i / 8), appendable at any bit offset: a slice spanning
// several cells of an out-of-core build is assembled from each cell's part.
class Bits {
 public:
  void push(bool bit) {
    if (count_ % 64 == 0) words_.push_back(0);
    if (bit) words_.back() |= std::uint64_t(1) << (count_ % 64);
    ++count_;
  }
  void append(const Bits& other) {
    const unsigned shift = unsigned(count_ % 64);
    if (shift == 0) {
      words_.insert(words_.end(), other.words_.begin(), other.words_.end());
    } else {
      for (const std::uint64_t w : other.words_) {
        words_.back() |= w << shift;
        words_.push_back(w >> (64 - shift));
      }
    }
    count_ += other.count_;
    words_.resize((count_ + 63) / 64);  // bits past count_ are zero, so the dropped word is empty
  }
  void writeTo(std::vector<std::byte>& out) const {
    const std::size_t at = out.size();
    out.resize(at + bitBytes(count_));
    std::memcpy(out.data() + at, words_.data(), bitBytes(count_));
  }

 private:
  std::vector<std::uint64_t> words_;
  std::size_t count_ = 0;
};

// A slice's sections before they are laid out: a split bit per parent, a valid mask per split parent, then
// per new voxel a presence bit and the present values, for contours, colors and normals.
struct SliceSections {
  Bits split, contourBits, colorBits, normalBits;
  std::vector<std::uint8_t> masks;
  std::vector<ContourResidual> contours;
  std::vector<std::uint32_t> colors;
  std::vector<NormalResidual> normals;

  void append(const SliceSections& o) {
    split.append(o.split), contourBits.append(o.contourBits);
    colorBits.append(o.colorBits), normalBits.append(o.normalBits);
    masks.insert(masks.end(), o.masks.begin(), o.masks.end());
    contours.insert(contours.end(), o.contours.begin(), o.contours.end());
    colors.insert(colors.end(), o.colors.begin(), o.colors.end());
    normals.insert(normals.end(), o.normals.begin(), o.normals.end());
  }
};

// The decoded slice: head, then the sections in the order sliceRawBytes counts them.
std::vector<std::byte> layOut(const SliceHead& head, const SliceSections& s) {
  std::vector<std::byte> out(sizeof head);
  std::memcpy(out.data(), &head, sizeof head);
  out.reserve(sliceRawBytes(head));
  const auto words = [&](const std::vector<std::uint32_t>& values) {
    const std::size_t at = out.size();
    out.resize(at + 4 * values.size());
    std::memcpy(out.data() + at, values.data(), 4 * values.size());
  };
  const auto planes = [&](const auto& values) {  // byte k of every value, then byte k + 1, ...
    for (std::size_t k = 0; k < std::tuple_size_v<typename std::decay_t<decltype(values)>::value_type>; ++k)
      for (const auto& v : values) out.push_back(std::byte(v[k]));
  };
  s.split.writeTo(out);
  for (const std::uint8_t mask : s.masks) out.push_back(std::byte(mask));
  s.contourBits.writeTo(out), planes(s.contours);
  if (head.attachments & 1u) s.colorBits.writeTo(out), words(s.colors);
  if (head.attachments & 2u) s.normalBits.writeTo(out), planes(s.normals);
  // The head's counts and the sections come from different places for a slice spanning cells: never write
  // a slice whose parts disagree with its head.
  if (out.size() != sliceRawBytes(head))
    throw std::logic_error("writeStore: a slice's sections and head disagree");
  return out;
}

bool bitAt(const std::byte* bits, std::size_t i) {
  return (std::to_integer<unsigned>(bits[i / 8]) >> (i % 8)) & 1u;
}

std::uint32_t wordAt(const std::byte* words, std::size_t i) {
  std::uint32_t w;
  std::memcpy(&w, words + 4 * i, 4);
  return w;
}

// ---------------------------------------------------------------------------------------------------------
// Writing: the tree level by level in Morton (breadth-first, slot) order, where every cube of any level holds
// a contiguous range of every deeper level.

// Per level of a subtree, from its root's level down: its voxels, those with children, contours, and the
// attribute values its slices store (inheritance applied).
struct LevelTotals {
  std::uint64_t voxels = 0, splits = 0, contours = 0, colors = 0, normals = 0;
};

class StoreWriter {
 public:
  // `tree` may be a root alone (a cell of an out-of-core build without children).
  StoreWriter(const VoxelTree& tree, const StoreWriteOptions& options, const SubtreePlacement& at)
      : tree_(tree), options_(options), at_(at) {
    if (tree.voxels.empty()) throw std::invalid_argument("writeStore: the tree has no root");
    const InheritanceRule inherits(options.inheritance);
    const std::size_t n = tree.voxels.size();
    effectiveColor_.assign(n, 0), effectiveNormal_.assign(n, 0);
    storesColor_.assign(n, 0), storesNormal_.assign(n, 0);
    if (at.rootLevel < 0 || at.rootLevel >= kMaxLevels)
      throw std::invalid_argument("writeStore: a subtree's root level must be in [0, " +
                                  std::to_string(kMaxLevels) + ")");
    effectiveColor_[0] = at.rootColor, effectiveNormal_[0] = at.rootNormal;
    levels_.push_back({{0u, at.rootCoord}});
    while (true) {
      std::vector<Voxel> next;
      for (const Voxel& parent : levels_.back()) {
        const VoxelRecord& r = tree.voxels[parent.record];
        const InheritanceRule::ParentNormal parentNormal =
            tree.hasNormals && r.childMask ? inherits.parentNormal(effectiveNormal_[parent.record])
                                           : InheritanceRule::ParentNormal{};
        for (std::uint32_t c = r.firstChild, slot = 0; slot < 8; ++slot) {
          if (!(r.childMask >> slot & 1u)) continue;
          if (c >= n) throw std::invalid_argument("writeStore: a child index is out of range");
          const VoxelRecord& child = tree.voxels[c];
          effectiveColor_[c] = effectiveColor_[parent.record];
          effectiveNormal_[c] = effectiveNormal_[parent.record];
          if (tree.hasColors && !inherits.color(child.color, effectiveColor_[parent.record]))
            storesColor_[c] = 1, effectiveColor_[c] = child.color;
          if (tree.hasNormals && !inherits.normal(child.normal, parentNormal)) {
            if (latticeNormalBits(octNormalCodeOf(child.normal)) != child.normal)
              throw std::invalid_argument(
                  "writeStore: a normal is not on the store's 16-bit lattice "
                  "(round it with latticeNormal)");
            storesNormal_[c] = 1, effectiveNormal_[c] = child.normal;
          }
          next.push_back({c, childCoord(parent.coord, int(slot))});
          ++c;
        }
      }
      if (next.empty()) break;
      if (std::size_t(at.rootLevel) + levels_.size() > std::size_t(kMaxLevels))
        throw std::invalid_argument("writeStore: the tree is deeper than " + std::to_string(kMaxLevels) +
                                    " levels");
      levels_.push_back(std::move(next));
    }
    // Prefix counts per level: children before each voxel, and the voxels with each kind of payload.
    prefix_.resize(levels_.size());
    for (std::size_t l = 0; l < levels_.size(); ++l) {
      Prefix& p = prefix_[l];
      const std::size_t count = levels_[l].size();
      p.children.assign(count + 1, 0), p.splits.assign(count + 1, 0), p.contours.assign(count + 1, 0);
      p.colors.assign(count + 1, 0), p.normals.assign(count + 1, 0);
      for (std::size_t i = 0; i < count; ++i) {
        const std::uint32_t v = levels_[l][i].record;
        const VoxelRecord& r = tree.voxels[v];
        p.children[i + 1] = p.children[i] + std::uint32_t(std::popcount(unsigned(r.childMask)));
        p.splits[i + 1] = p.splits[i] + (r.childMask != 0);
        p.contours[i + 1] = p.contours[i] + r.hasContour;
        p.colors[i + 1] = p.colors[i] + storesColor_[v];
        p.normals[i + 1] = p.normals[i] + storesNormal_[v];
      }
    }
  }

  // Plans the slices (splits included) and hands each one to `sink` (see FileSink). The root's cube is the
  // first cube: a subtree's slices start one level below its root.
  template <class Sink>
  void run(Sink& sink) {
    plan({at_.rootLevel, at_.rootCoord, 0, 7}, at_.rootLevel + 1, 0, 1, at_.parentSlice, sink);
  }
  // Plans the slices from `level` on of the tree's whole cube (an out-of-core cell whose coarser levels went
  // into slices spanning several cells).
  template <class Sink>
  void runFrom(int level, std::uint32_t parentSlice, Sink& sink) {
    if (level - 1 > topLevel()) return;
    plan({at_.rootLevel, at_.rootCoord, 0, 7}, level, 0, voxelsAt(level - 1).size(), parentSlice, sink);
  }
  std::size_t voxelCount() const { return tree_.voxels.size(); }
  EffectiveAttributes effective() const { return {effectiveColor_, effectiveNormal_}; }
  // The tree's deepest level (absolute).
  int topLevel() const { return at_.rootLevel + int(levels_.size()) - 1; }
  // The tree's voxels of its deepest level, Morton order: an out-of-core top's cells.
  std::vector<std::pair<std::uint32_t, glm::ivec3>> deepestVoxels() const {
    std::vector<std::pair<std::uint32_t, glm::ivec3>> out;
    for (const Voxel& v : levels_.back()) out.push_back({v.record, v.coord});
    return out;
  }
  std::vector<LevelTotals> totals() const {
    std::vector<LevelTotals> out(levels_.size());
    for (std::size_t l = 0; l < levels_.size(); ++l) {
      const Prefix& p = prefix_[l];
      out[l] = {levels_[l].size(), p.splits.back(), p.contours.back(), p.colors.back(), p.normals.back()};
    }
    return out;
  }
  // Out of core: the levels below this tree's deepest come from cells, the voxels of that level, each with
  // its subtree's totals (`cells[i]`, its root's level first).
  void addCells(const std::vector<std::vector<LevelTotals>>& cells) {
    std::size_t depth = 0;
    for (const auto& t : cells) depth = std::max(depth, t.size());
    cellPrefix_.assign(depth, {});
    for (std::size_t k = 0; k < depth; ++k) {
      CellPrefix& p = cellPrefix_[k];
      for (auto* v : {&p.voxels, &p.splits, &p.children, &p.contours, &p.colors, &p.normals})
        v->assign(cells.size() + 1, 0);
      for (std::size_t i = 0; i < cells.size(); ++i) {
        const LevelTotals here = k < cells[i].size() ? cells[i][k] : LevelTotals{};
        const std::uint64_t below = k + 1 < cells[i].size() ? cells[i][k + 1].voxels : 0;
        p.voxels[i + 1] = p.voxels[i] + here.voxels, p.splits[i + 1] = p.splits[i] + here.splits;
        p.children[i + 1] = p.children[i] + below, p.contours[i + 1] = p.contours[i] + here.contours;
        p.colors[i + 1] = p.colors[i] + here.colors, p.normals[i + 1] = p.normals[i] + here.normals;
      }
    }
  }
  // Level `level` for every parent the tree has at level - 1: a cell's part of a slice spanning cells.
  SliceSections sectionsOfLevel(int level) const {
    if (level - 1 > topLevel()) return {};
    return sections(level, 0, voxelsAt(level - 1).size());
  }

 private:
  struct Voxel {
    std::uint32_t record;
    glm::ivec3 coord;
  };
  struct Prefix {
    std::vector<std::uint32_t> children, splits, contours, colors, normals;
  };
  struct CellPrefix {  // per cell, in order: totals of one level below the tree's deepest
    std::vector<std::uint64_t> voxels, splits, children, contours, colors, normals;
  };
  // What a slice covers: a cube and a run of its sub-cubes (SliceInfo).
  struct Run {
    int cubeLevel;
    glm::ivec3 cube;
    int firstSlot, lastSlot;
  };

  // Per-level data by absolute voxel level (the root sits at at_.rootLevel).
  const std::vector<Voxel>& voxelsAt(int level) const { return levels_[std::size_t(level - at_.rootLevel)]; }
  const Prefix& prefixAt(int level) const { return prefix_[std::size_t(level - at_.rootLevel)]; }
  int deepestLevel() const { return topLevel() + std::max(0, int(cellPrefix_.size()) - 1); }
  // The head of the slice of level `level` over the parents [a, b) of level - 1.
  SliceHead headOf(int level, std::size_t a, std::size_t b) const {
    SliceHead h{};
    h.magic = kSliceMagic;
    h.attachments = (tree_.hasColors ? 1u : 0u) | (tree_.hasNormals ? 2u : 0u);
    if (level - 1 < topLevel()) {
      const Prefix& up = prefixAt(level - 1);
      const Prefix& here = prefixAt(level);
      const std::uint32_t ca = up.children[a], cb = up.children[b];
      h.parentCount = std::uint32_t(b - a);
      h.splitCount = up.splits[b] - up.splits[a];
      h.voxelCount = cb - ca;
      h.contourCount = here.contours[cb] - here.contours[ca];
      h.colorCount = here.colors[cb] - here.colors[ca];
      h.normalCount = here.normals[cb] - here.normals[ca];
      return h;
    }
    // Cells: the same cells [a, b) on every level. Runs this large split, so saturating counts are exact
    // enough to decide that.
    const auto k = std::size_t(level - 1 - topLevel());
    const auto count = [&](const std::vector<std::uint64_t>& prefix) {
      return std::uint32_t(std::min<std::uint64_t>(prefix[b] - prefix[a], 0xFFFFFFFFu));
    };
    const CellPrefix& up = cellPrefix_[k];
    h.parentCount = count(up.voxels), h.splitCount = count(up.splits), h.voxelCount = count(up.children);
    if (k + 1 < cellPrefix_.size()) {
      const CellPrefix& here = cellPrefix_[k + 1];
      h.contourCount = count(here.contours), h.colorCount = count(here.colors);
      h.normalCount = count(here.normals);
    }
    return h;
  }
  // The parents [a, b) of level - 1 give the voxels [first, second) of `level` (cells: the same cells).
  std::pair<std::size_t, std::size_t> childRange(int level, std::size_t a, std::size_t b) const {
    if (level - 1 >= topLevel()) return {a, b};
    const Prefix& up = prefixAt(level - 1);
    return {up.children[a], up.children[b]};
  }
  // The sub-cube of `cubeLevel` holding parent i of `level` (a cell's cube contains all of its voxels).
  glm::ivec3 subCube(int level, std::size_t i, int cubeLevel) const {
    const int parentLevel = std::min(level - 1, topLevel());
    return voxelsAt(parentLevel)[i].coord >> (parentLevel - cubeLevel);
  }

  // The slices of `run` from voxel level `level` on; its parents are [a, b) of level - 1.
  template <class Sink>
  void plan(const Run& run, int level, std::size_t a, std::size_t b, std::uint32_t parentSlice, Sink& sink) {
    if (level > deepestLevel()) return;
    const SliceHead head = headOf(level, a, b);
    if (head.voxelCount == 0) return;
    const bool fromCells = level > topLevel();
    if (fromCells && run.cubeLevel >= topLevel()) {
      sink.delegate(a, level, parentSlice);  // within one cell: its own subtree plans the rest
      return;
    }
    const bool wholeCube = isWholeCube(run.firstSlot, run.lastSlot);
    if (sliceRawBytes(head) > options_.sliceBytes && (!wholeCube || run.cubeLevel < level - 1)) {
      split(run, level, a, b, parentSlice, sink);
      return;
    }
    SliceInfo info;
    info.cubeLevel = run.cubeLevel;
    info.cubeCoord = run.cube;
    info.firstSlot = std::uint8_t(run.firstSlot), info.lastSlot = std::uint8_t(run.lastSlot);
    info.voxelLevel = level;
    info.parentCount = head.parentCount;
    info.voxelCount = head.voxelCount;
    info.contourCount = head.contourCount;
    info.colorCount = head.colorCount;
    info.normalCount = head.normalCount;
    info.parentSlice = parentSlice;
    const std::uint32_t id =
        fromCells ? sink.reserve(info, head, a, b) : sink.emit(layOut(head, sections(level, a, b)), info);
    const auto [ca, cb] = childRange(level, a, b);
    plan(run, level + 1, ca, cb, id, sink);
  }

  // Splits a run whose level `level` exceeds the slice size: its sub-cubes, in Morton order (their parents
  // are contiguous runs of [a, b)), are packed into groups that each fit; a group of one sub-cube becomes
  // that sub-cube's own run, which packs its own sub-cubes in turn where it still does not fit.
  template <class Sink>
  void split(const Run& run, int level, std::size_t a, std::size_t b, std::uint32_t parentSlice, Sink& sink) {
    struct Part {
      int slot;
      std::size_t a, b;
    };
    std::vector<Part> parts;
    for (std::size_t i = a; i < b;) {
      const glm::ivec3 sub = subCube(level, i, run.cubeLevel + 1);
      std::size_t j = i;
      while (j < b && subCube(level, j, run.cubeLevel + 1) == sub) ++j;
      // A cell without voxels on level - 1 (all stopped above it) is no part: a tree's parents give none for
      // its sub-cube, and both must pack the same runs.
      if (headOf(level, i, j).parentCount > 0) parts.push_back({childSlot(sub), i, j});
      i = j;
    }
    // Even shares: a run of n slices' worth closes each group near 1/n of it instead of filling groups to
    // the slice size and leaving a small last one.
    const double total = double(sliceRawBytes(headOf(level, a, b)));
    const double share = total / std::ceil(total / double(options_.sliceBytes));
    for (std::size_t first = 0; first < parts.size();) {
      std::size_t last = first;
      while (last + 1 < parts.size()) {
        const double now = double(sliceRawBytes(headOf(level, parts[first].a, parts[last].b)));
        const double grown = double(sliceRawBytes(headOf(level, parts[first].a, parts[last + 1].b)));
        if (grown > double(options_.sliceBytes) || std::abs(grown - share) > std::abs(now - share)) break;
        ++last;
      }
      const Part& p = parts[first];
      if (first == last)
        plan({run.cubeLevel + 1, childCoord(run.cube, p.slot), 0, 7}, level, p.a, p.b, parentSlice, sink);
      else
        plan({run.cubeLevel, run.cube, p.slot, parts[last].slot}, level, p.a, parts[last].b, parentSlice,
             sink);
      first = last + 1;
    }
  }

  // Level `level` of the parents [a, b) of level - 1 (in the tree).
  SliceSections sections(int level, std::size_t a, std::size_t b) const {
    SliceSections out;
    const std::vector<Voxel>& parents = voxelsAt(level - 1);
    for (std::size_t i = a; i < b; ++i) {
      const std::uint8_t mask = tree_.voxels[parents[i].record].childMask;
      out.split.push(mask != 0);
      if (mask) out.masks.push_back(mask);
    }
    const std::uint32_t ca = prefixAt(level - 1).children[a], cb = prefixAt(level - 1).children[b];
    if (ca == cb) return out;
    const std::vector<Voxel>& voxels = voxelsAt(level);
    NormalCodes codes;
    // Children follow their parents' order: walk both, for the parent's normal each child's is coded by.
    std::uint32_t i = ca;
    // The scene's root voxel has no contour in the store (the header holds its attributes only): readers
    // predict its children's contours without one, and so must this.
    const bool parentContours = level - 1 > 0;
    for (std::size_t p = a; p < b; ++p) {
      const std::uint32_t parent = parents[p].record;
      const VoxelRecord& up = tree_.voxels[parent];
      const ContourPositionPredictor position(parentContours && up.hasContour, up.contour);
      const std::uint16_t parentCode = tree_.hasNormals ? codes(effectiveNormal_[parent]) : 0;
      for (int slot = 0; slot < 8; ++slot) {
        if (!(up.childMask >> slot & 1u)) continue;
        const std::uint32_t v = voxels[i++].record;
        const VoxelRecord& r = tree_.voxels[v];
        const std::uint16_t code = tree_.hasNormals ? octNormalCodeOf(effectiveNormal_[v]) : 0;
        out.contourBits.push(r.hasContour);
        if (r.hasContour)
          out.contours.push_back(contourResidual(
              r.contour, (tree_.hasNormals ? predictedContourNormalBits(code) : 0) | position(slot)));
        if (tree_.hasColors) {
          out.colorBits.push(storesColor_[v] != 0);
          if (storesColor_[v]) out.colors.push_back(effectiveColor_[v]);
        }
        if (tree_.hasNormals) {
          out.normalBits.push(storesNormal_[v] != 0);
          if (storesNormal_[v]) out.normals.push_back(normalResidual(code, parentCode));
        }
      }
    }
    assert(i == cb);
    return out;
  }

  const VoxelTree& tree_;
  const StoreWriteOptions& options_;
  const SubtreePlacement at_;
  std::vector<std::uint32_t> effectiveColor_, effectiveNormal_;
  std::vector<std::uint8_t> storesColor_, storesNormal_;
  std::vector<std::vector<Voxel>> levels_;
  std::vector<Prefix> prefix_;
  std::vector<CellPrefix> cellPrefix_;
};

}  // namespace

bool mortonLess(const glm::ivec3& a, const glm::ivec3& b) {
  const auto msbBelow = [](std::uint32_t x, std::uint32_t y) { return x < y && x < (x ^ y); };
  int axis = 2;
  std::uint32_t highest = std::uint32_t(a.z ^ b.z);
  for (const int k : {1, 0}) {
    const std::uint32_t d = std::uint32_t(a[k] ^ b[k]);
    if (msbBelow(highest, d)) axis = k, highest = d;
  }
  return a[axis] < b[axis];
}

SliceParts slicePartsOf(const SliceInfo& s, bool hasColors, bool hasNormals) {
  SliceParts p;
  p.contours = bitBytes(s.voxelCount) + kContourBytes * s.contourCount;
  p.colors = hasColors ? bitBytes(s.voxelCount) + kColorBytes * s.colorCount : 0;
  p.normals = hasNormals ? bitBytes(s.voxelCount) + kNormalBytes * s.normalCount : 0;
  p.hierarchy = s.rawBytes - p.contours - p.colors - p.normals;
  return p;
}

SliceBox sliceBox(const SliceInfo& s) {
  const double size = std::ldexp(1.0, -s.cubeLevel);
  const glm::dvec3 corner = glm::dvec3(1.0) + glm::dvec3(s.cubeCoord) * size;
  if (s.wholeCube()) return {corner, corner + size};
  // The union of the run's sub-cubes: the slots set a bit per axis, so the run spans an axis's upper half
  // where any of its slots does (and likewise the lower half).
  glm::dvec3 lower = corner + size, upper = corner;
  for (int slot = s.firstSlot; slot <= s.lastSlot; ++slot) {
    const glm::dvec3 sub = corner + glm::dvec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1) * (0.5 * size);
    lower = glm::min(lower, sub), upper = glm::max(upper, sub + 0.5 * size);
  }
  return {lower, upper};
}

bool sliceWithin(const SliceInfo& inner, const SliceInfo& outer) {
  if (inner.cubeLevel < outer.cubeLevel) return false;
  if (inner.cubeLevel == outer.cubeLevel)
    return inner.cubeCoord == outer.cubeCoord && inner.firstSlot >= outer.firstSlot &&
           inner.lastSlot <= outer.lastSlot;
  // A finer cube: its ancestor one level below the outer cube is one of the outer run's sub-cubes.
  const glm::ivec3 sub = inner.cubeCoord >> (inner.cubeLevel - outer.cubeLevel - 1);
  if ((sub >> 1) != outer.cubeCoord) return false;
  const int slot = childSlot(sub);
  return slot >= outer.firstSlot && slot <= outer.lastSlot;
}

SliceError::SliceError(std::uint32_t s, const std::string& message) : std::runtime_error(message), slice(s) {}

SliceError StoreReader::sliceError(std::uint32_t id, const std::string& what) const {
  std::string name = "slice " + std::to_string(id);
  if (id < slices_.size()) {
    const SliceInfo& s = slices_[id];
    name += " (level " + std::to_string(s.voxelLevel) + ", cube (" + std::to_string(s.cubeCoord.x) + "," +
            std::to_string(s.cubeCoord.y) + "," + std::to_string(s.cubeCoord.z) + ") of level " +
            std::to_string(s.cubeLevel);
    if (s.firstSlot != 0 || s.lastSlot != 7)
      name += ", sub-cubes " + std::to_string(s.firstSlot) + "-" + std::to_string(s.lastSlot);
    name += ")";
  }
  return SliceError(id, path_.string() + ": " + name + ": " + what);
}

StoreFileWriter::StoreFileWriter(const std::filesystem::path& path, const StoreWriteOptions& options)
    : path_(path), temp_(path.string() + ".tmp." + std::to_string(::getpid())), options_(options) {
  if (options.sliceBytes < kMinSliceBytes)
    throw std::invalid_argument("writeStore: slice size must be at least " + std::to_string(kMinSliceBytes) +
                                " bytes (got " + std::to_string(options.sliceBytes) + ")");
  // Temporary name in the same folder, flushed, then renamed: the target is never half-written.
  file_ = std::fopen(temp_.c_str(), "wb");
  if (!file_) fail(path_, std::string("cannot write (") + std::strerror(errno) + ")");
  const FileHeader placeholder{};  // until the directory's place is known
  try {
    put(&placeholder, sizeof placeholder);
  } catch (...) {
    std::fclose(file_);  // no destructor runs for a constructor that throws
    std::error_code ignored;
    std::filesystem::remove(temp_, ignored);
    throw;
  }
  offset_ = sizeof placeholder;
}

StoreFileWriter::~StoreFileWriter() {
  if (!file_) return;
  std::fclose(file_);
  std::error_code ignored;
  std::filesystem::remove(temp_, ignored);
}

void StoreFileWriter::put(const void* data, std::size_t bytes) {
  if (std::fwrite(data, 1, bytes, file_) != bytes)
    fail(path_, std::string("cannot write (") + std::strerror(errno) + ")");
}

std::uint32_t StoreFileWriter::writeSlice(const std::vector<std::byte>& raw, SliceInfo info,
                                          std::uint32_t reserved) {
  compressed_.resize(ZSTD_compressBound(raw.size()));
  const std::size_t packed =
      ZSTD_compress(compressed_.data(), compressed_.size(), raw.data(), raw.size(), kZstdLevel);
  if (ZSTD_isError(packed)) fail(path_, std::string("compression failed: ") + ZSTD_getErrorName(packed));
  info.offset = offset_;
  info.compressedBytes = std::uint32_t(packed);
  info.rawBytes = std::uint32_t(raw.size());
  info.checksum = XXH3_64bits(compressed_.data(), packed);
  put(compressed_.data(), packed);
  offset_ += packed;
  if (reserved != SliceInfo::kNoSlice) {
    slices_[reserved] = info;
    return reserved;
  }
  slices_.push_back(info);
  return std::uint32_t(slices_.size() - 1);
}

namespace {

// Where StoreWriter's plan sends slices: written at once, in plan order.
struct FileSink {
  std::function<std::uint32_t(const std::vector<std::byte>&, const SliceInfo&)> write;
  std::uint32_t emit(const std::vector<std::byte>& raw, const SliceInfo& info) { return write(raw, info); }
  std::uint32_t reserve(const SliceInfo&, const SliceHead&, std::size_t, std::size_t) {
    throw std::logic_error("writeStore: a tree without cells reserved a slice");
  }
  void delegate(std::size_t, int, std::uint32_t) {
    throw std::logic_error("writeStore: a tree without cells handed on a cell");
  }
};

}  // namespace

std::vector<std::uint32_t> StoreFileWriter::append(const VoxelTree& tree, const SubtreePlacement& at,
                                                   EffectiveAttributes* effective) {
  if (!file_) throw std::logic_error("StoreFileWriter: append after finish");
  if (at.parentSlice != SliceInfo::kNoSlice && at.parentSlice >= slices_.size())
    throw std::invalid_argument("writeStore: a subtree's parent slice is not written yet");
  if (tree.voxels.empty() || tree.voxels[0].childMask == 0)
    throw std::invalid_argument("writeStore: the tree has no voxels below the root");
  StoreWriter writer(tree, options_, at);
  std::vector<std::uint32_t> ids;
  std::uint64_t voxelsWritten = 1;  // the root is the parent slice's (or the header's)
  FileSink sink{[&](const std::vector<std::byte>& raw, const SliceInfo& info) {
    ids.push_back(writeSlice(raw, info));
    voxelsWritten += info.voxelCount;
    if (options_.progress) options_.progress(double(voxelsWritten) / double(writer.voxelCount()));
    return ids.back();
  }};
  writer.run(sink);
  if (effective) *effective = writer.effective();
  return ids;
}

namespace {

// The out-of-core top's sink: its own levels are written at once; slices of cell levels that span several
// cells are reserved (an id in plan order, so parents still come first) and written once their last cell
// has given its part; a run within one cell is left to that cell.
struct ForestSink : FileSink {
  struct Reserved {
    SliceHead head;
    std::size_t lastCell;
    SliceSections parts;
  };
  std::vector<SliceInfo>& slices;
  std::map<std::uint32_t, Reserved> reserved;
  std::vector<std::vector<std::pair<int, std::uint32_t>>> cellParts;  // per cell: (level, reserved slice)
  std::vector<std::pair<int, std::uint32_t>> cellStart;  // per cell: (first level, parent slice) of its own

  std::uint32_t reserve(const SliceInfo& info, const SliceHead& head, std::size_t a, std::size_t b) {
    const auto id = std::uint32_t(slices.size());
    slices.push_back(info);
    reserved[id] = {head, b - 1, {}};
    for (std::size_t cell = a; cell < b; ++cell) cellParts[cell].push_back({info.voxelLevel, id});
    return id;
  }
  void delegate(std::size_t cell, int level, std::uint32_t parentSlice) {
    cellStart[cell] = {level, parentSlice};
  }
};

}  // namespace

void StoreFileWriter::appendForest(const VoxelTree& top, int cellLevel,
                                   const std::function<VoxelTree(glm::ivec3 cell, bool counting)>& loadCell) {
  if (!file_) throw std::logic_error("StoreFileWriter: append after finish");
  if (!slices_.empty()) throw std::logic_error("StoreFileWriter: a forest must be the store's first subtree");
  if (top.voxels.empty() || top.voxels[0].childMask == 0)
    throw std::invalid_argument("writeStore: the tree has no voxels below the root");
  const VoxelRecord& root = top.voxels[0];
  StoreWriter topWriter(top, options_, {0, glm::ivec3(0), root.color, root.normal, SliceInfo::kNoSlice});
  std::vector<std::pair<std::uint32_t, glm::ivec3>> cells;
  if (topWriter.topLevel() == cellLevel) cells = topWriter.deepestVoxels();
  const EffectiveAttributes effective = topWriter.effective();
  const auto placement = [&](std::size_t i) {
    const auto [record, coord] = cells[i];
    return SubtreePlacement{cellLevel, coord, effective.color[record], effective.normal[record],
                            SliceInfo::kNoSlice};
  };
  const auto progress = [&](std::size_t done) {
    if (options_.progress)
      options_.progress(double(done) / double(std::max<std::size_t>(2 * cells.size(), 1)));
  };
  // 1. Every cell's totals per level: the plan's sizes for slices spanning cells.
  std::vector<std::vector<LevelTotals>> totals(cells.size());
  for (std::size_t i = 0; i < cells.size(); ++i) {
    totals[i] = StoreWriter(loadCell(cells[i].second, true), options_, placement(i)).totals();
    progress(i + 1);
  }
  topWriter.addCells(totals);
  // 2. The plan: the top's slices written, the spanning ones reserved, the rest handed to their cells.
  const auto write = [&](const std::vector<std::byte>& raw, const SliceInfo& info) {
    return writeSlice(raw, info);
  };
  ForestSink sink{{write},
                  slices_,
                  {},
                  std::vector<std::vector<std::pair<int, std::uint32_t>>>(cells.size()),
                  std::vector<std::pair<int, std::uint32_t>>(cells.size(), {0, SliceInfo::kNoSlice})};
  topWriter.run(sink);
  // 3. Each cell: its parts of the spanning slices (a slice is written when its last cell is done), then its
  // own slices.
  FileSink own{write};
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const VoxelTree tree = loadCell(cells[i].second, false);
    StoreWriter cell(tree, options_, placement(i));
    for (const auto& [level, id] : sink.cellParts[i]) {
      ForestSink::Reserved& r = sink.reserved.at(id);
      r.parts.append(cell.sectionsOfLevel(level));
      if (r.lastCell != i) continue;
      writeSlice(layOut(r.head, r.parts), slices_[id], id);
      sink.reserved.erase(id);
    }
    if (const auto [level, parent] = sink.cellStart[i]; parent != SliceInfo::kNoSlice)
      cell.runFrom(level, parent, own);
    progress(cells.size() + i + 1);
  }
  if (!sink.reserved.empty()) throw std::logic_error("writeStore: a slice spanning cells was not completed");
}

void StoreFileWriter::finish(const StoreContents& contents) {
  if (!file_) throw std::logic_error("StoreFileWriter: finish twice");
  if (slices_.empty()) throw std::invalid_argument("writeStore: the store has no slices");
  for (const SliceInfo& slice : slices_)
    if (slice.compressedBytes == 0) throw std::logic_error("writeStore: a reserved slice was never written");
  std::vector<DirectoryEntry> directory(slices_.size());
  for (std::size_t i = 0; i < slices_.size(); ++i) directory[i] = entryOf(slices_[i]);
  const std::size_t directoryBytes = directory.size() * sizeof(DirectoryEntry);
  put(directory.data(), directoryBytes);

  FileHeader h{};
  std::memcpy(h.magic, kFileMagic, sizeof h.magic);
  h.version = kFileVersion;
  h.headerBytes = sizeof(FileHeader);
  for (int i = 0; i < 3; ++i) h.origin[i] = contents.transform.origin[i];
  h.size = contents.transform.size;
  h.levels = contents.parameters.levels;
  h.geometryError = contents.parameters.geometryError;
  h.colorError = contents.parameters.colorError;
  h.normalError = contents.parameters.normalError;
  h.contours = contents.parameters.contours;
  if (contents.hasColors) h.attachmentTypes |= 1u << (std::uint32_t(AttachmentType::Color) - 1);
  if (contents.hasNormals) h.attachmentTypes |= 1u << (std::uint32_t(AttachmentType::Normal) - 1);
  h.rootColor = contents.rootColor;
  h.rootNormal = contents.rootNormal;
  h.sliceBytes = options_.sliceBytes;
  h.sliceCount = std::uint32_t(slices_.size());
  h.directoryOffset = offset_;
  h.directoryBytes = directoryBytes;
  h.directoryChecksum = XXH3_64bits(directory.data(), directoryBytes);
  h.headerChecksum = headerChecksum(h);
  if (std::fseek(file_, 0, SEEK_SET) != 0) fail(path_, "cannot seek to the header");
  put(&h, sizeof h);
  if (std::fflush(file_) != 0 || ::fsync(::fileno(file_)) != 0)
    fail(path_, std::string("cannot write (") + std::strerror(errno) + ")");
  const int closed = std::fclose(file_);
  file_ = nullptr;
  if (closed != 0) {
    std::error_code ignored;
    std::filesystem::remove(temp_, ignored);
    fail(path_, std::string("cannot write (") + std::strerror(errno) + ")");
  }
  std::error_code ec;
  std::filesystem::rename(temp_, path_, ec);
  if (ec) {
    std::error_code ignored;
    std::filesystem::remove(temp_, ignored);
    fail(path_, "cannot rename into place (" + ec.message() + ")");
  }
}

std::vector<SliceInfo> writeStore(const std::filesystem::path& path, const VoxelTree& tree,
                                  const SceneTransform& transform, const BuildParameters& parameters,
                                  const StoreWriteOptions& options) {
  if (tree.voxels.empty() || tree.voxels[0].childMask == 0)
    throw std::invalid_argument("writeStore: the tree has no voxels below the root");
  StoreFileWriter writer(path, options);
  const VoxelRecord& root = tree.voxels[0];
  writer.append(tree, {0, glm::ivec3(0), root.color, root.normal, SliceInfo::kNoSlice});
  std::vector<SliceInfo> slices = writer.slices();
  writer.finish({transform, parameters, tree.hasColors, tree.hasNormals, root.color, root.normal});
  return slices;
}

// ---------------------------------------------------------------------------------------------------------
StoreReader::File::~File() {
  if (fd >= 0) ::close(fd);
}

StoreReader::StoreReader(const std::filesystem::path& path) : path_(path), file_(std::make_shared<File>()) {
  file_->fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (file_->fd < 0)
    fail(path, errno == ENOENT ? "no such file" : std::string("cannot open (") + std::strerror(errno) + ")");
  std::error_code ec;
  const std::uint64_t fileBytes = std::filesystem::file_size(path, ec);
  if (ec) fail(path, "cannot read its size (" + ec.message() + ")");
  if (fileBytes == 0) fail(path, "empty file (0 bytes), not an svostream file");
  FileHeader h{};
  const std::int64_t headerRead = readAt(file_->fd, 0, &h, sizeof h);
  if (headerRead < std::int64_t(sizeof h.magic) || std::memcmp(h.magic, kFileMagic, sizeof h.magic) != 0)
    fail(path, "not an svostream file (bad magic)");
  if (headerRead < std::int64_t(offsetof(FileHeader, headerBytes))) fail(path, "truncated header");
  if (h.version != kFileVersion)
    fail(path, "unsupported file version " + std::to_string(h.version) + " (this build reads " +
                   std::to_string(kFileVersion) + ")");
  if (headerRead != std::int64_t(sizeof h)) fail(path, "truncated header");
  if (h.headerBytes != sizeof h || (kCheckChecksums && headerChecksum(h) != h.headerChecksum))
    fail(path, "header checksum mismatch");
  if (h.levels < 1 || h.levels > kMaxLevels || !(h.size > 0.0) || h.sliceBytes < kMinSliceBytes)
    fail(path, "header holds invalid scene parameters");
  if (h.directoryBytes != std::uint64_t(h.sliceCount) * sizeof(DirectoryEntry) ||
      h.directoryOffset < sizeof h)
    fail(path, "header holds an invalid directory location");
  if (h.directoryOffset + h.directoryBytes > fileBytes)
    fail(path, "truncated: the directory ends at byte " +
                   std::to_string(h.directoryOffset + h.directoryBytes) + ", the file has " +
                   std::to_string(fileBytes));
  if (h.directoryOffset + h.directoryBytes != fileBytes)
    fail(path, std::to_string(fileBytes - h.directoryOffset - h.directoryBytes) +
                   " unexpected bytes after the directory");

  header_.transform.origin = {h.origin[0], h.origin[1], h.origin[2]};
  header_.transform.size = h.size;
  header_.parameters = {h.levels, h.geometryError, h.colorError, h.normalError, h.contours};
  header_.hasColors = h.attachmentTypes >> (std::uint32_t(AttachmentType::Color) - 1) & 1u;
  header_.hasNormals = h.attachmentTypes >> (std::uint32_t(AttachmentType::Normal) - 1) & 1u;
  header_.rootColor = h.rootColor;
  header_.rootNormal = h.rootNormal;
  header_.sliceBytes = h.sliceBytes;
  header_.directoryOffset = h.directoryOffset;
  header_.directoryBytes = h.directoryBytes;
  header_.fileBytes = fileBytes;

  std::vector<DirectoryEntry> directory(h.sliceCount);
  if (readAt(file_->fd, h.directoryOffset, directory.data(), h.directoryBytes) !=
      std::int64_t(h.directoryBytes))
    fail(path, "truncated: cannot read the directory");
  if (kCheckChecksums && XXH3_64bits(directory.data(), h.directoryBytes) != h.directoryChecksum)
    fail(path, "directory checksum mismatch");

  // Slices tile the bytes between the header and the directory (in file order, which is not always the
  // directory's: an out-of-core build writes a slice spanning cells after its last cell), so every byte has
  // a checksum.
  slices_.reserve(directory.size());
  for (std::size_t i = 0; i < directory.size(); ++i) {
    const DirectoryEntry& e = directory[i];
    const auto bad = [&](const std::string& what) {
      fail(path, "directory entry " + std::to_string(i) + ": " + what);
    };
    if (e.offset < sizeof h || e.compressedBytes == 0 || e.offset + e.compressedBytes > h.directoryOffset)
      bad("slice bytes out of place");
    if (e.rawBytes < sizeof(SliceHead) || e.rawBytes > kMaxSliceRawBytes) bad("invalid slice size");
    if (e.voxelLevel < 1 || e.voxelLevel > h.levels || e.cubeLevel >= e.voxelLevel) bad("invalid levels");
    for (const std::int32_t c : e.cubeCoord)
      if (c < 0 || std::int64_t(c) >= (std::int64_t(1) << e.cubeLevel)) bad("cube outside the octree");
    if (e.firstSlot > e.lastSlot || e.lastSlot > 7 ||
        (e.lastSlot - e.firstSlot < 7 && e.cubeLevel + 1 >= e.voxelLevel))
      bad("invalid run of sub-cubes");
    if (e.parentSlice != SliceInfo::kNoSlice && e.parentSlice >= i) bad("parent slice does not come first");
    slices_.push_back(sliceOf(e));
  }
  std::vector<std::pair<std::uint64_t, std::uint32_t>> extents;  // (offset, compressed bytes)
  extents.reserve(slices_.size());
  for (const SliceInfo& s : slices_) extents.push_back({s.offset, s.compressedBytes});
  std::sort(extents.begin(), extents.end());
  std::uint64_t expectedOffset = sizeof h;
  for (const auto& [offset, bytes] : extents) {
    if (offset != expectedOffset) fail(path, "slice bytes out of place at offset " + std::to_string(offset));
    expectedOffset += bytes;
  }
  if (expectedOffset != h.directoryOffset) fail(path, "the slices do not end where the directory starts");
}

SliceBytes StoreReader::readSlice(std::uint32_t id) const {
  if (id >= slices_.size()) throw sliceError(id, "no such slice");
  const SliceInfo& s = slices_[id];
  // pread on the descriptor kept open since construction: no reopening per slice, and safe to call from
  // several threads at once.
  // One compressed buffer per thread, reused, without a zero fill per slice (as the decoded bytes).
  thread_local std::vector<char, UninitializedAllocator<char>> compressed;
  compressed.resize(s.compressedBytes);
  const std::int64_t read = readAt(file_->fd, s.offset, compressed.data(), compressed.size());
  if (read < 0) throw sliceError(id, std::string("cannot read (") + std::strerror(errno) + ")");
  if (std::uint64_t(read) != s.compressedBytes) throw sliceError(id, "truncated");
  if (kCheckChecksums && XXH3_64bits(compressed.data(), compressed.size()) != s.checksum)
    throw sliceError(id, "checksum mismatch");
  if (ZSTD_getFrameContentSize(compressed.data(), compressed.size()) != s.rawBytes)
    throw sliceError(id, "size does not match its compressed frame");
  SliceBytes raw(s.rawBytes);
  // One decompression context per thread, reused: ZSTD_decompress would set one up for every slice.
  thread_local const std::unique_ptr<ZSTD_DCtx, std::size_t (*)(ZSTD_DCtx*)> context(ZSTD_createDCtx(),
                                                                                     ZSTD_freeDCtx);
  if (!context) throw std::bad_alloc();
  const std::size_t got =
      ZSTD_decompressDCtx(context.get(), raw.data(), raw.size(), compressed.data(), compressed.size());
  if (ZSTD_isError(got) || got != s.rawBytes) throw sliceError(id, "does not decompress");
  return raw;
}

void StoreReader::decodeSlice(std::uint32_t id, std::span<const std::byte> raw, std::span<SliceVoxel> parents,
                              std::vector<SliceVoxel>& children) const {
  const SliceInfo& s = slices_.at(id);
  if (parents.size() != s.parentCount)
    throw sliceError(id, "expects " + std::to_string(s.parentCount) + " parent voxels, its cube has " +
                             std::to_string(parents.size()));
  SliceHead head;
  if (raw.size() < sizeof head) throw sliceError(id, "shorter than its head");
  std::memcpy(&head, raw.data(), sizeof head);
  const std::uint32_t attachments = (header_.hasColors ? 1u : 0u) | (header_.hasNormals ? 2u : 0u);
  if (head.magic != kSliceMagic || head.parentCount != s.parentCount || head.voxelCount != s.voxelCount ||
      head.contourCount != s.contourCount || head.colorCount != s.colorCount ||
      head.normalCount != s.normalCount || head.attachments != attachments ||
      head.splitCount > head.parentCount)
    throw sliceError(id, "its head does not match the directory");
  if (sliceRawBytes(head) != raw.size()) throw sliceError(id, "section sizes do not add up to its size");

  const std::byte* cursor = raw.data() + sizeof head;
  const std::byte* splitBits = cursor;
  cursor += bitBytes(head.parentCount);
  const std::byte* masks = cursor;
  cursor += head.splitCount;
  std::uint32_t split = 0;
  const std::size_t firstAdded = children.size();
  // Per new voxel: its contour's predicted position field, and its normal's lattice code (its parent's until
  // the normals section gives its own).
  struct Prediction {
    std::uint32_t contourPosition;
    std::uint16_t normalCode;
  };
  std::vector<Prediction> predicted;
  predicted.reserve(std::min<std::size_t>(head.voxelCount, 8 * std::size_t(head.splitCount)));
  NormalCodes codes;
  // At most 8 children per split voxel, whose masks are bytes of this slice: a hostile count reserves no
  // more.
  // Geometric growth: callers append a level's slices one after another to one vector (loadTree), and an
  // exact reserve per slice copied the whole level every time.
  const std::size_t needed =
      firstAdded + std::min<std::size_t>(head.voxelCount, 8 * std::size_t(head.splitCount));
  if (needed > children.capacity()) children.reserve(std::max(needed, 2 * children.capacity()));
  for (std::size_t i = 0; i < parents.size(); ++i) {
    SliceVoxel& p = parents[i];
    if (!bitAt(splitBits, i)) continue;
    if (split == head.splitCount) throw sliceError(id, "more split bits than valid masks");
    const std::uint8_t mask = std::to_integer<std::uint8_t>(masks[split++]);
    if (mask == 0) throw sliceError(id, "a split voxel with no children");
    p.childMask = mask;
    const ContourPositionPredictor position(p.hasContour, p.contour);
    const std::uint16_t parentCode = header_.hasNormals ? codes(p.normal) : 0;
    for (int slot = 0; slot < 8; ++slot) {
      if (!(mask >> slot & 1u)) continue;
      SliceVoxel& child = children.emplace_back();  // in place: no temporary to copy (store forwarding)
      child.coord = childCoord(p.coord, slot);
      child.color = p.color, child.normal = p.normal;
      predicted.push_back({head.contourCount ? position(slot) : 0, parentCode});
    }
  }
  if (split != head.splitCount || children.size() - firstAdded != head.voxelCount)
    throw sliceError(id, "valid masks do not match the voxel count");
  SliceVoxel* added = children.data() + firstAdded;
  // Per-voxel sections: a presence bit each, then the present values (words, or byte planes). Normals
  // first: a contour is coded against its voxel's normal.
  const auto section = [&](const std::byte* at, std::uint32_t count, auto store) {
    const std::byte* bits = at;
    const std::byte* values = at + bitBytes(head.voxelCount);
    std::uint32_t k = 0;
    for (std::uint32_t i = 0; i < head.voxelCount; ++i) {
      if (!bitAt(bits, i)) continue;
      if (k == count) throw sliceError(id, "more presence bits than values");
      store(i, values, k++);
    }
    if (k != count) throw sliceError(id, "fewer presence bits than values");
  };
  const auto sectionBytes = [&](std::uint32_t count, std::size_t bytes) {
    return bitBytes(head.voxelCount) + bytes * std::size_t(count);
  };
  const std::byte* contours = cursor;
  const std::byte* colors = contours + sectionBytes(head.contourCount, kContourBytes);
  const std::byte* normals = colors + (header_.hasColors ? sectionBytes(head.colorCount, kColorBytes) : 0);
  // Byte `plane` of value k among `count` values stored as byte planes.
  const auto planeByte = [](const std::byte* values, std::uint32_t count, std::size_t plane,
                            std::uint32_t k) {
    return std::to_integer<std::uint8_t>(values[plane * count + k]);
  };
  const std::uint32_t* const lattice = latticeNormalTable();
  const std::uint32_t* const contourNormals = contourNormalPredictionTable();
  if (header_.hasNormals)
    section(normals, head.normalCount, [&](std::uint32_t i, const std::byte* values, std::uint32_t k) {
      const NormalResidual r{planeByte(values, head.normalCount, 0, k),
                             planeByte(values, head.normalCount, 1, k)};
      std::uint16_t& code = predicted[i].normalCode;  // the parent's, so far
      code = normalCodeOf(r, code);
      added[i].normal = lattice[code];
    });
  if (header_.hasColors)
    section(colors, head.colorCount, [&](std::uint32_t i, const std::byte* values, std::uint32_t k) {
      added[i].color = wordAt(values, k);
    });
  section(contours, head.contourCount, [&](std::uint32_t i, const std::byte* values, std::uint32_t k) {
    ContourResidual r;
    for (std::size_t plane = 0; plane < kContourBytes; ++plane)
      r[plane] = planeByte(values, head.contourCount, plane, k);
    const Prediction& p = predicted[i];
    added[i].hasContour = true;
    added[i].contour =
        contourOf(r, (header_.hasNormals ? contourNormals[p.normalCode] : 0) | p.contourPosition);
  });
}

std::span<SliceVoxel> StoreReader::claimParents(std::uint32_t id, std::vector<SliceVoxel>& level,
                                                std::vector<std::uint8_t>& covered) const {
  // The run's voxels one level above the slice: a contiguous Morton range.
  const SliceInfo& s = slices_[id];
  glm::ivec3 first, last;
  if (s.wholeCube()) {
    const int shift = s.voxelLevel - 1 - s.cubeLevel;
    first = s.cubeCoord << shift, last = first + ((1 << shift) - 1);
  } else {
    const int shift = s.voxelLevel - 1 - (s.cubeLevel + 1);  // the reader checked that the sub-cubes fit
    first = childCoord(s.cubeCoord, s.firstSlot) << shift;
    last = (childCoord(s.cubeCoord, s.lastSlot) << shift) + ((1 << shift) - 1);
  }
  const auto lo =
      std::lower_bound(level.begin(), level.end(), first,
                       [](const SliceVoxel& n, const glm::ivec3& k) { return mortonLess(n.coord, k); });
  const auto hi =
      std::upper_bound(level.begin(), level.end(), last,
                       [](const glm::ivec3& k, const SliceVoxel& n) { return mortonLess(k, n.coord); });
  for (auto p = lo; p != hi; ++p) {
    std::uint8_t& seen = covered[std::size_t(p - level.begin())];
    if (seen) throw sliceError(id, "overlaps another slice's sub-cubes");
    seen = 1;
  }
  return {lo, hi};
}

std::uint64_t StoreReader::verify(const std::function<void(double)>& progress, std::uint64_t* leaves) const {
  std::vector<std::vector<std::uint32_t>> childSlices(slices_.size());
  std::vector<std::uint32_t> roots;
  for (std::uint32_t i = 0; i < slices_.size(); ++i)
    (slices_[i].parentSlice == SliceInfo::kNoSlice ? roots : childSlices[slices_[i].parentSlice])
        .push_back(i);
  if (roots.size() != 1) fail(path_, std::to_string(roots.size()) + " slices start the hierarchy (one must)");
  std::uint64_t voxels = 1, leafVoxels = 0, visited = 0;
  // Depth first: a slice's voxels stay decoded while the slices below it are checked.
  const auto visit = [&](auto&& self, std::uint32_t id, std::span<SliceVoxel> parents) -> void {
    const SliceInfo& s = slices_[id];
    std::vector<SliceVoxel> decoded;
    decodeSlice(id, readSlice(id), parents, decoded);
    voxels += decoded.size();
    ++visited;
    if (progress) progress(double(visited) / double(slices_.size()));
    std::vector<std::uint8_t> covered(decoded.size(), 0);
    for (const std::uint32_t child : childSlices[id]) {
      const SliceInfo& c = slices_[child];
      if (c.voxelLevel != s.voxelLevel + 1 || !sliceWithin(c, s))
        throw sliceError(child, "its sub-cubes do not lie one level below its parent slice's");
      self(self, child, claimParents(child, decoded, covered));
    }
    // Every slice below has set its parents' child masks by now.
    leafVoxels += std::uint64_t(
        std::count_if(decoded.begin(), decoded.end(), [](const SliceVoxel& v) { return v.childMask == 0; }));
  };
  SliceVoxel root{glm::ivec3(0), 0, false, 0, header_.rootColor, header_.rootNormal};
  visit(visit, roots[0], std::span<SliceVoxel>(&root, 1));
  if (visited != slices_.size())
    fail(path_, std::to_string(slices_.size() - visited) + " slices are not reachable from the first");
  if (leaves) *leaves = leafVoxels;
  return voxels;
}

VoxelTree StoreReader::loadTree() const {
  const int levelCount = header_.parameters.levels;
  VoxelLevels levels(1);
  levels[0].push_back({glm::ivec3(0), 0, false, 0, header_.rootColor, header_.rootNormal});
  std::vector<std::vector<std::uint32_t>> slicesOf(levelCount + 1);
  for (std::uint32_t i = 0; i < slices_.size(); ++i) slicesOf[slices_[i].voxelLevel].push_back(i);

  for (int level = 1; level <= levelCount && !slicesOf[level].empty(); ++level) {
    std::vector<SliceVoxel>& parents = levels[level - 1];
    std::vector<std::uint8_t> covered(parents.size(), 0);  // a slice has given this voxel's split bit
    // Slices of one level cover disjoint Morton ranges of their parents and decode their children in their
    // parents' order: decoded in the order of their parent ranges, they append the level in Morton order, in
    // which every parent's children are contiguous and follow their parents' order (no sort of the voxels).
    std::vector<std::pair<std::span<SliceVoxel>, std::uint32_t>> claims;
    for (const std::uint32_t id : slicesOf[level]) claims.push_back({claimParents(id, parents, covered), id});
    std::stable_sort(claims.begin(), claims.end(),
                     [](const auto& a, const auto& b) { return a.first.data() < b.first.data(); });
    std::vector<SliceVoxel> voxels;
    for (const auto& [span, id] : claims) decodeSlice(id, readSlice(id), span, voxels);
    assert(std::is_sorted(voxels.begin(), voxels.end(), [](const SliceVoxel& a, const SliceVoxel& b) {
      return mortonLess(a.coord, b.coord);
    }));
    levels.push_back(std::move(voxels));
  }
  for (std::size_t l = levels.size(); l <= std::size_t(levelCount); ++l)
    if (!slicesOf[l].empty()) fail(path_, "slices of level " + std::to_string(l) + " have no parents");
  if (levels.size() < 2) fail(path_, "the store holds no voxels");
  return treeOfLevels(levels, header_.hasColors, header_.hasNormals);
}

VoxelTree treeOfLevels(const VoxelLevels& levels, bool hasColors, bool hasNormals) {
  VoxelTree tree;
  tree.hasColors = hasColors;
  tree.hasNormals = hasNormals;
  std::size_t total = 0;
  for (const auto& l : levels) total += l.size();
  tree.voxels.reserve(total);
  std::size_t nextChild = levels.empty() ? 0 : levels[0].size();
  for (const auto& level : levels) {
    for (const SliceVoxel& n : level) {
      // Fields written in place: a record assembled on the stack and pushed back stalled on store forwarding
      // (its narrow field stores read back as one wide load), a third of the pager's tree time.
      VoxelRecord& r = tree.voxels.emplace_back();
      r.childMask = n.childMask;
      r.firstChild = n.childMask ? std::uint32_t(nextChild) : 0;
      nextChild += std::size_t(std::popcount(unsigned(n.childMask)));
      r.hasContour = n.hasContour;
      r.contour = n.contour;
      r.color = n.color;
      r.normal = n.normal;
    }
  }
  return tree;
}

Octree readOctree(const std::filesystem::path& path) {
  const StoreReader reader(path);
  Octree octree;
  octree.transform = reader.header().transform;
  octree.parameters = reader.header().parameters;
  try {
    octree.block = layoutBlock(reader.loadTree());
  } catch (const std::invalid_argument& e) {
    fail(path, e.what());
  }
  return octree;
}

void writeOctree(const std::filesystem::path& path, const Octree& octree, const StoreWriteOptions& options) {
  writeStore(path, readBlock(octree.block.view()), octree.transform, octree.parameters, options);
}

}  // namespace svo
