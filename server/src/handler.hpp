// From a parsed request to its response: routes, access, scenes, ranges and conditional requests.
#pragma once

#include <atomic>
#include <string>
#include <string_view>

#include <boost/beast/http/message.hpp>
#include <boost/beast/http/string_body.hpp>

#include "body.hpp"
#include "catalog.hpp"
#include "log.hpp"
#include "metrics.hpp"
#include "slice_cache.hpp"
#include "svo/server/server.hpp"

namespace svo::server {

namespace http = boost::beast::http;

// What every connection shares.
struct Context {
  explicit Context(ServerOptions o)
      : options(std::move(o)),
        catalog(options.root),
        cache(options.cacheBytes),
        log(options.logFormat, options.logRequests, options.logSink) {}
  ServerOptions options;
  SceneCatalog catalog;
  SliceCache cache;
  Metrics metrics;
  Log log;
  std::atomic<bool> stopping{false};
};

using Request = http::request<http::string_body>;
using Response = http::response<PayloadBody>;

struct Answer {
  Response response;
  std::string_view route = "other";  // the metrics' route label
  bool slice = false;                // a slice's bytes: counted as sent once written
  std::string failure = {};          // what went wrong, for the request's log line (logged as an error)
  std::shared_ptr<const Scene> stream = {};  // set: accept the request's WebSocket upgrade to this view stream
};

// The answer to `request`. Never throws: a failure answers 500 and says why in Answer::failure.
Answer handle(const Request& request, Context& context);
// Slice `slice` of `scene` through the shared cache, counted in the metrics as a hit, a miss or a corrupt
// slice. Throws SliceError naming the store and slice.
SliceCache::Bytes cachedSlice(Context& context, const Scene& scene, std::uint32_t slice);
// A store's error as clients see it: named by the scene rather than by its path on the server.
std::string publicMessage(const std::string& what, const Scene& scene);
// The answer to a request Beast could not read (malformed, too large): `status` with one line, closing.
Answer refuse(http::status status, std::string_view reason);

}  // namespace svo::server
