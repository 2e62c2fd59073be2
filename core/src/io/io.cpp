#include "spokemesh/io.hpp"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>

namespace spokemesh {
namespace {

Result<std::string> slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return invalid_argument(path + ": cannot open for reading (" + std::strerror(errno) + ")");
  std::ostringstream buffer;
  buffer << in.rdbuf();
  if (in.bad()) return invalid_argument(path + ": read error");
  return std::move(buffer).str();
}

bool ends_with(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  return std::equal(suffix.rbegin(), suffix.rend(), s.rbegin(),
                    [](char a, char b) { return std::tolower(a) == std::tolower(b); });
}

// File content quoted in an error message: printable ASCII only, trimmed, at most 40
// characters, so a message stays one readable line whatever the file holds.
std::string printable(std::string_view raw) {
  std::string out;
  for (char ch : raw) {
    if (out.size() >= 40) {
      out += "...";
      break;
    }
    const unsigned char u = static_cast<unsigned char>(ch);
    if (u >= 0x20 && u < 0x7F)
      out.push_back(ch);
    else if (ch == '\t' || ch == '\n' || ch == '\r')
      out.push_back(' ');
    else
      out += "?";
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

// Between numbers: blanks, commas and semicolons (README, "Input").
bool is_separator(char c) {
  return c == ' ' || c == '\t' || c == ',' || c == ';' || c == '\r' || c == '\v' || c == '\f';
}

// Parses the numbers of one text line (comment already removed) into `out`.
// Returns the offending token on failure.
template <class T>
bool parse_numbers(std::string_view line, std::vector<T>& out, std::string& bad_token) {
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_separator(line[i])) ++i;
    if (i >= line.size()) break;
    std::size_t j = i;
    while (j < line.size() && !is_separator(line[j])) ++j;
    std::string_view token = line.substr(i, j - i);
    // One optional sign: '+' is dropped here (from_chars takes only '-'), so '+-1' stays an error.
    if (token.size() > 1 && token.front() == '+' && token[1] != '-' && token[1] != '+') token.remove_prefix(1);
    T value{};
    const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
    if (ec != std::errc() || end != token.data() + token.size()) {
      bad_token = printable(line.substr(i, j - i));
      return false;
    }
    out.push_back(value);
    i = j;
  }
  return true;
}

// Walks lines of a text file, skipping comments and blank lines.
template <class OnLine>
Status for_each_line(const std::string& text, OnLine&& on_line) {
  std::size_t line_no = 0, pos = 0;
  while (pos < text.size()) {
    std::size_t eol = text.find('\n', pos);
    if (eol == std::string::npos) eol = text.size();
    ++line_no;
    std::string_view line(text.data() + pos, eol - pos);
    if (const auto hash = line.find('#'); hash != std::string_view::npos) line = line.substr(0, hash);
    if (Status s = on_line(line, line_no); !s.is_ok()) return s;
    pos = eol + 1;
  }
  return Status::ok();
}

std::uint32_t read_le32(const unsigned char* p) {
  return p[0] | (p[1] << 8) | (p[2] << 16) | (std::uint32_t{p[3]} << 24);
}

struct NpyHeader {
  std::string descr;
  bool fortran = false;
  std::vector<std::uint64_t> shape;
  std::size_t data_offset = 0;
};

Result<NpyHeader> parse_npy_header(const std::string& bytes, const std::string& source) {
  if (bytes.size() < 10 || std::memcmp(bytes.data(), "\x93NUMPY", 6) != 0) {
    return invalid_argument(source + ": not a NumPy .npy file (bad magic)");
  }
  const auto* u = reinterpret_cast<const unsigned char*>(bytes.data());
  const int major = u[6];
  std::size_t header_len = 0, start = 0;
  if (major == 1) {
    header_len = u[8] | (u[9] << 8);
    start = 10;
  } else if (major == 2 || major == 3) {
    if (bytes.size() < 12) return invalid_argument(source + ": truncated .npy header");
    header_len = read_le32(u + 8);
    start = 12;
  } else {
    return invalid_argument(source + ": unsupported .npy version " + std::to_string(major));
  }
  if (bytes.size() < start + header_len) return invalid_argument(source + ": truncated .npy header");
  const std::string header = bytes.substr(start, header_len);
  NpyHeader h;
  h.data_offset = start + header_len;
  auto value_of = [&](const std::string& key) -> std::string {
    const auto k = header.find("'" + key + "'");
    if (k == std::string::npos) return {};
    auto colon = header.find(':', k);
    if (colon == std::string::npos) return {};
    ++colon;
    while (colon < header.size() && header[colon] == ' ') ++colon;
    if (colon < header.size() && header[colon] == '(') return header.substr(colon, header.find(')', colon) - colon + 1);
    if (colon < header.size() && header[colon] == '\'')
      return header.substr(colon + 1, header.find('\'', colon + 1) - colon - 1);
    const auto stop = header.find_first_of(",}", colon);
    return header.substr(colon, stop - colon);
  };
  h.descr = value_of("descr");
  h.fortran = value_of("fortran_order").find("True") != std::string::npos;
  const std::string shape = value_of("shape");
  if (h.descr.empty()) return invalid_argument(source + ": malformed .npy header (no 'descr' entry)");
  if (shape.empty()) return invalid_argument(source + ": malformed .npy header (no 'shape' entry)");
  std::vector<std::uint64_t> dims;
  for (std::size_t i = 1; i < shape.size();) {
    while (i < shape.size() && (shape[i] == ' ' || shape[i] == ',')) ++i;
    if (i >= shape.size() || shape[i] == ')') break;
    std::uint64_t v = 0;
    const auto [end, ec] = std::from_chars(shape.data() + i, shape.data() + shape.size(), v);
    if (ec != std::errc()) return invalid_argument(source + ": malformed .npy shape '" + printable(shape) + "'");
    dims.push_back(v);
    i = static_cast<std::size_t>(end - shape.data());
  }
  h.shape = dims;
  return h;
}

// Whether no field of a line parses as a number: a header ("x,y,z").
bool is_header(std::string_view line) {
  std::vector<double> one;
  std::string bad;
  bool any = false;
  for (std::size_t i = 0; i < line.size();) {
    while (i < line.size() && is_separator(line[i])) ++i;
    std::size_t j = i;
    while (j < line.size() && !is_separator(line[j])) ++j;
    if (j > i) {
      any = true;
      one.clear();
      if (parse_numbers(line.substr(i, j - i), one, bad)) return false;
    }
    i = j;
  }
  return any;
}

// Calls on_row(numbers, where) for each line of a text file that holds numbers
// (`where` names the file and line for messages); a token that is no number stops it.
// With allow_header, a first line of fields none of which is a number is skipped.
template <class OnRow>
Status for_each_number_row(const std::string& text, const std::string& source, OnRow&& on_row,
                           bool allow_header = false) {
  std::vector<double> row;
  std::string bad;
  bool first = true;
  return for_each_line(text, [&](std::string_view line, std::size_t line_no) -> Status {
    row.clear();
    const std::string where = source + ":" + std::to_string(line_no) + ": ";
    const bool was_first = first;
    if (!parse_numbers(line, row, bad)) {
      if (was_first && allow_header && is_header(line)) {
        first = false;
        return Status::ok();
      }
      return invalid_argument(where + "cannot parse '" + bad + "' as a number");
    }
    if (row.empty()) return Status::ok();
    first = false;
    return on_row(row, where);
  });
}

// The bytes of one element of a float64 or float32 .npy array (8 or 4), or 0 for
// another dtype.
int npy_float_bytes(const std::string& descr) {
  if (descr == "<f8" || descr == "=f8") return 8;
  if (descr == "<f4" || descr == "=f4") return 4;
  return 0;
}

// The bytes of one element of an int64, int32 or int16 .npy array, or 0.
int npy_int_bytes(const std::string& descr) {
  if (descr == "<i8" || descr == "=i8") return 8;
  if (descr == "<i4" || descr == "=i4") return 4;
  if (descr == "<i2" || descr == "=i2") return 2;
  return 0;
}

// Element k of a float array's data, as a double.
double npy_float_at(const char* data, std::size_t k, int item_bytes) {
  if (item_bytes == 8) {
    double v;
    std::memcpy(&v, data + k * 8, 8);
    return v;
  }
  float f;
  std::memcpy(&f, data + k * 4, 4);
  return f;
}

// Element k of an integer array's data.
std::int64_t npy_int_at(const char* data, std::size_t k, int item_bytes) {
  if (item_bytes == 8) {
    std::int64_t v;
    std::memcpy(&v, data + k * 8, 8);
    return v;
  }
  if (item_bytes == 4) {
    std::int32_t v;
    std::memcpy(&v, data + k * 4, 4);
    return v;
  }
  std::int16_t v;
  std::memcpy(&v, data + k * 2, 2);
  return v;
}

}  // namespace

