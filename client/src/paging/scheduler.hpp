// The pager's per-slice state on the render thread: what the view wants and how much (the view query's rank,
// raised by ray feedback), which slices failed, were denied room or are in flight, and whether a request can
// get room in the pool before it is made.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <unordered_map>
#include <utility>
#include <vector>

#include "paging/regions.hpp"
#include "svo/store/schedule.hpp"

namespace svo::paging {

// Consecutive slices of one region, `count` from `slice` on: a worker decodes them in turn and lays the
// region out once, so a cold view deepens a region by several levels in one commit.
struct LoadRequest {
  std::uint32_t slice = 0, count = 1;
  double priority = 0.0;
};

// When a slice whose fetch failed for a reason that may pass is asked for again: after `firstSeconds`,
// doubling with each further failure up to `maxSeconds`.
struct RetryBackoff {
  double firstSeconds = 1.0, maxSeconds = 10.0;
};

class Scheduler {
 public:
  Scheduler(const std::vector<SliceInfo>& slices, const RegionTable& regions, const RetryBackoff& backoff);

  // The view's wanted slices and their priorities (ray feedback applied to the load order), and each
  // region's priority from its resident slices. Returns the decoded bytes the view wants.
  std::uint64_t rank(const std::vector<SliceRequest>& wanted, RegionTable& regions);
  // Every slice of `slices` wanted at `priority` (the trunk, loaded at open).
  void want(const std::vector<std::uint32_t>& slices, double priority);
  // Ray feedback: the slices rays stopped short of; replaces the last frame's.
  void setFeedback(std::unordered_map<std::uint32_t, std::uint32_t> hits) { feedbackHits_ = std::move(hits); }

  double viewPriority(std::uint32_t slice) const { return viewPriority_[slice]; }
  double wantedPriority(std::uint32_t slice) const { return wantedPriority_[slice]; }
  bool failed(std::uint32_t slice) const { return failed_[slice] != 0; }
  void markFailed(std::uint32_t slice) { failed_[slice] = 1; }
  // The source could not deliver the slice for a reason that may pass (a server restarting, a timeout): it is
  // not asked for again until its backoff ends, and asked for again then.
  void markDeferred(std::uint32_t slice);
  // The slice loaded: its next failure starts the backoff afresh.
  void clearDeferred(std::uint32_t slice) { deferrals_[slice] = 0; }
  bool deferred(std::uint32_t slice) const {
    return deferrals_[slice] != 0 && Clock::now() < retryAt_[slice];
  }
  bool inFlight(std::uint32_t slice) const { return inFlight_[slice] != 0; }
  void setInFlight(const LoadRequest& request, bool value);
  // A block that did not fit at its priority: what it needed, so that the chain is not asked for again
  // until that much room is free (marked on its last slice, so a shorter chain can still load).
  void markDenied(std::uint32_t slice, std::size_t bytes) { denied_[slice] = bytes; }
  void clearDenied(std::uint32_t slice) { denied_[slice] = 0; }
  bool denied(std::uint32_t slice) const { return denied_[slice] != 0; }
  // A committed block's growth per decoded byte: the least measured bounds what later requests need.
  void learnBlockGrowth(double rawBytes, double grownBytes);

  // What the next requests are chosen from, after commits: the missing wanted slices that can load now
  // and get room, most wanted first; and which of the missing ones are in the view frustum and loadable
  // or in flight.
  struct Candidates {
    std::vector<SliceRequest> requests;
    std::uint32_t missing = 0, viewPending = 0;
    std::uint32_t deferred = 0;  // missing ones waiting for their backoff to end (markDeferred)
  };
  Candidates candidates();
  // Re-ranks the queued requests and the fetched ones waiting for a decoder for this view (the unwanted ones
  // are cancelled and counted) and adds candidates while fewer than `maxInFlight` requests are queued,
  // fetched or `busy` with the workers and each new one has room beside those in flight.
  void plan(std::vector<LoadRequest>& queued, std::vector<LoadRequest>& fetched, std::size_t busy,
            std::size_t maxInFlight, const Candidates& candidates, std::uint32_t& requested,
            std::uint32_t& cancelled);

  std::vector<std::uint32_t> wantedSlices() const;
  std::vector<std::uint32_t> failedSlices() const;
  // Slices whose last fetch failed for a reason that may pass and that have not loaded since.
  std::vector<std::uint32_t> deferredSlices() const;

 private:
  using Clock = std::chrono::steady_clock;
  bool requestable(std::uint32_t slice) const;
  void indexRoom();
  bool roomFor(std::size_t bytes, double priority, std::uint32_t region) const;
  std::size_t leastBlockGrowth(std::uint32_t slice) const;
  std::uint32_t chainLength(std::uint32_t slice) const;
  double leastBlockBytesPerRawByte() const;

  const std::vector<SliceInfo>& slices_;
  const RegionTable& regions_;
  RetryBackoff backoff_;
  std::unordered_map<std::uint32_t, std::uint32_t> feedbackHits_;
  std::vector<double> viewPriority_;    // per slice, the view query's rank (0 = not wanted): decides eviction
  std::vector<double> wantedPriority_;  // the same with ray feedback: decides load order
  std::vector<std::uint8_t> inView_;    // wanted and inside the view frustum
  std::vector<std::uint8_t> failed_, inFlight_;
  std::vector<std::uint8_t> deferrals_;     // failures that may pass since the slice last loaded (saturates)
  std::vector<Clock::time_point> retryAt_;  // when a deferred slice may be asked for again
  std::vector<std::size_t> denied_;  // bytes a slice dropped for lack of room needed (0 = not dropped)
  std::vector<std::pair<double, std::size_t>> evictableRoom_;  // see indexRoom
  std::optional<double> leastBlockBytesPerRawByte_;            // smallest measured (commit)
};

}  // namespace svo::paging
