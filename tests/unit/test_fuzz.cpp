// Runs the libFuzzer target over the store reader (tests/fuzz/fuzz_store.cpp) for a bounded number of inputs,
// seeded with a small valid store. tools/scripts/test.sh builds the target with clang and sets
// SVO_FUZZ_STORE; without it (a plain g++ build) the test is skipped.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/store/container.hpp"

namespace fs = std::filesystem;

namespace {

// Inputs per CI run: a few seconds, enough to reach the directory and slice decoders from the seed.
constexpr int kFuzzRuns = 20000;
// Largest input: the seed store plus room for the fuzzer to grow it.
constexpr int kFuzzMaxBytes = 32768;

TEST(Fuzz, StoreReaderRejectsMutatedStoresCleanly) {
  const char* fuzzer = std::getenv("SVO_FUZZ_STORE");
  if (!fuzzer || !*fuzzer)
    GTEST_SKIP() << "SVO_FUZZ_STORE is not set (tools/scripts/test.sh builds the target)";
  const fs::path dir = fs::temp_directory_path() / ("svo_fuzz_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "seeds");
  fs::create_directories(dir / "work");
  svo::BuildOptions options;
  options.levels = 4;
  svo::StoreWriteOptions store;
  store.sliceBytes = 256;
  svo::writeOctree(
      dir / "seeds" / "tetrahedra.svo",
      svo::buildOctree(svotest::makeRandomTriangles(9, 6, {-1, -1, -1}, {1, 1, 1}, 1.0), options), store);
  ASSERT_LT(fs::file_size(dir / "seeds" / "tetrahedra.svo"), std::uintmax_t(kFuzzMaxBytes));
  const std::string command = std::string(fuzzer) + " -runs=" + std::to_string(kFuzzRuns) +
                              " -max_len=" + std::to_string(kFuzzMaxBytes) +
                              " -seed=1 -artifact_prefix=" + (dir / "").string() + " " +
                              (dir / "work").string() + " " + (dir / "seeds").string() + " >" +
                              (dir / "log.txt").string() + " 2>&1";
  const int status = std::system(command.c_str());
  EXPECT_EQ(status, 0) << "the fuzzer found a failing input; its log and the input are in " << dir;
  if (status == 0) fs::remove_all(dir);
}

}  // namespace
