#include "spokemesh/shape_io.hpp"

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

namespace spokemesh {

namespace {

std::string lower_extension(const std::string& path) {
  const std::size_t slash = path.find_last_of('/');
  const std::size_t dot = path.find_last_of('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  std::string ext = path.substr(dot);
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

// Splits text into lines with '#' comments removed and commas as blanks.
std::vector<std::string> clean_lines(const std::string& text) {
  std::vector<std::string> lines;
  std::string line;
  std::istringstream in(text);
  while (std::getline(in, line)) {
    if (const std::size_t hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    for (char& c : line) {
      if (c == ',' || c == '\r' || c == '\t') c = ' ';
    }
    lines.push_back(line);
  }
  return lines;
}

bool parse_number(const std::string& item, double& v) {
  char* end = nullptr;
  v = std::strtod(item.c_str(), &end);
  return end != item.c_str() && *end == '\0';
}

// The three coordinates after a "v" or "vertex" tag, appended to `vertices`.
Status read_xyz(std::istringstream& fields, const std::string& at, std::vector<double>& vertices) {
  for (int c = 0; c < 3; ++c) {
    std::string item;
    double x;
    if (!(fields >> item) || !parse_number(item, x)) return invalid_argument(at + ": a vertex needs 3 coordinates");
    vertices.push_back(x);
  }
  return Status::ok();
}

// A polygon of the file as triangles, a fan from its first corner, numbered in place.
void add_fan(const std::vector<std::uint32_t>& ids, std::vector<std::uint32_t>& triangles) {
  for (std::size_t j = 1; j + 1 < ids.size(); ++j) triangles.insert(triangles.end(), {ids[0], ids[j], ids[j + 1]});
}

Result<ShapeDomain> parse_rings(const std::string& text, const std::string& name) {
  std::vector<std::vector<double>> rings;
  bool in_ring = false;
  const std::vector<std::string> lines = clean_lines(text);
  for (std::size_t i = 0; i < lines.size(); ++i) {
    std::istringstream fields(lines[i]);
    std::vector<double> values;
    std::string item;
    while (fields >> item) {
      double v;
      if (!parse_number(item, v)) {
        return invalid_argument(name + ":" + std::to_string(i + 1) + ": '" + item + "' is not a number");
      }
      values.push_back(v);
    }
    if (values.empty()) {
      // A blank line (a comment alone is not one) ends the ring.
      if (lines[i].find_first_not_of(' ') == std::string::npos) in_ring = false;
      continue;
    }
    if (values.size() != 2) {
      return invalid_argument(name + ":" + std::to_string(i + 1) + ": " + std::to_string(values.size()) +
                              " values; a ring's vertex is \"x y\"");
    }
    if (!in_ring) rings.emplace_back();
    in_ring = true;
    rings.back().insert(rings.back().end(), values.begin(), values.end());
  }
  return ShapeDomain::polygon(std::move(rings), name);
}

Result<ShapeDomain> parse_off(const std::string& text, const std::string& name) {
  const std::vector<std::string> lines = clean_lines(text);
  std::vector<std::pair<std::size_t, std::vector<std::string>>> rows;  // (line, fields), non-empty
  for (std::size_t i = 0; i < lines.size(); ++i) {
    std::istringstream fields(lines[i]);
    std::vector<std::string> f;
    std::string item;
    while (fields >> item) f.push_back(item);
    if (!f.empty()) rows.emplace_back(i + 1, std::move(f));
  }
  std::size_t r = 0;
  if (r < rows.size() && rows[r].second[0].size() >= 3 &&
      rows[r].second[0].compare(rows[r].second[0].size() - 3, 3, "OFF") == 0) {
    if (rows[r].second[0] != "OFF") {
      return invalid_argument(name + ":" + std::to_string(rows[r].first) + ": '" + rows[r].second[0] +
                              "' files are not read (plain OFF only)");
    }
    if (rows[r].second.size() > 1) {
      rows[r].second.erase(rows[r].second.begin());
    } else {
      ++r;
    }
  } else {
    return invalid_argument(name + ":1: not an OFF file (it must begin with OFF)");
  }
  if (r >= rows.size() || rows[r].second.size() < 2) return invalid_argument(name + ": no vertex and face counts");
  double nv_d, nf_d;
  if (!parse_number(rows[r].second[0], nv_d) || !parse_number(rows[r].second[1], nf_d) || nv_d < 0 || nf_d < 0 ||
      nv_d != std::floor(nv_d) || nf_d != std::floor(nf_d) || nv_d > 1e9 || nf_d > 1e9) {
    return invalid_argument(name + ":" + std::to_string(rows[r].first) + ": bad counts (\"vertices faces edges\")");
  }
  const std::size_t nv = static_cast<std::size_t>(nv_d), nf = static_cast<std::size_t>(nf_d);
  ++r;
  if (rows.size() < r + nv + nf) {
    return invalid_argument(name + ": " + std::to_string(nv) + " vertices and " + std::to_string(nf) +
                            " faces announced, but the file ends early");
  }
  std::vector<double> vertices;
  vertices.reserve(3 * nv);
  for (std::size_t v = 0; v < nv; ++v, ++r) {
    const auto& [line, f] = rows[r];
    if (f.size() < 3) return invalid_argument(name + ":" + std::to_string(line) + ": a vertex needs 3 coordinates");
    for (int c = 0; c < 3; ++c) {
      double x;
      if (!parse_number(f[c], x)) {
        return invalid_argument(name + ":" + std::to_string(line) + ": '" + f[c] + "' is not a number");
      }
      vertices.push_back(x);
    }
  }
  std::vector<std::uint32_t> triangles;
  for (std::size_t k = 0; k < nf; ++k, ++r) {
    const auto& [line, f] = rows[r];
    double count;
    if (!parse_number(f[0], count) || count < 3 || count != std::floor(count) || f.size() < 1 + count) {
      return invalid_argument(name + ":" + std::to_string(line) + ": a face is \"n i_1 ... i_n\" with n >= 3");
    }
    std::vector<std::uint32_t> ids;
    for (std::size_t j = 1; j <= static_cast<std::size_t>(count); ++j) {
      double id;
      if (!parse_number(f[j], id) || id < 0 || id != std::floor(id) || id >= static_cast<double>(nv)) {
        return invalid_argument(name + ":" + std::to_string(line) + ": '" + f[j] + "' is not a vertex index in [0, " +
                                std::to_string(nv) + ")");
      }
      ids.push_back(static_cast<std::uint32_t>(id));
    }
    add_fan(ids, triangles);
  }
  return ShapeDomain::solid(std::move(vertices), std::move(triangles), name);
}

Result<ShapeDomain> parse_obj(const std::string& text, const std::string& name) {
  std::vector<double> vertices;
  std::vector<std::uint32_t> triangles;
  const std::vector<std::string> lines = clean_lines(text);
  for (std::size_t i = 0; i < lines.size(); ++i) {
    std::istringstream fields(lines[i]);
    std::string tag;
    if (!(fields >> tag)) continue;
    const std::string at = name + ":" + std::to_string(i + 1);
    if (tag == "v") {
      if (Status st = read_xyz(fields, at, vertices); !st.is_ok()) return st;
    } else if (tag == "f") {
      std::vector<std::uint32_t> ids;
      std::string item;
      const long long nv = static_cast<long long>(vertices.size() / 3);
      while (fields >> item) {
        const std::string head = item.substr(0, item.find('/'));
        char* end = nullptr;
        const long long v = std::strtoll(head.c_str(), &end, 10);
        const long long id = v < 0 ? nv + v : v - 1;  // 1-based, or relative when negative
        if (end == head.c_str() || *end != '\0' || v == 0 || id < 0 || id >= nv) {
          return invalid_argument(at + ": '" + item +
                                  "' is not a vertex defined above (1-based, or negative: relative)");
        }
        ids.push_back(static_cast<std::uint32_t>(id));
      }
      if (ids.size() < 3) return invalid_argument(at + ": a face needs at least 3 vertices");
      add_fan(ids, triangles);
    }
  }
  return ShapeDomain::solid(std::move(vertices), std::move(triangles), name);
}

Result<ShapeDomain> parse_stl(const std::string& bytes, const std::string& name) {
  std::vector<double> vertices;
  std::vector<std::uint32_t> triangles;
  if (bytes.size() >= 84) {
    std::uint32_t count;
    std::memcpy(&count, bytes.data() + 80, 4);
    if (bytes.size() == 84 + 50 * static_cast<std::uint64_t>(count)) {
      vertices.reserve(9 * static_cast<std::size_t>(count));
      for (std::uint32_t f = 0; f < count; ++f) {
        const char* rec = bytes.data() + 84 + 50 * static_cast<std::size_t>(f) + 12;  // after the normal
        for (int k = 0; k < 9; ++k) {
          float x;
          std::memcpy(&x, rec + 4 * k, 4);
          vertices.push_back(static_cast<double>(x));
        }
        for (std::uint32_t k = 0; k < 3; ++k) triangles.push_back(3 * f + k);
      }
      return ShapeDomain::solid(std::move(vertices), std::move(triangles), name);
    }
  }
  const std::size_t start = bytes.find_first_not_of(" \t\r\n");
  if (start == std::string::npos || bytes.compare(start, 5, "solid") != 0) {
    return invalid_argument(name + ": neither binary STL (84 + 50 n bytes) nor ASCII STL (beginning with 'solid')");
  }
  const std::vector<std::string> lines = clean_lines(bytes);
  std::size_t in_facet = 0;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    std::istringstream fields(lines[i]);
    std::string tag;
    if (!(fields >> tag)) continue;
    const std::string at = name + ":" + std::to_string(i + 1);
    if (tag == "vertex") {
      if (Status st = read_xyz(fields, at, vertices); !st.is_ok()) return st;
      ++in_facet;
    } else if (tag == "endloop") {
      if (in_facet != 3)
        return invalid_argument(at + ": a facet has " + std::to_string(in_facet) + " vertices; STL's have 3");
      const std::uint32_t base = static_cast<std::uint32_t>(vertices.size() / 3 - 3);
      triangles.insert(triangles.end(), {base, base + 1, base + 2});
      in_facet = 0;
    }
  }
  return ShapeDomain::solid(std::move(vertices), std::move(triangles), name);
}

}  // namespace

std::string shape_domain_format(const std::string& path) {
  const std::string ext = lower_extension(path);
  if (ext == ".off" || ext == ".obj" || ext == ".stl" || ext == ".geojson") return ext.substr(1);
  if (ext == ".json") return "geojson";
  return "rings";
}

bool is_geojson_path(const std::string& path) { return shape_domain_format(path) == "geojson"; }

Result<ShapeDomain> parse_shape_domain(const std::string& bytes, const std::string& name) {
  const std::string format = shape_domain_format(name);
  if (format == "off") return parse_off(bytes, name);
  if (format == "obj") return parse_obj(bytes, name);
  if (format == "stl") return parse_stl(bytes, name);
  if (format == "geojson") return invalid_argument(name + ": GeoJSON is read by the clients, not here");
  return parse_rings(bytes, name);
}

Result<ShapeDomain> read_shape_domain(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return invalid_argument(path + ": cannot read the domain file");
  std::ostringstream bytes;
  bytes << in.rdbuf();
  return parse_shape_domain(bytes.str(), path);
}

}  // namespace spokemesh
