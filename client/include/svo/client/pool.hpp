// The block pool (paper sec. 7; docs/architecture.md): one arena of exactly the budget, in 8 KB pages,
// holding blocks as contiguous page runs. Blocks are relocatable by memcpy (all their pointers are relative),
// so when the free pages suffice but are scattered the pool compacts: it slides blocks together and tells the
// owner which ones moved, so the owner can patch the pointers that cross blocks. The pool never allocates
// past the arena.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <span>
#include <vector>

#include "svo/store/block.hpp"

namespace svo {

class BlockPool {
 public:
  using BlockId = std::uint32_t;

  // Throws std::invalid_argument when the budget holds less than one page.
  explicit BlockPool(std::size_t budgetBytes);

  std::size_t capacityBytes() const { return std::size_t(pageCount_) * kPageBytes; }
  std::size_t usedBytes() const { return std::size_t(usedPages_) * kPageBytes; }
  std::size_t freeBytes() const { return capacityBytes() - usedBytes(); }
  // Pages a block of `bytes` takes.
  static std::uint32_t pagesFor(std::size_t bytes) {
    return std::uint32_t((bytes + kPageBytes - 1) / kPageBytes);
  }

  // Copies `bytes` (a laid-out block) into free pages and returns its id, or nullopt when the free pages do
  // not suffice. Compacts first when they suffice but no run is long enough; `moved` hears of every block
  // that compaction relocated (after all of them have moved).
  std::optional<BlockId> insert(std::span<const std::byte> bytes,
                                const std::function<void(BlockId)>& moved = nullptr);
  void erase(BlockId id);
  // Maps the `bytes` of never used pages that a coming insert will most likely take (best fit from a fresh
  // arena takes them in order), so the OS maps them here and not in insert's memcpy: on the render thread
  // those first writes cost about 1 ms per MB block. The pages are mapped without being written (madvise
  // MADV_POPULATE_WRITE, Linux 5.14), so it may run beside insert, erase and another prefault: a page an
  // insert has begun to fill keeps what it holds. Where the kernel cannot, it maps nothing (insert does).
  void prefault(std::size_t bytes);

  std::byte* data(BlockId id) { return arena_.data() + std::size_t(blocks_.at(id).firstPage) * kPageBytes; }
  const std::byte* data(BlockId id) const {
    return arena_.data() + std::size_t(blocks_.at(id).firstPage) * kPageBytes;
  }
  std::size_t size(BlockId id) const { return std::size_t(blocks_.at(id).pages) * kPageBytes; }
  bool contains(BlockId id) const { return id < blocks_.size() && blocks_[id].pages != 0; }

  // A mirror of the arena (the GPU caster's buffer) needs to know what changed: with tracking on, every page
  // that insert or compaction writes, and every page given to markWritten, is reported once by
  // takeWrittenPages. Turning tracking on reports every page that holds a block. Off by default.
  struct PageRun {
    std::uint32_t first = 0, count = 0;
  };
  void trackWrittenPages();
  void markWritten(const void* at, std::size_t bytes);
  std::vector<PageRun> takeWrittenPages();
  std::span<const std::byte> arena() const { return {arena_.data(), arena_.size()}; }

  std::uint64_t compactions() const { return compactions_; }
  std::uint64_t movedBytes() const { return movedBytes_; }

  // Invariants: every block inside the arena and page aligned, no two blocks and no block and free run
  // overlap, free runs coalesced, and used + free pages = the arena. Throws std::logic_error naming the
  // first one broken.
  void check() const;

 private:
  struct Entry {
    std::uint32_t firstPage = 0, pages = 0;  // pages == 0: a free id
  };
  std::optional<std::uint32_t> takeRun(std::uint32_t pages);
  void release(std::uint32_t firstPage, std::uint32_t pages);
  void compact(std::uint32_t pages, const std::function<void(BlockId)>& moved);
  void markPages(std::uint32_t first, std::uint32_t count);

  AlignedBytes arena_;
  std::uint32_t pageCount_ = 0, usedPages_ = 0;
  // Every page below was written by insert or mapped by prefault (or is being mapped).
  std::atomic<std::uint32_t> touchedPages_{0};
  std::vector<Entry> blocks_;
  std::vector<BlockId> freeIds_;
  std::map<std::uint32_t, std::uint32_t> freeRuns_;  // first page -> pages
  std::uint64_t compactions_ = 0, movedBytes_ = 0;
  std::vector<std::uint8_t> written_;  // per page, while tracking; empty otherwise
};

}  // namespace svo
