// The out-of-core build (builder/build.hpp buildStore) against the in-core build of the same mesh and
// options: the stores decode (StoreReader::loadTree) to the same octree, voxel for voxel, at every cell level
// and thread count, and hold the same slices (cube, run, level, bytes and parent), those spanning cells too;
// an interrupted build leaves no store, and resuming keeps the cells already on disk and still gives the same
// octree; a resume refuses a work folder of another build; too little memory is a clear error before any
// work; a damaged spilled cell is built again, not trusted.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <tuple>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/builder/gen.hpp"
#include "svo/store/store_reader.hpp"

namespace fs = std::filesystem;

namespace {

// A colored sphere and a box: cells at every level hold surface, some cells are empty.
svo::Mesh testMesh() {
  svo::Mesh mesh = svotest::makeSphere({0, 0, 0}, 1.0, 20, 20);
  svotest::appendMesh(mesh, svotest::makeBox({-1.2, -1.2, -0.2}, {0.3, -0.9, 0.9}));
  for (const glm::dvec3& p : mesh.positions)
    mesh.colors.push_back(glm::vec4(0.5 + 0.4 * p.x, 0.5 + 0.4 * p.y, 0.5 - 0.4 * p.z, 1.0));
  return mesh;
}

svo::StoreWriteOptions smallSlices() {
  svo::StoreWriteOptions write;
  write.sliceBytes = 4096;
  return write;
}

// The in-core store of the same build, written and decoded.
svo::VoxelTree inCoreTree(const svo::Mesh& mesh, const svo::BuildOptions& options) {
  const svotest::TempFile file("svo_ooc_incore", ".svo");
  svo::writeOctree(file.path, svo::buildOctree(mesh, options), smallSlices());
  return svo::StoreReader(file.path).loadTree();
}

// A store's slices by what they cover: (voxel level, cube level, cube, run) -> decoded bytes and the parent's
// key. Ids and file offsets may differ between two stores of the same slices.
using SliceKey = std::tuple<int, int, int, int, int, int, int>;
std::map<SliceKey, std::pair<svo::SliceBytes, SliceKey>> slicesByKey(const svo::StoreReader& reader) {
  const auto& slices = reader.slices();
  const auto key = [&](std::uint32_t id) {
    if (id == svo::SliceInfo::kNoSlice) return SliceKey{};
    const svo::SliceInfo& s = slices[id];
    return SliceKey{s.voxelLevel,  s.cubeLevel, s.cubeCoord.x, s.cubeCoord.y,
                    s.cubeCoord.z, s.firstSlot, s.lastSlot};
  };
  std::map<SliceKey, std::pair<svo::SliceBytes, SliceKey>> out;
  for (std::uint32_t id = 0; id < slices.size(); ++id)
    out[key(id)] = {reader.readSlice(id), key(slices[id].parentSlice)};
  return out;
}

void expectSameTree(const svo::VoxelTree& a, const svo::VoxelTree& b) {
  ASSERT_EQ(a.voxels.size(), b.voxels.size());
  EXPECT_EQ(a.hasColors, b.hasColors);
  EXPECT_EQ(svotest::differingVoxels(a, b), 0u) << "of " << a.voxels.size() << " voxels";
}

}  // namespace

TEST(OutOfCore, EqualsTheInCoreBuildAtEveryCellLevel) {
  const svo::Mesh mesh = testMesh();
  for (const bool errorStop : {false, true}) {
    svo::BuildOptions options;
    options.levels = 7;
    if (errorStop) options.geometryError = 1.0f, options.colorError = 8.0f;  // leaves above the finest level
    const svo::VoxelTree reference = inCoreTree(mesh, options);
    const svotest::TempFile inCore("svo_ooc_incore", ".svo");
    svo::writeOctree(inCore.path, svo::buildOctree(mesh, options), smallSlices());
    const auto inCoreSlices = slicesByKey(svo::StoreReader(inCore.path));
    for (const int cellLevel : {1, 2, 3, 6}) {
      SCOPED_TRACE("cell level " + std::to_string(cellLevel) + (errorStop ? ", error-driven stop" : ""));
      const svotest::TempFile store("svo_ooc", ".svo");
      svo::OutOfCoreOptions ooc;
      ooc.cellLevel = cellLevel;
      ooc.threads = cellLevel == 2 ? 2 : 1;
      const svo::OutOfCoreReport report =
          svo::buildStore(*svo::meshTriangleSource(mesh), options, smallSlices(), ooc, store.path);
      EXPECT_GT(report.cells, 1u);
      EXPECT_FALSE(fs::exists(store.path.string() + ".build"));  // the work folder goes with success
      const svo::StoreReader reader(store.path);
      expectSameTree(reader.loadTree(), reference);
      const auto slices = slicesByKey(reader);
      EXPECT_EQ(slices.size(), inCoreSlices.size());
      EXPECT_TRUE(slices == inCoreSlices) << "the out-of-core store's slices differ from the in-core store's";
      EXPECT_EQ(reader.verify(), reference.voxels.size());
      // The report's statistics count the whole octree once.
      std::uint64_t voxels = 0;
      for (const std::uint64_t v : report.stats.voxelsPerLevel) voxels += v;
      EXPECT_EQ(voxels, reference.voxels.size());
    }
  }
}

