// Level arrays (level_arrays.hpp) against decodeSlice's voxel records: every fixture store and a store of
// many small slices decode to the same hierarchy, contours and shown values; bad slices throw. Their caster
// (level_raycast.hpp) and their beam pass against the block's on the same stores: the same hits and the same
// start t, bit for bit.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <filesystem>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "paging/level_pool.hpp"
#include "paging/regions.hpp"
#include "reference.hpp"
#include "svo/client/beam.hpp"
#include "svo/client/level_raycast.hpp"
#include "svo/client/raycast.hpp"
#include "svo/client/render.hpp"
#include "svo/store/block.hpp"
#include "svo/store/codec.hpp"
#include "svo/store/format.hpp"
#include "svo/store/level_arrays.hpp"
#include "svo/store/store_reader.hpp"

namespace {

namespace fs = std::filesystem;

// A store decoded both ways, slice by slice in each level's Morton order.
struct Decoded {
  svo::LevelOrderTree tree;
  std::vector<std::size_t> levelStart{0, 1};  // in tree.voxels
  std::vector<svo::OctreeLevel> levels;
};

Decoded decodeBoth(const svo::StoreReader& reader) {
  const svo::StoreIndex& index = reader.index();
  const svo::StoreHeader& header = reader.header();
  Decoded d;
  d.tree.hasColors = header.hasColors, d.tree.hasNormals = header.hasNormals;
  d.tree.voxels.push_back({.color = header.rootColor, .normal = header.rootNormal});
  d.levels.push_back(svo::rootLevel(header));
  for (int level = 1; level <= header.parameters.levels && !index.slicesOfLevel(level).empty(); ++level) {
    const std::size_t begin = d.levelStart[std::size_t(level) - 1], end = d.tree.voxels.size();
    std::vector<std::pair<std::size_t, std::uint32_t>> order;  // first parent in the level, slice
    for (const std::uint32_t id : index.slicesOfLevel(level)) {
      const std::span<svo::SliceVoxel> level(d.tree.voxels.data() + begin, end - begin);
      order.push_back({std::size_t(svo::sliceParents(index, id, level).data() - level.data()), id});
    }
    std::sort(order.begin(), order.end());
    d.levels.emplace_back();
    for (const auto& [first, id] : order) {
      const svo::SliceBytes raw = reader.readSlice(id);
      svo::decodeSlice(index, id, raw, d.tree, begin + first, begin + first + index.slices()[id].parentCount);
      svo::decodeSliceLevel(raw, index.slices()[id], header, d.levels[std::size_t(level) - 1], first,
                            d.levels.back());
    }
    d.levelStart.push_back(d.tree.voxels.size());
  }
  return d;
}

// Every voxel's child mask, contour and shown values as the level arrays give them, against its record.
void expectSameVoxels(const Decoded& d) {
  for (std::size_t l = 1; l < d.levels.size(); ++l) {
    const svo::OctreeLevel& level = d.levels[l];
    ASSERT_EQ(level.voxels, d.levelStart[l + 1] - d.levelStart[l]) << "level " << l;
    ASSERT_EQ(level.contourBits.size(), level.voxels);
    std::size_t parent = d.levelStart[l - 1], siblingsLeft = 0, contour = 0, color = 0, normal = 0;
    for (std::size_t i = 0; i < level.voxels; ++i) {
      while (siblingsLeft == 0) siblingsLeft = std::size_t(std::popcount(d.tree.voxels[parent++].childMask));
      --siblingsLeft;
      const svo::SliceVoxel& v = d.tree.voxels[d.levelStart[l] + i];
      const svo::SliceVoxel& p = d.tree.voxels[parent - 1];
      SCOPED_TRACE("level " + std::to_string(l) + ", voxel " + std::to_string(i));
      EXPECT_EQ(level.childMasks[i], v.childMask);
      ASSERT_EQ(level.contourBits[i], v.hasContour);
      if (v.hasContour) EXPECT_EQ(level.contours[contour++], v.contour);
      if (d.tree.hasColors) EXPECT_EQ(level.colorBits[i] ? level.colors[color++] : p.color, v.color);
      if (d.tree.hasNormals) {
        const std::uint16_t code = level.shownNormalCodes[i];
        EXPECT_EQ(svo::latticeNormalBits(code), v.normal);
        if (level.normalBits[i]) EXPECT_EQ(level.normalCodes[normal++], code);
      }
    }
    EXPECT_EQ(contour, level.contours.size());
    EXPECT_EQ(color, level.colors.size());
    EXPECT_EQ(normal, level.normalCodes.size());
  }
}

TEST(LevelArrays, FixturesDecodeAsTheirVoxelRecords) {
  for (const char* file : {"cube-v4.svo", "sphere-v4.svo", "runs-v4.svo", "cube-v5.svo", "sphere-v5.svo",
                           "runs-v5.svo", "shaded-v5.svo"}) {
    SCOPED_TRACE(file);
    const svo::StoreReader reader(fs::path(SVO_TEST_DATA) / "fixtures" / file);
    const Decoded d = decodeBoth(reader);
    ASSERT_GT(d.levels.size(), 2u);
    expectSameVoxels(d);
  }
}

TEST(LevelArrays, ManySlicesPerLevelDecodeAsTheirVoxelRecords) {
  const svotest::TempFile store("svo_level_arrays", ".svo");
  svotest::writeSphereAndBoxStore(store.path, 4096);
  const svo::StoreReader reader(store.path);
  const Decoded d = decodeBoth(reader);
  const std::size_t slicesOfDeepest = reader.index().slicesOfLevel(int(d.levels.size()) - 1).size();
  ASSERT_GT(slicesOfDeepest, 4u) << "the store should split its levels into many slices";
  expectSameVoxels(d);
  // Bytes as bytesOf counts them: the deepest level has no child masks, each part presence bits and values.
  const svo::LevelArrayBytes b = svo::bytesOf(d.levels, reader.header());
  std::size_t masks = 0, contours = 0;
  for (std::size_t l = 0; l < d.levels.size(); ++l) {
    if (l + 1 < d.levels.size()) masks += d.levels[l].voxels;
    contours += d.levels[l].contours.size();
  }
  EXPECT_GT(b.hierarchy, masks);
  EXPECT_LT(b.hierarchy, masks + 4 * (masks / svo::kChildCountGroup + d.levels.size()));
  EXPECT_GT(b.contours, 4 * contours);
}

// Rays through the octree's cube [1, 2]^3: from eyes outside and inside it, in random directions, along the
// axes and grazing the faces of the voxel grid, with and without a level-of-detail footprint.
std::vector<svo::OctreeRay> testRays() {
  std::vector<svo::OctreeRay> rays;
  std::mt19937 rng(29);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
  for (const glm::vec3 eye :
       {glm::vec3(2.7f, 2.4f, 3.1f), glm::vec3(0.2f, 1.6f, 1.3f), glm::vec3(1.45f, 1.5f, 1.55f)})
    for (int i = 0; i < 3000; ++i) {
      svo::OctreeRay r;
      r.origin = eye;
      r.direction = glm::vec3(1.5f) - eye + 0.6f * glm::vec3(unit(rng), unit(rng), unit(rng));
      // Footprints that stop at coarser voxels further away: about a level-4 voxel (1/16) at t = 1, and
      // one a tenth of that.
      r.footprintSlope = i % 3 == 0 ? 0.0f : i % 3 == 1 ? 0.06f : 0.006f;
      rays.push_back(r);
    }
  for (int axis = 0; axis < 3; ++axis)
    for (int i = 0; i < 400; ++i) {
      svo::OctreeRay r;  // along an axis, on the grid's planes (k / 64) and between them
      r.origin =
          glm::vec3(1.0f + float(i % 20) / 19.0f, 1.0f + float(i / 20) / 19.0f, 1.0f + float(i % 7) / 64.0f);
      r.origin[axis] = i % 2 ? 2.5f : 0.5f;
      r.direction = glm::vec3(0.0f);
      r.direction[axis] = i % 2 ? -1.0f : 1.0f;
      rays.push_back(r);
      r.direction[(axis + 1) % 3] = 1e-4f;  // grazing
      rays.push_back(r);
    }
  return rays;
}

TEST(LevelArrays, CastRaysAsTheBlockDoes) {
  const svotest::TempFile store("svo_level_cast", ".svo");
  svotest::writeSphereAndBoxStore(store.path, 4096);
  for (const fs::path& path : {fs::path(SVO_TEST_DATA) / "fixtures" / "sphere-v5.svo",
                               fs::path(SVO_TEST_DATA) / "fixtures" / "runs-v5.svo",
                               fs::path(SVO_TEST_DATA) / "fixtures" / "shaded-v5.svo", store.path}) {
    SCOPED_TRACE(path.string());
    const svo::StoreReader reader(path);
    const svo::LevelOctree levels(decodeBoth(reader).levels, reader.header());
    const svo::Octree octree = svo::readOctree(reader);
    std::size_t hits = 0, lodStops = 0;
    for (const bool contours : {true, false}) {
      svo::CastOptions options;
      options.contours = contours;
      for (const svo::OctreeRay& ray : testRays()) {
        const svo::CastHit a = svo::castRay(octree.block.view(), ray, options);
        const svo::LevelCastHit b = svo::castRay(levels, ray, options);
        ASSERT_EQ(a.hit, b.hit);
        EXPECT_EQ(a.iterations, b.iterations);
        if (!a.hit) continue;
        ++hits, lodStops += !a.leaf;
        EXPECT_EQ(a.leaf, b.leaf);
        EXPECT_EQ(std::bit_cast<std::uint32_t>(a.t), std::bit_cast<std::uint32_t>(b.t));
        EXPECT_EQ(a.scale, b.scale);
        EXPECT_EQ(a.childSlot, b.childSlot);
        EXPECT_EQ(a.cubeMin, b.cubeMin);
        EXPECT_EQ(a.position, b.position);
        // What the voxel shows, its own value or an ancestor's (the block inherits equal values only).
        for (const svo::AttachmentType type : {svo::AttachmentType::Color, svo::AttachmentType::Normal})
          EXPECT_EQ(svo::hitAttribute(octree.block.view(), a, type), svo::hitAttribute(levels, b, type));
      }
    }
    EXPECT_GT(hits, 1000u);
    EXPECT_GT(lodStops, 50u);
  }
}

// castPacket over level arrays against castRay over them, ray by ray: the same hit, t, voxel, position,
// path and iteration count, bit for bit, with each SIMD loop this CPU has. Random rays (incoherent packets,
// axis-parallel and grazing ones among them) and a camera's pixels in castTile's 4x4 blocks (coherent
// packets, which descend together), in full packets and in partial ones of 13.
TEST(LevelArrays, PacketsCastAsCastRay) {
  const svotest::TempFile store("svo_level_packet", ".svo");
  svotest::writeSphereAndBoxStore(store.path, 4096);
  const auto same = [](const svo::LevelCastHit& a, const svo::LevelCastHit& b) {
    if (a.hit != b.hit || a.iterations != b.iterations) return false;
    if (!a.hit) return true;
    if (std::bit_cast<std::uint32_t>(a.t) != std::bit_cast<std::uint32_t>(b.t) || a.scale != b.scale ||
        !(a.parent == b.parent) || a.childSlot != b.childSlot || a.leaf != b.leaf)
      return false;
    for (int i = 0; i < 3; ++i)
      if (std::bit_cast<std::uint32_t>(a.position[i]) != std::bit_cast<std::uint32_t>(b.position[i]) ||
          std::bit_cast<std::uint32_t>(a.cubeMin[i]) != std::bit_cast<std::uint32_t>(b.cubeMin[i]))
        return false;
    for (int s = a.scale + 1; s < svo::kMaxLevels; ++s)
      if (!(a.pathParent[s] == b.pathParent[s])) return false;
    return true;
  };
  for (const fs::path& path : {fs::path(SVO_TEST_DATA) / "fixtures" / "sphere-v5.svo",
                               fs::path(SVO_TEST_DATA) / "fixtures" / "shaded-v5.svo", store.path}) {
    SCOPED_TRACE(path.string());
    const svo::StoreReader reader(path);
    const svo::LevelOctree levels(decodeBoth(reader).levels, reader.header());
    std::vector<svo::OctreeRay> rays = testRays();
    const svo::SceneTransform& transform = reader.header().transform;
    svo::Camera camera = svo::Camera::framing(transform, {-0.35, -0.25, -1.0}, 64, 48);
    for (const float lod : {0.0f, 1.0f})
      for (const double closer : {1.0, 0.3}) {
        svo::Camera c = camera;
        c.eye = c.target + closer * (c.eye - c.target);
        const svo::PixelRays pixels(transform, c, lod);
        for (int y = 0; y < c.height; y += 4)
          for (int x = 0; x < c.width; x += 4)
            for (int i = 0; i < 16; ++i) rays.push_back(pixels(x + i % 4, y + i / 4));
      }
    std::vector<svo::PacketSimd> loops{svo::PacketSimd::None};
    for (const svo::PacketSimd simd : {svo::PacketSimd::Avx512, svo::PacketSimd::Avx2})
      if (svo::cpuHas(simd)) loops.push_back(simd);
    std::size_t hits = 0;
    for (const svo::PacketSimd simd : loops)
      for (const bool contours : {true, false})
        for (const int lanes : {svo::kPacketLanes, 13}) {
          SCOPED_TRACE(
              fmt::format("loop {}, contours {}, packets of {}", svo::nameOf(simd), contours, lanes));
          svo::CastOptions options;
          options.contours = contours, options.recordPath = true, options.simd = simd;
          for (std::size_t first = 0; first < rays.size(); first += std::size_t(lanes)) {
            const int count = int(std::min<std::size_t>(std::size_t(lanes), rays.size() - first));
            svo::LevelCastHit packet[svo::kPacketLanes];
            svo::castPacket(levels.region(), &rays[first], count, options, packet);
            for (int l = 0; l < count; ++l) {
              const svo::LevelCastHit single = svo::castRay(levels, rays[first + std::size_t(l)], options);
              ASSERT_TRUE(same(single, packet[l])) << "ray " << first + std::size_t(l);
              hits += single.hit;
            }
          }
        }
    EXPECT_GT(hits, 10000u);
  }
}

// The beam pass (beam.hpp) over level arrays stops where it stops over the block of the same octree: the same
// start t, bit for bit, after the same cubes (the block's pass is checked against a brute-force reference in
// test_beam.cpp). Views from outside, grazing, and from inside the scene; tiles of 4, 8 and 13 pixels.
TEST(LevelArrays, BeamPassesStopWhereTheBlocksDo) {
  const svotest::TempFile store("svo_level_beam", ".svo");
  svotest::writeSphereAndBoxStore(store.path, 4096);
  for (const fs::path& path : {fs::path(SVO_TEST_DATA) / "fixtures" / "sphere-v5.svo",
                               fs::path(SVO_TEST_DATA) / "fixtures" / "runs-v5.svo", store.path}) {
    SCOPED_TRACE(path.string());
    const svo::StoreReader reader(path);
    const svo::LevelOctree levels(decodeBoth(reader).levels, reader.header());
    const svo::Octree octree = svo::readOctree(reader);
    const glm::dvec3 centre = octree.transform.toWorld(glm::dvec3(1.5));
    std::vector<svo::Camera> cameras = {svo::Camera::framing(octree.transform, {-0.35, -0.25, -1.0}, 61, 47),
                                        svo::Camera::framing(octree.transform, {0.0, -1.0, 1e-4}, 40, 40)};
    svo::Camera inside = cameras[0];
    inside.eye = centre + glm::dvec3(0.05, 0.02, 0.01) * octree.transform.size;
    inside.target = centre + glm::dvec3(1.0, 0.3, 0.2) * octree.transform.size;
    inside.fovYDegrees = 100.0;
    cameras.push_back(inside);
    std::size_t tiles = 0, emptyTiles = 0;
    for (const svo::Camera& camera : cameras)
      for (const float lod : {0.0f, 1.0f, 4.0f}) {
        const svo::PixelRays rays(octree.transform, camera, lod);
        for (const int tileSize : {4, 8, 13})
          svo::forEachTile(camera.width, camera.height, tileSize, 1, [&](const svo::PixelTile& tile) {
            const svo::BeamResult a = svo::castBeam(octree.block.view(), rays, tile);
            const svo::BeamResult b = svo::castBeam(levels.region(), rays, tile);
            ++tiles, emptyTiles += std::isinf(a.tStart);
            EXPECT_EQ(std::bit_cast<std::uint32_t>(a.tStart), std::bit_cast<std::uint32_t>(b.tStart))
                << "tile at (" << tile.x0 << ", " << tile.y0 << ")";
            EXPECT_EQ(a.cubesTested, b.cubesTested);
          });
      }
    EXPECT_GT(emptyTiles, 0u);
    EXPECT_LT(emptyTiles, tiles);
  }
}

// Regions of level arrays as a pager loads, deepens and evicts them, in random order: rays cast through them
// hit as the block of the whole octree cut to the resident slices does.
TEST(LevelArrays, PagedRegionsCastAsTheWholeOctreeCutToThem) {
  const svotest::TempFile store("svo_level_pool", ".svo");
  svotest::writeSphereAndBoxStore(store.path, 2048);
  for (const fs::path& path : {fs::path(SVO_TEST_DATA) / "fixtures" / "runs-v5.svo", store.path}) {
    SCOPED_TRACE(path.string());
    const svo::StoreReader reader(path);
    svo::paging::RegionTable table(reader.slices(), std::size_t(1) << 20, path.string());
    svo::paging::LevelPool pool(table, reader.slices(), reader.header());
    std::mt19937 rng(7);
    // Loads up to `count` of the region's next slices; a chain of several sometimes ends in a truncated
    // slice, which ends the growth at the slice before it.
    std::size_t cutShort = 0;
    const auto load = [&](std::uint32_t r, std::uint32_t count) {
      svo::paging::Region& region = table[r];
      std::vector<svo::SliceBytes> raw;
      for (std::uint32_t k = region.resident;
           k < std::min(region.resident + count, std::uint32_t(region.slices.size())); ++k)
        raw.push_back(reader.readSlice(region.slices[k]));
      const bool truncate = raw.size() >= 2 && rng() % 3 == 0;
      if (truncate) raw.back().resize(raw.back().size() / 2);
      std::optional<std::string> error;
      svo::paging::LevelGrowth growth = pool.grow(r, region.resident, raw, &error);
      ASSERT_EQ(growth.added, raw.size() - truncate) << error.value_or("");
      ASSERT_EQ(error.has_value(), truncate);
      cutShort += truncate;
      region.resident += growth.added;
      pool.install(r, std::move(growth));
    };
    load(0, 2);
    std::size_t checks = 0, crossings = 0;
    for (int step = 0; step < 40; ++step) {
      // Deepen a resident region, or load a region whose parent is complete, or evict a leaf region.
      std::vector<std::uint32_t> loadable, evictable;
      for (std::uint32_t r = 0; r < table.size(); ++r) {
        const svo::paging::Region& region = table[r];
        const bool parentComplete = region.parent < 0 || table[std::uint32_t(region.parent)].complete();
        if (!region.complete() && parentComplete &&
            (region.resident > 0 || table[std::uint32_t(region.parent)].resident))
          loadable.push_back(r);
        if (r != 0 && region.resident &&
            std::none_of(region.children.begin(), region.children.end(),
                         [&](std::uint32_t c) { return table[c].resident != 0; }))
          evictable.push_back(r);
      }
      if (loadable.empty() && evictable.empty()) break;
      if (!evictable.empty() && (loadable.empty() || rng() % 5 == 0)) {
        const std::uint32_t r = evictable[rng() % evictable.size()];
        pool.evict(r);
        table[r].resident = 0;
      } else {
        {
          const std::uint32_t count = 1 + rng() % 3;
          load(loadable[rng() % loadable.size()], count);
        }
      }
      if (step % 2 == 0) continue;
      std::vector<std::uint32_t> resident;
      for (std::uint32_t r = 0; r < table.size(); ++r)
        for (std::uint32_t k = 0; k < table[r].resident; ++k) resident.push_back(table[r].slices[k]);
      const svo::Block cut = svo::layoutBlock(svotest::truncatedTree(reader, resident), {});
      for (const svo::OctreeRay& ray : testRays()) {
        const svo::CastHit a = svo::castRay(cut.view(), ray);
        const svo::LevelCastHit b = svo::castRay(*pool.trunk(), ray);
        ASSERT_EQ(a.hit, b.hit);
        ASSERT_EQ(a.iterations, b.iterations);
        if (!a.hit) continue;
        ++checks, crossings += b.parent.region != pool.trunk();
        EXPECT_EQ(a.leaf, b.leaf);
        EXPECT_EQ(std::bit_cast<std::uint32_t>(a.t), std::bit_cast<std::uint32_t>(b.t));
        EXPECT_EQ(a.scale, b.scale);
        EXPECT_EQ(a.childSlot, b.childSlot);
        EXPECT_EQ(a.position, b.position);
        for (const svo::AttachmentType type : {svo::AttachmentType::Color, svo::AttachmentType::Normal})
          EXPECT_EQ(svo::hitAttribute(cut.view(), a, type), svo::hitAttribute(b, type));
      }
    }
    EXPECT_GT(checks, 10000u);
    EXPECT_GT(crossings, 1000u);  // hits in regions other than the trunk
    EXPECT_GT(cutShort, 0u);
  }
}

TEST(LevelArrays, LevelsThatAreNoOctreeAreRefused) {
  const svo::StoreReader reader(fs::path(SVO_TEST_DATA) / "fixtures" / "sphere-v5.svo");
  const svo::StoreHeader& header = reader.header();
  const std::vector<svo::OctreeLevel> good = decodeBoth(reader).levels;
  EXPECT_NO_THROW(svo::LevelOctree(good, header));
  EXPECT_THROW(svo::LevelOctree({}, header), std::invalid_argument);
  std::vector<svo::OctreeLevel> shortLevel = good;  // a level missing the children its parents count
  shortLevel[2].voxels -= 1;
  EXPECT_THROW(svo::LevelOctree(shortLevel, header), std::invalid_argument);
  std::vector<svo::OctreeLevel> cut = good;  // the deepest level's parents still have children
  cut.pop_back();
  EXPECT_THROW(svo::LevelOctree(cut, header), std::invalid_argument);
  std::vector<svo::OctreeLevel> lostNormal = good;  // a normal code short of the presence bits
  ASSERT_TRUE(header.hasNormals);
  lostNormal[2].normalCodes.pop_back();
  EXPECT_THROW(svo::LevelOctree(lostNormal, header), std::invalid_argument);
}

TEST(LevelArrays, BadSlicesThrow) {
  const svo::StoreReader reader(fs::path(SVO_TEST_DATA) / "fixtures" / "sphere-v5.svo");
  const svo::StoreHeader& header = reader.header();
  const std::uint32_t id = reader.index().slicesOfLevel(2).front();
  const svo::SliceInfo& slice = reader.index().slices()[id];
  // Level 1 as its own slice gives it, to decode level 2 on.
  svo::OctreeLevel root = svo::rootLevel(header), level1, level2;
  const std::uint32_t first = reader.index().slicesOfLevel(1).front();
  svo::decodeSliceLevel(reader.readSlice(first), reader.index().slices()[first], header, root, 0, level1);
  ASSERT_EQ(level1.voxels, slice.parentCount);
  const svo::SliceBytes good = reader.readSlice(id);
  const auto decode = [&](std::vector<std::byte> bytes, std::size_t firstParent = 0) {
    svo::OctreeLevel parents = level1, children;
    svo::decodeSliceLevel(bytes, slice, header, parents, firstParent, children);
  };
  const std::vector<std::byte> bytes(good.begin(), good.end());
  EXPECT_NO_THROW(decode(bytes));
  EXPECT_THROW(decode(bytes, 1), svo::SliceDecodeError);  // its parents run past their level
  EXPECT_THROW(decode(std::vector<std::byte>(bytes.begin(), bytes.end() - 1)), svo::SliceDecodeError);
  svo::SliceHead head;
  std::memcpy(&head, bytes.data(), sizeof head);
  const std::size_t masks = sizeof head + (head.parentCount + 7) / 8;
  std::vector<std::byte> zeroMask = bytes;
  zeroMask[masks] = std::byte{0};
  EXPECT_THROW(decode(zeroMask), svo::SliceDecodeError);
  std::vector<std::byte> moreChildren = bytes;  // a mask with a child more than the voxel count
  moreChildren[masks] = std::byte(std::to_integer<unsigned>(bytes[masks]) == 0xFF ? 0x7F : 0xFF);
  EXPECT_THROW(decode(moreChildren), svo::SliceDecodeError);
  std::vector<std::byte> noSplit = bytes;  // a split bit cleared: the masks outnumber the split parents
  for (std::size_t k = sizeof head; k < masks; ++k)
    if (noSplit[k] != std::byte{0}) {
      noSplit[k] &= std::byte(std::to_integer<unsigned>(noSplit[k]) - 1);
      break;
    }
  EXPECT_THROW(decode(noSplit), svo::SliceDecodeError);
  std::vector<std::byte> extraContour = bytes;  // a contour presence bit more than the contour count
  const std::size_t contourBits = masks + head.splitCount;
  for (std::size_t i = 0; i < head.voxelCount; ++i)
    if (!((std::to_integer<unsigned>(extraContour[contourBits + i / 8]) >> (i % 8)) & 1u)) {
      extraContour[contourBits + i / 8] |= std::byte(1u << (i % 8));
      break;
    }
  EXPECT_THROW(decode(extraContour), svo::SliceDecodeError);
}

}  // namespace
