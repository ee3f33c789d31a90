#include "svo/client/http_source.hpp"

#include <curl/curl.h>

#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <random>
#include <thread>
#include <utility>

namespace svo {
namespace {

// Object stores and CDNs redirect once or twice (to a region, to a signed URL); more is a loop.
constexpr long kMaxRedirects = 5;
// Each backoff is drawn from [kJitterLow, 1] of its nominal length ("equal jitter"), so that the fetch
// threads that failed together do not all come back in the same millisecond.
constexpr double kJitterLow = 0.5;
constexpr const char* kUserAgent = "svostream";

void initCurl() {
  static const CURLcode code = curl_global_init(CURL_GLOBAL_DEFAULT);
  if (code != CURLE_OK)
    throw ByteSourceError(std::string("libcurl cannot start: ") + curl_easy_strerror(code));
}

// The URL checked by libcurl's parser, scheme http or https, and the same URL without user or password (what
// messages call it). Throws ByteSourceError "URL: what is wrong".
std::string checkedUrl(const std::string& url) {
  const std::unique_ptr<CURLU, void (*)(CURLU*)> parsed(curl_url(), curl_url_cleanup);
  if (!parsed) throw std::bad_alloc();
  if (const CURLUcode rc = curl_url_set(parsed.get(), CURLUPART_URL, url.c_str(), 0); rc != CURLUE_OK)
    throw ByteSourceError(url + ": not a valid URL (" + curl_url_strerror(rc) + ")");
  char* scheme = nullptr;
  curl_url_get(parsed.get(), CURLUPART_SCHEME, &scheme, 0);
  const std::string s = scheme ? scheme : "";
  curl_free(scheme);
  if (s != "http" && s != "https")
    throw ByteSourceError(url + ": the scheme must be http or https (got \"" + s + "\")");
  curl_url_set(parsed.get(), CURLUPART_USER, nullptr, 0);
  curl_url_set(parsed.get(), CURLUPART_PASSWORD, nullptr, 0);
  char* clean = nullptr;
  if (curl_url_get(parsed.get(), CURLUPART_URL, &clean, 0) != CURLUE_OK || !clean)
    throw ByteSourceError(url + ": not a valid URL");
  std::string out = clean;
  curl_free(clean);
  return out;
}

// The value of response header `name` of the last request (after redirects), or "".
std::string headerOf(CURL* curl, const char* name) {
  curl_header* h = nullptr;
  if (curl_easy_header(curl, name, 0, CURLH_HEADER, -1, &h) != CURLHE_OK || !h) return {};
  return h->value;
}

// "bytes FIRST-LAST/TOTAL", or for an unsatisfiable range "bytes */TOTAL" (first and last then unset).
struct ContentRange {
  std::optional<std::uint64_t> first, last;
  std::uint64_t total = 0;
};
std::optional<ContentRange> parseContentRange(const std::string& value) {
  const auto number = [](std::string_view text) -> std::optional<std::uint64_t> {
    std::uint64_t v = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size() || text.empty()) return std::nullopt;
    return v;
  };
  std::string_view v = value;
  if (!v.starts_with("bytes ")) return std::nullopt;
  v.remove_prefix(6);
  const std::size_t slash = v.find('/');
  if (slash == std::string_view::npos) return std::nullopt;
  ContentRange out;
  const auto total = number(v.substr(slash + 1));
  if (!total) return std::nullopt;
  out.total = *total;
  const std::string_view range = v.substr(0, slash);
  if (range == "*") return out;
  const std::size_t dash = range.find('-');
  if (dash == std::string_view::npos) return std::nullopt;
  out.first = number(range.substr(0, dash));
  out.last = number(range.substr(dash + 1));
  if (!out.first || !out.last || *out.first > *out.last) return std::nullopt;
  return out;
}

// Failures that may pass: the server is restarting, overloaded, or the network dropped the connection.
bool transientCode(CURLcode code) {
  switch (code) {
    case CURLE_COULDNT_CONNECT:
    case CURLE_OPERATION_TIMEDOUT:
    case CURLE_SEND_ERROR:
    case CURLE_RECV_ERROR:
    case CURLE_GOT_NOTHING:
    case CURLE_PARTIAL_FILE:
    case CURLE_HTTP2:
    case CURLE_HTTP2_STREAM:
    case CURLE_SSL_CONNECT_ERROR:
      return true;
    default:
      return false;
  }
}

bool transientStatus(long status) {
  return status == 408 || status == 429 || (status >= 500 && status <= 599);
}

std::string rangeText(std::uint64_t first, std::uint64_t last) {
  return std::to_string(first) + "-" + std::to_string(last);
}

}  // namespace

