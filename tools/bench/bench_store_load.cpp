// `svo bench store`'s load costs: a pager load's stages timed apart on one thread with the slices' bytes in
// memory (no disk and no frames beside them, so the numbers hold still between runs), per voxel against the
// 10 ns a worker may spend to keep up with a disk; and the designs that skip the layout: the pool's laid-out
// block bytes stored as they are, with what that costs on disk and to decompress, and the slices decoded
// straight into arrays per level, with what they take in memory and cost the caster.
#include "bench_store_load.hpp"

#include <algorithm>
#include <bit>
#include <cstddef>
#include <stdexcept>
#include <string>
#include <utility>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <zstd.h>

#include "bench_common.hpp"
#include "svo/client/level_raycast.hpp"
#include "svo/client/raycast.hpp"
#include "svo/client/render.hpp"
#include "svo/store/block.hpp"
#include "svo/store/format.hpp"
#include "svo/store/level_arrays.hpp"
#include "svo/store/store_types.hpp"

namespace svo::tools::bench {

namespace {

// Voxels of the levels measured: enough that a run lasts tens of milliseconds (timer and scheduler noise
// near 1%), few enough that a block stays under glibc's largest mmap threshold (32 MiB at about 15 B a
// voxel), so that from the second run on the layout writes into memory the run before freed, as a pager
// worker's loads do, not into freshly mapped pages.
constexpr std::uint64_t kLoadSampleVoxels = std::uint64_t(2) << 20;
// What a pager load may spend per voxel added to the pool: 100 M voxels a second on one core, so that a core
// or two keep up with a disk that reads slices at 1-2 GB/s (2-3 B a voxel on the generated terrains).
constexpr double kLoadGoalNanoseconds = 10.0;
// The view both casters are timed on: a square image of the sampled levels' cube, from the default view's
// direction (svo render) at this many cube sizes from its centre, with this field of view.
constexpr int kCastImageSize = 256;
constexpr float kCastEyeDistance = 1.8f;
constexpr float kCastFieldOfView = 0.6f;  // the image plane's width at unit distance
// The stored blocks' zstd levels: zstd's default and its strongest.
constexpr int kStoredBlockZstdLevels[] = {3, 19};

// The deepest level whose voxels, with those of the levels above, stay within kLoadSampleVoxels.
int deepestSampledLevel(const StoreIndex& index) {
  std::uint64_t voxels = 1;
  int deepest = 0;
  for (int level = 1; level <= index.header().parameters.levels && !index.slicesOfLevel(level).empty();
       ++level) {
    for (const std::uint32_t id : index.slicesOfLevel(level)) voxels += index.slices()[id].voxelCount;
    if (voxels > kLoadSampleVoxels && deepest > 0) break;
    deepest = level;
  }
  return deepest;
}

// A slice in the order both decoders take them: its level, its first parent's index in the level above, its
// index in the sampled ids.
struct SliceAt {
  int level = 0;
  std::size_t firstParent = 0, k = 0;
};

// Every sampled slice decoded onto the level above it, level by level in its parents' order: the level-order
// tree a pager load lays out. `order`, where given, hears that order.
void decodeLevels(const StoreIndex& index, int deepest, const std::vector<SliceBytes>& raw,
                  const std::vector<std::uint32_t>& ids, LevelOrderTree& tree,
                  std::vector<SliceAt>* order = nullptr) {
  tree.voxels.clear();
  tree.voxels.push_back({.color = index.header().rootColor, .normal = index.header().rootNormal});
  std::size_t levelBegin = 0, next = 0;
  for (int level = 1; level <= deepest; ++level) {
    const std::size_t levelEnd = tree.voxels.size();
    const std::span<SliceVoxel> parents(tree.voxels.data() + levelBegin, levelEnd - levelBegin);
    // Slices of one level cover disjoint runs of their parents: in the runs' order they append the level in
    // Morton order.
    std::vector<std::pair<std::size_t, std::size_t>> runs;  // parents' first index, slice's index in ids
    const std::size_t count = index.slicesOfLevel(level).size();
    for (std::size_t k = next; k < next + count; ++k)
      runs.push_back({std::size_t(sliceParents(index, ids[k], parents).data() - tree.voxels.data()), k});
    std::sort(runs.begin(), runs.end());
    for (const auto& [first, k] : runs) {
      decodeSlice(index, ids[k], raw[k], tree, first, first + index.slices()[ids[k]].parentCount);
      if (order) order->push_back({level, first - levelBegin, k});
    }
    next += count;
    levelBegin = levelEnd;
  }
}

// The same slices decoded into arrays per level (level_arrays.hpp), in `order`.
void decodeLevelArrays(const StoreIndex& index, int deepest, const std::vector<SliceBytes>& raw,
                       const std::vector<std::uint32_t>& ids, const std::vector<SliceAt>& order,
                       std::vector<OctreeLevel>& levels) {
  levels.resize(std::size_t(deepest) + 1);  // as a pager worker's arrays: their memory kept between loads
  for (OctreeLevel& level : levels) level.clear();
  levels[0] = rootLevel(index.header());
  for (const SliceAt& s : order)
    decodeSliceLevel(raw[s.k], index.slices()[ids[s.k]], index.header(), levels[std::size_t(s.level) - 1],
                     s.firstParent, levels[std::size_t(s.level)]);
}

// The level arrays against the tree decodeSlice gave: the same hierarchy, contours, and values each voxel
// shows (its own where its presence bit is set, else its parent's). Throws std::logic_error at the first
// difference, so that the bench never times a decoder that is wrong.
void checkLevelArrays(const LevelOrderTree& tree, const std::vector<OctreeLevel>& levels) {
  const auto fail = [](int level, std::size_t i, const char* what) {
    throw std::logic_error(
        fmt::format("level arrays: voxel {} of level {}: {} differs from decodeSlice's", i, level, what));
  };
  std::size_t parentStart = 0, start = 1;
  for (std::size_t l = 1; l < levels.size(); ++l) {
    const OctreeLevel& level = levels[l];
    if (start + level.voxels > tree.voxels.size()) fail(int(l), 0, "the voxel count");
    std::size_t parent = parentStart, childrenLeft = 0, contour = 0, color = 0;
    for (std::size_t i = 0; i < level.voxels; ++i) {
      while (childrenLeft == 0) childrenLeft = std::size_t(std::popcount(tree.voxels[parent++].childMask));
      --childrenLeft;
      const SliceVoxel& v = tree.voxels[start + i];
      const SliceVoxel& p = tree.voxels[parent - 1];
      if (level.childMasks[i] != v.childMask) fail(int(l), i, "the child mask");
      if (level.contourBits[i] != v.hasContour || (v.hasContour && level.contours[contour++] != v.contour))
        fail(int(l), i, "the contour");
      if (tree.hasNormals && latticeNormalBits(level.shownNormalCodes[i]) != v.normal)
        fail(int(l), i, "the normal");
      if (tree.hasColors && (level.colorBits[i] ? level.colors[color++] : p.color) != v.color)
        fail(int(l), i, "the color");
    }
    parentStart = start, start += level.voxels;
  }
}

// Primary rays of a pinhole view of the cube [1, 2]^3 (octree units), row by row.
std::vector<OctreeRay> viewRays() {
  const glm::vec3 back = -glm::normalize(glm::vec3(kDefaultViewDirection));
  const glm::vec3 eye = glm::vec3(1.5f) + kCastEyeDistance * back;
  const glm::vec3 right = glm::normalize(glm::cross(-back, glm::vec3(0.0f, 1.0f, 0.0f)));
  const glm::vec3 up = glm::cross(right, -back);
  std::vector<OctreeRay> rays;
  for (int y = 0; y < kCastImageSize; ++y)
    for (int x = 0; x < kCastImageSize; ++x) {
      const float u = (float(x) + 0.5f) / kCastImageSize - 0.5f,
                  v = (float(y) + 0.5f) / kCastImageSize - 0.5f;
      rays.push_back({.origin = eye, .direction = -back + kCastFieldOfView * (u * right + v * up)});
    }
  return rays;
}

// Both casters over the same rays, timed; throws std::logic_error where a hit differs.
LoadCosts::Casting measureCasting(const Block& block, const LevelOctree& levels, int runs) {
  const std::vector<OctreeRay> rays = viewRays();
  std::vector<CastHit> blockHits(rays.size());
  std::vector<LevelCastHit> levelHits(rays.size());
  CastOptions options;
  options.recordPath = false;  // depth alone: neither records the ancestors that attribute look-ups walk
  const auto summaries = timeInterleaved(
      runs,
      [&] {
        for (std::size_t i = 0; i < rays.size(); ++i) blockHits[i] = castRay(block.view(), rays[i], options);
      },
      [&] {
        for (std::size_t i = 0; i < rays.size(); ++i) levelHits[i] = castRay(levels, rays[i], options);
      });
  LoadCosts::Casting out{summaries[0], summaries[1], rays.size(), 0};
  for (std::size_t i = 0; i < rays.size(); ++i) {
    const CastHit& a = blockHits[i];
    const LevelCastHit& b = levelHits[i];
    if (a.hit != b.hit || (a.hit && (a.t != b.t || a.scale != b.scale || a.childSlot != b.childSlot)))
      throw std::logic_error(fmt::format("level arrays: ray {} hits otherwise than the block's", i));
    out.hits += a.hit;
  }
  return out;
}

// The block in slice-sized chunks, each compressed alone as a slice is.
std::vector<std::vector<char>> compressChunks(const AlignedBytes& block, std::size_t chunk, int level) {
  std::vector<std::vector<char>> out;
  for (std::size_t offset = 0; offset < block.size(); offset += chunk) {
    const std::size_t n = std::min(chunk, block.size() - offset);
    std::vector<char> packed(ZSTD_compressBound(n));
    const std::size_t size = ZSTD_compress(packed.data(), packed.size(), block.data() + offset, n, level);
    if (ZSTD_isError(size)) throw std::runtime_error(std::string("zstd: ") + ZSTD_getErrorName(size));
    packed.resize(size);
    out.push_back(std::move(packed));
  }
  return out;
}

LoadCosts::StoredBlock measureStoredBlock(const Block& block, AttributeLayout attributes, std::size_t chunk,
                                          int zstdLevel, int runs) {
  LoadCosts::StoredBlock r;
  r.attributes = attributes;
  r.memoryBytes = block.bytes().size();
  r.zstdLevel = zstdLevel;
  const std::vector<std::vector<char>> chunks = compressChunks(block.bytes(), chunk, zstdLevel);
  for (const auto& c : chunks) r.diskBytes += c.size();
  AlignedBytes back(block.bytes().size(), /*zeroed=*/false);
  r.decompress = timeRuns(runs, [&] {
    std::size_t offset = 0;
    for (const auto& c : chunks) {
      const std::size_t n = ZSTD_decompress(back.data() + offset, back.size() - offset, c.data(), c.size());
      if (ZSTD_isError(n)) throw std::runtime_error(std::string("zstd: ") + ZSTD_getErrorName(n));
      offset += n;
    }
  });
  return r;
}

std::string nanosecondsPerVoxel(double seconds, std::uint64_t voxels) {
  return fmt::format("{:.1f} ns", seconds * 1e9 / double(voxels));
}
std::string voxelsPerSecond(double seconds, std::uint64_t voxels) {
  return fmt::format("{:.0f} M", double(voxels) / seconds * 1e-6);
}

}  // namespace

LoadCosts measureLoadCosts(const StoreReader& reader, int runs) {
  const StoreIndex& index = reader.index();
  LoadCosts costs;
  costs.deepestLevel = deepestSampledLevel(index);
  std::vector<std::uint32_t> ids;  // level by level, as decodeLevels takes them
  for (int level = 1; level <= costs.deepestLevel; ++level)
    for (const std::uint32_t id : index.slicesOfLevel(level)) {
      ids.push_back(id);
      costs.voxels += index.slices()[id].voxelCount;
      costs.storeDiskBytes += index.slices()[id].compressedBytes;
    }
  costs.slices = ids.size();
  costs.voxels += 1;  // the root
  spdlog::info("load costs: levels 1-{} ({} voxels), {} runs ...", costs.deepestLevel,
               formatCount(costs.voxels), runs);
  std::vector<SliceBytes> sliceBytes(ids.size());
  LevelOrderTree tree;
  tree.hasColors = index.header().hasColors, tree.hasNormals = index.header().hasNormals;
  tree.voxels.reserve(costs.voxels);  // as a pager worker's array: reserved once, kept between loads
  LayoutOptions rawLayout, compressedLayout;
  // A store's values: the store decided what inherits.
  rawLayout.inheritEqualOnly = compressedLayout.inheritEqualOnly = true;
  compressedLayout.attributes = AttributeLayout::Compressed;
  // A pause hook keeps the unit encoding on this thread, as a pager worker's is.
  rawLayout.betweenPasses = compressedLayout.betweenPasses = [] {};
  Block rawBlock, compressedBlock;
  for (std::size_t k = 0; k < ids.size(); ++k) sliceBytes[k] = reader.readSlice(ids[k]);
  std::vector<SliceAt> order;
  decodeLevels(index, costs.deepestLevel, sliceBytes, ids, tree, &order);
  std::vector<OctreeLevel> levels;
  const auto summaries = timeInterleaved(
      runs,
      [&] {
        for (std::size_t k = 0; k < ids.size(); ++k) sliceBytes[k] = reader.readSlice(ids[k]);
      },
      [&] { decodeLevels(index, costs.deepestLevel, sliceBytes, ids, tree); },
      [&] { rawBlock = layoutBlock(tree, rawLayout, &costs.blockStats[0]); },
      [&] { compressedBlock = layoutBlock(tree, compressedLayout, &costs.blockStats[1]); },
      [&] { decodeLevelArrays(index, costs.deepestLevel, sliceBytes, ids, order, levels); });
  costs.read = summaries[0], costs.decode = summaries[1];
  costs.layoutRaw = summaries[2], costs.layoutCompressed = summaries[3];
  costs.levelArrays.decode = summaries[4];
  costs.levelArrays.bytes = bytesOf(levels, index.header());
  checkLevelArrays(tree, levels);
  spdlog::info("load costs: casting rays through the block and the level arrays ...");
  costs.casting = measureCasting(rawBlock, LevelOctree(levels, index.header()), runs);
  costs.leaves = std::uint64_t(std::count_if(tree.voxels.begin(), tree.voxels.end(),
                                             [](const SliceVoxel& v) { return v.childMask == 0; }));
  const std::size_t chunk = std::max<std::size_t>(index.header().sliceBytes, kPageBytes);
  for (const int level : kStoredBlockZstdLevels) {
    spdlog::info("load costs: the blocks at zstd -{} ...", level);
    costs.stored.push_back(measureStoredBlock(rawBlock, AttributeLayout::Raw, chunk, level, runs));
    costs.stored.push_back(
        measureStoredBlock(compressedBlock, AttributeLayout::Compressed, chunk, level, runs));
  }
  return costs;
}

void printLoadCosts(const LoadCosts& costs) {
  printTitle("What a load costs per voxel (one thread, the slices' bytes in memory)");
  fmt::print("levels 1-{} of the store: {} slices, {} voxels, {} of them leaves here; median of the runs\n",
             costs.deepestLevel, costs.slices, formatCount(costs.voxels), formatCount(costs.leaves));
  const std::uint64_t n = costs.voxels;
  Table stages({"stage", "time", "per voxel", "voxels per s", "goal"});
  const auto row = [&](const std::string& name, double seconds, const std::string& goal) {
    stages.addRow(
        {name, formatSeconds(seconds), nanosecondsPerVoxel(seconds, n), voxelsPerSecond(seconds, n), goal});
  };
  row("read + XXH3 + zstd (readSlice, page cache)", costs.read.median, "");
  row("decode (decodeSlice onto the level above)", costs.decode.median, "");
  row("layout, raw attributes (layoutBlock)", costs.layoutRaw.median, "");
  row("layout, compressed attributes", costs.layoutCompressed.median, "");
  const std::string goal = fmt::format("<= {:.0f} ns", kLoadGoalNanoseconds);
  row("a load, raw attributes (the three)", costs.read.median + costs.decode.median + costs.layoutRaw.median,
      goal);
  row("a load, compressed attributes",
      costs.read.median + costs.decode.median + costs.layoutCompressed.median, goal);
  stages.print();
  fmt::print(
      "a pager load does these on a region's levels (svo bench stream prints them per stage with the disk, "
      "the "
      "frames\nand the levels it reads back); goal: a worker keeping up with the disk, {:.0f} ns a voxel "
      "(100 M voxels per second per core)\n",
      kLoadGoalNanoseconds);

  printTitle("The pool's blocks stored as laid out instead (no decode, no layout: decompress and link)");
  const double leaves = double(std::max<std::uint64_t>(costs.leaves, 1));
  Table stored({"block", "in memory", "zstd", "on disk", "vs the store's slices", "decompress per voxel",
                "voxels per s"});
  for (const LoadCosts::StoredBlock& s : costs.stored)
    stored.addRow({fmt::format("{} attributes", nameOf(s.attributes)),
                   fmt::format("{:.2f} B/leaf", double(s.memoryBytes) / leaves),
                   fmt::format("-{}", s.zstdLevel),
                   fmt::format("{:.2f} B/leaf", double(s.diskBytes) / leaves),
                   fmt::format("{:.2f}x", double(s.diskBytes) /
                                              double(std::max<std::uint64_t>(costs.storeDiskBytes, 1))),
                   nanosecondsPerVoxel(s.decompress.median, n), voxelsPerSecond(s.decompress.median, n)});
  stored.print();
  fmt::print(
      "the store's slices of these levels: {:.2f} B per leaf voxel on disk. Leaves here: voxels without "
      "children "
      "in levels\n1-{}. Stored blocks: compressed in slice-sized chunks, each alone\n",
      double(costs.storeDiskBytes) / leaves, costs.deepestLevel);

  printTitle("The slices decoded into arrays per level instead (no voxel records, no layout)");
  Table levelCost({"stage", "time", "per voxel", "voxels per s", "goal"});
  const double levelDecode = costs.levelArrays.decode.median;
  levelCost.addRow({"decode into level arrays (decodeSliceLevel)", formatSeconds(levelDecode),
                    nanosecondsPerVoxel(levelDecode, n), voxelsPerSecond(levelDecode, n), ""});
  levelCost.addRow({"a load: read + XXH3 + zstd, then that", formatSeconds(costs.read.median + levelDecode),
                    nanosecondsPerVoxel(costs.read.median + levelDecode, n),
                    voxelsPerSecond(costs.read.median + levelDecode, n), goal});
  levelCost.print();
  Table pools({"pool", "hierarchy", "contours", "colors", "normals", "in all"});
  const auto perLeaf = [&](std::uint64_t bytes) {
    return fmt::format("{:.2f} B/leaf", double(bytes) / leaves);
  };
  const LevelArrayBytes& b = costs.levelArrays.bytes;
  pools.addRow({"level arrays (normals: the store's 16-bit codes)", perLeaf(b.hierarchy), perLeaf(b.contours),
                perLeaf(b.colors), perLeaf(b.normals), perLeaf(b.total())});
  for (int k = 0; k < 2; ++k) {
    const LayoutStats& s = costs.blockStats[k];
    pools.addRow({fmt::format("blocks, {} attributes", k == 0 ? "raw" : "compressed"),
                  perLeaf(s.hierarchyBytes), perLeaf(s.contourBytes), perLeaf(s.colorBytes),
                  perLeaf(s.normalBytes), perLeaf(s.totalBytes)});
  }
  pools.print();
  const LoadCosts::Casting& c = costs.casting;
  Table casting({"caster (castRay, one thread)", "per ray", "vs the block's"});
  const auto perRay = [&](double seconds) {
    return fmt::format("{:.0f} ns", seconds * 1e9 / double(c.rays));
  };
  casting.addRow({"the raw block", perRay(c.block.median), "1.00x"});
  casting.addRow({"the level arrays", perRay(c.levels.median),
                  fmt::format("{:.2f}x", c.levels.median / c.block.median)});
  casting.print();
  fmt::print(
      "level arrays: a voxel's children follow those the child masks before it count "
      "(a 32-bit count per {} voxels), and\n"
      "a present contour, color or normal those the presence bits before it count "
      "(a 32-bit count per {} voxels).\n"
      "Measured as the layout a pool could hold: checked against decodeSlice's tree, "
      "and cast (depth only, one ray\n"
      "at a time) through a {} x {} view of their cube, {} of its rays hitting as in the block, "
      "bit for bit\n",
      kChildCountGroup, kPresenceCountGroup, kCastImageSize, kCastImageSize, formatCount(c.hits));
}

}  // namespace svo::tools::bench
