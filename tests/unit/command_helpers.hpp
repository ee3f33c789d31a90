// Helpers of the tests that run `svo` and other programs through a shell and compare the PNGs they write.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <OpenImageIO/imageio.h>

namespace svotest {

// A PNG's first three channels as 8-bit codes, rows from the top; empty (and a test failure) when unreadable.
struct Rgb8 {
  int width = 0, height = 0;
  std::vector<std::uint8_t> pixels;
};
inline Rgb8 readRgb8(const std::filesystem::path& png) {
  Rgb8 out;
  auto in = OIIO::ImageInput::open(png.string());
  if (!in) {
    ADD_FAILURE() << png << ": " << OIIO::geterror();
    return out;
  }
  out.width = in->spec().width, out.height = in->spec().height;
  out.pixels.resize(std::size_t(out.width) * out.height * 3);
  in->read_image(0, 0, 0, 3, OIIO::TypeDesc::UINT8, out.pixels.data());
  return out;
}

// The `svo` the command tests run: the AddressSanitizer build where the test script names one, else this
// build's.
inline std::string svoBinary() {
  if (const char* asan = std::getenv("SVO_ASAN_BINARY"); asan && *asan) return asan;
  return SVO_BINARY;
}

// A file's whole contents (empty when it cannot be read).
inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// What a shell command printed on stdout and stderr, then a last line "exit N" with its exit status.
inline std::string runShell(const std::string& command) {
  std::string out;
  FILE* pipe = ::popen((command + " 2>&1; echo \"exit $?\"").c_str(), "r");
  if (!pipe) return out;
  char buffer[4096];
  while (std::size_t n = std::fread(buffer, 1, sizeof buffer, pipe)) out.append(buffer, n);
  ::pclose(pipe);
  return out;
}

}  // namespace svotest
