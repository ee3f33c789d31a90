#include "handler.hpp"

#include <cassert>
#include <exception>
#include <memory>
#include <optional>

#include <fmt/format.h>
#include <boost/beast/websocket/rfc6455.hpp>
#include <nlohmann/json.hpp>

#include "svo/server/request.hpp"
#include "svo/store/store_reader.hpp"

namespace svo::server {
namespace {

constexpr std::string_view kServerName = "svostream";
// A slice's URL always names the same bytes while its store stands; its ETag is its checksum.
constexpr std::string_view kImmutable = "public, max-age=31536000, immutable";
// Whole files, directories and metadata change when a store is replaced: caches revalidate by ETag.
constexpr std::string_view kRevalidate = "no-cache";
constexpr std::string_view kBinary = "application/octet-stream";
constexpr std::string_view kJson = "application/json";
constexpr std::string_view kText = "text/plain; charset=utf-8";
constexpr std::string_view kMetricsType = "text/plain; version=0.0.4; charset=utf-8";
constexpr std::string_view kRealm = "Bearer realm=\"svostream\"";

Payload memory(std::string text) {
  auto owner = std::make_shared<const std::string>(std::move(text));
  const auto* data = reinterpret_cast<const std::byte*>(owner->data());
  return {owner, data, nullptr, 0, owner->size()};
}

// A response of `status` to `request`, with `body` (its length announced, its bytes left out for HEAD).
Response respond(const Request* request, http::status status, std::string_view contentType, Payload body) {
  Response res{status, request ? request->version() : 11};
  res.set(http::field::server, kServerName);
  res.set(http::field::content_type, contentType);
  res.keep_alive(request && request->keep_alive());
  res.content_length(body.length);
  if (!request || request->method() != http::verb::head) res.body() = std::move(body);
  return res;
}

Answer line(const Request& request, http::status status, std::string_view route, const std::string& text) {
  return {respond(&request, status, kText, memory(text + "\n")), route};
}

// Null when the request may proceed; else the 401 or 403 answer. A scene with a token file takes that
// token; anything else takes the server's, when it has one.
std::optional<Answer> deny(const Request& request, Context& context, const Scene* scene,
                           std::string_view route) {
  std::string_view required = context.options.token;
  if (scene && scene->token) {
    if (scene->token->empty()) {
      Answer a = line(request, http::status::forbidden, route, scene->name + ": access refused");
      a.failure = scene->name + ": its token file is empty; the scene is refused to every client";
      return a;
    }
    required = *scene->token;
  }
  if (required.empty()) return std::nullopt;
  const std::optional<std::string_view> token = bearerToken(request[http::field::authorization]);
  if (!token) {
    Answer a = line(request, http::status::unauthorized, route, "a bearer token is required");
    a.response.set(http::field::www_authenticate, kRealm);
    return a;
  }
  if (!constantTimeEquals(*token, required))
    return line(request, http::status::forbidden, route, "the bearer token is not valid here");
  return std::nullopt;
}

// `full`, a representation with entity tag `etag`, as the request asks for it: 304 when If-None-Match
// matches, 206 for one satisfiable range (unless If-Range names another version), 416 for an
// unsatisfiable one, else 200.
void describe(Response& res, const std::string& etag, std::string_view cacheControl) {
  res.set(http::field::etag, etag);
  res.set(http::field::cache_control, cacheControl);
  res.set(http::field::accept_ranges, "bytes");
}

// The 304 answer when If-None-Match matches `etag`.
std::optional<Answer> notModified(const Request& request, std::string_view route, const std::string& etag,
                                  std::string_view cacheControl) {
  const auto inm = request[http::field::if_none_match];
  if (inm.empty() || !ifNoneMatchMatches(inm, etag)) return std::nullopt;
  Response res{http::status::not_modified, request.version()};
  res.set(http::field::server, kServerName);
  res.keep_alive(request.keep_alive());
  describe(res, etag, cacheControl);
  return Answer{std::move(res), route};
}

Answer represent(const Request& request, std::string_view route, std::string_view contentType,
                 const Payload& full, const std::string& etag, std::string_view cacheControl) {
  if (auto unchanged = notModified(request, route, etag, cacheControl)) return std::move(*unchanged);
  RangeRequest range;
  const auto rangeField = request[http::field::range];
  const auto ifRange = request[http::field::if_range];
  if (!rangeField.empty() && (ifRange.empty() || ifRangeMatches(ifRange, etag)))
    range = parseRange(rangeField, full.length);
  Answer a;
  a.route = route;
  switch (range.kind) {
    case RangeKind::Whole:
      a.response = respond(&request, http::status::ok, contentType, full);
      break;
    case RangeKind::Partial:
      a.response = respond(&request, http::status::partial_content, contentType,
                           full.part(range.range.first, range.range.length()));
      a.response.set(http::field::content_range,
                     fmt::format("bytes {}-{}/{}", range.range.first, range.range.last, full.length));
      break;
    case RangeKind::Unsatisfiable:
      a.response = respond(&request, http::status::range_not_satisfiable, kText,
                           memory(fmt::format("range not satisfiable: {} bytes\n", full.length)));
      a.response.set(http::field::content_range, fmt::format("bytes */{}", full.length));
      break;
  }
  describe(a.response, etag, cacheControl);
  return a;
}

nlohmann::json info(const Scene& scene) {
  const StoreIndex& index = *scene.index;
  const StoreHeader& h = index.header();
  nlohmann::json perLevel = nlohmann::json::array();
  for (int level = 1; level <= h.parameters.levels; ++level)
    perLevel.push_back(index.slicesOfLevel(level).size());
  std::uint64_t compressed = 0, raw = 0;
  for (const SliceInfo& s : index.slices()) compressed += s.compressedBytes, raw += s.rawBytes;
  nlohmann::json attachments = nlohmann::json::array();
  if (h.hasColors) attachments.push_back("color");
  if (h.hasNormals) attachments.push_back("normal");
  const glm::dvec3 lo = h.transform.origin, hi = h.transform.toWorld(glm::dvec3(2.0));
  return {{"name", scene.name},
          {"etag", scene.etag},
          {"formatVersion", h.version},
          {"fileBytes", h.fileBytes},
          {"levels", h.parameters.levels},
          {"sliceBytes", h.sliceBytes},
          {"sliceCount", index.slices().size()},
          {"rootSlices", std::vector<std::uint32_t>(index.rootSlices().begin(), index.rootSlices().end())},
          {"slicesPerLevel", perLevel},
          {"compressedSliceBytes", compressed},
          {"rawSliceBytes", raw},
          {"directory",
           {{"offset", h.directoryOffset},
            {"bytes", h.directoryBytes},
            {"checksum", fmt::format("{:016x}", h.directoryChecksum)}}},
          {"transform",
           {{"origin", {h.transform.origin.x, h.transform.origin.y, h.transform.origin.z}},
            {"size", h.transform.size}}},
          {"bounds", {{"min", {lo.x, lo.y, lo.z}}, {"max", {hi.x, hi.y, hi.z}}}},
          {"attachments", attachments},
          {"rootColor", h.rootColor},
          {"rootNormal", h.rootNormal},
          {"build",
           {{"geometryError", h.parameters.geometryError},
            {"colorError", h.parameters.colorError},
            {"normalError", h.parameters.normalError},
            {"contours", h.parameters.contours}}}};
}

Answer scenes(const Request& request, Context& context) {
  nlohmann::json list = nlohmann::json::array();
  std::string failures;
  for (const std::string& name : context.catalog.names()) {
    nlohmann::json entry = {{"name", name}};
    try {
      if (const auto scene = context.catalog.find(name)) {
        entry["fileBytes"] = scene->index->header().fileBytes;
        entry["levels"] = scene->index->header().parameters.levels;
        entry["slices"] = scene->index->slices().size();
        entry["protected"] = scene->token.has_value();
      }
    } catch (const std::exception& e) {
      failures += (failures.empty() ? "" : "; ") + std::string(e.what());
      entry["error"] = "does not open (the server's log says why)";
    }
    list.push_back(std::move(entry));
  }
  Answer a{respond(&request, http::status::ok, kJson, memory(list.dump() + "\n")), "scenes"};
  a.failure = std::move(failures);
  return a;
}

Answer slice(const Request& request, Context& context, const Scene& scene, const std::string& idText) {
  const std::optional<std::uint32_t> id = parseSliceId(idText);
  if (!id) return line(request, http::status::bad_request, "slice", "not a slice id: " + idText);
  const std::size_t count = scene.index->slices().size();
  if (*id >= count)
    return line(request, http::status::not_found, "slice",
                fmt::format("{} has no slice {} (it has {})", scene.name, *id, count));
  // The client holding this version needs no byte of it: answered before the slice is read.
  const std::string etag = fmt::format("\"{:016x}\"", scene.index->slices()[*id].checksum);
  if (auto unchanged = notModified(request, "slice", etag, kImmutable)) return std::move(*unchanged);
  SliceCache::Bytes cached;
  try {
    cached = cachedSlice(context, scene, *id);
  } catch (const SliceError& e) {
    Answer a = line(request, http::status::internal_server_error, "slice", publicMessage(e.what(), scene));
    a.failure = e.what();
    return a;
  }
  const Payload bytes{cached, cached->data(), nullptr, 0, cached->size()};
  Answer a = represent(request, "slice", kBinary, bytes, etag, kImmutable);
  a.slice = true;
  return a;
}

Answer sceneRoute(const Request& request, Context& context, const TargetPath& path) {
  const std::vector<Route> routes = sceneRoutes(path.segments);
  assert(!routes.empty());  // route() sends only scene routes here
  std::shared_ptr<const Scene> scene;
  Route route = routes.front();
  try {
    for (const Route& r : routes)
      if ((scene = context.catalog.find(r.scene))) {
        route = r;
        break;
      }
  } catch (const std::exception& e) {
    if (auto denied = deny(request, context, nullptr, "scene")) return std::move(*denied);
    Answer a = line(request, http::status::internal_server_error, "scene",
                    "a store of this name does not open (the server's log says why)");
    a.failure = e.what();
    return a;
  }
  if (auto denied = deny(request, context, scene.get(), "scene")) return std::move(*denied);
  if (!scene) return line(request, http::status::not_found, "scene", "no scene " + route.scene);
  const Payload file{nullptr, nullptr, scene->source, 0, scene->source->size()};
  const StoreHeader& h = scene->index->header();
  switch (route.kind) {
    case RouteKind::File:
      return represent(request, "file", kBinary, file, scene->etag, kRevalidate);
    case RouteKind::Directory:
      return represent(request, "directory", kBinary, file.part(h.directoryOffset, h.directoryBytes),
                       scene->directoryEtag, kRevalidate);
    case RouteKind::Info:
      return represent(request, "info", kJson, memory(info(*scene).dump(2) + "\n"),
                       fmt::format("\"i-{:016x}\"", scene->headerChecksum), kRevalidate);
    case RouteKind::Slice:
      return slice(request, context, *scene, route.sliceId);
    case RouteKind::Stream: {
      if (!boost::beast::websocket::is_upgrade(request)) {
        Answer a = line(request, http::status::upgrade_required, "stream",
                        scene->name + "/stream is a WebSocket: send an upgrade request");
        a.response.set(http::field::upgrade, "websocket");
        return a;
      }
      Answer a{Response{http::status::switching_protocols, request.version()}, "stream"};
      a.stream = scene;
      return a;
    }
    default:
      return line(request, http::status::not_found, "other", "not found");
  }
}

Answer route(const Request& request, Context& context) {
  if (request.method() != http::verb::get && request.method() != http::verb::head) {
    Answer a = line(request, http::status::method_not_allowed, "other",
                    "method not allowed: " + std::string(request.method_string()));
    a.response.set(http::field::allow, "GET, HEAD");
    return a;
  }
  const TargetPath path = parseTargetPath(request.target());
  if (!path.error.empty()) return line(request, http::status::bad_request, "other", path.error);
  const Route r = parseRoute(path.segments);
  switch (r.kind) {
    case RouteKind::Health:
      return line(request, http::status::ok, "healthz", "ok");
    case RouteKind::Metrics:
      if (auto denied = deny(request, context, nullptr, "metrics")) return std::move(*denied);
      return {respond(&request, http::status::ok, kMetricsType,
                      memory(context.metrics.text(context.cache.bytes(), context.cache.capacity()))),
              "metrics"};
    case RouteKind::Scenes:
      if (auto denied = deny(request, context, nullptr, "scenes")) return std::move(*denied);
      return scenes(request, context);
    case RouteKind::NotFound:
      if (auto denied = deny(request, context, nullptr, "other")) return std::move(*denied);
      return line(request, http::status::not_found, "other", "not found");
    default:
      return sceneRoute(request, context, path);
  }
}

}  // namespace

std::string publicMessage(const std::string& what, const Scene& scene) {
  const std::string prefix = scene.index->name() + ": ";
  return what.rfind(prefix, 0) == 0 ? scene.name + ": " + what.substr(prefix.size())
                                    : scene.name + ": " + what;
}

SliceCache::Bytes cachedSlice(Context& context, const Scene& scene, std::uint32_t slice) {
  SliceCache::Result cached;
  try {
    cached = context.cache.get(scene, slice);
  } catch (const SliceError&) {
    context.metrics.countCorruptSlice();
    throw;
  }
  if (cached.hit)
    context.metrics.countCacheHit();
  else
    context.metrics.countCacheMiss();
  return std::move(cached.bytes);
}

Answer handle(const Request& request, Context& context) {
  try {
    return route(request, context);
  } catch (const std::exception& e) {
    Answer a = line(request, http::status::internal_server_error, "other", "internal error");
    a.response.keep_alive(false);
    a.failure = e.what();
    return a;
  }
}

Answer refuse(http::status status, std::string_view reason) {
  Answer a{respond(nullptr, status, kText, memory(std::string(reason) + "\n")), "other"};
  a.failure = "refused: " + std::string(reason);
  return a;
}

}  // namespace svo::server
