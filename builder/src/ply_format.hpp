// The PLY format's typed properties, shared by the point-cloud reader (point_cloud_io.cpp) and the streaming
// mesh reader (triangle_source.cpp): the type names, sizes and values, the element and property records of a
// header, and a property line's parse. Header-only so that each fuzz target links its one reader alone.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <istream>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace svo::detail::ply {

// A PLY header longer than this is not one the readers take.
inline constexpr std::size_t kMaxHeaderBytes = std::size_t(1) << 16;

enum class Type : std::uint8_t { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };

inline std::optional<Type> parseType(std::string_view name) {
  static constexpr std::pair<std::string_view, Type> kNames[] = {
      {"char", Type::Int8},      {"int8", Type::Int8},       {"uchar", Type::UInt8},
      {"uint8", Type::UInt8},    {"short", Type::Int16},     {"int16", Type::Int16},
      {"ushort", Type::UInt16},  {"uint16", Type::UInt16},   {"int", Type::Int32},
      {"int32", Type::Int32},    {"uint", Type::UInt32},     {"uint32", Type::UInt32},
      {"float", Type::Float32},  {"float32", Type::Float32}, {"double", Type::Float64},
      {"float64", Type::Float64}};
  for (const auto& [text, type] : kNames)
    if (name == text) return type;
  return std::nullopt;
}

inline std::size_t sizeOf(Type t) {
  constexpr std::size_t kSizes[] = {1, 1, 2, 2, 4, 4, 4, 8};
  return kSizes[int(t)];
}

// The value at `p` (file byte order `swap` away from ours) as a double: exact for every PLY type.
inline double valueAt(const char* p, Type t, bool swap = false) {
  char bytes[8];
  const std::size_t n = sizeOf(t);
  std::memcpy(bytes, p, n);
  if (swap) std::reverse(bytes, bytes + n);
  const auto get = [&bytes]<class T>(T v) {
    std::memcpy(&v, bytes, sizeof v);
    return double(v);
  };
  switch (t) {
    case Type::Int8:
      return get(std::int8_t{});
    case Type::UInt8:
      return get(std::uint8_t{});
    case Type::Int16:
      return get(std::int16_t{});
    case Type::UInt16:
      return get(std::uint16_t{});
    case Type::Int32:
      return get(std::int32_t{});
    case Type::UInt32:
      return get(std::uint32_t{});
    case Type::Float32:
      return get(float{});
    case Type::Float64:
      return get(double{});
  }
  return 0.0;
}

struct Property {
  std::string name;
  Type type = Type::UInt8;
  bool list = false;
  Type countType = Type::UInt8;
};

struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::vector<Property> properties;
  std::size_t fixedBytes() const {  // record size without lists
    std::size_t n = 0;
    for (const Property& p : properties) n += p.list ? 0 : sizeOf(p.type);
    return n;
  }
  bool hasList() const {
    return std::any_of(properties.begin(), properties.end(), [](const Property& p) { return p.list; });
  }
};

// The rest of a `property` line after its keyword: `TYPE NAME` or `list COUNTTYPE ITEMTYPE NAME`. nullopt
// with `error` set when it is not one.
inline std::optional<Property> parseProperty(std::istream& words, std::string& error) {
  Property p;
  std::string type;
  words >> type;
  if (type == "list") {
    std::string countType, itemType;
    words >> countType >> itemType;
    const auto c = parseType(countType), i = parseType(itemType);
    if (!c || !i) return error = "unknown list type", std::nullopt;
    p.list = true, p.countType = *c, p.type = *i;
  } else {
    const auto t = parseType(type);
    if (!t) return error = "unknown type '" + type + "'", std::nullopt;
    p.type = *t;
  }
  if (!(words >> p.name)) return error = "a property needs a name", std::nullopt;
  return p;
}

}  // namespace svo::detail::ply
