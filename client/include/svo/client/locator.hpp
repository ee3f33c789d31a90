// Where a command's store argument leads: a local .svo file, or an http:// or https:// URL of one on any
// static HTTP server, read by range requests. Both give the same byte source interface and the same slice
// source, so every command streams through the same pager either way.
#pragma once

#include <memory>
#include <string>
#include <string_view>

#include "svo/client/http_source.hpp"
#include "svo/client/slice_source.hpp"
#include "svo/store/byte_source.hpp"

namespace svo {

// Whether `locator` names a URL ("scheme://..."), supported or not; anything else is a local path.
bool isUrl(std::string_view locator);

// The bytes of the store at `locator`: a LocalFileSource, or an HttpByteSource (with `remote`'s token,
// timeouts and retries). Throws std::runtime_error with one line naming the locator: no such file, an
// unsupported URL scheme, an unreachable server, a refused token.
std::shared_ptr<const ByteSource> openByteSource(const std::string& locator,
                                                 const RemoteOptions& remote = {});

// The store at `locator` as the pager's slice source (its header and directory read and checked): a URL
// gives a ViewStreamSource (svo serve's view stream, range requests for the rest) unless
// `remote.viewStream` is false.
std::shared_ptr<SliceSource> openSliceSource(const std::string& locator, const RemoteOptions& remote = {});
// The same over `bytes`, the store at `locator` already opened by openByteSource (to keep its statistics).
std::shared_ptr<SliceSource> sliceSourceOver(std::shared_ptr<const ByteSource> bytes, const std::string& locator,
                                             const RemoteOptions& remote = {});

}  // namespace svo
