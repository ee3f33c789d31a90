// End-to-end: the `svo` command on good and bad input. Bad input must give one clear error line naming the
// problem, a non-zero exit and no file at the target path. When SVO_ASAN_BINARY is set (tools/scripts/test.sh
// builds it) the same runs happen under AddressSanitizer, which turns any memory error into a failure.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>
#include <csignal>
#include <cstring>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <nlohmann/json.hpp>

#include "cli_fixture.hpp"
#include "command_helpers.hpp"
#include "reference.hpp"
#include "svo/store/store_reader.hpp"

namespace fs = std::filesystem;
using namespace svotest::cli;

TEST_F(Cli, BuildAndRenderRoundTrip) {
  const fs::path svoFile = dir_ / "tet.svo", png = dir_ / "tet.png", exr = dir_ / "tet.exr";
  CommandResult b = svo("build " + tetrahedron().string() + " -o " + svoFile.string() + " --levels 6");
  ASSERT_EQ(b.exitCode, 0) << b.err;
  const svo::Octree octree = svo::readOctree(svoFile);
  EXPECT_EQ(octree.parameters.levels, 6);
  // The build report: phases, and voxel counts per level that add up and match the store.
  const nlohmann::json report = nlohmann::json::parse(slurp(dir_ / "tet.svo.build.json"));
  for (const char* phase : {"load", "voxelize", "write"})
    EXPECT_GE(report.at("phaseSeconds").at(phase).get<double>(), 0.0);
  std::uint64_t voxels = 0;
  for (const auto& v : report.at("voxelsPerLevel")) voxels += v.get<std::uint64_t>();
  EXPECT_EQ(voxels, report.at("voxels").get<std::uint64_t>());
  EXPECT_EQ(voxels, svo::StoreReader(svoFile).loadTree().voxels.size());
  EXPECT_GT(report.at("peakResidentBytes").get<std::uint64_t>(), 0u);
  // No colors in an OBJ without materials: no color attachment (leave out what the scene does not need).
  EXPECT_EQ(octree.block.view().attachment(svo::AttachmentType::Color), nullptr);
  EXPECT_NE(octree.block.view().attachment(svo::AttachmentType::Normal), nullptr);
  CommandResult r = svo("render " + svoFile.string() + " -o " + png.string() + " --width 64 --height 48");
  ASSERT_EQ(r.exitCode, 0) << r.err;
  EXPECT_TRUE(fs::file_size(png) > 0);
  EXPECT_NE(r.out.find("Mrays/s"), std::string::npos);
  CommandResult x =
      svo("render " + svoFile.string() + " -o " + exr.string() + " --width 32 --height 32 --aux");
  ASSERT_EQ(x.exitCode, 0) << x.err;
}