struct HttpByteSource::Handle {
  CURL* curl = nullptr;
  char error[CURL_ERROR_SIZE] = {};
  ~Handle() {
    if (curl) curl_easy_cleanup(curl);
  }
};

struct HttpByteSource::HeaderList {
  curl_slist* list = nullptr;
  ~HeaderList() { curl_slist_free_all(list); }
};

// What a request must be answered with.
struct HttpByteSource::Expected {
  std::uint64_t first = 0, last = 0;
  // The opening request: no size or validator known yet, and a file shorter than asked answers with all it
  // has.
  bool probe = false;
};

// What one request got.
struct HttpByteSource::Answer {
  CURLcode code = CURLE_OK;
  std::string curlError;
  long status = 0;
  std::size_t received = 0;
  bool stopped = false;  // the body was refused: not a 206 for the range asked, or longer than asked
  std::string contentRange, etag, lastModified;
  curl_off_t retryAfter = 0;  // seconds, from a Retry-After header
};

namespace {

// Whether a Content-Range answers for bytes [first, last]: exactly, or for an opening probe the whole of a
// shorter file.
bool answers(const std::optional<ContentRange>& range, std::uint64_t first, std::uint64_t last, bool probe) {
  if (!range || !range->first || *range->first != first) return false;
  return *range->last == last || (probe && *range->last < last && *range->last + 1 == range->total);
}

// The body of one request, written straight into the caller's buffer once its headers are checked.
struct Body {
  CURL* curl = nullptr;
  std::uint64_t first = 0, last = 0;
  bool probe = false;
  std::span<std::byte> out;
  std::size_t received = 0;
  bool checked = false, stopped = false;
};

std::size_t onBody(char* data, std::size_t size, std::size_t count, void* user) {
  Body& body = *static_cast<Body*>(user);
  const std::size_t n = size * count;
  if (!body.checked) {
    // A whole file answering a range request (200) may be gigabytes: stop before taking a byte of a body
    // that is not exactly the range asked.
    body.checked = true;
    long status = 0;
    curl_easy_getinfo(body.curl, CURLINFO_RESPONSE_CODE, &status);
    body.stopped = status != 206 || !answers(parseContentRange(headerOf(body.curl, "Content-Range")),
                                             body.first, body.last, body.probe);
  }
  if (body.stopped || n > body.out.size() - body.received) {
    body.stopped = true;
    return CURL_WRITEFUNC_ERROR;
  }
  std::memcpy(body.out.data() + body.received, data, n);
  body.received += n;
  return n;
}

}  // namespace

HttpByteSource::HttpByteSource(const std::string& url, const RemoteOptions& options)
    : url_(url), options_(options), headers_(std::make_unique<HeaderList>()) {
  if (options.retries < 0 || !(options.connectTimeoutSeconds > 0.0) ||
      !(options.requestTimeoutSeconds > 0.0) || options.backoffBaseSeconds < 0.0 ||
      options.backoffMaxSeconds < 0.0 || options.retryBudgetSeconds < 0.0)
    throw ByteSourceError(url + ": timeouts must be positive, retries and backoff not negative");
  initCurl();
  name_ = checkedUrl(url);
  prefix_.resize(kHttpPrefixBytes);
  Answer answer;
  try {
    answer = fetch({0, kHttpPrefixBytes - 1, true}, prefix_);
  } catch (const TransientSourceError& e) {
    throw TransientSourceError(name_ + ": " + e.what());
  } catch (const ByteSourceError& e) {
    throw ByteSourceError(name_ + ": " + e.what());
  }
  size_ = parseContentRange(answer.contentRange)->total;  // fetch accepted it
  prefix_.resize(answer.received);
  validatorIsEtag_ = !answer.etag.empty();
  validator_ = validatorIsEtag_ ? answer.etag : answer.lastModified;
  // If-Range takes a strong ETag or a date: a weak ETag (W/"...") would always get the whole file.
  const bool strongEtag = validatorIsEtag_ && !answer.etag.starts_with("W/");
  const std::string ifRange = strongEtag ? answer.etag : answer.lastModified;
  if (!ifRange.empty()) {
    headers_->list = curl_slist_append(nullptr, ("If-Range: " + ifRange).c_str());
    if (!headers_->list) throw std::bad_alloc();
  }
}