Result<PointSet> parse_text_points(const std::string& text, const std::string& source) {
  std::vector<double> coords;
  int d = 0;
  std::size_t points = 0;
  Status status = for_each_number_row(
      text, source,
      [&](const std::vector<double>& row, const std::string& where) -> Status {
        if (d == 0) d = static_cast<int>(row.size());
        if (static_cast<int>(row.size()) != d) {
          return invalid_argument(where + "has " + std::to_string(row.size()) +
                                  " coordinates, but earlier lines have " + std::to_string(d));
        }
        for (std::size_t c = 0; c < row.size(); ++c) {
          if (!std::isfinite(row[c]))
            return invalid_argument(where + "coordinate " + std::to_string(c) + " is not finite");
          if (std::fabs(row[c]) > kMaxCoordinate) {
            return invalid_argument(where + "coordinate " + std::to_string(c) + " has magnitude above 1e100");
          }
        }
        coords.insert(coords.end(), row.begin(), row.end());
        ++points;
        return Status::ok();
      },
      /*allow_header=*/true);
  if (!status.is_ok()) return status;
  if (points == 0) return invalid_argument(source + ": no points (the input is empty)");
  return PointSet(d, std::move(coords));
}

Result<NpyPoints> npy_points_layout(const std::string& head, std::uint64_t file_size, const std::string& source) {
  auto header = parse_npy_header(head, source);
  if (!header.is_ok()) return header.status();
  const NpyHeader& h = header.value();
  const int float_bytes = npy_float_bytes(h.descr), int_bytes = npy_int_bytes(h.descr);
  const int item = float_bytes != 0 ? float_bytes : int_bytes;
  if (item == 0) {
    return invalid_argument(source + ": .npy dtype '" + printable(h.descr) +
                            "' is not supported (need float64, float32, int64, int32 or int16, little-endian)");
  }
  if (h.fortran) return invalid_argument(source + ": .npy array is in Fortran order (need C order)");
  if (h.shape.size() != 2)
    return invalid_argument(source + ": .npy array must have shape (n, d), found " + std::to_string(h.shape.size()) +
                            " axes");
  const std::uint64_t n = h.shape[0], d = h.shape[1];
  if (n == 0 || d == 0) return invalid_argument(source + ": no points (the input is empty)");
  if (d > static_cast<std::uint64_t>(kMaxApproxDimension)) {
    return invalid_argument(source + ": dimension " + std::to_string(d) + " is too large (at most " +
                            std::to_string(kMaxApproxDimension) + ")");
  }
  NpyPoints layout{n, static_cast<int>(d), item, h.data_offset, int_bytes != 0};
  const std::uint64_t need = n * d * layout.item_bytes;
  if (file_size - h.data_offset < need) {
    return invalid_argument(source + ": truncated .npy data: expected " + std::to_string(need) + " bytes, found " +
                            std::to_string(file_size - h.data_offset));
  }
  return layout;
}