TEST(OutOfCore, AStreamedPlyBuildsTheOctreeOfTheLoadedMesh) {
  // The PLY is streamed (never loaded whole); the reference is assimp's load of the same file, in core.
  const svotest::TempFile ply("svo_ooc_stream", ".ply");
  svo::writePly(ply.path, testMesh());
  const svo::Mesh loaded = svo::loadMesh(ply.path);
  svo::BuildOptions options;
  options.levels = 7;
  const svo::VoxelTree reference = inCoreTree(loaded, options);
  const auto source = svo::openTriangleSource(ply.path);
  ASSERT_NE(source->format().find("streamed"), std::string::npos);
  const svotest::TempFile store("svo_ooc_stream", ".svo");
  svo::OutOfCoreOptions ooc;
  ooc.cellLevel = 3;
  ooc.threads = 2;
  const svo::OutOfCoreReport report = svo::buildStore(*source, options, smallSlices(), ooc, store.path);
  EXPECT_GT(report.cells, 8u);
  expectSameTree(svo::StoreReader(store.path).loadTree(), reference);
}

TEST(OutOfCore, AnInterruptedBuildResumesFromTheSpilledCells) {
  const svo::Mesh mesh = testMesh();
  svo::BuildOptions options;
  options.levels = 7;
  const svo::VoxelTree reference = inCoreTree(mesh, options);
  const svotest::TempFile store("svo_ooc_resume", ".svo");
  const fs::path work = store.path.string() + ".build";
  svo::OutOfCoreOptions ooc;
  ooc.cellLevel = 2;
  int spilled = 0;
  ooc.cellSpilled = [&](glm::ivec3) {
    if (++spilled == 5) throw std::runtime_error("interrupted");
  };
  EXPECT_THROW(svo::buildStore(*svo::meshTriangleSource(mesh), options, smallSlices(), ooc, store.path),
               std::runtime_error);
  EXPECT_FALSE(fs::exists(store.path));  // nothing half-written at the target
  ASSERT_TRUE(fs::exists(work / "manifest.json"));

  // One spilled cell damaged in its header (its root record): the resume must not trust it.
  std::vector<fs::path> cells;
  for (const auto& e : fs::directory_iterator(work))
    if (e.path().extension() == ".bin") cells.push_back(e.path());
  ASSERT_EQ(cells.size(), 5u);
  {
    std::fstream f(cells.front(), std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(40);
    const char byte = char(f.get() ^ 0xFF);
    f.seekp(40);
    f.put(byte);
  }

  // Resuming rebuilds only what is not on disk intact.
  ooc.resume = true;
  std::set<std::string> rebuilt;
  ooc.cellSpilled = [&](glm::ivec3 c) {
    rebuilt.insert(std::to_string(c.x) + std::to_string(c.y) + std::to_string(c.z));
  };
  const svo::OutOfCoreReport report =
      svo::buildStore(*svo::meshTriangleSource(mesh), options, smallSlices(), ooc, store.path);
  EXPECT_EQ(report.cellsReused, 4u);
  // Every cell of this mesh holds surface, so the reused and the rebuilt ones are all of them, once each.
  EXPECT_EQ(rebuilt.size() + report.cellsReused, report.cells);
  expectSameTree(svo::StoreReader(store.path).loadTree(), reference);
  EXPECT_FALSE(fs::exists(work));
}

TEST(OutOfCore, ResumeRefusesTheWorkFolderOfAnotherBuildAndSmallMemoryIsClear) {
  const svo::Mesh mesh = testMesh();
  svo::BuildOptions options;
  options.levels = 6;
  const svotest::TempFile store("svo_ooc_other", ".svo");
  svo::OutOfCoreOptions ooc;
  ooc.cellLevel = 2;
  ooc.cellSpilled = [](glm::ivec3) { throw std::runtime_error("interrupted"); };
  EXPECT_THROW(svo::buildStore(*svo::meshTriangleSource(mesh), options, smallSlices(), ooc, store.path),
               std::runtime_error);
  options.levels = 7;
  ooc.resume = true;
  ooc.cellSpilled = nullptr;
  try {
    svo::buildStore(*svo::meshTriangleSource(mesh), options, smallSlices(), ooc, store.path);
    ADD_FAILURE() << "a resume accepted another build's cells";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("levels"), std::string::npos) << e.what();
  }
  fs::remove_all(store.path.string() + ".build");

  svo::OutOfCoreOptions tiny;
  tiny.memoryBytes = 1024;
  try {
    svo::buildStore(*svo::meshTriangleSource(mesh), options, smallSlices(), tiny, store.path);
    ADD_FAILURE() << "1 KiB of memory was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("--memory"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(store.path));
}
