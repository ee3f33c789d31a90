// The point-cloud tests' shared parts (test_points.cpp, test_points_out_of_core.cpp): the fixtures (a
// scratch folder, and `svo build` run on it), clouds with known answers, their files and the tree walk.
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <glm/geometric.hpp>
#include <glm/trigonometric.hpp>

#include "command_helpers.hpp"
#include "svo/builder/points.hpp"
#include "svo/store/format.hpp"

namespace pointtest {

namespace fs = std::filesystem;
using svo::PointCloud;
using svotest::slurp;

// The real scan: assimp-testmodels' pond, 70051 points with normals and colors.
inline const fs::path kPond = "/usr/share/assimp/models/PLY/pond.0.ply";
inline const fs::path kPoints = "/usr/share/assimp/models/PLY/points.ply";

class Points : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("svo_points_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path write(const std::string& name, const std::string& bytes) {
    std::ofstream(dir_ / name, std::ios::binary) << bytes;
    return dir_ / name;
  }
  fs::path dir_;
};

// Points of float precision with colors and normals, for files that keep them exactly.
inline PointCloud exactCloud(int n) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  PointCloud c;
  for (int i = 0; i < n; ++i) {
    const glm::vec3 p(u(rng), u(rng), 0.25f * u(rng));
    c.positions.emplace_back(p);
    c.normals.push_back(glm::normalize(glm::vec3(0.1f * u(rng), 0.1f * u(rng), 1.0f)));
    c.colors.emplace_back(float(int(127.5f + 127.0f * p.x)), float(int(127.5f + 127.0f * p.y)), 200.0f, 1.0f);
  }
  return c;
}

inline std::string number(double v) {
  char text[64];
  std::snprintf(text, sizeof text, "%.17g", v);  // a float read back as a double exactly
  return text;
}

// A PLY of the cloud; colors as 0..255 codes in `colors` (the cloud's are codes, not linear values).
inline std::string ply(const PointCloud& c, bool binary) {
  std::string out =
      std::string("ply\nformat ") + (binary ? "binary_little_endian" : "ascii") +
      " 1.0\ncomment made by test_points\nelement vertex " + std::to_string(c.positions.size()) +
      "\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float "
      "ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar "
      "blue\nend_header\n";
  for (std::size_t i = 0; i < c.positions.size(); ++i) {
    const float v[6] = {float(c.positions[i].x), float(c.positions[i].y), float(c.positions[i].z),
                        c.normals[i].x,          c.normals[i].y,          c.normals[i].z};
    const unsigned char rgb[3] = {(unsigned char)c.colors[i].r, (unsigned char)c.colors[i].g,
                                  (unsigned char)c.colors[i].b};
    if (binary) {
      out.append(reinterpret_cast<const char*>(v), sizeof v);
      out.append(reinterpret_cast<const char*>(rgb), sizeof rgb);
    } else {
      for (float f : v) out += number(f) + " ";
      out += std::to_string(rgb[0]) + " " + std::to_string(rgb[1]) + " " + std::to_string(rgb[2]) + "\n";
    }
  }
  return out;
}

inline std::string xyz(const PointCloud& c) {
  std::string out = "# x y z r g b nx ny nz\n";
  for (std::size_t i = 0; i < c.positions.size(); ++i) {
    const glm::dvec3& p = c.positions[i];
    const glm::vec3& n = c.normals[i];
    out += number(p.x) + " " + number(p.y) + " " + number(p.z) + " " + std::to_string(int(c.colors[i].r)) +
           " " + std::to_string(int(c.colors[i].g)) + " " + std::to_string(int(c.colors[i].b)) + " " +
           number(n.x) + " " + number(n.y) + " " + number(n.z) + "\n";
  }
  return out;
}

inline double degreesBetween(glm::dvec3 a, glm::dvec3 b) {
  return glm::degrees(std::acos(std::clamp(glm::dot(glm::normalize(a), glm::normalize(b)), -1.0, 1.0)));
}

// The tree's voxels with their cube coordinates and levels, walked from the root (children in slot order).
struct Voxel {
  glm::ivec3 coord;
  int level;
  svo::VoxelRecord record;
};