HttpByteSource::~HttpByteSource() = default;

HttpStats HttpByteSource::stats() const {
  return {requests_.load(std::memory_order_relaxed), retries_.load(std::memory_order_relaxed),
          bytes_.load(std::memory_order_relaxed)};
}

std::unique_ptr<HttpByteSource::Handle> HttpByteSource::acquire() const {
  {
    std::lock_guard lock(poolMutex_);
    if (!idle_.empty()) {
      std::unique_ptr<Handle> h = std::move(idle_.back());
      idle_.pop_back();
      return h;
    }
  }
  auto h = std::make_unique<Handle>();
  h->curl = curl_easy_init();
  if (!h->curl) throw ByteSourceError("libcurl cannot make a handle");
  CURL* c = h->curl;
  curl_easy_setopt(c, CURLOPT_URL, url_.c_str());
  curl_easy_setopt(c, CURLOPT_NOSIGNAL, 1L);  // several threads: no SIGALRM for timeouts
  curl_easy_setopt(c, CURLOPT_ERRORBUFFER, h->error);
  curl_easy_setopt(c, CURLOPT_USERAGENT, kUserAgent);
  if (!options_.caFile.empty()) curl_easy_setopt(c, CURLOPT_CAINFO, options_.caFile.c_str());
  curl_easy_setopt(c, CURLOPT_HTTP_VERSION, long(CURL_HTTP_VERSION_2TLS));
  curl_easy_setopt(c, CURLOPT_PROTOCOLS_STR, "http,https");
  curl_easy_setopt(c, CURLOPT_REDIR_PROTOCOLS_STR, "http,https");
  curl_easy_setopt(c, CURLOPT_FOLLOWLOCATION, 1L);
  curl_easy_setopt(c, CURLOPT_MAXREDIRS, kMaxRedirects);
  curl_easy_setopt(c, CURLOPT_CONNECTTIMEOUT_MS, long(std::ceil(options_.connectTimeoutSeconds * 1e3)));
  curl_easy_setopt(c, CURLOPT_TIMEOUT_MS, long(std::ceil(options_.requestTimeoutSeconds * 1e3)));
  curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, onBody);
  if (!options_.token.empty()) {
    // libcurl sends it only to the URL's host, not to another host a redirect leads to.
    curl_easy_setopt(c, CURLOPT_HTTPAUTH, CURLAUTH_BEARER);
    curl_easy_setopt(c, CURLOPT_XOAUTH2_BEARER, options_.token.c_str());
  }
  return h;
}

void HttpByteSource::release(std::unique_ptr<Handle> handle) const {
  std::lock_guard lock(poolMutex_);
  idle_.push_back(std::move(handle));
}

HttpByteSource::Answer HttpByteSource::perform(Handle& handle, const Expected& expected,
                                               std::span<std::byte> out) const {
  CURL* c = handle.curl;
  Body body{c, expected.first, expected.last, expected.probe, out};
  const std::string range = rangeText(expected.first, expected.last);
  curl_easy_setopt(c, CURLOPT_RANGE, range.c_str());
  curl_easy_setopt(c, CURLOPT_WRITEDATA, &body);
  curl_easy_setopt(c, CURLOPT_HTTPHEADER, expected.probe ? nullptr : headers_->list);
  handle.error[0] = '\0';
  requests_.fetch_add(1, std::memory_order_relaxed);
  Answer a;
  a.code = curl_easy_perform(c);
  a.curlError = handle.error;
  curl_easy_getinfo(c, CURLINFO_RESPONSE_CODE, &a.status);
  curl_easy_getinfo(c, CURLINFO_RETRY_AFTER, &a.retryAfter);
  a.received = body.received;
  a.stopped = body.stopped;
  if (a.status != 0) {
    a.contentRange = headerOf(c, "Content-Range");
    a.etag = headerOf(c, "ETag");
    a.lastModified = headerOf(c, "Last-Modified");
  }
  return a;
}

struct HttpByteSource::Verdict {
  enum Kind { Accept, Retry, Fail } kind = Accept;
  std::string reason;
};

