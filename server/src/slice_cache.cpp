#include "slice_cache.hpp"

#include "svo/store/store_reader.hpp"

namespace svo::server {
namespace {

// What an entry costs beyond its bytes: list and map nodes, the shared pointer's control block and the
// vector's header (about 150 bytes with glibc on x86-64, rounded up).
constexpr std::uint64_t kEntryOverheadBytes = 192;

}  // namespace

std::uint64_t SliceCache::charge(const SliceBytes& bytes) {
  return bytes.size() + kEntryOverheadBytes;
}

SliceCache::Result SliceCache::get(const Scene& scene, std::uint32_t slice) {
  const Key key{scene.id, slice};
  {
    std::lock_guard lock(mutex_);
    const auto it = entries_.find(key);
    if (it != entries_.end()) {
      lru_.splice(lru_.begin(), lru_, it->second);
      return {it->second->bytes, true};
    }
  }
  // Read and checked outside the lock: other slices keep serving meanwhile. Two connections missing the
  // same slice at once both read it; the first to finish keeps its copy.
  auto bytes = std::make_shared<SliceBytes>();
  fetchSlice(*scene.source, *scene.index, slice, *bytes);
  checkSlice(*scene.index, slice, *bytes);
  const std::uint64_t cost = charge(*bytes);
  std::lock_guard lock(mutex_);
  if (cost > capacity_) return {std::move(bytes), false};
  const auto [it, inserted] = entries_.try_emplace(key);
  if (!inserted) {
    lru_.splice(lru_.begin(), lru_, it->second);
    return {it->second->bytes, false};
  }
  lru_.push_front({key, std::move(bytes)});
  it->second = lru_.begin();
  bytes_ += cost;
  while (bytes_ > capacity_) {
    const Entry& last = lru_.back();
    bytes_ -= charge(*last.bytes);
    entries_.erase(last.key);
    lru_.pop_back();
  }
  return {lru_.front().bytes, false};
}

std::uint64_t SliceCache::bytes() const {
  std::lock_guard lock(mutex_);
  return bytes_;
}

}  // namespace svo::server