Status decode_npy_rows(const NpyPoints& layout, const char* data, std::uint64_t first_row, std::uint64_t rows,
                       std::vector<double>& out, const std::string& source) {
  const auto d = static_cast<std::uint64_t>(layout.dimension);
  const std::size_t count = static_cast<std::size_t>(rows * d);
  out.resize(count);
  for (std::size_t k = 0; k < count; ++k) {
    if (layout.integer) {
      // Integers are exact in double up to 2^53; beyond, a coordinate would be rounded.
      const std::int64_t i = npy_int_at(data, k, layout.item_bytes);
      if (i > (std::int64_t{1} << 53) || i < -(std::int64_t{1} << 53)) {
        return invalid_argument(source + ": element [" + std::to_string(first_row + k / d) + ", " +
                                std::to_string(k % d) + "] = " + std::to_string(i) +
                                " is not exactly a double (integers are read up to 2^53 in magnitude)");
      }
      out[k] = static_cast<double>(i);
      continue;
    }
    const double v = npy_float_at(data, k, layout.item_bytes);
    if (!std::isfinite(v) || std::fabs(v) > kMaxCoordinate) {
      return invalid_argument(source + ": element [" + std::to_string(first_row + k / d) + ", " +
                              std::to_string(k % d) + "] " +
                              (std::isfinite(v) ? "has magnitude above 1e100" : "is not finite"));
    }
    out[k] = v;
  }
  return Status::ok();
}

Result<PointSet> parse_npy_points(const std::string& bytes, const std::string& source) {
  auto layout = npy_points_layout(bytes, bytes.size(), source);
  if (!layout.is_ok()) return layout.status();
  const NpyPoints& l = layout.value();
  std::vector<double> coords;
  if (Status s = decode_npy_rows(l, bytes.data() + l.data_offset, 0, l.count, coords, source); !s.is_ok()) return s;
  return PointSet(l.dimension, std::move(coords));
}

