// End-to-end: the `svo` command on good and bad input. Bad input must give one clear error line naming the
// problem, a non-zero exit and no file at the target path. When SVO_ASAN_BINARY is set (tools/scripts/test.sh
// builds it) the same runs happen under AddressSanitizer, which turns any memory error into a failure.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>
#include <cmath>
#include <csignal>
#include <cstring>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>

#include <OpenImageIO/imageio.h>
#include <nlohmann/json.hpp>

#include "command_helpers.hpp"
#include "reference.hpp"
#include "svo/store/store_reader.hpp"

namespace fs = std::filesystem;

namespace {

struct CommandResult {
  int exitCode = 0;
  std::string out, err;
};

using svotest::slurp;

std::vector<std::string> lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) out.push_back(line);
  return out;
}

// The line of a printed table under `title` that starts with `first` (a row's first cell), or "" where either
// is missing.
std::string tableRow(const std::string& out, const std::string& title, const std::string& first) {
  const std::size_t at = out.find(title);
  const std::size_t row = at == std::string::npos ? at : out.find(first, at);
  return row == std::string::npos ? "" : out.substr(row, out.find('\n', row) - row);
}

// A plot as the plot driver leaves it: a PNG of `width` x `height` pixels that OpenImageIO reads, and beside
// it its data, NAME.csv. Returns the data rows (panel,series,x,y) after checking the header.
std::vector<std::string> plotRows(const fs::path& png, int width, int height) {
  const auto input = OIIO::ImageInput::open(png.string());
  EXPECT_TRUE(input) << png << ": " << OIIO::geterror();
  if (input) {
    EXPECT_EQ(input->spec().width, width) << png;
    EXPECT_EQ(input->spec().height, height) << png;
  }
  fs::path csv = png;
  csv.replace_extension(".csv");
  std::vector<std::string> rows = lines(slurp(csv));
  EXPECT_FALSE(rows.empty()) << csv;
  if (rows.empty()) return rows;
  EXPECT_EQ(rows.front(), "panel,series,x,y") << csv;
  rows.erase(rows.begin());
  return rows;
}

// The rows of `rows` that belong to the series `name` (second field, unquoted names only).
std::size_t countSeries(const std::vector<std::string>& rows, const std::string& name) {
  return std::size_t(std::count_if(rows.begin(), rows.end(), [&](const std::string& row) {
    return row.find("," + name + ",") != std::string::npos;
  }));
}

class Cli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("svo_cli_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // `environment`: variable assignments for this run ("SVO_MACHINE_MEMORY=1G"); `program`: the optimized
  // build instead of the sanitized one, for runs too long under AddressSanitizer.
  CommandResult svo(const std::string& args, const std::string& environment = "",
                    const std::string& program = svotest::svoBinary()) {
    const fs::path out = dir_ / "stdout.txt", err = dir_ / "stderr.txt";
    const std::string command =
        environment + " " + program + " " + args + " >" + out.string() + " 2>" + err.string();
    const int status = std::system(command.c_str());
    CommandResult r;
    r.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : 128;
    r.out = slurp(out);
    r.err = slurp(err);
    return r;
  }
  fs::path write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / name, std::ios::binary) << text;
    return dir_ / name;
  }
  // A tetrahedron: the smallest closed mesh.
  fs::path tetrahedron() {
    return write("tet.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n");
  }
  // Expects failure with exactly one line on stderr that mentions `needle`, and nothing at `target`.
  void expectCleanFailure(const CommandResult& r, const std::string& needle, const fs::path& target) {
    EXPECT_NE(r.exitCode, 0) << r.err;
    EXPECT_LT(r.exitCode, 128) << "crashed: " << r.err;
    EXPECT_NE(r.err.find(needle), std::string::npos) << "stderr: " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "stderr: " << r.err;
    EXPECT_EQ(r.err.find("AddressSanitizer"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(target));
    for (const auto& e : fs::recursive_directory_iterator(dir_))
      EXPECT_EQ(e.path().string().find(".tmp"), std::string::npos) << "left behind: " << e.path();
  }

  fs::path dir_;
};

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

