// Runs the libFuzzer targets over the store reader (tests/fuzz/fuzz_store.cpp), the streaming PLY reader
// (tests/fuzz/fuzz_ply.cpp), the point-cloud readers (tests/fuzz/fuzz_points.cpp), the server's request
// parsers (tests/fuzz/fuzz_request.cpp) and the view stream's messages (tests/fuzz/fuzz_view.cpp) for a
// bounded number of inputs, each seeded with small valid inputs.
// tools/scripts/test.sh builds the targets with clang and sets SVO_FUZZ_STORE, SVO_FUZZ_PLY, SVO_FUZZ_POINTS,
// SVO_FUZZ_REQUEST and SVO_FUZZ_VIEW; without them (a plain g++ build) the tests are skipped.
#include <gtest/gtest.h>

#include <array>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/builder/gen.hpp"
#include "svo/store/store_writer.hpp"
#include "svo/store/view_stream.hpp"

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

TEST(Fuzz, PointCloudReadersRejectMutatedFilesCleanly) {
  const char* fuzzer = std::getenv("SVO_FUZZ_POINTS");
  if (!fuzzer || !*fuzzer)
    GTEST_SKIP() << "SVO_FUZZ_POINTS is not set (tools/scripts/test.sh builds the target)";
  const fs::path dir = freshDir("svo_fuzz_points_");
  // Seeds: the first byte picks the reader (even: PLY, odd: .xyz). A binary PLY with normals and colors, an
  // ASCII one with a list element before the vertices, and .xyz lines of each layout.
  std::string binary =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\n"
      "property uchar green\nproperty uchar blue\nend_header\n";
  for (int i = 0; i < 3; ++i) {
    const float values[6] = {float(i), 0.5f * float(i), 1.0f, 0.0f, 0.0f, 1.0f};
    const unsigned char rgb[3] = {std::uint8_t(40 * i), 200, 7};
    binary.append(reinterpret_cast<const char*>(values), sizeof values);
    binary.append(reinterpret_cast<const char*>(rgb), sizeof rgb);
  }
  const std::array<std::pair<const char*, std::string>, 4> seeds = {{
      {"binary.ply", std::string(1, '\0') + binary},
      {"ascii.ply", std::string(1, '\0') +
                        "ply\nformat ascii 1.0\ncomment seed\nelement camera 1\nproperty list uchar int "
                        "ids\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\n"
                        "property float diffuse_red\nproperty float diffuse_green\nproperty float "
                        "diffuse_blue\nend_header\n3 1 2 3\n0 0 0 0.5 0.5 0.5\n1 2 3 1 0 0\n"},
      {"colors.xyz", "\x01# x y z r g b nx ny nz\n0 0 0 255 0 0 0 0 1\n1,2,3,0,255,0,0,1,0\n"},
      {"normals.xyz", "\x01" "0 0 0 0 0 1\n1 1 1 0 1 0\n2 0 1 1 0 0\n"},
  }};
  for (const auto& [name, bytes] : seeds) std::ofstream(dir / "seeds" / name, std::ios::binary) << bytes;
  EXPECT_TRUE(fuzz(fuzzer, dir)) << "the fuzzer found a failing input; its log and the input are in " << dir;
}

TEST(Fuzz, RequestParsersKeepTheirPromises) {
  const char* fuzzer = std::getenv("SVO_FUZZ_REQUEST");
  if (!fuzzer || !*fuzzer)
    GTEST_SKIP() << "SVO_FUZZ_REQUEST is not set (tools/scripts/test.sh builds the target)";
  const fs::path dir = freshDir("svo_fuzz_request_");
  // Inputs are "target NUL header NUL size" (fuzz_request.cpp): the forms the server meets.
  using namespace std::string_literals;  // the seeds hold NUL bytes
  const std::string seeds[] = {
      "/scene/slices/12\0bytes=0-99\0"s + "1000",
      "/sub/scene.svo?x=1\0bytes=-500\0"s + "300",
      "/%2E%2E%2Fetc/passwd\0W/\"abc\", \"def\"\0"s + "0",
      "/scenes/a/b/info\0Bearer tok-en.1~\0"s + "18446744073709551615",
      "/a/directory\0bytes=5-\0"s + "5",
  };
  int n = 0;
  for (const std::string& seed : seeds)
    std::ofstream(dir / "seeds" / ("seed" + std::to_string(n++)), std::ios::binary) << seed;
  EXPECT_TRUE(fuzz(fuzzer, dir)) << "the fuzzer found a failing input; its log and the input are in " << dir;
}

TEST(Fuzz, ViewStreamParsersKeepTheirPromises) {
  const char* fuzzer = std::getenv("SVO_FUZZ_VIEW");
  if (!fuzzer || !*fuzzer)
    GTEST_SKIP() << "SVO_FUZZ_VIEW is not set (tools/scripts/test.sh builds the target)";
  const fs::path dir = freshDir("svo_fuzz_view_");
  svo::stream::View view;
  view.id = 3;
  view.query.frustum = {{1, 0, 0, 1.5}};
  view.budgetBytes = 1 << 20;
  view.held = {1, 5};
  std::array<std::byte, svo::stream::kSliceFrameHeaderBytes> frame{};
  svo::stream::writeSliceFrameHeader({7, 9}, frame);
  const std::string seeds[] = {
      svo::stream::encodeView(view),
      svo::stream::encodeAck(4096),
      svo::stream::encodeWant(std::vector<std::uint32_t>{4, 2}),
      svo::stream::encodePlan(2, std::vector<std::uint32_t>{0, 3, 99}),
      svo::stream::encodeSliceError(2, 4, "slice 4: checksum mismatch"),
      std::string(reinterpret_cast<const char*>(frame.data()), frame.size()),
  };
  int n = 0;
  for (const std::string& seed : seeds)
    std::ofstream(dir / "seeds" / ("seed" + std::to_string(n++)), std::ios::binary) << seed;
  EXPECT_TRUE(fuzz(fuzzer, dir)) << "the fuzzer found a failing input; its log and the input are in " << dir;
}

}  // namespace
