// Where a store's bytes come from (docs/architecture.md: the local file, memory, HTTP range requests). A reader asks a
// source for byte ranges only: the header, the directory, then slices on demand (store_index.hpp,
// store_reader.hpp).
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace svo {

// A source could not deliver bytes it has. The message is the reason only ("cannot read (...)"): the
// reader adds what it was reading (the header, the directory, a slice).
struct ByteSourceError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// A source could not deliver bytes for a reason that may pass (a server restarting or overloaded, a timeout):
// the same read may succeed later, unlike bytes that are missing or wrong.
struct TransientSourceError : ByteSourceError {
  using ByteSourceError::ByteSourceError;
};

class ByteSource {
 public:
  virtual ~ByteSource() = default;
  // What messages call the bytes: a path, a URL.
  virtual const std::string& name() const = 0;
  virtual std::uint64_t size() const = 0;
  // Reads up to out.size() bytes at `offset` into `out`; returns how many, fewer only where the bytes end.
  // Safe to call from several threads at once. Throws ByteSourceError when the bytes cannot be read.
  virtual std::size_t read(std::uint64_t offset, std::span<std::byte> out) const = 0;
};

// A file on a local disk, read with pread on the descriptor opened here: no reopening per read, and no
// shared file position between threads.
class LocalFileSource final : public ByteSource {
 public:
  // Opens the file and takes its size; throws std::runtime_error naming it when it cannot.
  explicit LocalFileSource(const std::filesystem::path& path);
  ~LocalFileSource() override;
  LocalFileSource(const LocalFileSource&) = delete;
  LocalFileSource& operator=(const LocalFileSource&) = delete;
  const std::string& name() const override { return name_; }
  std::uint64_t size() const override { return size_; }
  std::size_t read(std::uint64_t offset, std::span<std::byte> out) const override;

 private:
  std::string name_;
  int fd_ = -1;
  std::uint64_t size_ = 0;
};

// Bytes held in memory (tests, fuzzing, a store fetched whole).
class MemorySource final : public ByteSource {
 public:
  MemorySource(std::string name, std::vector<std::byte> bytes);
  const std::string& name() const override { return name_; }
  std::uint64_t size() const override { return bytes_.size(); }
  std::size_t read(std::uint64_t offset, std::span<std::byte> out) const override;

 private:
  std::string name_;
  std::vector<std::byte> bytes_;
};

}  // namespace svo
