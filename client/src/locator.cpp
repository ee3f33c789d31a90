#include "svo/client/locator.hpp"

#include "svo/client/stream_source.hpp"

#include <algorithm>
#include <cctype>
#include <stdexcept>

namespace svo {

bool isUrl(std::string_view locator) {
  // RFC 3986: scheme = ALPHA *( ALPHA / DIGIT / "+" / "-" / "." ), then "://" for a URL with a host.
  const std::size_t colon = locator.find("://");
  if (colon == std::string_view::npos || colon == 0 || !std::isalpha(static_cast<unsigned char>(locator[0])))
    return false;
  return std::all_of(locator.begin(), locator.begin() + std::ptrdiff_t(colon), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '+' || c == '-' || c == '.';
  });
}

std::shared_ptr<const ByteSource> openByteSource(const std::string& locator, const RemoteOptions& remote) {
  if (!isUrl(locator)) return std::make_shared<LocalFileSource>(locator);
  std::string scheme = locator.substr(0, locator.find("://"));
  std::transform(scheme.begin(), scheme.end(), scheme.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  if (scheme != "http" && scheme != "https")
    throw std::runtime_error(
        locator + ": stores are read from a local path or an http:// or https:// URL, not " + scheme + "://");
  return std::make_shared<HttpByteSource>(locator, remote);
}

std::shared_ptr<SliceSource> openSliceSource(const std::string& locator, const RemoteOptions& remote) {
  return sliceSourceOver(openByteSource(locator, remote), locator, remote);
}

std::shared_ptr<SliceSource> sliceSourceOver(std::shared_ptr<const ByteSource> bytes, const std::string& locator,
                                             const RemoteOptions& remote) {
  if (isUrl(locator) && remote.viewStream)
    return std::make_shared<ViewStreamSource>(std::move(bytes), locator, remote);
  return std::make_shared<StoreSliceSource>(std::move(bytes));
}

}  // namespace svo