Result<PointSet> read_points(const std::string& path) {
  auto bytes = slurp(path);
  if (!bytes.is_ok()) return bytes.status();
  if (ends_with(path, ".npy")) return parse_npy_points(bytes.value(), path);
  return parse_text_points(bytes.value(), path);
}

namespace {

// One weight, checked: `where` names its line or index.
Status take_weight(double v, WeightKind kind, const std::string& where, std::vector<double>& out) {
  const char* what = kind == WeightKind::kRadius ? "radius" : kind == WeightKind::kValue ? "value" : "weight";
  if (!std::isfinite(v)) return invalid_argument(where + what + " is not finite");
  if (kind == WeightKind::kRadius) {
    if (v < 0) return invalid_argument(where + "radius " + std::to_string(v) + " is negative");
    if (v > kMaxCoordinate) return invalid_argument(where + "radius has magnitude above 1e100");
    out.push_back(v * v);
  } else {
    if (std::fabs(v) > kMaxWeight) return invalid_argument(where + what + " has magnitude above 1e200");
    out.push_back(v);
  }
  return Status::ok();
}

Status check_weight_count(std::size_t got, std::size_t count, WeightKind kind, const std::string& source) {
  if (got == count) return Status::ok();
  return invalid_argument(source + ": " + std::to_string(got) +
                          (kind == WeightKind::kRadius  ? " radii"
                           : kind == WeightKind::kValue ? " values"
                                                        : " weights") +
                          " for " + std::to_string(count) + " points (one a point, in the points' order)");
}

}  // namespace

Result<std::vector<double>> weights_from_values(std::span<const double> values, const std::string& source,
                                                std::size_t count, WeightKind kind) {
  if (Status s = check_weight_count(values.size(), count, kind, source); !s.is_ok()) return s;
  std::vector<double> out;
  out.reserve(values.size());
  for (std::size_t k = 0; k < values.size(); ++k) {
    if (Status s = take_weight(values[k], kind, source + ": index " + std::to_string(k) + ": ", out); !s.is_ok())
      return s;
  }
  return out;
}

Result<std::vector<double>> parse_text_weights(const std::string& text, const std::string& source, std::size_t count,
                                               WeightKind kind) {
  std::vector<double> out;
  Status status =
      for_each_number_row(text, source, [&](const std::vector<double>& row, const std::string& where) -> Status {
        if (row.size() != 1) {
          return invalid_argument(where + "has " + std::to_string(row.size()) + " numbers; expected one " +
                                  (kind == WeightKind::kRadius  ? "radius"
                                   : kind == WeightKind::kValue ? "value"
                                                                : "weight") +
                                  " a line");
        }
        return take_weight(row[0], kind, where, out);
      });
  if (!status.is_ok()) return status;
  if (Status s = check_weight_count(out.size(), count, kind, source); !s.is_ok()) return s;
  return out;
}

Result<std::vector<double>> parse_npy_weights(const std::string& bytes, const std::string& source, std::size_t count,
                                              WeightKind kind) {
  auto header = parse_npy_header(bytes, source);
  if (!header.is_ok()) return header.status();
  const NpyHeader& h = header.value();
  const int item_bytes = npy_float_bytes(h.descr);
  if (item_bytes == 0) {
    return invalid_argument(source + ": .npy dtype '" + printable(h.descr) +
                            "' is not supported (need float64 or float32)");
  }
  if (h.fortran && h.shape.size() == 2)
    return invalid_argument(source + ": .npy array is in Fortran order (need C order)");
  if (!(h.shape.size() == 1 || (h.shape.size() == 2 && h.shape[1] == 1))) {
    return invalid_argument(source + ": .npy " + (kind == WeightKind::kValue ? "values" : "weights") +
                            " must have shape (n,) or (n, 1), found " + std::to_string(h.shape.size()) + " axes");
  }
  const std::uint64_t n = h.shape[0];
  const auto item = static_cast<std::size_t>(item_bytes);
  if (n > (bytes.size() - h.data_offset) / item) {  // (n * item may overflow)
    return invalid_argument(source + ": truncated .npy data: " + std::to_string(n) + " values need more than the " +
                            std::to_string(bytes.size() - h.data_offset) + " bytes found");
  }
  if (Status s = check_weight_count(n, count, kind, source); !s.is_ok()) return s;
  std::vector<double> out;
  out.reserve(n);
  for (std::uint64_t k = 0; k < n; ++k) {
    const double v = npy_float_at(bytes.data() + h.data_offset, k, item_bytes);
    if (Status s = take_weight(v, kind, source + ": index " + std::to_string(k) + ": ", out); !s.is_ok()) return s;
  }
  return out;
}

