// 32 lanes as two 16-lane AVX-512 halves, for packet_loop.inl: GCC lowers a 1024-bit vector type lane by
// lane, so each operation is written here for both halves. No includes here.
using HalfFloats = float __attribute__((vector_size(64)));
using HalfInts = std::int32_t __attribute__((vector_size(64)));

template <class T, class H>
struct [[gnu::may_alias]] Halves {
  H lo, hi;
  T& operator[](int l) { return reinterpret_cast<T*>(this)[l]; }
  T operator[](int l) const { return reinterpret_cast<const T*>(this)[l]; }
};
using Floats = Halves<float, HalfFloats>;
using Ints = Halves<std::int32_t, HalfInts>;

// clang-format off
#define SVO_HALVES_ARITHMETIC(op)                                                               \
  template <class T, class H>                                                                   \
  [[gnu::always_inline]] inline Halves<T, H> operator op(Halves<T, H> a, Halves<T, H> b) {      \
    return {a.lo op b.lo, a.hi op b.hi};                                                        \
  }                                                                                             \
  template <class T, class H>                                                                   \
  [[gnu::always_inline]] inline Halves<T, H> operator op(Halves<T, H> a, T b) {                 \
    return {a.lo op b, a.hi op b};                                                              \
  }                                                                                             \
  template <class T, class H>                                                                   \
  [[gnu::always_inline]] inline Halves<T, H> operator op(T a, Halves<T, H> b) {                 \
    return {a op b.lo, a op b.hi};                                                              \
  }                                                                                             \
  template <class T, class H>                                                                   \
  [[gnu::always_inline]] inline Halves<T, H>& operator op##=(Halves<T, H>& a, Halves<T, H> b) { \
    a.lo op##= b.lo, a.hi op##= b.hi;                                                         \
    return a;                                                                                   \
  }
SVO_HALVES_ARITHMETIC(+)
SVO_HALVES_ARITHMETIC(-)
SVO_HALVES_ARITHMETIC(*)
SVO_HALVES_ARITHMETIC(/)
SVO_HALVES_ARITHMETIC(&)
SVO_HALVES_ARITHMETIC(|)
SVO_HALVES_ARITHMETIC(^)
SVO_HALVES_ARITHMETIC(<<)
SVO_HALVES_ARITHMETIC(>>)
#undef SVO_HALVES_ARITHMETIC
// clang-format on

#define SVO_HALVES_COMPARISON(op)                                                  \
  template <class T, class H>                                                      \
  [[gnu::always_inline]] inline Ints operator op(Halves<T, H> a, Halves<T, H> b) { \
    return {a.lo op b.lo, a.hi op b.hi};                                           \
  }                                                                                \
  template <class T, class H>                                                      \
  [[gnu::always_inline]] inline Ints operator op(Halves<T, H> a, T b) {            \
    return {a.lo op b, a.hi op b};                                                 \
  }
SVO_HALVES_COMPARISON(<)
SVO_HALVES_COMPARISON(<=)
SVO_HALVES_COMPARISON(>)
SVO_HALVES_COMPARISON(>=)
SVO_HALVES_COMPARISON(==)
SVO_HALVES_COMPARISON(!=)
#undef SVO_HALVES_COMPARISON

template <class T, class H>
[[gnu::always_inline]] inline Halves<T, H> operator-(Halves<T, H> a) {
  return {-a.lo, -a.hi};
}
[[gnu::always_inline]] inline Ints operator~(Ints a) {
  return {~a.lo, ~a.hi};
}
template <class T, class H>
[[gnu::always_inline]] inline Halves<T, H> select(Ints mask, Halves<T, H> a, Halves<T, H> b) {
  return {mask.lo ? a.lo : b.lo, mask.hi ? a.hi : b.hi};
}
[[gnu::always_inline]] inline Floats toFloats(Ints a) {
  return {__builtin_convertvector(a.lo, HalfFloats), __builtin_convertvector(a.hi, HalfFloats)};
}
[[gnu::always_inline]] inline Ints bitsOf(Floats a) {
  return {(HalfInts)a.lo, (HalfInts)a.hi};
}
[[gnu::always_inline]] inline Floats floatsOf(Ints a) {
  return {(HalfFloats)a.lo, (HalfFloats)a.hi};
}
[[gnu::always_inline]] inline unsigned lanesOf(Ints mask) {
  return unsigned(_mm512_movepi32_mask(__m512i(mask.lo))) | unsigned(_mm512_movepi32_mask(__m512i(mask.hi)))
                                                                << 16;
}