TEST_F(Cli, BenchQualityWritesReportPlotAndImages) {
  const fs::path out = dir_ / "quality";
  const CommandResult r = svo("bench quality " + tetrahedron().string() +
                              " --size 48 --levels 4,5 --runs 1 --threads 1 -o " + out.string());
  ASSERT_EQ(r.exitCode, 0) << r.err;
  const std::string report = slurp(out / "quality.md");
  // 2 levels x 4 lod x contours on/off x beam on/off = 32 settings, one table row each.
  EXPECT_EQ(std::count(report.begin(), report.end(), '\n') >= 32, true) << report;
  EXPECT_NE(report.find("## Goals"), std::string::npos);
  for (const char* png : {"reference.png", "best.png", "worst-difference.png", "error-vs-time.png"}) {
    EXPECT_TRUE(fs::exists(out / png)) << png;
    EXPECT_GT(fs::file_size(out / png), 100u) << png;
  }
  // Three panels (RMSE, depth, silhouette), each with its Pareto front: at least one point per panel.
  const std::vector<std::string> plotted = plotRows(out / "error-vs-time.png", 1400, 1000);
  EXPECT_GE(countSeries(plotted, "Pareto front"), 3u);
  expectCleanFailure(svo("bench quality " + tetrahedron().string() + " --levels 4,x -o " + out.string()),
                     "--levels", dir_ / "nothing");
}

TEST_F(Cli, BenchQualityStreamWritesOneCurvePerSourceAndBudget) {
  const fs::path out = dir_ / "stream";
  // svo serve in process by its view stream and by range requests, behind a relay adding 1 ms each way.
  const CommandResult r = svo("bench quality " + tetrahedron().string() +
                              " --stream --levels 6 --budgets 128K,4M --sources local,serve,serve-range "
                              "--link-delay 1 --size 32 --threads 1 -o " +
                              out.string());
  ASSERT_EQ(r.exitCode, 0) << r.err;
  std::istringstream csv(slurp(out / "stream.csv"));
  std::string line;
  std::getline(csv, line);
  EXPECT_EQ(line.rfind("source,budget_bytes,seconds,", 0), 0u) << line;
  std::map<std::pair<std::string, long>, std::vector<double>> timesOf;
  while (std::getline(csv, line)) {
    std::istringstream fields(line);
    std::string source;
    std::getline(fields, source, ',');
    std::vector<double> v;
    for (std::string f; std::getline(fields, f, ',');) v.push_back(std::stod(f));
    ASSERT_EQ(v.size(), 7u) << line;
    for (const double x : v) EXPECT_TRUE(std::isfinite(x)) << line;
    timesOf[{source, long(v[0])}].push_back(v[1]);
  }
  ASSERT_EQ(timesOf.size(), 6u);  // local, serve, serve-range x 128K, 4M
  for (const auto& [run, times] : timesOf) {
    EXPECT_GE(times.size(), 2u) << run.first << " " << run.second;  // the first frame and the converged one
    EXPECT_TRUE(std::is_sorted(times.begin(), times.end())) << run.first << " " << run.second;
  }
  EXPECT_GT(fs::file_size(out / "error-vs-time-streaming.png"), 100u);
  // One curve per source and budget in each of the three panels, every frame kept a point (errors clamped
  // up to 1e-4); the curves' names hold a comma, so the plot's CSV quotes them.
  std::size_t frames = 0, named = 0;
  for (const auto& [run, times] : timesOf) frames += times.size();
  const std::vector<std::string> plotted = plotRows(out / "error-vs-time-streaming.png", 1400, 1000);
  EXPECT_EQ(plotted.size(), 3 * frames);
  for (const std::string source : {"local file", "svo serve stream", "svo serve ranges"})
    for (const std::string budget : {"128.0 KiB", "4.0 MiB"})
      named += countSeries(plotted, "\"" + source + ", " + budget + "\"");
  EXPECT_EQ(named, 3 * frames);
  EXPECT_NE(r.out.find("slices pushed by the view stream"), std::string::npos) << r.out;
  EXPECT_EQ(svo("bench quality " + tetrahedron().string() + " --budgets 4M -o " + out.string()).exitCode, 2);
  expectCleanFailure(svo("bench quality " + tetrahedron().string() + " --stream --sources local,local -o " +
                         (dir_ / "twice").string()),
                     "--sources", dir_ / "twice" / "stream.csv");
  expectCleanFailure(svo("bench quality " + tetrahedron().string() + " --stream --link-delay 10 -o " +
                         (dir_ / "nolink").string()),
                     "--link-delay", dir_ / "nolink" / "stream.csv");
}

