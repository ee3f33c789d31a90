// The body of every response: bytes in memory (a cached slice, a JSON document, a line of text) or a byte
// range of a store file, read with pread one chunk at a time as the socket takes them. A connection queues
// at most one chunk of file bytes: Beast asks for the next only once the last is written.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include <boost/beast/core/error.hpp>
#include <boost/beast/http/message.hpp>
#include <boost/optional.hpp>
#include <boost/system/error_code.hpp>

#include "svo/store/byte_source.hpp"
#include "svo/store/store_types.hpp"

namespace svo::server {

// Bytes of file read per write: a 1 MB slice in four writes, and what one connection holds at most.
inline constexpr std::size_t kFileChunkBytes = 256 * 1024;

struct Payload {
  std::shared_ptr<const void> owner;  // keeps `data` alive
  const std::byte* data = nullptr;    // memory bytes, or null for a file range
  std::shared_ptr<const ByteSource> file;
  std::uint64_t offset = 0, length = 0;  // into `data` or `file`

  // Bytes [first, first + count) of this payload.
  Payload part(std::uint64_t first, std::uint64_t count) const {
    Payload p = *this;
    p.offset += first;
    p.length = count;
    return p;
  }
};

struct PayloadBody {
  using value_type = Payload;
  static std::uint64_t size(const value_type& v) { return v.length; }

  class writer {
   public:
    using const_buffers_type = boost::asio::const_buffer;
    template <bool isRequest, class Fields>
    writer(const boost::beast::http::header<isRequest, Fields>&, const value_type& v) : payload_(v) {}
    void init(boost::beast::error_code& ec) { ec = {}; }
    boost::optional<std::pair<const_buffers_type, bool>> get(boost::beast::error_code& ec) {
      ec = {};
      const std::uint64_t left = payload_.length - done_;
      if (left == 0) return boost::none;
      const std::byte* data = nullptr;
      std::size_t count = 0;
      if (payload_.data) {
        data = payload_.data + payload_.offset + done_;
        count = std::size_t(left);
      } else {
        count = std::size_t(std::min<std::uint64_t>(left, kFileChunkBytes));
        chunk_.resize(count);
        std::size_t got = 0;
        try {
          got = payload_.file->read(payload_.offset + done_, chunk_);
        } catch (const ByteSourceError&) {
        }
        if (got != count) {  // the file shrank or failed under us: end the response, the client sees it cut
          ec = boost::system::errc::make_error_code(boost::system::errc::io_error);
          return boost::none;
        }
        data = chunk_.data();
      }
      done_ += count;
      return std::make_pair(const_buffers_type(data, count), done_ < payload_.length);
    }

   private:
    const value_type& payload_;
    std::uint64_t done_ = 0;
    SliceBytes chunk_;  // no zero fill: every byte is read before it is sent
  };
};

}  // namespace svo::server