Result<std::vector<double>> read_weights(const std::string& path, std::size_t count, WeightKind kind) {
  auto bytes = slurp(path);
  if (!bytes.is_ok()) return bytes.status();
  if (ends_with(path, ".npy")) return parse_npy_weights(bytes.value(), path, count, kind);
  return parse_text_weights(bytes.value(), path, count, kind);
}

Result<std::vector<std::uint32_t>> read_simplices(const std::string& path, int width) {
  auto bytes = slurp(path);
  if (!bytes.is_ok()) return bytes.status();
  std::vector<std::uint32_t> out;
  if (ends_with(path, ".npy")) {
    auto header = parse_npy_header(bytes.value(), path);
    if (!header.is_ok()) return header.status();
    const NpyHeader& h = header.value();
    const bool i8 = h.descr == "<i8", i4 = h.descr == "<i4";
    if (!i8 && !i4)
      return invalid_argument(path + ": .npy dtype '" + printable(h.descr) +
                              "' is not supported for a mesh (need int64 or int32)");
    if (h.shape.size() != 2 || h.shape[1] != static_cast<std::uint64_t>(width)) {
      return invalid_argument(path + ": mesh array must have shape (m, " + std::to_string(width) + ")");
    }
    const std::size_t item = i8 ? 8 : 4;
    const std::uint64_t count = h.shape[0] * h.shape[1];
    if (bytes.value().size() - h.data_offset < count * item) return invalid_argument(path + ": truncated .npy data");
    out.resize(count);
    for (std::size_t k = 0; k < count; ++k) {
      std::int64_t v = 0;
      if (i8) {
        std::memcpy(&v, bytes.value().data() + h.data_offset + k * 8, 8);
      } else {
        std::int32_t w;
        std::memcpy(&w, bytes.value().data() + h.data_offset + k * 4, 4);
        v = w;
      }
      if (v < 0 || v > 0xFFFFFFFFll) {
        return invalid_argument(path + ": simplex " + std::to_string(k / width) + " has invalid index " +
                                std::to_string(v));
      }
      out[k] = static_cast<std::uint32_t>(v);
    }
    return out;
  }
  std::vector<std::int64_t> row;
  std::string bad;
  Status status = for_each_line(bytes.value(), [&](std::string_view line, std::size_t line_no) -> Status {
    row.clear();
    const std::string where = path + ":" + std::to_string(line_no) + ": ";
    if (!parse_numbers(line, row, bad)) return invalid_argument(where + "cannot parse '" + bad + "' as an index");
    if (row.empty()) return Status::ok();
    if (static_cast<int>(row.size()) != width) {
      return invalid_argument(where + "has " + std::to_string(row.size()) + " indices, expected " +
                              std::to_string(width));
    }
    for (std::int64_t v : row) {
      if (v < 0 || v > 0xFFFFFFFFll) return invalid_argument(where + "invalid index " + std::to_string(v));
      out.push_back(static_cast<std::uint32_t>(v));
    }
    return Status::ok();
  });
  if (!status.is_ok()) return status;
  return out;
}

void append_index_lines(std::string& out, std::span<const std::uint32_t> tuples, int width) {
  char buf[16];
  for (std::size_t i = 0; i < tuples.size(); ++i) {
    const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, tuples[i]);
    out.append(buf, end);
    out.push_back((i + 1) % static_cast<std::size_t>(width) == 0 ? '\n' : ' ');
  }
}

// ---------------------------------------------------------------------------------
// Writers

std::string npy_header(const std::string& descr, std::uint64_t rows, std::uint64_t cols) {
  return npy_header_of_shape(descr, std::to_string(rows) + ", " + std::to_string(cols));
}

std::string npy_vector_header(const std::string& descr, std::uint64_t rows) {
  return npy_header_of_shape(descr, std::to_string(rows) + ",");
}

std::string npy_header_of_shape(const std::string& descr, const std::string& shape) {
  std::string dict = "{'descr': '" + descr + "', 'fortran_order': False, 'shape': (" + shape + "), }";
  dict.resize(kNpyHeaderBytes - 10 - 1, ' ');
  dict.push_back('\n');
  std::string out("\x93NUMPY\x01\x00", 8);
  out.push_back(static_cast<char>(dict.size() & 0xFF));
  out.push_back(static_cast<char>(dict.size() >> 8));
  return out + dict;
}

