#include "paging/load_workers.hpp"

#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <cassert>
#include <chrono>

namespace svo::paging {
namespace {

// Names the thread (top, perf and gdb tell the workers apart) and sets its nice value: Linux nice values
// are per thread (best effort; an unprivileged process may always lower its own priority).
void setUpWorker(const char* name, int nice) {
  pthread_setname_np(pthread_self(), name);
  if (nice != 0) setpriority(PRIO_PROCESS, id_t(syscall(SYS_gettid)), nice);
}

}  // namespace

LoadWorkers::LoadWorkers(const Options& options, Fetch fetch, Build build)
    : options_(options), fetch_(std::move(fetch)), build_(std::move(build)) {
  for (int i = 0; i < options.fetchThreads; ++i)
    threads_.emplace_back([this](std::stop_token stop) { fetchLoop(stop); });
  for (int i = 0; i < options.decodeThreads; ++i)
    threads_.emplace_back([this, i](std::stop_token stop) { decodeLoop(i, stop); });
}

LoadWorkers::~LoadWorkers() {
  for (auto& t : threads_) t.request_stop();
  {
    std::lock_guard lock(frameMutex_);
    stopping_ = true;
  }
  frameEnded_.notify_all();
  requested_.notify_all();
  fetchedReady_.notify_all();
  threads_.clear();  // joins
}

void LoadWorkers::fetchLoop(std::stop_token stop) {
  setUpWorker("svo-fetch", options_.nice);
  while (true) {
    LoadRequest request;
    {
      std::unique_lock lock(mutex_);
      if (!requested_.wait(lock, stop, [&] { return !queue_.empty(); })) return;
      request = queue_.front();
      queue_.pop_front();
      ++fetching_;
    }
    FetchedChain chain = fetch_(request);
    {
      std::lock_guard lock(mutex_);
      --fetching_;
      fetched_.push_back({request, std::move(chain)});
    }
    fetchedReady_.notify_one();
  }
}

void LoadWorkers::decodeLoop(int decoder, std::stop_token stop) {
  setUpWorker("svo-decode", options_.nice);
  const Pauses pauses{[this, decoder] { waitForFrameEnd(decoder, false); },
                      [this, decoder] { waitForFrameEnd(decoder, true); }};
  while (true) {
    Fetched item;
    {
      std::unique_lock lock(mutex_);
      if (!fetchedReady_.wait(lock, stop, [&] { return !fetched_.empty(); })) return;
      // The most wanted of the fetched requests first.
      const auto best = std::max_element(
          fetched_.begin(), fetched_.end(),
          [](const Fetched& a, const Fetched& b) { return a.request.priority < b.request.priority; });
      item = std::move(*best);
      fetched_.erase(best);
      ++decoding_;
    }
    BuiltBlock built = build_(item.request, std::move(item.chain), pauses);
    {
      std::lock_guard lock(mutex_);
      --decoding_;
      done_.push_back(std::move(built));
    }
    doneReady_.notify_all();
  }
}

std::size_t LoadWorkers::edit(const Edit& change) {
  std::size_t inFlight = 0;
  {
    std::lock_guard lock(mutex_);
    std::vector<LoadRequest> queued(queue_.begin(), queue_.end()), fetched;
    for (const Fetched& f : fetched_) fetched.push_back(f.request);
    change(queued, fetched, busy());
    queue_.assign(queued.begin(), queued.end());
    // A slice is in flight once, so the edited requests match the fetched chains by slice.
    std::vector<Fetched> kept;
    for (const LoadRequest& request : fetched) {
      const auto it = std::find_if(fetched_.begin(), fetched_.end(),
                                   [&](const Fetched& f) { return f.request.slice == request.slice; });
      assert(it != fetched_.end());
      kept.push_back({request, std::move(it->chain)});
    }
    fetched_ = std::move(kept);
    inFlight = queue_.size() + fetched_.size() + busy();
  }
  requested_.notify_all();
  return inFlight;
}

std::vector<BuiltBlock> LoadWorkers::takeDone() {
  std::lock_guard lock(mutex_);
  return std::exchange(done_, {});
}

void LoadWorkers::putBack(std::vector<BuiltBlock>&& blocks) {
  std::lock_guard lock(mutex_);
  for (BuiltBlock& b : blocks) done_.push_back(std::move(b));
}

void LoadWorkers::waitForWork(double seconds) {
  std::unique_lock lock(mutex_);
  doneReady_.wait_for(lock, std::chrono::duration<double>(seconds), [&] { return !done_.empty(); });
}

void LoadWorkers::frameBegins(int decodersGoingOn, bool withinStages) {
  std::lock_guard lock(frameMutex_);
  frameRendering_ = true;
  decodersDuringFrame_ = decodersGoingOn;
  frameWithinStages_ = withinStages;
}

void LoadWorkers::frameEnds() {
  {
    std::lock_guard lock(frameMutex_);
    frameRendering_ = false;
  }
  frameEnded_.notify_all();
}

void LoadWorkers::waitForFrameEnd(int decoder, bool withinStage) {
  std::unique_lock lock(frameMutex_);
  frameEnded_.wait(lock, [&] {
    return !frameRendering_ || decoder < decodersDuringFrame_ || (withinStage && !frameWithinStages_) ||
           stopping_;
  });
}

}  // namespace svo::paging