TEST_F(Cli, BenchStreamReportsWhatTheViewGoalAsks) {
  const fs::path mesh = dir_ / "terrain.ply", store = dir_ / "terrain.svo", out = dir_ / "bench";
  ASSERT_EQ(svo("gen terrain --triangles 20k -o " + mesh.string()).exitCode, 0);
  ASSERT_EQ(svo("build " + mesh.string() + " --levels 7 --slice-size 4K -o " + store.string()).exitCode, 0);
  // With a busy thread beside it, as on a shared desktop.
  const CommandResult r =
      svo("bench stream " + store.string() +
          " --size 32 --runs 1 --frames 4 --budgets 4M --background-load 1 -o " + out.string());
  ASSERT_EQ(r.exitCode, 0) << r.err;
  EXPECT_NE(r.out.find("background load: 1 busy threads"), std::string::npos) << r.out;
  EXPECT_GT(fs::file_size(out / "error_vs_time.png"), 100u);
  // The first run's frames of the 4M close-up, RMSE against the converged one (clamped up to 1e-4).
  const std::vector<std::string> plotted = plotRows(out / "error_vs_time.png", 1000, 700);
  EXPECT_GE(countSeries(plotted, "4.0 MiB"), 1u);
  EXPECT_EQ(countSeries(plotted, "4.0 MiB"), plotted.size());
  // The goal table's row: budget, sequential read, read + zstd alone, alone / seq, worker CPU to view, cores.
  const std::string row = tableRow(r.out, "what view / seq <= 1.5x asks", "4.0 MiB");
  ASSERT_FALSE(row.empty()) << r.out;
  std::istringstream fields(row);
  double budget, seq, alone, ratio, cpu, cores;
  std::string mib, ms1, ms2, ms3;
  char x;
  fields >> budget >> mib >> seq >> ms1 >> alone >> ms2 >> ratio >> x >> cpu >> ms3 >> cores;
  ASSERT_FALSE(fields.fail()) << row;
  EXPECT_EQ(ms1 + ms2 + ms3, "msmsms");
  EXPECT_GE(seq, 0.0);  // a file left in the page cache reads in microseconds: 0.0 ms
  EXPECT_GE(alone, 0.0);
  EXPECT_GT(cpu, 0.0);
  // The derived columns agree with the printed times, within the times' rounding to 0.1 ms.
  constexpr double kHalfStep = 0.05;
  EXPECT_GE(ratio + 0.005, (alone - kHalfStep) / (seq + kHalfStep));
  EXPECT_LE(ratio - 0.005, (alone + kHalfStep) / std::max(1e-3, seq - kHalfStep));
  EXPECT_GE(cores + 0.05, (cpu - kHalfStep) / (1.5 * (seq + kHalfStep)));
  // Where reading and zstd alone miss the goal, the bench says that no decoder can meet it here.
  if (std::abs(ratio - 1.5) > 0.01)
    EXPECT_EQ(r.out.find("the disk outruns zstd alone") != std::string::npos, ratio > 1.5) << r.out;
  EXPECT_LE(cores - 0.05, (cpu + kHalfStep) / (1.5 * std::max(1e-3, seq - kHalfStep)));
  // The main row ends with the path's mean RMSE against its resident frames, then the most resident.
  const std::string mainRow = tableRow(r.out, "svo bench stream", "4.0 MiB");
  std::istringstream mainFields(mainRow);
  std::vector<std::string> tokens;
  for (std::string t; mainFields >> t;) tokens.push_back(t);
  ASSERT_GE(tokens.size(), 3u) << r.out;
  EXPECT_TRUE(tokens.back().ends_with("B")) << mainRow;
  const double pathRmse = std::stod(tokens[tokens.size() - 3]);
  EXPECT_GE(pathRmse, 0.0) << mainRow;
  EXPECT_LE(pathRmse, 1.0) << mainRow;
  // The workers' CPU row: the stages (read + zstd, assemble, decode, layout, pool pages) add up to the total.
  const std::string cpuRow = tableRow(r.out, "pager workers' CPU", "4.0 MiB");
  ASSERT_FALSE(cpuRow.empty()) << r.out;
  std::istringstream cpuFields(cpuRow);
  double stages[5], total;
  std::string units;
  cpuFields >> budget >> mib;
  for (double& stage : stages) {
    cpuFields >> stage >> units;
    EXPECT_EQ(units, "ms");
  }
  cpuFields >> total >> units;
  ASSERT_FALSE(cpuFields.fail()) << cpuRow;
  EXPECT_EQ(units, "ms");
  EXPECT_GT(stages[2], 0.0) << "decode";
  EXPECT_GT(stages[3], 0.0) << "layout";
  EXPECT_NEAR(stages[0] + stages[1] + stages[2] + stages[3] + stages[4], total, 6 * kHalfStep);
  expectCleanFailure(svo("bench stream " + (dir_ / "none.svo").string() + " -o " + out.string()), "none.svo",
                     dir_ / "none.svo");
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

TEST_F(Cli, BenchAccelWritesTablesMarkdownAndPlot) {
  const fs::path md = dir_ / "accel.md", png = dir_ / "accel.png";
  CommandResult r =
      svo("bench accel --mesh " + tetrahedron().string() +
          " --sizes 500 --scenes field,sphere --structures kd-binned,org,oavm --size 24 --threads 1"
          " --markdown " +
          md.string() + " --plot " + png.string());
  ASSERT_EQ(r.exitCode, 0) << r.err;
  for (const char* word :
       {"tet.obj", "field", "sphere", "kd-binned", "org", "oavm", "Mrays/s", "Paper claims"})
    EXPECT_NE(r.out.find(word), std::string::npos) << word << "\n" << r.out;
  EXPECT_NE(slurp(md).find("| org |"), std::string::npos);
  EXPECT_GT(fs::file_size(png), 0u);
  // Build time per triangle against N: a panel per generated scene, a point per structure and scene size.
  const std::vector<std::string> plotted = plotRows(png, 1400, 1000);
  for (const char* structure : {"kd-binned", "org", "oavm"}) EXPECT_EQ(countSeries(plotted, structure), 2u);
  expectCleanFailure(svo("bench accel --structures bvh --markdown " + md.string() + "x"), "bvh",
                     md.string() + "x");
  expectCleanFailure(svo("bench accel --scenes nowhere --markdown " + md.string() + "x"), "nowhere",
                     md.string() + "x");
}

TEST_F(Cli, BenchRaycastPrintsBothCamerasAndTheScalingPlot) {
  const CommandResult r = svo("bench raycast " + tetrahedron().string() +
                              " --levels 5 --size 32 --runs 1 --threads 1,2 --lod-pixels 1,2");
  ASSERT_EQ(r.exitCode, 0) << r.err;
  // One row per camera, thread count and LOD, each with its iterations and error against Embree.
  for (const char* row : {"tet +whole +1 +1 px ", "tet +whole +2 +2 px ", "tet +close +1 +1 px +100.0% ",
                          "tet +close +2 +2 px +100.0% "})
    EXPECT_TRUE(std::regex_search(r.out, std::regex(row))) << row << "\n" << r.out;

  // The packet loop by name (any case); the title names the loop that ran.
  const CommandResult oneByOne = svo("bench raycast " + tetrahedron().string() +
                                     " --levels 5 --size 32 --runs 1 --threads 1 --simd NONE");
  ASSERT_EQ(oneByOne.exitCode, 0) << oneByOne.err;
  EXPECT_NE(oneByOne.out.find("ESVO (one ray at a time) vs Embree"), std::string::npos) << oneByOne.out;

  const fs::path out = dir_ / "raycast";
  expectCleanFailure(svo("bench raycast " + tetrahedron().string() + " --simd sse -o " + out.string() + "x"),
                     "--simd", out.string() + "x");
  const CommandResult scaling =
      svo("bench raycast --scaling 200,2k --levels 5 --size 32 --runs 1 --cameras whole -o " + out.string());
  ASSERT_EQ(scaling.exitCode, 0) << scaling.err;
  EXPECT_NE(scaling.out.find("whole camera: "), std::string::npos) << scaling.out;
  const std::vector<std::string> plotted = plotRows(out / "raycast_scaling.png", 1400, 1000);
  // A point per triangle count for each of the two (Embree's where the binary has the peers: the
  // AddressSanitizer build has not).
  const bool peers = scaling.out.find("peer not built") == std::string::npos;
  EXPECT_EQ(countSeries(plotted, "ESVO castRay + beam"), 2u);
  EXPECT_EQ(countSeries(plotted, "Embree rtcIntersect1"), peers ? 2u : 0u) << scaling.out;

  expectCleanFailure(svo("bench raycast --levels 5 -o " + out.string() + "x"), "--scaling",
                     out.string() + "x");
  expectCleanFailure(svo("bench raycast --scaling 5 -o " + out.string() + "x"), "'5'", out.string() + "x");
  expectCleanFailure(
      svo("bench raycast " + tetrahedron().string() + " --scaling 1k -o " + out.string() + "x"), "not both",
      out.string() + "x");
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

TEST_F(Cli, BenchStoreOnAStoreAndOnAMesh) {
  const fs::path store = dir_ / "tet.svo";
  ASSERT_EQ(svo("build " + tetrahedron().string() + " -o " + store.string() + " --levels 6").exitCode, 0);
  const CommandResult r = svo("bench store " + store.string() + " --runs 1");
  ASSERT_EQ(r.exitCode, 0) << r.err;
  for (const char* row : {"StoreReader::readSlice", "ZSTD_decompress", "random slice order", "dd if=FILE",
                          "contours", "whole file"})
    EXPECT_NE(r.out.find(row), std::string::npos) << row << "\n" << r.out;
  // A mesh: built on 1 and 2 threads (and OpenVDB when the peers are built), the store kept where asked.
  const fs::path kept = dir_ / "kept.svo";
  const CommandResult m =
      svo("bench store " + tetrahedron().string() + " --levels 4 --runs 1 --store " + kept.string());
  ASSERT_EQ(m.exitCode, 0) << m.err;
  EXPECT_NE(m.out.find("ESVO buildOctree"), std::string::npos) << m.out;
  EXPECT_NE(m.out.find("byte-identical: yes"), std::string::npos) << m.out;
  EXPECT_EQ(svo("verify " + kept.string()).exitCode, 0);
  // Bad input: one line, exit 1 for a damaged store, 2 for a bad command line.
  const fs::path bad = write("bad.svo", "not a store");
  const CommandResult b = svo("bench store " + bad.string());
  EXPECT_EQ(b.exitCode, 1);
  EXPECT_EQ(std::count(b.err.begin(), b.err.end(), '\n'), 1) << b.err;
  EXPECT_EQ(svo("bench store " + store.string() + " --runs 0").exitCode, 2);
}

TEST_F(Cli, BenchBuildMeasuresInCoreAndOutOfCorePerThreadCount) {
  const fs::path store = dir_ / "tet.svo";
  ASSERT_EQ(svo("build " + tetrahedron().string() + " -o " + store.string() + " --levels 5").exitCode, 0);
  const std::uint64_t voxels = svo::StoreReader(store).loadTree().voxels.size();
  const CommandResult r =
      svo("bench build " + tetrahedron().string() + " --resolutions 32 --runs 1 --threads 1,2");
  ASSERT_EQ(r.exitCode, 0) << r.err;
  // One row per thread count, each with the octree's voxel count (the in-core and out-of-core builds agree).
  std::istringstream lines(r.out);
  std::vector<std::string> rows;
  for (std::string line; std::getline(lines, line);)
    if (line.rfind("32^3", 0) == 0) rows.push_back(line + " ");
  ASSERT_EQ(rows.size(), 2u) << r.out;
  std::string count = std::to_string(voxels);  // as the table writes it: 12,345
  for (int i = int(count.size()) - 3; i > 0; i -= 3) count.insert(std::size_t(i), ",");
  for (std::size_t i = 0; i < rows.size(); ++i) {
    EXPECT_NE(rows[i].find(" " + count + " "), std::string::npos) << rows[i];
    std::istringstream tokens(rows[i]);
    std::string resolution, threads;
    tokens >> resolution >> threads;
    EXPECT_EQ(threads, std::to_string(i + 1)) << rows[i];
  }
  EXPECT_EQ(svo("bench build " + tetrahedron().string() + " --threads -1").exitCode, 2);
}

}  // namespace

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
