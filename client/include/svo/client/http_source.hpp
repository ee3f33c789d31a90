// A store read from any static HTTP server by range requests (docs/architecture.md: nginx, an object
// store, a CDN). Each read is one `Range: bytes=a-b` request whose answer must be 206 with exactly that
// Content-Range; the store's size comes from the first answer. The ETag (or else Last-Modified) of that first
// answer pins the file: every later request carries it in If-Range and every answer must carry it too, so a
// store replaced on the server mid-stream is a clear error instead of mixed bytes.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "svo/store/byte_source.hpp"

namespace svo {

// Seconds to wait for a TCP (and TLS) connection before the attempt counts as failed: a loopback or LAN
// server answers within milliseconds, a distant one within a second.
inline constexpr double kDefaultConnectTimeoutSeconds = 5.0;
// Seconds one range request may take in all: a 1 MB slice needs under a second on a 10 Mbit/s link.
inline constexpr double kDefaultRequestTimeoutSeconds = 30.0;
// Attempts after the first for a request that failed for a reason that may pass (connection refused or
// reset, timeout, HTTP 408, 429, 5xx).
inline constexpr int kDefaultRetries = 4;
// The first retry waits about this long; each further one twice as long (with jitter), up to
// kDefaultBackoffMaxSeconds: 0.2 + 0.4 + 0.8 + 1.6 s outlasts a server restart of a second or two.
inline constexpr double kDefaultBackoffBaseSeconds = 0.2;
inline constexpr double kDefaultBackoffMaxSeconds = 5.0;
// A request gives up retrying once this many seconds have passed since its first attempt, whatever the count.
inline constexpr double kDefaultRetryBudgetSeconds = 20.0;

// The opening request asks for the file's first bytes and keeps them, so that the first read (a store's
// 256-byte header) needs no round trip of its own: one page, in the same round trip as a one-byte probe.
inline constexpr std::uint64_t kHttpPrefixBytes = 4096;

// How a remote store is reached. Commands fill `token` from --token or the SVO_TOKEN environment variable.
struct RemoteOptions {
  std::string token;  // sent as `Authorization: Bearer TOKEN` when not empty
  // For https:// URLs: the certificates (PEM) that vouch for the server, when not the system's (a private
  // CA, a self-signed certificate); empty: the system's.
  std::string caFile;
  double connectTimeoutSeconds = kDefaultConnectTimeoutSeconds;
  double requestTimeoutSeconds = kDefaultRequestTimeoutSeconds;
  int retries = kDefaultRetries;
  double backoffBaseSeconds = kDefaultBackoffBaseSeconds;
  double backoffMaxSeconds = kDefaultBackoffMaxSeconds;
  double retryBudgetSeconds = kDefaultRetryBudgetSeconds;
  // Open svo serve's view stream beside the range requests (a server without one declines it, and then
  // ranges alone are used); false: range requests only.
  bool viewStream = true;
};

// What a source has asked of its server so far.
struct HttpStats {
  std::uint64_t requests = 0;  // attempts, retries included (the opening probe too)
  std::uint64_t retries = 0;   // attempts after a failure that may pass
  std::uint64_t bytes = 0;     // body bytes received in 206 answers
};

class HttpByteSource final : public ByteSource {
 public:
  // Checks the URL (http:// or https://) and asks for its first bytes (kept for reads among them): the answer
  // gives the size and the validator later answers must match. Throws ByteSourceError "URL: reason"
  // (TransientSourceError when the server could not be reached within the retries).
  HttpByteSource(const std::string& url, const RemoteOptions& options = {});
  ~HttpByteSource() override;
  HttpByteSource(const HttpByteSource&) = delete;
  HttpByteSource& operator=(const HttpByteSource&) = delete;

  // The URL (without any user or password it held).
  const std::string& name() const override { return name_; }
  std::uint64_t size() const override { return size_; }
  // One range request for [offset, min(offset + out.size(), size())), none for bytes among the first ones
  // the opening request brought. Thread safe: each concurrent caller
  // gets its own connection, kept alive for later reads. Throws ByteSourceError with the reason (the reader
  // adds the URL), TransientSourceError when the retries ran out on failures that may pass.
  std::size_t read(std::uint64_t offset, std::span<std::byte> out) const override;

  // The ETag or Last-Modified that pins the file ("" when the server sent neither).
  const std::string& validator() const { return validator_; }
  HttpStats stats() const;

 private:
  struct Handle;
  struct Expected;
  struct Answer;
  struct Verdict;
  // A handle from the pool (a new one when all are in use), with its kept-alive connection.
  std::unique_ptr<Handle> acquire() const;
  void release(std::unique_ptr<Handle> handle) const;
  // One request for the expected bytes into `out`.
  Answer perform(Handle& handle, const Expected& expected, std::span<std::byte> out) const;
  // Whether an answer is the one expected, a failure that may pass, or one that will not.
  Verdict judge(const Answer& answer, const Expected& expected) const;
  // The expected bytes into `out`, retrying failures that may pass; returns the accepted answer.
  Answer fetch(const Expected& expected, std::span<std::byte> out) const;

  std::string url_, name_;
  RemoteOptions options_;
  std::uint64_t size_ = 0;
  std::string validator_;          // the first answer's ETag, or its Last-Modified
  std::vector<std::byte> prefix_;  // the file's first bytes, from the first answer
  bool validatorIsEtag_ = false;
  struct HeaderList;
  std::unique_ptr<HeaderList> headers_;  // If-Range, once the validator is known
  mutable std::mutex poolMutex_;
  mutable std::vector<std::unique_ptr<Handle>> idle_;
  mutable std::atomic<std::uint64_t> requests_{0}, retries_{0}, bytes_{0};
};

}  // namespace svo
