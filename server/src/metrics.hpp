// The server's Prometheus metrics (prometheus-cpp's registry and text format; the server's own /metrics
// route serves them, no separate exposer).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include <prometheus/counter.h>
#include <prometheus/family.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>

namespace svo::server {

class Metrics {
 public:
  Metrics();
  // One answered request: its route's label, status, seconds from its last byte read to its last byte
  // written, and bytes written (head and body).
  void countRequest(std::string_view route, unsigned status, double seconds, std::uint64_t bytesWritten);
  void countSliceSent() { slicesSent_.Increment(); }
  void countCacheHit() { cacheHits_.Increment(); }
  void countCacheMiss() { cacheMisses_.Increment(); }
  void countCorruptSlice() { corruptSlices_.Increment(); }
  void connectionOpened() { connections_.Increment(); }
  void streamOpened() { streams_.Increment(); }
  // A view stream that ended after writing `bytesWritten` (counted as one request of route "stream", status
  // 101, outside the latency histogram: a stream lasts as long as its viewer).
  void streamClosed(std::uint64_t bytesWritten);
  void countViewUpdate() { viewUpdates_.Increment(); }
  void countStreamSliceSent() { streamSlicesSent_.Increment(); }
  // Planned slices a newer view dropped before they were sent.
  void countSuperseded(std::uint64_t slices) { superseded_.Increment(double(slices)); }
  void connectionClosed() { connections_.Decrement(); }
  // The text exposition of every metric, with the cache's fill as of now.
  std::string text(std::uint64_t cacheBytes, std::uint64_t cacheCapacity);

 private:
  std::shared_ptr<prometheus::Registry> registry_;
  prometheus::Family<prometheus::Counter>& requests_;
  prometheus::Counter& bytesWritten_;
  prometheus::Counter& slicesSent_;
  prometheus::Counter& cacheHits_;
  prometheus::Counter& cacheMisses_;
  prometheus::Counter& corruptSlices_;
  prometheus::Gauge& cacheHitRatio_;
  prometheus::Gauge& cacheBytes_;
  prometheus::Gauge& cacheCapacity_;
  prometheus::Gauge& connections_;
  prometheus::Gauge& streams_;
  prometheus::Counter& viewUpdates_;
  prometheus::Counter& streamSlicesSent_;
  prometheus::Counter& superseded_;
  prometheus::Histogram& latency_;
};

}  // namespace svo::server
