// The `svo` command run end to end (test_cli.cpp, test_cli_bench.cpp): a fixture with a scratch folder per
// test, the command's exit code and output, and readers of the tables and plots it writes.
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <OpenImageIO/imageio.h>

#include "command_helpers.hpp"

namespace svotest::cli {

namespace fs = std::filesystem;

struct CommandResult {
  int exitCode = 0;
  std::string out, err;
};

using svotest::slurp;

inline std::vector<std::string> lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) out.push_back(line);
  return out;
}

// The line of a printed table under `title` that starts with `first` (a row's first cell), or "" where either
// is missing.
inline std::string tableRow(const std::string& out, const std::string& title, const std::string& first) {
  const std::size_t at = out.find(title);
  const std::size_t row = at == std::string::npos ? at : out.find(first, at);
  return row == std::string::npos ? "" : out.substr(row, out.find('\n', row) - row);
}

// A plot as the plot driver leaves it: a PNG of `width` x `height` pixels that OpenImageIO reads, and beside
// it its data, NAME.csv. Returns the data rows (panel,series,x,y) after checking the header.
inline std::vector<std::string> plotRows(const fs::path& png, int width, int height) {
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
inline std::size_t countSeries(const std::vector<std::string>& rows, const std::string& name) {
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

}  // namespace svotest::cli
