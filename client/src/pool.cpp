#include "svo/client/pool.hpp"

#include <algorithm>
#include <cassert>
#include <cstring>
#include <stdexcept>
#include <string>

#include <sys/mman.h>

namespace svo {

BlockPool::BlockPool(std::size_t budgetBytes) {
  if (budgetBytes < kPageBytes)
    throw std::invalid_argument("block pool: a budget of " + std::to_string(budgetBytes) +
                                " bytes holds no 8 KB page");
  pageCount_ = std::uint32_t(std::min<std::size_t>(budgetBytes / kPageBytes, UINT32_MAX));
  // Exactly the budget, rounded down to whole pages, and not zero-filled: the OS maps each page on its first
  // write (insert, or prefault ahead of it), so opening a large budget costs nothing.
  arena_ = AlignedBytes(std::size_t(pageCount_) * kPageBytes, /*zeroed=*/false);
  freeRuns_[0] = pageCount_;
}

std::optional<std::uint32_t> BlockPool::takeRun(std::uint32_t pages) {
  // Best fit: the shortest run that holds the block keeps long runs for large blocks.
  auto best = freeRuns_.end();
  for (auto it = freeRuns_.begin(); it != freeRuns_.end(); ++it)
    if (it->second >= pages && (best == freeRuns_.end() || it->second < best->second)) best = it;
  if (best == freeRuns_.end()) return std::nullopt;
  const std::uint32_t first = best->first, length = best->second;
  freeRuns_.erase(best);
  if (length > pages) freeRuns_[first + pages] = length - pages;
  return first;
}

void BlockPool::release(std::uint32_t firstPage, std::uint32_t pages) {
  auto next = freeRuns_.lower_bound(firstPage);
  if (next != freeRuns_.end() && next->first == firstPage + pages) {
    pages += next->second;
    next = freeRuns_.erase(next);
  }
  if (next != freeRuns_.begin()) {
    auto prev = std::prev(next);
    if (prev->first + prev->second == firstPage) {
      prev->second += pages;
      return;
    }
  }
  freeRuns_[firstPage] = pages;
}

void BlockPool::compact(std::uint32_t pages, const std::function<void(BlockId)>& moved) {
  std::vector<BlockId> order;
  for (BlockId id = 0; id < blocks_.size(); ++id)
    if (blocks_[id].pages) order.push_back(id);
  std::sort(order.begin(), order.end(),
            [&](BlockId a, BlockId b) { return blocks_[a].firstPage < blocks_[b].firstPage; });
  // Slide blocks towards the start only until the gap after them holds `pages`: moving the whole arena for
  // one block would cost a frame.
  std::vector<BlockId> relocated;
  std::uint32_t next = 0;
  for (std::size_t k = 0; k < order.size(); ++k) {
    Entry& e = blocks_[order[k]];
    if (e.firstPage != next) {
      // Moving towards the start: source and destination may overlap, memmove copies front to back.
      std::memmove(arena_.data() + std::size_t(next) * kPageBytes,
                   arena_.data() + std::size_t(e.firstPage) * kPageBytes, std::size_t(e.pages) * kPageBytes);
      movedBytes_ += std::uint64_t(e.pages) * kPageBytes;
      markPages(next, e.pages);
      e.firstPage = next;
      relocated.push_back(order[k]);
    }
    next += e.pages;
    const std::uint32_t gapEnd = k + 1 < order.size() ? blocks_[order[k + 1]].firstPage : pageCount_;
    if (gapEnd - next >= pages) break;
  }
  // The free runs are the gaps between the blocks now.
  std::sort(order.begin(), order.end(),
            [&](BlockId a, BlockId b) { return blocks_[a].firstPage < blocks_[b].firstPage; });
  freeRuns_.clear();
  std::uint32_t cursor = 0;
  for (const BlockId id : order) {
    if (blocks_[id].firstPage > cursor) freeRuns_[cursor] = blocks_[id].firstPage - cursor;
    cursor = blocks_[id].firstPage + blocks_[id].pages;
  }
  if (cursor < pageCount_) freeRuns_[cursor] = pageCount_ - cursor;
  ++compactions_;
  if (moved)
    for (const BlockId id : relocated) moved(id);
}

std::optional<BlockPool::BlockId> BlockPool::insert(std::span<const std::byte> bytes,
                                                    const std::function<void(BlockId)>& moved) {
  const std::uint32_t pages = pagesFor(bytes.size());
  if (pages == 0 || pages > pageCount_ - usedPages_) return std::nullopt;
  std::optional<std::uint32_t> first = takeRun(pages);
  if (!first) {
    compact(pages, moved);
    first = takeRun(pages);
    if (!first) throw std::logic_error("block pool: no run after compaction although the pages are free");
  }
  BlockId id;
  if (!freeIds_.empty()) {
    id = freeIds_.back();
    freeIds_.pop_back();
  } else {
    id = BlockId(blocks_.size());
    blocks_.push_back({});
  }
  blocks_[id] = {*first, pages};
  usedPages_ += pages;
  for (std::uint32_t touched = touchedPages_.load(std::memory_order_relaxed); touched < *first + pages;)
    touchedPages_.compare_exchange_weak(touched, *first + pages, std::memory_order_relaxed);
  std::byte* at = arena_.data() + std::size_t(*first) * kPageBytes;
  std::memcpy(at, bytes.data(), bytes.size());
  std::memset(at + bytes.size(), 0, std::size_t(pages) * kPageBytes - bytes.size());
  markPages(*first, pages);
  return id;
}

void BlockPool::prefault(std::size_t bytes) {
  // Claims the next never used pages, so that two prefaults map different ones.
  std::uint32_t begin = touchedPages_.load(std::memory_order_relaxed), end = 0;
  do {
    end = std::uint32_t(std::min<std::uint64_t>(pageCount_, std::uint64_t(begin) + pagesFor(bytes)));
    if (end <= begin) return;
  } while (!touchedPages_.compare_exchange_weak(begin, end, std::memory_order_relaxed));
#ifdef MADV_POPULATE_WRITE
  // A failure (a kernel without it) leaves the pages to insert's first writes.
  madvise(arena_.data() + std::size_t(begin) * kPageBytes, std::size_t(end - begin) * kPageBytes,
          MADV_POPULATE_WRITE);
#endif
}

void BlockPool::erase(BlockId id) {
  if (!contains(id)) throw std::logic_error("block pool: erasing block " + std::to_string(id) + " twice");
  Entry& e = blocks_[id];
  release(e.firstPage, e.pages);
  usedPages_ -= e.pages;
  e = {};
  freeIds_.push_back(id);
}

void BlockPool::check() const {
  const auto fail = [](const std::string& what) { throw std::logic_error("block pool invariant: " + what); };
  // Every page is owned by exactly one block or one free run.
  std::vector<std::uint8_t> owner(pageCount_, 0);
  std::uint64_t used = 0;
  const auto claim = [&](std::uint32_t first, std::uint32_t pages, const std::string& who) {
    if (pages == 0 || std::uint64_t(first) + pages > pageCount_) fail(who + " lies outside the arena");
    for (std::uint32_t p = first; p < first + pages; ++p) {
      if (owner[p]) fail(who + " overlaps something else at page " + std::to_string(p));
      owner[p] = 1;
    }
  };
  for (BlockId id = 0; id < blocks_.size(); ++id) {
    if (!blocks_[id].pages) continue;
    claim(blocks_[id].firstPage, blocks_[id].pages, "block " + std::to_string(id));
    used += blocks_[id].pages;
  }
  std::uint32_t previousEnd = 0;
  bool first = true;
  for (const auto& [page, pages] : freeRuns_) {
    if (!first && page == previousEnd) fail("free runs at page " + std::to_string(page) + " not coalesced");
    claim(page, pages, "free run at page " + std::to_string(page));
    previousEnd = page + pages, first = false;
  }
  if (used != usedPages_)
    fail("used page count " + std::to_string(usedPages_) + " but blocks hold " + std::to_string(used));
  if (std::count(owner.begin(), owner.end(), 0) != 0) fail("pages neither used nor free");
}

void BlockPool::markPages(std::uint32_t first, std::uint32_t count) {
  if (written_.empty()) return;
  std::fill(written_.begin() + first, written_.begin() + first + count, std::uint8_t(1));
}

void BlockPool::trackWrittenPages() {
  written_.assign(pageCount_, 0);
  for (const Entry& e : blocks_)
    if (e.pages) markPages(e.firstPage, e.pages);
}

void BlockPool::markWritten(const void* at, std::size_t bytes) {
  if (written_.empty() || bytes == 0) return;
  const std::size_t offset = std::size_t(static_cast<const std::byte*>(at) - arena_.data());
  assert(offset + bytes <= arena_.size());
  const auto first = std::uint32_t(offset / kPageBytes);
  markPages(first, std::uint32_t((offset + bytes - 1) / kPageBytes) - first + 1);
}

std::vector<BlockPool::PageRun> BlockPool::takeWrittenPages() {
  std::vector<PageRun> runs;
  for (std::uint32_t p = 0; p < written_.size(); ++p) {
    if (!written_[p]) continue;
    if (!runs.empty() && runs.back().first + runs.back().count == p) {
      ++runs.back().count;
    } else {
      runs.push_back({p, 1});
    }
    written_[p] = 0;
  }
  return runs;
}

}  // namespace svo
