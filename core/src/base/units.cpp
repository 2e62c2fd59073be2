#include "spokemesh/units.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <vector>

namespace spokemesh {
namespace {

// The leading number of `text`, and the rest (the unit); nullopt-like false if none.
bool split_number(const std::string& text, double& value, std::string& unit) {
  const char* begin = text.c_str();
  char* end = nullptr;
  value = std::strtod(begin, &end);
  if (end == begin) return false;
  unit = text.substr(static_cast<std::size_t>(end - begin));
  return true;
}

}  // namespace

Result<std::chrono::milliseconds> parse_duration(const std::string& text, const std::string& flag) {
  double v = 0;
  std::string unit;
  double scale = 0;
  if (split_number(text, v, unit)) {
    if (unit.empty() || unit == "ms")
      scale = 1;
    else if (unit == "s")
      scale = 1e3;
    else if (unit == "m")
      scale = 60e3;
    else if (unit == "h")
      scale = 3600e3;
  }
  if (scale == 0 || !(v > 0) || v * scale > 1e12) {
    return invalid_argument(flag + ": \"" + text + "\" is not a duration like 500ms, 30s, 2m or 1h");
  }
  return std::chrono::milliseconds(static_cast<std::int64_t>(v * scale));
}

Result<std::uint64_t> parse_bytes(const std::string& text, const std::string& flag) {
  double v = 0;
  std::string unit;
  double scale = 0;
  if (split_number(text, v, unit)) {
    if (!unit.empty() && (unit.back() == 'B' || unit.back() == 'b')) unit.pop_back();
    if (unit.size() == 2 && unit[1] == 'i') unit.pop_back();
    const char u = unit.empty() ? '\0' : static_cast<char>(std::toupper(static_cast<unsigned char>(unit[0])));
    if (unit.empty())
      scale = 1;
    else if (unit.size() == 1 && u == 'K')
      scale = 1024.0;
    else if (unit.size() == 1 && u == 'M')
      scale = 1024.0 * 1024;
    else if (unit.size() == 1 && u == 'G')
      scale = 1024.0 * 1024 * 1024;
    else if (unit.size() == 1 && u == 'T')
      scale = 1024.0 * 1024 * 1024 * 1024;
  }
  if (scale == 0 || !(v > 0) || v * scale > 1.8e19) {
    return invalid_argument(flag + ": \"" + text + "\" is not a size like 512M or 4G");
  }
  return static_cast<std::uint64_t>(v * scale);
}

Result<std::vector<double>> parse_number_list(const std::string& text, const std::string& what, std::size_t max_count) {
  std::vector<double> values;
  std::size_t at = 0;
  while (at <= text.size()) {
    const std::size_t comma = std::min(text.find(',', at), text.size());
    const std::string item = text.substr(at, comma - at);
    char* end = nullptr;
    const double v = std::strtod(item.c_str(), &end);
    if (item.empty() || end == item.c_str() || *end != '\0' || !std::isfinite(v)) {
      return invalid_argument(what + ": value " + std::to_string(values.size()) + " ('" + item.substr(0, 40) +
                              "') is not a finite number");
    }
    values.push_back(v);
    if (values.size() > max_count)
      return invalid_argument(what + ": more than " + std::to_string(max_count) + " values");
    at = comma + 1;
  }
  return values;
}

}  // namespace spokemesh