namespace {

std::string temp_name_for(const std::string& path) {
  static std::atomic<unsigned> counter{0};
  return path + ".partial-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
}

class TextWriter final : public MeshWriter {
 public:
  using MeshWriter::MeshWriter;
  Status write(std::span<const std::uint32_t> simplices) override {
    buffer_.clear();
    append_index_lines(buffer_, simplices, points_.dimension() + 1);
    std::fwrite(buffer_.data(), 1, buffer_.size(), file_);
    return check_stream("write");
  }

 private:
  Status finish() override { return Status::ok(); }
  std::string buffer_;
};

class NpyWriter final : public MeshWriter {
 public:
  NpyWriter(std::string path, const PointSet& points, std::FILE* file, std::string temp)
      : MeshWriter(std::move(path), points, file, std::move(temp)) {
    const std::string header = npy_header("<i8", 0, points.dimension() + 1);
    std::fwrite(header.data(), 1, header.size(), file_);
  }
  Status write(std::span<const std::uint32_t> simplices) override {
    buffer_.resize(simplices.size());
    std::copy(simplices.begin(), simplices.end(), buffer_.begin());  // little-endian host
    std::fwrite(buffer_.data(), sizeof(std::int64_t), buffer_.size(), file_);
    rows_ += simplices.size() / static_cast<std::size_t>(points_.dimension() + 1);
    return check_stream("write");
  }

 private:
  Status finish() override {
    const std::string header = npy_header("<i8", rows_, points_.dimension() + 1);
    std::fseek(file_, 0, SEEK_SET);
    std::fwrite(header.data(), 1, header.size(), file_);
    return check_stream("write header");
  }
  std::vector<std::int64_t> buffer_;
  std::uint64_t rows_ = 0;
};

// Formats whose headers need the simplex count: simplices are spooled to an
// anonymous temporary file first (bounded memory), then written out.
class SpooledWriter final : public MeshWriter {
 public:
  SpooledWriter(std::string path, const PointSet& points, std::FILE* file, std::string temp, Format format)
      : MeshWriter(std::move(path), points, file, std::move(temp)), format_(format), spool_(std::tmpfile()) {}
  ~SpooledWriter() override {
    if (spool_ != nullptr) std::fclose(spool_);
  }
  Status write(std::span<const std::uint32_t> simplices) override {
    if (spool_ == nullptr) return internal_error("cannot create a temporary spool file");
    std::fwrite(simplices.data(), sizeof(std::uint32_t), simplices.size(), spool_);
    count_ += simplices.size() / static_cast<std::size_t>(points_.dimension() + 1);
    return std::ferror(spool_) ? internal_error("write error on the temporary spool file") : Status::ok();
  }

 private:
  template <class F>
  Status for_each_simplex(F&& f) {
    std::rewind(spool_);
    const int w = points_.dimension() + 1;
    std::vector<std::uint32_t> chunk(static_cast<std::size_t>(w) * 4096);
    std::uint64_t index = 0;
    for (;;) {
      const std::size_t got = std::fread(chunk.data(), sizeof(std::uint32_t), chunk.size(), spool_);
      for (std::size_t i = 0; i + w <= got; i += w) f(&chunk[i], index++);
      if (got < chunk.size()) break;
    }
    return std::ferror(spool_) ? internal_error("read error on the temporary spool file") : Status::ok();
  }

  Status finish() override {
    if (spool_ == nullptr) return internal_error("cannot create a temporary spool file");
    const int d = points_.dimension();
    const std::size_t n = points_.size();
    std::vector<double> box(2 * static_cast<std::size_t>(d));
    for (int c = 0; c < d; ++c) box[c] = box[d + c] = points_.point(0)[c];
    for (std::size_t i = 1; i < n; ++i) {
      for (int c = 0; c < d; ++c) {
        box[c] = std::min(box[c], points_.point(i)[c]);
        box[d + c] = std::max(box[d + c], points_.point(i)[c]);
      }
    }
    const MeshFileLayout layout(format_, d, n, count_, box);
    const auto point = [&](std::uint32_t v) { return points_.point(v); };
    std::string out;
    auto flush = [&](bool force) {
      if (out.size() > (1 << 20) || force) {
        std::fwrite(out.data(), 1, out.size(), file_);
        out.clear();
      }
    };
    Status status;
    for (const MeshFileLayout::Section& section : layout.sections()) {
      if (section.kind == MeshFileLayout::Section::kText) {
        out += section.text;
      } else if (section.kind == MeshFileLayout::Section::kPoints) {
        for (std::size_t i = 0; i < n; ++i) {
          layout.point_line(section.variant, out, i, points_.point(i));
          flush(false);
        }
      } else {
        Status s = for_each_simplex([&](const std::uint32_t* simplex, std::uint64_t index) {
          layout.row_line(section.variant, out, simplex, index, point);
          flush(false);
        });
        if (status.is_ok()) status = s;
      }
    }
    flush(true);
    if (!status.is_ok()) return status;
    return check_stream("write");
  }