HttpByteSource::Verdict HttpByteSource::judge(const Answer& a, const Expected& expected) const {
  if (a.code != CURLE_OK && !(a.code == CURLE_WRITE_ERROR && a.stopped)) {
    std::string reason = curl_easy_strerror(a.code);
    if (!a.curlError.empty()) reason += " (" + a.curlError + ")";
    return {transientCode(a.code) ? Verdict::Retry : Verdict::Fail, reason};
  }
  const bool token = !options_.token.empty();
  const std::string asked = "bytes " + rangeText(expected.first, expected.last);
  const std::string status = "HTTP " + std::to_string(a.status);
  const auto range = parseContentRange(a.contentRange);
  // The answer's validator against the first answer's: a different one means another file.
  const std::string& now = validatorIsEtag_ ? a.etag : a.lastModified;
  if ((a.status == 200 || a.status == 206) && !expected.probe && !validator_.empty() && !now.empty() &&
      now != validator_)
    return {Verdict::Fail, std::string("the store changed on the server since it was opened (") +
                               (validatorIsEtag_ ? "ETag " : "Last-Modified ") + validator_ + ", now " + now +
                               "): open it again"};
  switch (a.status) {
    case 206:
      if (!answers(range, expected.first, expected.last, expected.probe))
        return {Verdict::Fail, "asked for " + asked + ", the server answered \"" + a.contentRange + "\""};
      if (!expected.probe && range->total != size_)
        return {Verdict::Fail, "the store changed on the server since it was opened (" +
                                   std::to_string(size_) + " bytes, now " + std::to_string(range->total) +
                                   "): open it again"};
      if (a.received != *range->last - *range->first + 1)
        return {Verdict::Retry,
                "the answer to " + asked + " ended after " + std::to_string(a.received) + " bytes"};
      return {};
    case 200:
      return {Verdict::Fail,
              "the server does not answer range requests (" + status +
                  " with the whole file): serve the store from one that does (nginx, an object "
                  "store)"};
    case 401:
      return {Verdict::Fail, token ? "token refused (" + status + ")"
                                   : "needs a token (--token or SVO_TOKEN; " + status + ")"};
    case 403:
      return {Verdict::Fail, token ? "token refused (" + status + ")" : "access forbidden (" + status + ")"};
    case 404:
    case 410:
      return {Verdict::Fail, "no such store at this URL (" + status + ")"};
    case 416:
      if (expected.probe && range && !range->first) return {};  // an empty file: "bytes */0"
      return {Verdict::Fail, "the server has no " + asked + " (" + status +
                                 "): the file is shorter than the store's directory says"};
    default:
      if (transientStatus(a.status)) return {Verdict::Retry, "the server failed (" + status + ")"};
      return {Verdict::Fail, "unexpected answer to a range request (" + status + ")"};
  }
}

HttpByteSource::Answer HttpByteSource::fetch(const Expected& expected, std::span<std::byte> out) const {
  thread_local std::minstd_rand jitter(std::random_device{}());
  const auto start = std::chrono::steady_clock::now();
  for (int attempt = 0;; ++attempt) {
    std::unique_ptr<Handle> handle = acquire();
    Answer answer = perform(*handle, expected, out);
    release(std::move(handle));
    const Verdict verdict = judge(answer, expected);
    if (verdict.kind == Verdict::Accept) {
      bytes_.fetch_add(answer.received, std::memory_order_relaxed);
      return answer;
    }
    if (verdict.kind == Verdict::Fail) throw ByteSourceError(verdict.reason);
    const double nominal =
        std::min(options_.backoffMaxSeconds, options_.backoffBaseSeconds * std::ldexp(1.0, attempt));
    double delay = nominal * std::uniform_real_distribution<double>(kJitterLow, 1.0)(jitter);
    delay = std::max(delay, std::min(double(answer.retryAfter), options_.backoffMaxSeconds));
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (attempt >= options_.retries || elapsed + delay > options_.retryBudgetSeconds) {
      char tail[96];
      std::snprintf(tail, sizeof tail, " (gave up after %d attempts in %.1f s)", attempt + 1, elapsed);
      throw TransientSourceError(verdict.reason + tail);
    }
    retries_.fetch_add(1, std::memory_order_relaxed);
    std::this_thread::sleep_for(std::chrono::duration<double>(delay));
  }
}

std::size_t HttpByteSource::read(std::uint64_t offset, std::span<std::byte> out) const {
  if (offset >= size_ || out.empty()) return 0;
  const std::size_t count = std::size_t(std::min<std::uint64_t>(out.size(), size_ - offset));
  if (offset + count <= prefix_.size()) {
    std::memcpy(out.data(), prefix_.data() + offset, count);
    return count;
  }
  fetch({offset, offset + count - 1, false}, out.first(count));
  return count;
}

}  // namespace svo
