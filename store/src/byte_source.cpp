#include "svo/store/byte_source.hpp"

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <system_error>
#include <utility>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace svo {

LocalFileSource::LocalFileSource(const std::filesystem::path& path) : name_(path.string()) {
  const auto fail = [&](const std::string& what) { throw std::runtime_error(name_ + ": " + what); };
  fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0)
    fail(errno == ENOENT ? "no such file" : std::string("cannot open (") + std::strerror(errno) + ")");
  struct stat st {};
  std::error_code ec;
  if (::fstat(fd_, &st) != 0)
    ec.assign(errno, std::generic_category());
  else if (!S_ISREG(st.st_mode))  // as std::filesystem::file_size says of other kinds of file
    ec = std::make_error_code(S_ISDIR(st.st_mode) ? std::errc::is_a_directory : std::errc::not_supported);
  if (ec) {
    ::close(fd_);  // no destructor runs for a constructor that throws
    fail("cannot read its size (" + ec.message() + ")");
  }
  size_ = std::uint64_t(st.st_size);
}

LocalFileSource::~LocalFileSource() {
  ::close(fd_);
}

std::size_t LocalFileSource::read(std::uint64_t offset, std::span<std::byte> out) const {
  std::size_t done = 0;
  while (done < out.size()) {
    const ssize_t got = ::pread(fd_, out.data() + done, out.size() - done, off_t(offset + done));
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) throw ByteSourceError(std::string("cannot read (") + std::strerror(errno) + ")");
    if (got == 0) break;
    done += std::size_t(got);
  }
  return done;
}

MemorySource::MemorySource(std::string name, std::vector<std::byte> bytes)
    : name_(std::move(name)), bytes_(std::move(bytes)) {}

std::size_t MemorySource::read(std::uint64_t offset, std::span<std::byte> out) const {
  if (offset >= bytes_.size()) return 0;
  const std::size_t count = std::min<std::uint64_t>(out.size(), bytes_.size() - offset);
  std::memcpy(out.data(), bytes_.data() + offset, count);
  return count;
}

}  // namespace svo
