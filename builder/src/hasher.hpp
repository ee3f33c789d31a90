// XXH3-64 over several byte ranges in turn, as if they were one (the builder's checksums and fingerprints).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>

#include <xxhash.h>

namespace svo {

class Hasher {
 public:
  Hasher() : state_(XXH3_createState()) {
    if (!state_) throw std::bad_alloc();
    XXH3_64bits_reset(state_.get());
  }
  template <class T>
  Hasher& add(const T* data, std::size_t count) {
    XXH3_64bits_update(state_.get(), data, count * sizeof(T));
    return *this;
  }
  std::uint64_t digest() const { return XXH3_64bits_digest(state_.get()); }

 private:
  struct Free {
    void operator()(XXH3_state_t* s) const { XXH3_freeState(s); }
  };
  std::unique_ptr<XXH3_state_t, Free> state_;
};

}  // namespace svo
