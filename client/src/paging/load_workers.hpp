// The pager's workers: fetch threads bring each request's slices from the source (I/O: many may wait at
// once), decode threads turn them into blocks (CPU: as many as the cores the pager may take). Requests wait
// in priority order; the render thread re-ranks the ones not yet fetched between frames, takes the finished
// blocks, and marks the frames during which only some decode threads go on.
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <mutex>
#include <stop_token>
#include <thread>
#include <vector>

#include "paging/region_loader.hpp"
#include "paging/scheduler.hpp"

namespace svo::paging {

class LoadWorkers {
 public:
  struct Options {
    int fetchThreads = 1, decodeThreads = 1;
    int nice = 0;  // of every worker thread (0-19)
  };
  using Fetch = std::function<FetchedChain(const LoadRequest&)>;
  using Build = std::function<BuiltBlock(const LoadRequest&, FetchedChain&&, const Pauses& pauses)>;

  LoadWorkers(const Options& options, Fetch fetch, Build build);
  ~LoadWorkers();  // stops and joins every thread; unfinished requests are dropped
  LoadWorkers(const LoadWorkers&) = delete;
  LoadWorkers& operator=(const LoadWorkers&) = delete;

  // Edits, under the queue lock, the requests not yet fetched (highest priority first after the edit) and
  // the fetched ones waiting for a decode thread (those removed are never decoded; priorities may change);
  // `busy` counts the ones being fetched or built, or done and not taken. Returns all in flight after.
  using Edit = std::function<void(std::vector<LoadRequest>& queued, std::vector<LoadRequest>& fetched,
                                  std::size_t busy)>;
  std::size_t edit(const Edit& change);
  std::vector<BuiltBlock> takeDone();
  void putBack(std::vector<BuiltBlock>&& blocks);  // taken but not committed: offered again next time
  // Blocks until a block is done or `seconds` pass.
  void waitForWork(double seconds);

  // A frame renders from frameBegins to frameEnds: the decode threads beyond the first `decodersGoingOn` wait
  // at their next stage meanwhile, and `withinStages` within their stage too (Pauses).
  void frameBegins(int decodersGoingOn, bool withinStages);
  void frameEnds();

 private:
  struct Fetched {
    LoadRequest request;
    FetchedChain chain;
  };
  void fetchLoop(std::stop_token stop);
  void decodeLoop(int decoder, std::stop_token stop);
  void waitForFrameEnd(int decoder, bool withinStage);
  std::size_t busy() const { return fetching_ + decoding_ + done_.size(); }

  Options options_;
  Fetch fetch_;
  Build build_;
  std::mutex mutex_;  // everything below
  std::condition_variable_any requested_, fetchedReady_;
  std::condition_variable doneReady_;
  std::deque<LoadRequest> queue_;  // highest priority first
  std::vector<Fetched> fetched_;   // waiting for a decode thread
  std::size_t fetching_ = 0, decoding_ = 0;
  std::vector<BuiltBlock> done_;
  std::mutex frameMutex_;
  std::condition_variable frameEnded_;
  bool frameRendering_ = false, stopping_ = false;  // under frameMutex_: paused decoders leave when stopping
  int decodersDuringFrame_ = 0;                     // under frameMutex_: frameBegins' decodersGoingOn
  bool frameWithinStages_ = false;                  // under frameMutex_: frameBegins' withinStages
  std::vector<std::jthread> threads_;
};

}  // namespace svo::paging