// A build killed with SIGKILL mid-way leaves no store at the target; --resume keeps the cells on disk and
// gives the same octree as an in-core build.
TEST_F(Cli, OutOfCoreBuildSurvivesSigkillAndResumes) {
  const fs::path mesh = dir_ / "sphere.ply", store = dir_ / "s.svo", inCore = dir_ / "in.svo";
  ASSERT_EQ(svo("gen sphere --triangles 20k -o " + mesh.string()).exitCode, 0);
  const std::string build = "build " + mesh.string() + " --levels 9 --cell-level 3 --threads 1 -o ";
  ASSERT_EQ(svo(build.substr(0, build.find(" --cell-level")) + " -o " + inCore.string()).exitCode, 0);

  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    const int null = ::open("/dev/null", O_WRONLY);
    ::dup2(null, 1), ::dup2(null, 2);
    const std::string bin = svotest::svoBinary(), m = mesh.string(), s = store.string();
    ::execl(bin.c_str(), bin.c_str(), "build", m.c_str(), "--levels", "9", "--cell-level", "3", "--threads",
            "1", "-o", s.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  // Kill it once two cells are on disk (or when it is done, whichever comes first).
  const fs::path work = store.string() + ".build";
  for (int i = 0; i < 3000; ++i) {
    std::size_t cells = 0;
    std::error_code ec;
    for (fs::directory_iterator it(work, ec), end; !ec && it != end; it.increment(ec))
      cells += it->path().extension() == ".bin";
    if (cells >= 2 || ::waitpid(pid, nullptr, WNOHANG) == pid) break;
    ::usleep(10000);
  }
  ::kill(pid, SIGKILL);
  ::waitpid(pid, nullptr, 0);
  const bool interrupted = !fs::exists(store);
  if (interrupted) EXPECT_TRUE(fs::exists(work / "manifest.json"));
  std::printf("the build was %s\n", interrupted ? "killed mid-way" : "done before the kill");

  const CommandResult resumed = svo(build + store.string() + " --resume");
  ASSERT_EQ(resumed.exitCode, 0) << resumed.err;
  if (interrupted) EXPECT_EQ(resumed.out.find(" 0 reused"), std::string::npos) << resumed.out;
  const svo::VoxelTree a = svo::StoreReader(store).loadTree(), b = svo::StoreReader(inCore).loadTree();
  ASSERT_EQ(a.voxels.size(), b.voxels.size());
  EXPECT_EQ(svotest::differingVoxels(a, b), 0u);
  EXPECT_FALSE(fs::exists(work));
  EXPECT_EQ(svo("verify " + store.string()).exitCode, 0);

  // Bad out-of-core options: one line, nothing written.
  const fs::path none = dir_ / "none.svo";
  EXPECT_EQ(svo("build " + mesh.string() + " --levels 5 --cell-level 5 -o " + none.string()).exitCode, 2);
  expectCleanFailure(svo("build " + mesh.string() + " --memory 1K -o " + none.string()), "--memory", none);
}

// Without --memory, a build whose in-core estimate exceeds half of the machine's memory goes out of core
// within that half, says so, and gives the in-core build's octree; one that fits stays in core.
TEST_F(Cli, BuildGoesOutOfCoreWhenInCoreWouldNotFitTheMachine) {
  const fs::path mesh = dir_ / "sphere.ply", inCore = dir_ / "in.svo", outOfCore = dir_ / "out.svo";
  ASSERT_EQ(svo("gen sphere --triangles 20k -o " + mesh.string()).exitCode, 0);
  const std::string build = "build " + mesh.string() + " --levels 10 -o ";
  // 6 M voxels: the two builds run the optimized binary (minutes under AddressSanitizer); the bad input
  // below runs the sanitized one.
  const CommandResult big = svo(build + inCore.string(), "", SVO_BINARY);
  ASSERT_EQ(big.exitCode, 0) << big.err;
  EXPECT_NE(big.out.find("building in core"), std::string::npos) << big.out;
  // About 550 MiB in core: a 900 MiB machine leaves it 450 MiB.
  const CommandResult small = svo(build + outOfCore.string(), "SVO_MACHINE_MEMORY=900M", SVO_BINARY);
  ASSERT_EQ(small.exitCode, 0) << small.err;
  EXPECT_NE(small.out.find("building out of core within 450.0 MiB"), std::string::npos) << small.out;
  EXPECT_NE(small.out.find("out of core: "), std::string::npos) << small.out;
  const svo::VoxelTree a = svo::StoreReader(inCore).loadTree(), b = svo::StoreReader(outOfCore).loadTree();
  ASSERT_EQ(a.voxels.size(), b.voxels.size());
  EXPECT_EQ(svotest::differingVoxels(a, b), 0u);
  // --resume alone resumes out of core within the default bound (here: nothing to resume, a fresh build).
  const fs::path resumed = dir_ / "resumed.svo";
  const CommandResult resume =
      svo("build " + tetrahedron().string() + " --levels 5 --resume -o " + resumed.string());
  ASSERT_EQ(resume.exitCode, 0) << resume.err;
  EXPECT_NE(resume.out.find("out of core: "), std::string::npos) << resume.out;
  // A machine too small even for the out-of-core build: one line naming the bound, nothing written.
  const fs::path none = dir_ / "none.svo";
  expectCleanFailure(svo(build + none.string(), "SVO_MACHINE_MEMORY=100M"), "default memory bound", none);
  expectCleanFailure(svo(build + none.string(), "SVO_MACHINE_MEMORY=lots"), "SVO_MACHINE_MEMORY", none);
}

TEST_F(Cli, FlatMeshBuilds) {
  // One bounding-box extent is zero: a valid scene, not an error.
  const fs::path mesh = write("flat.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n");
  CommandResult b = svo("build " + mesh.string() + " -o " + (dir_ / "flat.svo").string() + " --levels 5");
  EXPECT_EQ(b.exitCode, 0) << b.err;
}

TEST_F(Cli, MissingMesh) {
  expectCleanFailure(svo("build " + (dir_ / "nope.obj").string() + " -o " + (dir_ / "o.svo").string()),
                     "nope.obj", dir_ / "o.svo");
}

TEST_F(Cli, UnknownFormat) {
  const fs::path junk = write("junk.qqq", "this is not a mesh\n\x01\x02");
  expectCleanFailure(svo("build " + junk.string() + " -o " + (dir_ / "o.svo").string()), "junk.qqq",
                     dir_ / "o.svo");
}

TEST_F(Cli, EmptyMesh) {
  const fs::path empty = write("empty.obj", "# nothing\n");
  expectCleanFailure(svo("build " + empty.string() + " -o " + (dir_ / "o.svo").string()), "empty.obj",
                     dir_ / "o.svo");
}

TEST_F(Cli, NonFiniteVertex) {
  const fs::path bad = write("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
  expectCleanFailure(svo("build " + bad.string() + " -o " + (dir_ / "o.svo").string()), "nan.obj",
                     dir_ / "o.svo");
  const fs::path inf = write("inf.obj", "v 0 0 0\nv inf 0 0\nv 0 1 0\nf 1 2 3\n");
  expectCleanFailure(svo("build " + inf.string() + " -o " + (dir_ / "o.svo").string()), "inf.obj",
                     dir_ / "o.svo");
}

TEST_F(Cli, OnlyDegenerateTriangles) {
  const fs::path bad = write("degen.obj", "v 0 0 0\nv 1 1 1\nv 2 2 2\nv 3 0 0\nf 1 2 3\nf 1 1 4\n");
  expectCleanFailure(svo("build " + bad.string() + " -o " + (dir_ / "o.svo").string()), "triangles",
                     dir_ / "o.svo");
}

TEST_F(Cli, LevelsOutOfRange) {
  for (const char* levels : {"0", "24", "-3", "ten"}) {
    CommandResult r =
        svo("build " + tetrahedron().string() + " -o " + (dir_ / "o.svo").string() + " --levels " + levels);
    EXPECT_NE(r.exitCode, 0) << levels;
    EXPECT_NE(r.err.find("--levels"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "o.svo"));
  }
}

TEST_F(Cli, UnwritableOutput) {
  expectCleanFailure(svo("build " + tetrahedron().string() + " -o " + (dir_ / "missing" / "o.svo").string()),
                     "does not exist", dir_ / "missing" / "o.svo");
}

TEST_F(Cli, TruncatedForeignAndCorruptStores) {
  const fs::path good = dir_ / "good.svo";
  ASSERT_EQ(svo("build " + tetrahedron().string() + " -o " + good.string() + " --levels 6").exitCode, 0);
  std::string bytes = slurp(good);
  const fs::path png = dir_ / "x.png";
  const fs::path truncated = write("truncated.svo", bytes.substr(0, bytes.size() / 2));
  expectCleanFailure(svo("render " + truncated.string() + " -o " + png.string()), "truncated", png);
  const fs::path shortHeader = write("short.svo", bytes.substr(0, 20));
  expectCleanFailure(svo("render " + shortHeader.string() + " -o " + png.string()), "short.svo", png);
  const fs::path foreign =
      write("foreign.svo", "\x89PNG\r\n\x1a\n not an octree at all, but long enough to read");
  expectCleanFailure(svo("render " + foreign.string() + " -o " + png.string()), "not an svostream file", png);
  std::string flipped = bytes;
  flipped[flipped.size() - 10] ^= 0x40;
  const fs::path corrupt = write("corrupt.svo", flipped);
  expectCleanFailure(svo("render " + corrupt.string() + " -o " + png.string()), "checksum", png);
  std::string version = bytes;
  version[8] = 99;
  const fs::path future = write("future.svo", version);
  expectCleanFailure(svo("render " + future.string() + " -o " + png.string()), "version", png);
}

TEST_F(Cli, BadCameraAndOutput) {
  const fs::path good = dir_ / "good.svo";
  ASSERT_EQ(svo("build " + tetrahedron().string() + " -o " + good.string() + " --levels 5").exitCode, 0);
  expectCleanFailure(svo("render " + good.string() + " -o " + (dir_ / "x.bmp").string()), ".png or .exr",
                     dir_ / "x.bmp");
  expectCleanFailure(
      svo("render " + good.string() + " -o " + (dir_ / "x.png").string() + " --eye 1,1,1 --target 1,1,1"),
      "eye", dir_ / "x.png");
  const fs::path cams = write("cams.json", "{\"eye\": [1, 2], \"target\": [0, 0, 0]}");
  expectCleanFailure(
      svo("render " + good.string() + " -o " + (dir_ / "x.png").string() + " --camera " + cams.string()),
      "eye", dir_ / "x.png");
  expectCleanFailure(svo("render " + good.string() + " -o " + (dir_ / "x.png").string() + " --beam-tile 65"),
                     "--beam-tile", dir_ / "x.png");
}

// CLI11 reads "nan" and "inf" as floats and its range checks let them through; every float option refuses
// them, and the exact-unit angle its out-of-range values, before any work.
TEST_F(Cli, NonFiniteAndOutOfRangeNumbersAreRefused) {
  const fs::path good = dir_ / "good.svo";
  ASSERT_EQ(svo("build " + tetrahedron().string() + " -o " + good.string() + " --levels 5").exitCode, 0);
  const fs::path png = dir_ / "x.png";
  for (const std::string flag :
       {"--fov nan", "--lod-pixels inf", "--timeout nan", "--view nan,0,1", "--view 0,0,0",
        "--exact-normals nan", "--exact-normals -1", "--exact-normals 91"})
    expectCleanFailure(svo("render " + good.string() + " -o " + png.string() + " " + flag),
                       flag.substr(0, flag.find(' ')), png);
  for (const std::string flag : {"--geometry-error nan", "--leaf-contour-min-reduction inf"})
    expectCleanFailure(
        svo("build " + tetrahedron().string() + " -o " + (dir_ / "o.svo").string() + " " + flag),
        flag.substr(0, flag.find(' ')), dir_ / "o.svo");
  ASSERT_EQ(
      svo("render " + good.string() + " -o " + png.string() + " --attributes compressed --exact-normals 0")
          .exitCode,
      0);
  EXPECT_TRUE(fs::exists(png));
}

TEST_F(Cli, VerifyAndInspect) {
  const fs::path store = dir_ / "tet.svo";
  ASSERT_EQ(svo("build " + tetrahedron().string() + " -o " + store.string() + " --levels 6 --slice-size 256")
                .exitCode,
            0);
  const CommandResult ok = svo("verify " + store.string());
  EXPECT_EQ(ok.exitCode, 0) << ok.err;
  EXPECT_NE(ok.out.find("ok"), std::string::npos) << ok.out;
  // inspect --json: the per-level voxel counts add up to the tree's voxels below the root.
  const CommandResult json = svo("inspect --json " + store.string());
  ASSERT_EQ(json.exitCode, 0) << json.err;
  const nlohmann::json j = nlohmann::json::parse(json.out);
  std::uint64_t voxels = 0;
  for (const auto& level : j.at("perLevel")) voxels += level.at("voxels").get<std::uint64_t>();
  const svo::VoxelTree tree = svo::StoreReader(store).loadTree();
  EXPECT_EQ(voxels + 1, tree.voxels.size());
  EXPECT_EQ(j.at("formatVersion"), svo::kFileVersion);
  EXPECT_EQ(svo("inspect " + store.string()).exitCode, 0);
  // A store of the previous format reads, and inspect says a rebuild writes the current one.
  const CommandResult old =
      svo("inspect " + (fs::path(SVO_TEST_DATA) / "fixtures" / "sphere-v4.svo").string());
  EXPECT_EQ(old.exitCode, 0) << old.err;
  EXPECT_NE(old.out.find("format 4, "), std::string::npos) << old.out;
  EXPECT_NE(old.out.find("svo build writes format " + std::to_string(svo::kFileVersion)), std::string::npos)
      << old.out;
  // A flipped byte inside the slices: verify fails with one line naming the slice.
  std::string bytes = slurp(store);
  bytes[300] ^= 0x10;
  const fs::path bad = write("bad.svo", bytes);
  const CommandResult r = svo("verify " + bad.string());
  EXPECT_EQ(r.exitCode, 1);
  EXPECT_NE(r.err.find("slice"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("checksum"), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
}

TEST_F(Cli, GenStiffWritesEveryCaseAndTheyBuild) {
  const fs::path dir = dir_ / "stiff";
  const CommandResult r = svo("gen stiff -o " + dir.string());
  ASSERT_EQ(r.exitCode, 0) << r.err;
  std::size_t files = 0;
  for (const auto& e : fs::directory_iterator(dir)) files += e.path().extension() == ".ply";
  EXPECT_EQ(files, std::size_t(std::count(r.out.begin(), r.out.end(), '\n')));
  EXPECT_GE(files, 10u);
  // A stiff case loads back and builds like any mesh.
  EXPECT_EQ(
      svo("build " + (dir / "needle.ply").string() + " -o " + (dir_ / "needle.svo").string() + " --levels 9")
          .exitCode,
      0);
}

TEST_F(Cli, BeamTileDoesNotChangeTheImage) {
  // The beam pass (sec. 6.2) only skips space no ray can hit: the written PNGs are byte-identical.
  const fs::path store = dir_ / "tet.svo";
  ASSERT_EQ(svo("build " + tetrahedron().string() + " -o " + store.string() + " --levels 7").exitCode, 0);
  const std::string common = " --width 96 --height 80 --view 0.3,-0.5,-1";
  ASSERT_EQ(svo("render " + store.string() + " -o " + (dir_ / "off.png").string() + common + " --beam-tile 0")
                .exitCode,
            0);
  ASSERT_EQ(svo("render " + store.string() + " -o " + (dir_ / "on.png").string() + common + " --beam-tile 4")
                .exitCode,
            0);
  EXPECT_EQ(slurp(dir_ / "off.png"), slurp(dir_ / "on.png"));
}

TEST_F(Cli, GenWritesALoadableSceneAndRejectsBadParameters) {
  const fs::path ply = dir_ / "city.ply";
  const CommandResult ok = svo("gen city --triangles 2k --seed 4 -o " + ply.string());
  ASSERT_EQ(ok.exitCode, 0) << ok.err;
  EXPECT_NE(ok.out.find("wrote"), std::string::npos) << ok.out;
  ASSERT_EQ(svo("build " + ply.string() + " -o " + (dir_ / "city.svo").string() + " --levels 6").exitCode, 0);

  const fs::path target = dir_ / "bad.ply";
  expectCleanFailure(svo("gen castle -o " + target.string()), "unknown scene kind", target);
  expectCleanFailure(svo("gen terrain --triangles 0 -o " + target.string()), "--triangles", target);
  expectCleanFailure(svo("gen terrain --triangles 1e15 -o " + target.string()), "--triangles", target);
  expectCleanFailure(svo("gen terrain --triangles lots -o " + target.string()), "--triangles", target);
  expectCleanFailure(svo("gen sphere -o " + (dir_ / "scene.obj").string()), ".ply", dir_ / "scene.obj");
  const fs::path missing = dir_ / "no" / "such" / "folder" / "scene.ply";
  expectCleanFailure(svo("gen sphere -o " + missing.string()), "does not exist", missing);
  EXPECT_EQ(svo("gen castle -o " + target.string()).exitCode, 2);
}

TEST_F(Cli, StreamingRenderStressAndTheirBadInput) {
  const fs::path store = dir_ / "tet.svo";
  ASSERT_EQ(svo("build " + tetrahedron().string() + " -o " + store.string() + " --levels 7 --slice-size 4096")
                .exitCode,
            0);
  // One view until converged, and a two-frame path with its CSV and plot.
  const CommandResult one = svo("render " + store.string() + " --budget 16M --width 64 --height 64 -o " +
                                (dir_ / "one.png").string());
  ASSERT_EQ(one.exitCode, 0) << one.err;
  EXPECT_NE(one.out.find("converged in"), std::string::npos) << one.out;
  EXPECT_TRUE(fs::exists(dir_ / "one.png"));
  const fs::path cams =
      write("path.json",
            "[{\"eye\": [2, 1, 2], \"target\": [0.2, 0.2, 0.2], \"width\": 48, \"height\": 48},"
            " {\"eye\": [0.6, 0.5, 0.7], \"target\": [0.2, 0.2, 0.2], \"width\": 48, \"height\": 48}]");
  const CommandResult path = svo("render " + store.string() + " --budget 16M --path " + cams.string() +
                                 " -o " + (dir_ / "frames").string());
  ASSERT_EQ(path.exitCode, 0) << path.err;
  EXPECT_TRUE(fs::exists(dir_ / "frames" / "frame_0001.png"));
  EXPECT_TRUE(fs::exists(dir_ / "frames" / "error.png"));
  // Errors against the converged frames, per frame; an exact match (0) has no place on the log axis.
  EXPECT_LE(plotRows(dir_ / "frames" / "error.png", 1400, 600).size(), 4u);
  const std::string csv = slurp(dir_ / "frames" / "frames.csv");
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 3) << csv;  // header + 2 frames

  // Without --budget a store is read whole, or on a machine whose memory share cannot hold that, streamed
  // through a default pool until the view converges: the same image, bit for bit.
  const fs::path whole = dir_ / "whole.png", streamed = dir_ / "streamed.png";
  const CommandResult wholeRun =
      svo("render " + store.string() + " --width 64 --height 64 -o " + whole.string());
  ASSERT_EQ(wholeRun.exitCode, 0) << wholeRun.err;
  EXPECT_NE(wholeRun.out.find("read whole as one block"), std::string::npos) << wholeRun.out;
  const CommandResult streamedRun =
      svo("render " + store.string() + " --width 64 --height 64 -o " + streamed.string(),
          "SVO_MACHINE_MEMORY=1M");
  ASSERT_EQ(streamedRun.exitCode, 0) << streamedRun.err;
  EXPECT_NE(streamedRun.out.find("streamed through a 512.0 KiB block pool (default: reading it whole"),
            std::string::npos)
      << streamedRun.out;
  EXPECT_EQ(slurp(whole), slurp(streamed));
  // The same in the compressed attribute layout: its own image, whole and streamed alike.
  const std::string compressed = " --attributes compressed --width 64 --height 64 -o ";
  ASSERT_EQ(svo("render " + store.string() + compressed + (dir_ / "cw.png").string()).exitCode, 0);
  ASSERT_EQ(svo("render " + store.string() + compressed + (dir_ / "cs.png").string(), "SVO_MACHINE_MEMORY=1M")
                .exitCode,
            0);
  EXPECT_EQ(slurp(dir_ / "cw.png"), slurp(dir_ / "cs.png"));
  expectCleanFailure(svo("render " + store.string() + " --attributes dxt -o " + (dir_ / "a.png").string()),
                     "--attributes", dir_ / "a.png");

  // Without --budget a camera path streams through a default pool, and says so.
  const CommandResult defaultPath =
      svo("render " + store.string() + " --path " + cams.string() + " -o " + (dir_ / "y").string());
  ASSERT_EQ(defaultPath.exitCode, 0) << defaultPath.err;
  EXPECT_NE(defaultPath.out.find("block pool (default: a camera path streams"), std::string::npos)
      << defaultPath.out;

  // The stress test: at a budget below the store's decoded size the sequences evict and re-load; every row's
  // resident maximum stays within its budget.
  const CommandResult stress = svo("stress " + store.string() + " --budgets 64K,8M --frames 12 --size 32");
  ASSERT_EQ(stress.exitCode, 0) << stress.err;
  std::uint64_t evictions64K = 0;
  int rows = 0;
  for (const std::string& line : lines(stress.out)) {
    // budget, unit, sequence, frames, wanted view (2), wanted all (2), loads, evictions, cancelled, re-loads
    std::istringstream fields(line);
    double budget = 0.0, wantedView, wantedAll, resident;
    std::string budgetUnit, sequence, unit1, unit2, thrash, worst, ms1, p99, ms2, residentUnit;
    std::uint64_t frames = 0, loads = 0, evictions = 0, cancelled = 0, reloads = 0;
    if (!(fields >> budget >> budgetUnit >> sequence >> frames >> wantedView >> unit1 >> wantedAll >> unit2 >>
          loads >> evictions >> cancelled >> reloads >> thrash >> worst >> ms1 >> p99 >> ms2 >> resident >>
          residentUnit))
      continue;
    ++rows;
    EXPECT_EQ(frames, 12u) << line;
    EXPECT_LE(reloads, loads) << line;
    const double budgetBytes = budget * (budgetUnit == "KiB" ? 1024.0 : 1048576.0);
    EXPECT_LE(resident * (residentUnit == "KiB" ? 1024.0 : 1048576.0), budgetBytes) << line;
    if (budgetUnit == "KiB") evictions64K += evictions;
  }
  EXPECT_EQ(rows, 6) << stress.out;  // two budgets, three sequences
  EXPECT_GT(evictions64K, 0u) << stress.out;

  // The soak: rows over time with the resident set, and its plot.
  const fs::path soak = dir_ / "soak";
  const CommandResult soaked = svo("stress " + store.string() +
                                   " --budgets 64K --frames 6 --size 32 --minutes 0.02 -o " + soak.string());
  ASSERT_EQ(soaked.exitCode, 0) << soaked.err;
  const std::vector<std::string> soakRows = lines(slurp(soak / "soak.csv"));
  ASSERT_GE(soakRows.size(), 2u);
  EXPECT_EQ(soakRows[0], "seconds,budget,sequence,loads,evictions,cancelled,reloads,max_resident,rss_bytes");
  EXPECT_GT(std::stoull(soakRows.back().substr(soakRows.back().rfind(',') + 1)), 0u) << soakRows.back();
  EXPECT_TRUE(fs::exists(soak / "soak_rss.png"));
  // A point per soak row: seconds and the resident set in MiB, as soak.csv has them.
  const std::vector<std::string> rssPoints = plotRows(soak / "soak_rss.png", 1000, 700);
  ASSERT_EQ(rssPoints.size(), soakRows.size() - 1);
  const std::string& lastRow = soakRows.back();
  const double lastRss = std::stod(lastRow.substr(lastRow.rfind(',') + 1)) / double(1 << 20);
  EXPECT_NEAR(std::stod(rssPoints.back().substr(rssPoints.back().rfind(',') + 1)), lastRss, 1e-6 * lastRss);

  // Bad input: a budget below the trunk, a path that is not an array, a stress soak without time.
  expectCleanFailure(svo("render " + store.string() + " --budget 1K -o " + (dir_ / "x.png").string()),
                     "budget", dir_ / "x.png");
  EXPECT_EQ(svo("stress " + store.string() + " --minutes 0").exitCode, 2);
  const fs::path notArray = write("bad.json", "{\"eye\": [1, 1, 1], \"target\": [0, 0, 0]}");
  expectCleanFailure(svo("render " + store.string() + " --budget 16M --path " + notArray.string() + " -o " +
                         (dir_ / "z").string()),
                     "array", dir_ / "z" / "frames.csv");
}
