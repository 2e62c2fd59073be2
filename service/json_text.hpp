// JsonText: answers written straight into their JSON text, without building a document
// first (a star's answer is ~2.5 KB of numbers; building an nlohmann::json of nested
// arrays and dumping it cost more than the star itself). Numbers: integers in decimal,
// doubles shortest-round-trip (std::to_chars; ".0" appended to integral values so a
// float reads back as a float), non-finite doubles as null (as nlohmann writes them).
// The caller writes keys in the order the answers have always had (alphabetical: the
// order nlohmann's std::map-backed objects print).
//
// Thread safety: none; one JsonText per answer.
#pragma once

#include <charconv>
#include <cmath>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

namespace spokemesh::service {

class JsonText {
 public:
  explicit JsonText(std::string& out) : out_(out) {}

  JsonText& raw(std::string_view text) {
    out_ += text;
    return *this;
  }
  // "key": (with the comma before it unless it opens its object).
  JsonText& key(std::string_view name) {
    if (!first_) out_ += ',';
    first_ = false;
    out_ += '"';
    out_ += name;
    out_ += "\":";
    return *this;
  }
  JsonText& open_object() {
    out_ += '{';
    first_ = true;
    return *this;
  }
  JsonText& close_object() {
    out_ += '}';
    first_ = false;
    return *this;
  }
  JsonText& boolean(bool v) { return raw(v ? "true" : "false"); }
  template <class Int>
  JsonText& integer(Int v) {
    char buf[24];
    out_.append(buf, std::to_chars(buf, buf + sizeof buf, v).ptr);
    return *this;
  }
  JsonText& number(double v) {
    if (!std::isfinite(v)) return raw("null");
    char buf[32];
    char* end = std::to_chars(buf, buf + sizeof buf, v).ptr;
    out_.append(buf, end);
    if (std::string_view(buf, static_cast<std::size_t>(end - buf)).find_first_of(".e") == std::string_view::npos) {
      out_ += ".0";
    }
    return *this;
  }
  // A string the server made or validated (ids, mode names): valid UTF-8; quotes,
  // backslashes and control characters escaped.
  JsonText& string(std::string_view text) {
    out_ += '"';
    for (const char ch : text) {
      if (ch == '"' || ch == '\\') {
        out_ += '\\';
        out_ += ch;
      } else if (static_cast<unsigned char>(ch) < 0x20) {
        static constexpr char kHex[] = "0123456789abcdef";
        out_ += "\\u00";
        out_ += kHex[(ch >> 4) & 0xf];
        out_ += kHex[ch & 0xf];
      } else {
        out_ += ch;
      }
    }
    out_ += '"';
    return *this;
  }
  // [v, v, ...]
  template <class T>
  JsonText& array(std::span<const T> values) {
    out_ += '[';
    for (std::size_t i = 0; i < values.size(); ++i) {
      if (i != 0) out_ += ',';
      value(values[i]);
    }
    out_ += ']';
    return *this;
  }
  template <class T>
  JsonText& array(const std::vector<T>& values) {
    return array(std::span<const T>(values));
  }
  // [[v..v], [v..v], ...]: rows of `width` values.
  template <class T>
  JsonText& rows(std::span<const T> flat, std::size_t width) {
    out_ += '[';
    for (std::size_t i = 0; width != 0 && i + width <= flat.size(); i += width) {
      if (i != 0) out_ += ',';
      array(flat.subspan(i, width));
    }
    out_ += ']';
    return *this;
  }
  template <class T>
  JsonText& rows(const std::vector<T>& flat, std::size_t width) {
    return rows(std::span<const T>(flat), width);
  }

 private:
  template <class T>
  void value(T v) {
    if constexpr (std::is_floating_point_v<T>) {
      number(v);
    } else {
      integer(v);
    }
  }
  std::string& out_;
  bool first_ = true;
};

}  // namespace spokemesh::service
