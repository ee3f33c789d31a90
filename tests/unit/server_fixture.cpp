#include "server_fixture.hpp"

#include <unistd.h>

#include <fstream>
#include <sstream>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/store/store_reader.hpp"
#include "svo/store/store_writer.hpp"

namespace fs = std::filesystem;

namespace svotest {

ServedStores::ServedStores() {
  const std::string pid = std::to_string(::getpid());
  root = fs::temp_directory_path() / ("svo_serve_" + pid);
  outside = fs::temp_directory_path() / ("svo_serve_outside_" + pid);
  fs::remove_all(root);
  fs::remove_all(outside);
  fs::create_directories(root / "sub");
  fs::create_directories(root / ".hidden");
  fs::create_directories(outside);
  svo::Mesh sphere = makeSphere({0, 0, 0}, 1.0, 24, 24);
  for (const glm::dvec3& p : sphere.positions)
    sphere.colors.push_back(glm::vec4(0.5 + 0.4 * p.x, 0.5 + 0.4 * p.y, 0.5 - 0.4 * p.z, 1.0));
  svo::BuildOptions options;
  options.levels = 7;
  svo::StoreWriteOptions write;
  write.sliceBytes = 4096;
  svo::writeOctree(root / "sphere.svo", svo::buildOctree(sphere, options), write);
  options.levels = 5;
  svo::writeOctree(root / "sub" / "box.svo", svo::buildOctree(makeBox({-1, -1, -1}, {0.5, 0.2, 1}), options),
                   write);
  fs::copy_file(root / "sub" / "box.svo", root / "secret.svo");
  std::ofstream(root / "secret.svo.token") << "s3cret\n";
  fs::copy_file(root / "sub" / "box.svo", outside / "x.svo");
  fs::copy_file(root / "sub" / "box.svo", root / ".hidden" / "h.svo");
  fs::create_symlink(outside / "x.svo", root / "escape.svo");
  fs::create_directory_symlink(outside, root / "linkdir");
  std::ofstream(root / "notes.txt") << "not a store\n";
  // corrupt.svo: the sphere with one byte of its last slice changed; header and directory still check.
  fs::copy_file(root / "sphere.svo", root / "corrupt.svo");
  const svo::StoreReader reader(root / "corrupt.svo");
  corruptSlice = std::uint32_t(reader.slices().size() - 1);
  const svo::SliceInfo& s = reader.slices()[corruptSlice];
  std::fstream f(root / "corrupt.svo", std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(std::streamoff(s.offset + s.compressedBytes / 2));
  const char old = char(f.get());
  f.seekp(std::streamoff(s.offset + s.compressedBytes / 2));
  f.put(char(old ^ 0x5a));
}

ServedStores::~ServedStores() {
  std::error_code ec;
  fs::remove_all(root, ec);
  fs::remove_all(outside, ec);
}

const ServedStores& servedStores() {
  static const ServedStores stores;
  return stores;
}

std::string slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

bool LogLines::contains(const std::string& text) {
  std::lock_guard lock(mutex);
  for (const std::string& l : lines)
    if (l.find(text) != std::string::npos) return true;
  return false;
}

std::vector<std::string> LogLines::copy() {
  std::lock_guard lock(mutex);
  return lines;
}

RunningServer startServer(svo::server::ServerOptions options) {
  RunningServer r;
  if (options.root.empty()) options.root = servedStores().root;
  if (options.threads == 0) options.threads = 4;
  options.logSink = [log = r.log](std::string_view line) {
    std::lock_guard lock(log->mutex);
    log->lines.emplace_back(line);
  };
  r.server = std::make_unique<svo::server::Server>(options);
  r.server->start();
  r.port = r.server->port();
  return r;
}

RunningServer& sharedServer() {
  static RunningServer r = startServer();
  return r;
}

}  // namespace svotest
