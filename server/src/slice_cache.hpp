// Compressed slices as stored, shared by every connection and bounded in bytes: the least recently used
// go first. A slice enters only after the store's own check (checkSlice: size and checksum), so every
// byte sent from the cache is the byte the directory vouches for.
#pragma once

#include <cstdint>
#include <list>
#include <memory>
#include <mutex>
#include <unordered_map>

#include "catalog.hpp"
#include "svo/store/store_types.hpp"

namespace svo::server {

class SliceCache {
 public:
  using Bytes = std::shared_ptr<const SliceBytes>;
  struct Result {
    Bytes bytes;
    bool hit = false;
  };
  explicit SliceCache(std::uint64_t capacityBytes) : capacity_(capacityBytes) {}
  // Slice `slice` of `scene`: from the cache, else read from its file, checked and kept (a slice larger
  // than the whole capacity is served without being kept). Throws SliceError naming the store and slice
  // when the slice is bad; a bad slice is never kept. Safe to call from several threads at once.
  Result get(const Scene& scene, std::uint32_t slice);
  // Bytes held, each slice counted with its bookkeeping.
  std::uint64_t bytes() const;
  std::uint64_t capacity() const { return capacity_; }

 private:
  struct Key {
    std::uint64_t scene = 0;
    std::uint32_t slice = 0;
    bool operator==(const Key&) const = default;
  };
  struct KeyHash {
    std::size_t operator()(const Key& k) const {
      return std::hash<std::uint64_t>()(k.scene * 0x9E3779B97F4A7C15ull ^ k.slice);
    }
  };
  struct Entry {
    Key key;
    Bytes bytes;
  };
  static std::uint64_t charge(const SliceBytes& bytes);

  const std::uint64_t capacity_;
  mutable std::mutex mutex_;
  std::list<Entry> lru_;  // most recently used first
  std::unordered_map<Key, std::list<Entry>::iterator, KeyHash> entries_;
  std::uint64_t bytes_ = 0;
};

}  // namespace svo::server
