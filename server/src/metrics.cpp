#include "metrics.hpp"

#include <prometheus/text_serializer.h>

namespace svo::server {
namespace {

using prometheus::BuildCounter;
using prometheus::BuildGauge;
using prometheus::BuildHistogram;

// Latency buckets, seconds: a cached slice on loopback answers in tens of microseconds, a whole store to a
// slow client takes seconds.
const prometheus::Histogram::BucketBoundaries kLatencyBuckets = {
    0.00005, 0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10};

prometheus::Counter& counter(prometheus::Registry& r, const std::string& name, const std::string& help) {
  return BuildCounter().Name(name).Help(help).Register(r).Add({});
}

prometheus::Gauge& gauge(prometheus::Registry& r, const std::string& name, const std::string& help) {
  return BuildGauge().Name(name).Help(help).Register(r).Add({});
}

}  // namespace

Metrics::Metrics()
    : registry_(std::make_shared<prometheus::Registry>()),
      requests_(BuildCounter()
                    .Name("svo_http_requests_total")
                    .Help("HTTP requests answered, by route and status")
                    .Register(*registry_)),
      bytesWritten_(
          counter(*registry_, "svo_http_sent_bytes_total", "bytes written to clients (heads and bodies)")),
      slicesSent_(counter(*registry_, "svo_slices_sent_total", "slice responses sent in full (200 or 206)")),
      cacheHits_(counter(*registry_, "svo_slice_cache_hits_total", "slice requests answered from the cache")),
      cacheMisses_(counter(*registry_, "svo_slice_cache_misses_total", "slice requests read from the store")),
      corruptSlices_(
          counter(*registry_, "svo_corrupt_slices_total", "slice reads that failed the store's check")),
      cacheHitRatio_(gauge(*registry_, "svo_slice_cache_hit_ratio", "hits / (hits + misses) since start")),
      cacheBytes_(gauge(*registry_, "svo_slice_cache_bytes", "bytes the slice cache holds")),
      cacheCapacity_(gauge(*registry_, "svo_slice_cache_capacity_bytes", "the slice cache's bound")),
      connections_(gauge(*registry_, "svo_http_open_connections", "client connections open now")),
      streams_(gauge(*registry_, "svo_streams_open", "view streams open now")),
      viewUpdates_(counter(*registry_, "svo_stream_view_updates_total", "views received on view streams")),
      streamSlicesSent_(counter(*registry_, "svo_stream_slices_sent_total", "slices pushed on view streams")),
      superseded_(counter(*registry_, "svo_stream_superseded_slices_total",
                          "planned slices a newer view dropped before they were sent")),
      latency_(BuildHistogram()
                   .Name("svo_http_request_duration_seconds")
                   .Help("from a request's last byte read to its response's last byte written")
                   .Register(*registry_)
                   .Add({}, kLatencyBuckets)) {}

void Metrics::countRequest(std::string_view route, unsigned status, double seconds,
                           std::uint64_t bytesWritten) {
  requests_.Add({{"route", std::string(route)}, {"status", std::to_string(status)}}).Increment();
  bytesWritten_.Increment(double(bytesWritten));
  latency_.Observe(seconds);
}

void Metrics::streamClosed(std::uint64_t bytesWritten) {
  streams_.Decrement();
  requests_.Add({{"route", "stream"}, {"status", "101"}}).Increment();
  bytesWritten_.Increment(double(bytesWritten));
}

std::string Metrics::text(std::uint64_t cacheBytes, std::uint64_t cacheCapacity) {
  const double hits = cacheHits_.Value(), misses = cacheMisses_.Value();
  cacheHitRatio_.Set(hits + misses > 0 ? hits / (hits + misses) : 0.0);
  cacheBytes_.Set(double(cacheBytes));
  cacheCapacity_.Set(double(cacheCapacity));
  return prometheus::TextSerializer().Serialize(registry_->Collect());
}

}  // namespace svo::server
