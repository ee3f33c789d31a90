// The stores under the served folder, by name (relative path without .svo), each opened on first use: its
// index read and checked once, its file descriptor shared by every request.
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "svo/store/byte_source.hpp"
#include "svo/store/store_index.hpp"

namespace svo::server {

// Which file a path held when it was opened: a store replaced by rename (how the writer finishes one) gets
// a new inode.
struct FileIdentity {
  std::uint64_t device = 0, inode = 0, size = 0;
  std::int64_t mtimeNanoseconds = 0;
  bool operator==(const FileIdentity&) const = default;
};

// A store as the server serves it.
struct Scene {
  std::string name;
  std::filesystem::path path;  // canonical, inside the root
  std::shared_ptr<const LocalFileSource> source;
  std::shared_ptr<const StoreIndex> index;
  std::uint64_t headerChecksum = 0;  // the header's own XXH3 (docs/format.md, offset 248)
  std::string etag;                  // the whole file's strong entity tag
  std::string directoryEtag;
  std::optional<std::string> token;  // NAME.svo.token's content: the scene's own bearer token
  std::uint64_t id = 0;              // distinct per opening: cache keys of a replaced file never collide
  FileIdentity identity;
};

class SceneCatalog {
 public:
  // Throws std::runtime_error when `root` is not a readable folder.
  explicit SceneCatalog(const std::filesystem::path& root);
  const std::filesystem::path& root() const { return root_; }
  // Every store's name under the root, sorted: .svo files in any sub-folder (symlinked folders are not
  // followed, so no cycles; symlinked files count when they resolve inside the root), none under a
  // hidden folder.
  std::vector<std::string> names() const;
  // The scene `name`, opened on first use and checked against its file again after kSceneRecheck (a
  // replaced file is opened anew); nullptr when no store of that name resolves inside the root. Throws
  // std::runtime_error naming the store when it exists but does not open.
  std::shared_ptr<const Scene> find(const std::string& name);

 private:
  struct Entry {
    std::shared_ptr<const Scene> scene;
    std::chrono::steady_clock::time_point checked;
  };
  // The canonical path of store `name` when it is a regular file inside the root.
  std::optional<std::filesystem::path> resolve(const std::string& name) const;
  std::shared_ptr<const Scene> open(const std::string& name, const std::filesystem::path& path,
                                    const FileIdentity& identity);

  std::filesystem::path root_;  // canonical
  std::mutex mutex_;
  std::map<std::string, Entry> entries_;
  std::uint64_t nextId_ = 1;
};

}  // namespace svo::server
