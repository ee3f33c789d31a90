#include "paging/scheduler.hpp"

#include <algorithm>
#include <cmath>

namespace svo::paging {
namespace {

// Ray feedback: a slice that rays saw stopping at too coarse a voxel ranks this many times higher than its
// distance-only priority; the distance rule cannot tell a visible cube from an occluded one.
constexpr double kFeedbackBoost = 4.0;
// A block's bytes per decoded slice byte it holds, for judging whether a chained request's block will fit
// before it is built (measured: 2.4-3.0 on the bunny's single-slice regions, 1.5 on its 8-slice trunk).
constexpr double kBlockBytesPerRawByte = 3.0;
// The least a block can grow per decoded slice byte before any block was measured: every contour and
// attribute value of the slice is in the block, and a descriptor outweighs the split bit and valid mask it
// replaces. Used to skip requests whose blocks cannot fit; measured blocks then raise it.
constexpr double kLeastBlockBytesPerRawByte = 1.0;

}  // namespace

Scheduler::Scheduler(const std::vector<SliceInfo>& slices, const RegionTable& regions,
                     const RetryBackoff& backoff)
    : slices_(slices), regions_(regions), backoff_(backoff) {
  const std::size_t n = slices.size();
  viewPriority_.assign(n, 0.0), wantedPriority_.assign(n, 0.0), denied_.assign(n, 0);
  inView_.assign(n, 0), failed_.assign(n, 0), inFlight_.assign(n, 0);
  deferrals_.assign(n, 0), retryAt_.assign(n, {});
}

void Scheduler::markDeferred(std::uint32_t slice) {
  // The fetch itself retried with its own short backoff; this one spaces out whole rounds of those while a
  // server stays away. No jitter: at most maxInFlight requests come back at once.
  const double seconds = std::min(
      backoff_.maxSeconds, backoff_.firstSeconds * std::ldexp(1.0, std::min<int>(deferrals_[slice], 30)));
  retryAt_[slice] =
      Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  deferrals_[slice] = std::uint8_t(std::min(255, deferrals_[slice] + 1));
}

std::uint64_t Scheduler::rank(const std::vector<SliceRequest>& wanted, RegionTable& regions) {
  std::fill(wantedPriority_.begin(), wantedPriority_.end(), 0.0);
  std::fill(viewPriority_.begin(), viewPriority_.end(), 0.0);
  std::fill(inView_.begin(), inView_.end(), 0);
  std::uint64_t wantedBytes = 0;
  for (const SliceRequest& r : wanted) {
    wantedBytes += slices_[r.slice].rawBytes;
    viewPriority_[r.slice] = r.priority;
    inView_[r.slice] = r.inFrustum;
    wantedPriority_[r.slice] = r.priority * (feedbackHits_.count(r.slice) ? kFeedbackBoost : 1.0);
  }
  for (std::uint32_t i = 0; i < regions.size(); ++i) {
    Region& r = regions[i];
    r.priority = 0.0;
    for (std::uint32_t k = 0; k < r.resident; ++k)
      r.priority = std::max(r.priority, viewPriority_[r.slices[k]]);
  }
  return wantedBytes;
}

void Scheduler::want(const std::vector<std::uint32_t>& slices, double priority) {
  for (const std::uint32_t slice : slices) wantedPriority_[slice] = viewPriority_[slice] = priority;
}

void Scheduler::setInFlight(const LoadRequest& request, bool value) {
  const Region& region = regions_[regions_.regionOf(request.slice)];
  const std::uint32_t first = regions_.indexInRegion(request.slice);
  for (std::uint32_t k = 0; k < request.count; ++k) inFlight_[region.slices[first + k]] = value;
}

void Scheduler::learnBlockGrowth(double rawBytes, double grownBytes) {
  if (rawBytes > 0.0 && grownBytes > 0.0)
    leastBlockBytesPerRawByte_ =
        std::min(leastBlockBytesPerRawByte_.value_or(INFINITY), grownBytes / rawBytes);
}

bool Scheduler::requestable(std::uint32_t slice) const {
  if (failed_[slice] || inFlight_[slice] || deferred(slice)) return false;
  const Region& region = regions_[regions_.regionOf(slice)];
  if (region.resident != regions_.indexInRegion(slice)) return false;
  if (region.resident == 0 && region.parent >= 0 && !regions_[std::uint32_t(region.parent)].complete())
    return false;
  return true;
}

// The evictable leaf regions by priority with their running byte sums, for roomFor (evictable() with the
// priority test left to the lookup).
void Scheduler::indexRoom() {
  evictableRoom_.clear();
  for (std::uint32_t r = 1; r < regions_.size(); ++r)
    if (regions_.evictable(r, INFINITY))
      evictableRoom_.push_back({regions_[r].priority, regions_.heldBytes(r)});
  std::sort(evictableRoom_.begin(), evictableRoom_.end());
  for (std::size_t i = 1; i < evictableRoom_.size(); ++i)
    evictableRoom_[i].second += evictableRoom_[i - 1].second;
}

// Whether `bytes` more could be made room for at `priority` for a block of `region`: free pages plus the leaf
// regions less wanted (as indexed by indexRoom), less the region and its parent, which a commit keeps.
bool Scheduler::roomFor(std::size_t bytes, double priority, std::uint32_t region) const {
  const auto less = std::lower_bound(evictableRoom_.begin(), evictableRoom_.end(),
                                     std::pair<double, std::size_t>(priority, 0));
  std::size_t room = regions_.freeBytes() + (less == evictableRoom_.begin() ? 0 : std::prev(less)->second);
  const auto kept = [&](std::uint32_t r) {
    if (regions_.evictable(r, priority)) room -= std::min(room, regions_.heldBytes(r));
  };
  kept(region);
  if (regions_[region].parent >= 0) kept(std::uint32_t(regions_[region].parent));
  return room >= bytes;
}

// Decoded slice bytes to block bytes, at least: the smallest ratio measured, or the prior before any.
double Scheduler::leastBlockBytesPerRawByte() const {
  return leastBlockBytesPerRawByte_.value_or(kLeastBlockBytesPerRawByte);
}

// The least a slice's request adds to the pool: what it needed when last dropped for lack of room, or its
// decoded bytes at the smallest block growth per decoded byte measured so far. A request that cannot get
// that much room is not made: reading, decoding and laying out a block that is then dropped takes the
// cores from the frames and delays convergence.
std::size_t Scheduler::leastBlockGrowth(std::uint32_t slice) const {
  const std::uint32_t r = regions_.regionOf(slice);
  const Region& region = regions_[r];
  const std::size_t grown = std::size_t(leastBlockBytesPerRawByte() * double(slices_[slice].rawBytes));
  if (regions_.levels()) return std::max(denied_[slice], grown);  // level arrays grow in place
  const std::size_t pages =
      std::size_t(BlockPool::pagesFor((region.resident ? region.blockBytes : 0) + grown)) * kPageBytes;
  const std::size_t held = regions_.heldBytes(r);
  return std::max(denied_[slice], pages > held ? pages - held : 0);
}

// How many of the region's slices from `slice` on one request takes: the following ones too while the view
// wants them and the grown block would still fit the free pages (a chain never evicts to make room for its
// tail).
std::uint32_t Scheduler::chainLength(std::uint32_t slice) const {
  const std::uint32_t r = regions_.regionOf(slice);
  const Region& region = regions_[r];
  const std::size_t free = regions_.freeBytes();
  // A new block needs room beside the old one; level arrays only for what they add.
  double estimate = (regions_.levels() ? 0.0 : double(regions_.heldBytes(r))) +
                    kBlockBytesPerRawByte * slices_[slice].rawBytes;
  std::uint32_t count = 1;
  for (std::uint32_t i = regions_.indexInRegion(slice) + 1; i < region.slices.size(); ++i, ++count) {
    const std::uint32_t s = region.slices[i];
    estimate += kBlockBytesPerRawByte * slices_[s].rawBytes;
    if (viewPriority_[s] <= 0.0 || failed_[s] || deferrals_[s] || denied_[s] > free ||
        estimate > double(free))
      break;
  }
  return count;
}

Scheduler::Candidates Scheduler::candidates() {
  indexRoom();
  Candidates out;
  for (std::uint32_t s = 0; s < slices_.size(); ++s) {
    if (wantedPriority_[s] <= 0.0 || failed_[s]) continue;
    const Region& region = regions_[regions_.regionOf(s)];
    if (region.resident > regions_.indexInRegion(s)) continue;
    ++out.missing;
    const bool candidate =
        requestable(s) && roomFor(leastBlockGrowth(s), viewPriority_[s], regions_.regionOf(s));
    if (candidate) out.requests.push_back({s, wantedPriority_[s], 0.0, true});
    const bool waiting = deferred(s);
    out.deferred += waiting;
    out.viewPending += inView_[s] && (candidate || inFlight_[s] || waiting);
  }
  std::sort(out.requests.begin(), out.requests.end(),
            [](const SliceRequest& a, const SliceRequest& b) { return a.priority > b.priority; });
  return out;
}

void Scheduler::plan(std::vector<LoadRequest>& queued, std::vector<LoadRequest>& fetched, std::size_t busy,
                     std::size_t maxInFlight, const Candidates& candidates, std::uint32_t& requested,
                     std::uint32_t& cancelled) {
  // Re-rank what is queued or fetched with this view's priorities; what it no longer wants is cancelled
  // (a fetched one is then never decoded).
  std::erase_if(fetched, [&](LoadRequest& q) {
    q.priority = wantedPriority_[q.slice];
    if (q.priority > 0.0) return false;
    setInFlight(q, false);
    cancelled += q.count;
    return true;
  });
  busy += fetched.size();
  std::vector<LoadRequest> keep;
  for (const LoadRequest& q : queued) {
    if (wantedPriority_[q.slice] > 0.0) {
      keep.push_back({q.slice, q.count, wantedPriority_[q.slice]});
    } else {
      setInFlight(q, false);
      cancelled += q.count;
    }
  }
  // What the requests in flight will take, at least: a new request must fit beside them, or several
  // requests that each fit alone are read and laid out only for the later ones to be dropped.
  const double perRawByte = leastBlockBytesPerRawByte();
  std::size_t reserved = 0;
  for (std::uint32_t s = 0; s < slices_.size(); ++s)
    if (inFlight_[s]) reserved += std::size_t(perRawByte * double(slices_[s].rawBytes));
  for (const SliceRequest& c : candidates.requests) {
    if (keep.size() + busy >= maxInFlight) break;
    const std::size_t growth = leastBlockGrowth(c.slice);
    if (!roomFor(reserved + growth, viewPriority_[c.slice], regions_.regionOf(c.slice))) continue;
    reserved += growth;
    keep.push_back({c.slice, chainLength(c.slice), c.priority});
    setInFlight(keep.back(), true);
    requested += keep.back().count;
  }
  std::sort(keep.begin(), keep.end(),
            [](const LoadRequest& a, const LoadRequest& b) { return a.priority > b.priority; });
  // Over the limit after re-ranking: the least wanted wait for a later update.
  while (keep.size() + busy > maxInFlight && !keep.empty()) {
    setInFlight(keep.back(), false);
    cancelled += keep.back().count;
    keep.pop_back();
  }
  queued = std::move(keep);
}

std::vector<std::uint32_t> Scheduler::wantedSlices() const {
  std::vector<std::uint32_t> out;
  for (std::uint32_t s = 0; s < viewPriority_.size(); ++s)
    if (viewPriority_[s] > 0.0) out.push_back(s);
  return out;
}

std::vector<std::uint32_t> Scheduler::deferredSlices() const {
  std::vector<std::uint32_t> out;
  for (std::uint32_t s = 0; s < deferrals_.size(); ++s)
    if (deferrals_[s]) out.push_back(s);
  return out;
}

std::vector<std::uint32_t> Scheduler::failedSlices() const {
  std::vector<std::uint32_t> out;
  for (std::uint32_t s = 0; s < failed_.size(); ++s)
    if (failed_[s]) out.push_back(s);
  return out;
}

}  // namespace svo::paging
