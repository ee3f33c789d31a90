#include "catalog.hpp"

#include <sys/stat.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <fmt/format.h>

#include "svo/server/request.hpp"

namespace svo::server {
namespace fs = std::filesystem;
namespace {

// How long a scene is served without looking at its file again: a replaced store is seen within this
// long, for one stat per scene per interval (nginx's open_file_cache_valid plays the same part).
constexpr std::chrono::seconds kSceneRecheck{1};
// The header's own checksum: its last 8 bytes (docs/format.md).
constexpr std::uint64_t kHeaderChecksumOffset = kStoreHeaderBytes - 8;
constexpr std::string_view kStoreExtension = ".svo";
constexpr std::string_view kTokenExtension = ".token";

std::optional<FileIdentity> identityOf(const fs::path& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return std::nullopt;
  return FileIdentity{std::uint64_t(st.st_dev), std::uint64_t(st.st_ino), std::uint64_t(st.st_size),
                      std::int64_t(st.st_mtim.tv_sec) * 1'000'000'000 + st.st_mtim.tv_nsec};
}

// Whether canonical `path` lies strictly below canonical `root`, compared by components.
bool within(const fs::path& path, const fs::path& root) {
  auto p = path.begin();
  for (auto r = root.begin(); r != root.end(); ++r, ++p) {
    if (r->empty()) continue;  // a trailing separator
    if (p == path.end() || *p != *r) return false;
  }
  return p != path.end();
}

// The token file's content without surrounding white space; nothing when there is no such file.
std::optional<std::string> readToken(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::nullopt;
  std::stringstream text;
  text << in.rdbuf();
  std::string token = text.str();
  const auto space = [](unsigned char c) { return std::isspace(c) != 0; };
  token.erase(std::find_if_not(token.rbegin(), token.rend(), space).base(), token.end());
  token.erase(token.begin(), std::find_if_not(token.begin(), token.end(), space));
  return token;
}

}  // namespace

SceneCatalog::SceneCatalog(const fs::path& root) {
  std::error_code ec;
  root_ = fs::canonical(root, ec);
  if (ec) throw std::runtime_error(root.string() + ": " + ec.message());
  if (!fs::is_directory(root_)) throw std::runtime_error(root.string() + ": not a folder");
}

std::vector<std::string> SceneCatalog::names() const {
  std::vector<std::string> out;
  std::error_code ec;
  fs::recursive_directory_iterator it(root_, fs::directory_options::skip_permission_denied, ec);
  for (; !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    const fs::path& path = it->path();
    const std::string leaf = path.filename().string();
    if (leaf.starts_with(".")) {
      if (it->is_directory(ec)) it.disable_recursion_pending();
      continue;
    }
    if (path.extension() != kStoreExtension) continue;
    std::string name = path.lexically_relative(root_).generic_string();
    name.resize(name.size() - kStoreExtension.size());
    if (isSafeSceneName(name) && resolve(name)) out.push_back(std::move(name));
  }
  std::sort(out.begin(), out.end());
  return out;
}

std::optional<fs::path> SceneCatalog::resolve(const std::string& name) const {
  if (!isSafeSceneName(name)) return std::nullopt;
  std::error_code ec;
  fs::path path = fs::canonical(root_ / (name + std::string(kStoreExtension)), ec);
  if (ec || !within(path, root_) || !fs::is_regular_file(path, ec)) return std::nullopt;
  return path;
}

std::shared_ptr<const Scene> SceneCatalog::find(const std::string& name) {
  const auto now = std::chrono::steady_clock::now();
  std::shared_ptr<const Scene> known;
  {
    std::lock_guard lock(mutex_);
    const auto it = entries_.find(name);
    if (it != entries_.end()) {
      if (now - it->second.checked < kSceneRecheck) return it->second.scene;
      known = it->second.scene;
    }
  }
  // The identity is taken before the file opens: a file replaced in between is seen at the next check.
  const std::optional<fs::path> path = resolve(name);
  const std::optional<FileIdentity> identity = path ? identityOf(*path) : std::nullopt;
  if (!identity) {
    std::lock_guard lock(mutex_);
    entries_.erase(name);
    return nullptr;
  }
  std::shared_ptr<const Scene> scene =
      known && known->path == *path && known->identity == *identity ? known : open(name, *path, *identity);
  std::lock_guard lock(mutex_);
  entries_[name] = {scene, now};
  return scene;
}

std::shared_ptr<const Scene> SceneCatalog::open(const std::string& name, const fs::path& path,
                                                const FileIdentity& identity) {
  auto scene = std::make_shared<Scene>();
  scene->name = name;
  scene->path = path;
  scene->identity = identity;
  scene->source = std::make_shared<const LocalFileSource>(path);
  scene->index = std::make_shared<const StoreIndex>(readStoreIndex(*scene->source));
  std::array<std::byte, 8> checksum{};
  if (scene->source->read(kHeaderChecksumOffset, checksum) != checksum.size())
    throw std::runtime_error(path.string() + ": truncated header");
  std::memcpy(&scene->headerChecksum, checksum.data(), checksum.size());
  // The header's checksum covers the directory's, which covers every slice's: with the size it names the
  // file's bytes, whatever the file's path or mtime, so replicas behind a load balancer agree on it.
  scene->etag = fmt::format("\"{:x}-{:016x}\"", scene->source->size(), scene->headerChecksum);
  scene->directoryEtag = fmt::format("\"d-{:016x}\"", scene->index->header().directoryChecksum);
  scene->token = readToken(root_ / (name + std::string(kStoreExtension) + std::string(kTokenExtension)));
  std::lock_guard lock(mutex_);
  scene->id = nextId_++;
  return scene;
}

}  // namespace svo::server
