// Reading JSON input with messages that name the file and the field path ("frames[3].T_W_C").
// Private to the sensor module; every reader of outside JSON in it goes through these.
#pragma once

#include <array>
#include <cmath>
#include <filesystem>
#include <sstream>
#include <string>

#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/input_limits.h"

namespace romunect::json_fields {

using nlohmann::json;

inline const char* TypeName(const json& j) { return j.type_name(); }

// Parses a whole file; malformed or truncated JSON names the byte where parsing stopped. Only a
// regular file of at most kMaxTextFileBytes is read, and nesting past kMaxJsonDepth is refused
// before nlohmann::json (whose copies recurse) sees it.
inline json ParseFile(const std::filesystem::path& path) {
  const std::string text = ReadInputFile(path, kMaxTextFileBytes, "JSON file");
  CheckJsonNesting(text, path.string());
  try {
    return json::parse(text);
  } catch (const json::exception& e) {  // syntax, and numbers out of a double's range (1e999)
    throw InputError(path.string(), "", std::string("malformed JSON (") + e.what() + ")");
  }
}

// A cursor into a JSON document that knows its file and field path.
class Field {
 public:
  Field(const json& value, std::string source, std::string path)
      : value_(value), source_(std::move(source)), path_(std::move(path)) {}

  const json& value() const { return value_; }
  const std::string& path() const { return path_; }
  const std::string& source() const { return source_; }

  [[noreturn]] void Fail(const std::string& problem) const {
    throw InputError(source_, path_.empty() ? "(document)" : path_, problem);
  }

  bool Has(const std::string& key) const { return value_.is_object() && value_.contains(key); }

  Field operator[](const std::string& key) const {
    if (!value_.is_object()) Fail(std::string("expected an object, found ") + TypeName(value_));
    if (!value_.contains(key)) {
      throw InputError(source_, Join(key), "missing (required)");
    }
    return Field(value_.at(key), source_, Join(key));
  }

  Field operator[](size_t i) const { return Field(value_.at(i), source_, path_ + "[" + std::to_string(i) + "]"); }

  size_t ArraySize() const {
    if (!value_.is_array()) Fail(std::string("expected an array, found ") + TypeName(value_));
    return value_.size();
  }

  double Number() const {
    if (!value_.is_number()) Fail(std::string("expected a number, found ") + TypeName(value_));
    const double x = value_.get<double>();
    if (!std::isfinite(x)) Fail("expected a finite number");
    return x;
  }

  double PositiveNumber() const {
    const double x = Number();
    if (!(x > 0.0)) Fail("expected a positive number, found " + Format(x));
    return x;
  }

  int Int() const {
    if (!value_.is_number_integer()) {
      Fail(std::string("expected an integer, found ") + (value_.is_number() ? value_.dump() : TypeName(value_)));
    }
    // An unsigned value above 2^63 (2^64 - 1) would wrap to a negative long long: checked as unsigned.
    if (value_.is_number_unsigned() && value_.get<unsigned long long>() > 2147483647ULL) {
      Fail("integer out of range: " + value_.dump());
    }
    const auto x = value_.get<long long>();
    if (x < -2147483647LL || x > 2147483647LL) Fail("integer out of range: " + value_.dump());
    return static_cast<int>(x);
  }

  std::string String() const {
    if (!value_.is_string()) Fail(std::string("expected a string, found ") + TypeName(value_));
    std::string text = value_.get<std::string>();
    // "\u0000" would cut a path or name short where C strings take over.
    if (text.find('\0') != std::string::npos) Fail("a string may not hold a NUL character (\\u0000)");
    return text;
  }

  bool Bool() const {
    if (!value_.is_boolean()) Fail(std::string("expected true or false, found ") + TypeName(value_));
    return value_.get<bool>();
  }

  template <size_t N>
  std::array<double, N> Numbers() const {
    if (!value_.is_array() || value_.size() != N) {
      Fail("expected an array of " + std::to_string(N) + " numbers, found " +
           (value_.is_array() ? std::to_string(value_.size()) + " entries" : std::string(TypeName(value_))));
    }
    std::array<double, N> out{};
    for (size_t i = 0; i < N; ++i) out[i] = (*this)[i].Number();
    return out;
  }

 private:
  std::string Join(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }
  static std::string Format(double x) {
    std::ostringstream s;
    s << x;
    return s.str();
  }

  const json& value_;
  std::string source_;
  std::string path_;
};

}  // namespace romunect::json_fields
