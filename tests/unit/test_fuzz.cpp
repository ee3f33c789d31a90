// Runs the libFuzzer targets over the store reader (tests/fuzz/fuzz_store.cpp) and the streaming PLY reader
// (tests/fuzz/fuzz_ply.cpp) for a bounded number of inputs, each seeded with a small valid file.
// tools/scripts/test.sh builds the targets with clang and sets SVO_FUZZ_STORE and SVO_FUZZ_PLY; without them
// (a plain g++ build) the tests are skipped.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/builder/gen.hpp"
#include "svo/store/store_writer.hpp"

namespace fs = std::filesystem;

namespace {

// Inputs per CI run: a few seconds, enough to reach the directory and slice decoders from the seed.
constexpr int kFuzzRuns = 20000;
// Largest input: the seed store plus room for the fuzzer to grow it.
constexpr int kFuzzMaxBytes = 32768;

// Runs `fuzzer` from the seeds in dir/seeds; true when it found nothing (dir is then removed).
bool fuzz(const char* fuzzer, const fs::path& dir) {
  const std::string command = std::string(fuzzer) + " -runs=" + std::to_string(kFuzzRuns) +
                              " -max_len=" + std::to_string(kFuzzMaxBytes) +
                              " -seed=1 -artifact_prefix=" + (dir / "").string() + " " +
                              (dir / "work").string() + " " + (dir / "seeds").string() + " >" +
                              (dir / "log.txt").string() + " 2>&1";
  const bool clean = std::system(command.c_str()) == 0;
  if (clean) fs::remove_all(dir);
  return clean;
}

fs::path freshDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / (name + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "seeds");
  fs::create_directories(dir / "work");
  return dir;
}

TEST(Fuzz, StoreReaderRejectsMutatedStoresCleanly) {
  const char* fuzzer = std::getenv("SVO_FUZZ_STORE");
  if (!fuzzer || !*fuzzer)
    GTEST_SKIP() << "SVO_FUZZ_STORE is not set (tools/scripts/test.sh builds the target)";
  const fs::path dir = freshDir("svo_fuzz_");
  svo::BuildOptions options;
  options.levels = 4;
  svo::StoreWriteOptions store;
  store.sliceBytes = 256;
  svo::writeOctree(
      dir / "seeds" / "tetrahedra.svo",
      svo::buildOctree(svotest::makeRandomTriangles(9, 6, {-1, -1, -1}, {1, 1, 1}, 1.0), options), store);
  ASSERT_LT(fs::file_size(dir / "seeds" / "tetrahedra.svo"), std::uintmax_t(kFuzzMaxBytes));
  EXPECT_TRUE(fuzz(fuzzer, dir)) << "the fuzzer found a failing input; its log and the input are in " << dir;
}

TEST(Fuzz, PlyReaderRejectsMutatedFilesCleanly) {
  const char* fuzzer = std::getenv("SVO_FUZZ_PLY");
  if (!fuzzer || !*fuzzer)
    GTEST_SKIP() << "SVO_FUZZ_PLY is not set (tools/scripts/test.sh builds the target)";
  const fs::path dir = freshDir("svo_fuzz_ply_");
  // A small colored binary PLY, as svo gen writes them.
  svo::Mesh mesh = svotest::makeRandomTriangles(6, 7, {-1, -1, -1}, {1, 1, 1}, 1.0);
  for (const glm::dvec3& p : mesh.positions) mesh.colors.push_back(glm::vec4(glm::vec3(0.5 + 0.4 * p), 1.0f));
  svo::writePly(dir / "seeds" / "triangles.ply", mesh);
  ASSERT_LT(fs::file_size(dir / "seeds" / "triangles.ply"), std::uintmax_t(kFuzzMaxBytes));
  EXPECT_TRUE(fuzz(fuzzer, dir)) << "the fuzzer found a failing input; its log and the input are in " << dir;
}

}  // namespace