  Format format_;
  std::FILE* spool_;
  std::uint64_t count_ = 0;
};

}  // namespace

namespace {

void append_coordinate(std::string& out, double v) {
  char buf[32];
  const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, end);
}

}  // namespace

MeshFileLayout::MeshFileLayout(MeshWriter::Format format, int d, std::uint64_t n, std::uint64_t simplices,
                               std::span<const double> box)
    : format_(format), d_(d), n_(n) {
  using K = Section::Kind;
  const std::string count = std::to_string(simplices);
  if (format == MeshWriter::Format::kVtu) {
    sections_ = {
        {K::kText,
         "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"0.1\" byte_order=\"LittleEndian\">\n"
         "<UnstructuredGrid>\n<Piece NumberOfPoints=\"" +
             std::to_string(n) + "\" NumberOfCells=\"" + count +
             "\">\n<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n"},
        {K::kPoints, "", 0},
        {K::kText,
         "</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n"},
        {K::kRows, "", 0},
        {K::kText, "</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n"},
        {K::kRows, "", 1},
        {K::kText, "</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n"},
        {K::kRows, "", 2},
        {K::kText, "</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n"},
    };
  } else if (format == MeshWriter::Format::kMsh) {
    sections_ = {
        {K::kText, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n" + std::to_string(n) + "\n"},
        {K::kPoints, "", 0},
        {K::kText, "$EndNodes\n$Elements\n" + count + "\n"},
        {K::kRows, "", 0},
        {K::kText, "$EndElements\n"},
    };
  } else {  // .svg (2-d): the triangles, then the points, scaled to 1000 units across
    for (int c = 0; c < 2; ++c) {
      lo_[c] = box[static_cast<std::size_t>(c)];
      hi_[c] = box[static_cast<std::size_t>(d + c)];
    }
    const double span = std::max({hi_[0] - lo_[0], hi_[1] - lo_[1], 1e-300});
    scale_ = 1000.0 / span;
    const double margin = 10;
    const double w = (hi_[0] - lo_[0]) * scale_ + 2 * margin, h = (hi_[1] - lo_[1]) * scale_ + 2 * margin;
    radius_ = std::clamp(300.0 / std::sqrt(static_cast<double>(n)), 0.5, 4.0);
    sections_ = {
        {K::kText, "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + std::to_string(static_cast<int>(w)) +
                       "\" height=\"" + std::to_string(static_cast<int>(h)) + "\" viewBox=\"0 0 " + std::to_string(w) +
                       " " + std::to_string(h) +
                       "\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n"
                       "<g fill=\"#cfe3f7\" stroke=\"#1f4e79\" stroke-width=\"0.6\" stroke-linejoin=\"round\">\n"},
        {K::kRows, "", 0},
        {K::kText, "</g>\n<g fill=\"#c0392b\">\n"},
        {K::kPoints, "", 0},
        {K::kText, "</g>\n</svg>\n"},
    };
  }
}

void MeshFileLayout::point_line(int /*variant*/, std::string& out, std::uint64_t i, const double* p) const {
  if (format_ == MeshWriter::Format::kVtu) {
    for (int c = 0; c < 3; ++c) {
      append_coordinate(out, c < d_ ? p[c] : 0.0);
      out.push_back(c == 2 ? '\n' : ' ');
    }
  } else if (format_ == MeshWriter::Format::kMsh) {
    out += std::to_string(i + 1);
    for (int c = 0; c < 3; ++c) {
      out.push_back(' ');
      append_coordinate(out, c < d_ ? p[c] : 0.0);
    }
    out.push_back('\n');
  } else {
    const double margin = 10;
    out += "<circle cx=\"";
    append_coordinate(out, margin + (p[0] - lo_[0]) * scale_);
    out += "\" cy=\"";
    append_coordinate(out, margin + (hi_[1] - lo_[1]) * scale_ - (p[1] - lo_[1]) * scale_);
    out += "\" r=\"" + std::to_string(radius_) + "\"/>\n";
  }
}

void MeshFileLayout::row_line(int variant, std::string& out, const std::uint32_t* s, std::uint64_t index,
                              const std::function<const double*(std::uint32_t)>& point) const {
  const auto w = static_cast<std::uint64_t>(d_ + 1);
  if (format_ == MeshWriter::Format::kVtu) {
    if (variant == 0) {
      append_index_lines(out, std::span<const std::uint32_t>(s, w), d_ + 1);
    } else if (variant == 1) {
      out += std::to_string((index + 1) * w);
      out.push_back('\n');
    } else {
      out += d_ == 2 ? "5\n" : "10\n";  // VTK_TRIANGLE, VTK_TETRA
    }
  } else if (format_ == MeshWriter::Format::kMsh) {
    out += std::to_string(index + 1);
    out += d_ == 2 ? " 2 2 1 1" : " 4 2 1 1";  // triangle / tetrahedron, tags: physical, elementary
    for (std::uint64_t k = 0; k < w; ++k) {
      out.push_back(' ');
      out += std::to_string(s[k] + 1);
    }
    out.push_back('\n');
  } else {
    const double margin = 10;
    out += "<polygon points=\"";
    for (int k = 0; k < 3; ++k) {
      const double* p = point(s[k]);
      append_coordinate(out, margin + (p[0] - lo_[0]) * scale_);
      out.push_back(',');
      append_coordinate(out, margin + (hi_[1] - lo_[1]) * scale_ - (p[1] - lo_[1]) * scale_);
      out.push_back(k == 2 ? '"' : ' ');
    }
    out += "/>\n";
  }
}

Result<MeshWriter::Format> MeshWriter::format_for(const std::string& path, int dimension) {
  if (ends_with(path, ".simplices") || ends_with(path, ".txt") || ends_with(path, ".edges")) return Format::kText;
  if (ends_with(path, ".npy")) return Format::kNpy;
  if (ends_with(path, ".vtu") || ends_with(path, ".msh")) {
    if (dimension != 2 && dimension != 3) {
      return invalid_argument(path + ": .vtu and .msh output is for 2-d and 3-d meshes (this one is " +
                              std::to_string(dimension) + "-d); use .simplices or .npy");
    }
    return ends_with(path, ".vtu") ? Format::kVtu : Format::kMsh;
  }
  if (ends_with(path, ".svg")) {
    if (dimension != 2)
      return invalid_argument(path + ": .svg output is for 2-d meshes; use .simplices, .npy, .vtu or .msh");
    return Format::kSvg;
  }
  return invalid_argument(path + ": unknown output format (use .simplices, .txt, .npy, .vtu, .msh or .svg)");
}

Result<std::unique_ptr<MeshWriter>> MeshWriter::open(const std::string& path, const PointSet& points) {
  auto format = format_for(path, points.dimension());
  if (!format.is_ok()) return format.status();
  std::string temp = temp_name_for(path);
  std::FILE* file = std::fopen(temp.c_str(), "wb");
  if (file == nullptr) return invalid_argument(path + ": cannot open for writing (" + std::strerror(errno) + ")");
  std::unique_ptr<MeshWriter> writer;
  switch (format.value()) {
    case Format::kText:
      writer.reset(new TextWriter(path, points, file, temp));
      break;
    case Format::kNpy:
      writer.reset(new NpyWriter(path, points, file, temp));
      break;
    default:
      writer.reset(new SpooledWriter(path, points, file, temp, format.value()));
      break;
  }
  return writer;
}

Result<std::unique_ptr<MeshWriter>> MeshWriter::open_tuples(const std::string& path, const PointSet& shape) {
  auto format = format_for(path, shape.dimension());
  if (!format.is_ok()) return format.status();
  if (format.value() != Format::kText && format.value() != Format::kNpy) {
    return invalid_argument(path + ": index tuples are written as text (.edges, .txt) or .npy");
  }
  return open(path, shape);
}

MeshWriter::MeshWriter(std::string path, const PointSet& points, std::FILE* file, std::string temp_path)
    : path_(std::move(path)), points_(points), file_(file), temp_path_(std::move(temp_path)) {}

MeshWriter::~MeshWriter() {
  if (file_ != nullptr) std::fclose(file_);
  if (!committed_) std::remove(temp_path_.c_str());
}

Status MeshWriter::check_stream(const char* what) {
  if (std::ferror(file_)) return internal_error(path_ + ": " + what + " failed (" + std::strerror(errno) + ")");
  return Status::ok();
}

Status MeshWriter::commit() {
  if (Status s = finish(); !s.is_ok()) return s;
  if (std::fflush(file_) != 0 || ::fsync(::fileno(file_)) != 0) {
    return internal_error(path_ + ": flush failed (" + std::strerror(errno) + ")");
  }
  std::fclose(file_);
  file_ = nullptr;
  if (std::rename(temp_path_.c_str(), path_.c_str()) != 0) {
    return internal_error(path_ + ": cannot rename the finished file into place (" + std::strerror(errno) + ")");
  }
  committed_ = true;
  return Status::ok();
}

}  // namespace spokemesh