inline void walk(const svo::VoxelTree& t, std::uint32_t i, glm::ivec3 coord, int level,
                 std::vector<Voxel>& out) {
  const svo::VoxelRecord& r = t.voxels[i];
  out.push_back({coord, level, r});
  std::uint32_t child = r.firstChild;
  for (int s = 0; s < 8; ++s)
    if (r.childMask >> s & 1) walk(t, child++, svo::childCoord(coord, s), level + 1, out);
}

// A random (Poisson) sample of the unit sphere, n points, normals analytic: its spacing is sqrt(4 pi / n).
inline PointCloud randomSphere(int n, unsigned seed) {
  PointCloud c;
  std::mt19937 rng(seed);
  std::normal_distribution<double> g;
  for (int i = 0; i < n; ++i) {
    c.positions.push_back(glm::normalize(glm::dvec3(g(rng), g(rng), g(rng))));
    c.normals.emplace_back(c.positions.back());
  }
  return c;
}

// assimp-testmodels' pond.0.ply as packaged is damaged: a CR-LF conversion dropped the 0x0D byte before
// 0x0A bytes in its binary records (one of its colors reads 13 10 9 once restored), 69 bytes in all, so from
// its 627th record on the records are misaligned and many read as garbage (non-finite or huge positions).
// This restores what it can: where a record does not read as a point (finite, within 1000 units, a unit
// normal), a CR goes back before the LF within a record back that makes it read as one; records that still
// do not read as points are dropped. Returns the file of the points that read, and their count.
inline std::pair<std::string, std::size_t> repairedPond() {
  std::ifstream in(kPond, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::size_t start = bytes.find("end_header\n") + 11, record = 31;  // 6 floats, 3 uchars, a float
  std::string data = bytes.substr(start);
  const auto plausible = [&](std::size_t at) {
    if (at + record > data.size()) return false;
    float v[6];
    std::memcpy(v, data.data() + at, sizeof v);
    for (const float f : v)
      if (!std::isfinite(f)) return false;
    const float length = std::sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5]);
    return std::max({std::abs(v[0]), std::abs(v[1]), std::abs(v[2])}) < 1e3f &&
           std::abs(length - 1.0f) < 1e-3f;
  };
  std::string records;
  std::size_t count = 0;
  for (std::size_t at = 0; at + record <= data.size(); at += record) {
    for (std::size_t p = at < record ? 1 : at - record; !plausible(at) && p < at + record; ++p) {
      if (data[p] != '\n' || data[p - 1] == '\r') continue;
      data.insert(p, 1, '\r');
      if (!plausible(at)) data.erase(p, 1);
    }
    if (plausible(at)) records.append(data, at, record), ++count;
  }
  std::string header = bytes.substr(0, start);
  header.replace(header.find("70051"), 5, std::to_string(count));
  return {header + records, count};
}

class PointsCli : public Points {
 protected:
  // `svo build INPUT -o OUT ARGS`: exit status and stderr.
  std::pair<int, std::string> build(const fs::path& input, const fs::path& out,
                                    const std::string& args = "") {
    const fs::path err = dir_ / "stderr.txt";
    const std::string command = svotest::svoBinary() + " build " + input.string() + " -o " + out.string() +
                                " " + args + " >" + (dir_ / "stdout.txt").string() + " 2>" + err.string();
    const int status = std::system(command.c_str());
    return {WIFEXITED(status) ? WEXITSTATUS(status) : 128, slurp(err)};
  }
  // One error line naming the file and mentioning `problem`, a non-zero exit, no crash, nothing at the
  // target.
  void expectCleanFailure(const fs::path& input, const std::string& problem, const std::string& args = "") {
    const fs::path out = dir_ / "o.svo";
    const auto [code, err] = build(input, out, "--levels 6 " + args);
    EXPECT_NE(code, 0) << err;
    EXPECT_LT(code, 128) << "crashed: " << err;
    EXPECT_NE(err.find(input.filename().string()), std::string::npos) << err;
    EXPECT_NE(err.find(problem), std::string::npos) << "stderr: " << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << "stderr: " << err;
    EXPECT_EQ(err.find("AddressSanitizer"), std::string::npos) << err;
    EXPECT_FALSE(fs::exists(out));
    for (const auto& e : fs::directory_iterator(dir_))
      EXPECT_EQ(e.path().string().find(".tmp"), std::string::npos) << "left behind: " << e.path();
  }
};

}  // namespace pointtest
