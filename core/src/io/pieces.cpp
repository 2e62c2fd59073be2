#include "spokemesh/pieces.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "spokemesh/data_dir.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/space_split.hpp"

namespace spokemesh {
namespace {

constexpr char kPieceMagic[8] = {'S', 'M', 'P', 'I', 'E', 'C', 'E', '1'};
constexpr const char* kManifestHeader = "spokemesh-pieces 1";

template <class T>
void put(std::string& out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));  // little-endian hosts only (CMake checks)
  out.append(bytes, sizeof(T));
}

template <class T>
bool get(const std::string& in, std::size_t& at, T& value) {
  if (in.size() - at < sizeof(T) || at > in.size()) return false;
  std::memcpy(&value, in.data() + at, sizeof(T));
  at += sizeof(T);
  return true;
}

std::uint32_t crc_of(const char* data, std::size_t size) {
  uLong crc = ::crc32(0L, Z_NULL, 0);
  while (size > 0) {
    const auto step = static_cast<uInt>(std::min<std::size_t>(size, 1u << 30));
    crc = ::crc32(crc, reinterpret_cast<const Bytef*>(data), step);
    data += step;
    size -= step;
  }
  return static_cast<std::uint32_t>(crc);
}

std::string number_text(double v) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.17g", v);
  return buffer;
}

void append_numbers(std::string& out, const std::vector<double>& values) {
  for (double v : values) {
    out += ' ';
    out += number_text(v);
  }
}

Result<std::string> read_whole(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status{Code::kNotFound, path + ": not found"};
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

std::uint64_t Piece::own_count() const {
  return static_cast<std::uint64_t>(std::count(own.begin(), own.end(), std::uint8_t{1}));
}

std::vector<double> held_box_of(std::span<const double> box, std::uint64_t count, std::span<const double> global_box) {
  const std::size_t d = box.size() / 2;
  double volume = 1, widest = 0;
  for (std::size_t c = 0; c < d; ++c) {
    volume *= box[d + c] - box[c];
    widest = std::max(widest, box[d + c] - box[c]);
  }
  const double m = static_cast<double>(std::max<std::uint64_t>(count, 1));
  const double spacing = volume > 0 ? std::pow(volume / m, 1.0 / static_cast<double>(d))
                                    : widest / std::pow(m, 1.0 / static_cast<double>(d));
  const double depth = kHaloSpacings * spacing;
  std::vector<double> held(box.begin(), box.end());
  for (std::size_t c = 0; c < d; ++c) {
    held[c] = std::max(global_box[c], box[c] - depth);
    held[d + c] = std::min(global_box[d + c], box[d + c] + depth);
  }
  return held;
}

std::string manifest_text(const PieceManifest& m) {
  std::string out = std::string(kManifestHeader) + "\n";
  out += "set " + m.set_id + "\n";
  out += "dimension " + std::to_string(m.dimension) + "\n";
  out += "count " + std::to_string(m.count) + "\n";
  out += "piece_points " + std::to_string(m.piece_points) + "\n";
  out += "global_box";
  append_numbers(out, m.global_box);
  out += "\npieces " + std::to_string(m.pieces.size()) + "\n";
  for (std::size_t p = 0; p < m.pieces.size(); ++p) {
    const PieceEntry& e = m.pieces[p];
    char crc[16];
    std::snprintf(crc, sizeof crc, "%08x", e.crc);
    out += "piece " + std::to_string(p) + " start " + std::to_string(e.start) + " count " + std::to_string(e.count) +
           " held " + std::to_string(e.held) + " bytes " + std::to_string(e.bytes) + " crc " + crc + " box";
    append_numbers(out, e.box);
    out += " held_box";
    append_numbers(out, e.held_box);
    out += "\n";
  }
  return out;
}

Result<PieceManifest> parse_manifest(const std::string& text, const std::string& source) {
  PieceManifest m;
  std::istringstream in(text);
  std::string line;
  int number = 0;
  auto bad = [&](const std::string& why) {
    return invalid_argument(source + ":" + std::to_string(number) + ": " + why);
  };
  std::size_t expected = 0;
  bool header = false;
  while (std::getline(in, line)) {
    ++number;
    std::istringstream words(line);
    std::string key;
    if (!(words >> key)) continue;
    if (!header) {
      if (line != kManifestHeader)
        return bad("not a pieces manifest (expected \"" + std::string(kManifestHeader) + "\")");
      header = true;
      continue;
    }
    auto doubles = [&](std::size_t count, std::vector<double>& out) {
      out.resize(count);
      for (double& v : out) {
        if (!(words >> v)) return false;
      }
      return true;
    };
    if (key == "set") {
      words >> m.set_id;
    } else if (key == "dimension") {
      if (!(words >> m.dimension) || m.dimension < 1 || m.dimension > 64) return bad("bad dimension");
    } else if (key == "count") {
      if (!(words >> m.count)) return bad("bad count");
    } else if (key == "piece_points") {
      if (!(words >> m.piece_points) || m.piece_points == 0) return bad("bad piece_points");
    } else if (key == "global_box") {
      if (m.dimension == 0 || !doubles(2 * static_cast<std::size_t>(m.dimension), m.global_box)) {
        return bad("bad global_box");
      }
    } else if (key == "pieces") {
      if (!(words >> expected) || expected == 0 || expected > m.count) return bad("bad piece count");
    } else if (key == "piece") {
      PieceEntry e;
      std::size_t index = 0;
      std::string k1, k2, k3, k4, k5, k6, k7;
      std::string crc;
      const std::size_t dd = 2 * static_cast<std::size_t>(m.dimension);
      if (!(words >> index >> k1 >> e.start >> k2 >> e.count >> k3 >> e.held >> k4 >> e.bytes >> k5 >> crc >> k6) ||
          k1 != "start" || k2 != "count" || k3 != "held" || k4 != "bytes" || k5 != "crc" || k6 != "box" ||
          index != m.pieces.size() || m.dimension == 0 || !doubles(dd, e.box) || !(words >> k7) || k7 != "held_box" ||
          !doubles(dd, e.held_box)) {
        return bad("malformed piece line");
      }
      e.crc = static_cast<std::uint32_t>(std::stoul(crc, nullptr, 16));
      m.pieces.push_back(std::move(e));
    } else {
      return bad("unknown field \"" + key + "\"");
    }
  }
  if (!header) return invalid_argument(source + ": empty manifest");
  if (m.pieces.size() != expected || m.pieces.empty()) {
    return invalid_argument(source + ": lists " + std::to_string(m.pieces.size()) + " pieces, says " +
                            std::to_string(expected));
  }
  std::uint64_t next = 0;
  for (const PieceEntry& e : m.pieces) {
    if (e.start != next) return invalid_argument(source + ": pieces do not tile the sweep order");
    next += e.count;
  }
  if (next != m.count)
    return invalid_argument(source + ": pieces hold " + std::to_string(next) + " of " + std::to_string(m.count) +
                            " points");
  return m;
}

std::string piece_bytes(const Piece& piece, std::uint32_t pieces) {
  const std::size_t held = piece.ids.size();
  const auto d = static_cast<std::size_t>(piece.dimension);
  std::string out;
  out.reserve(96 + 32 * d + held * (9 + 8 * d));
  out.append(kPieceMagic, sizeof kPieceMagic);
  put<std::uint32_t>(out, static_cast<std::uint32_t>(piece.dimension));
  put<std::uint32_t>(out, piece.index);
  put<std::uint32_t>(out, pieces);
  put<std::uint32_t>(out, 0);
  put<std::uint64_t>(out, piece.set_count);
  put<std::uint64_t>(out, piece.start);
  put<std::uint64_t>(out, piece.own_count());
  put<std::uint64_t>(out, held);
  for (double v : piece.box) put(out, v);
  for (double v : piece.held_box) put(out, v);
  out.append(reinterpret_cast<const char*>(piece.ids.data()), held * 8);
  out.append(reinterpret_cast<const char*>(piece.own.data()), held);
  out.append(reinterpret_cast<const char*>(piece.coords.data()), held * d * 8);
  put<std::uint32_t>(out, crc_of(out.data(), out.size()));
  return out;
}

Result<Piece> read_piece(const std::string& path, const PieceManifest& manifest, std::uint32_t index) {
  auto bytes = read_whole(path);
  if (!bytes.is_ok()) return bytes.status();
  const std::string& in = bytes.value();
  const PieceEntry& entry = manifest.pieces.at(index);
  auto corrupt = [&](const std::string& why) { return invalid_argument(path + ": corrupt piece file: " + why); };
  if (in.size() != entry.bytes) {
    return corrupt(std::to_string(in.size()) + " bytes, the manifest says " + std::to_string(entry.bytes));
  }
  if (in.size() < sizeof kPieceMagic + 4 || std::memcmp(in.data(), kPieceMagic, sizeof kPieceMagic) != 0) {
    return corrupt("no SMPIECE1 header");
  }
  std::uint32_t stored_crc = 0;
  std::memcpy(&stored_crc, in.data() + in.size() - 4, 4);
  if (crc_of(in.data(), in.size() - 4) != stored_crc || stored_crc != entry.crc) return corrupt("CRC-32 mismatch");
  Piece p;
  std::size_t at = sizeof kPieceMagic;
  std::uint32_t d = 0, idx = 0, count = 0, zero = 0;
  std::uint64_t own = 0, held = 0;
  get(in, at, d);
  get(in, at, idx);
  get(in, at, count);
  get(in, at, zero);
  get(in, at, p.set_count);
  get(in, at, p.start);
  get(in, at, own);
  get(in, at, held);
  if (static_cast<int>(d) != manifest.dimension || idx != index || count != manifest.pieces.size() ||
      p.set_count != manifest.count || p.start != entry.start || own != entry.count || held != entry.held) {
    return corrupt("header disagrees with the manifest");
  }
  const std::size_t dd = 2 * static_cast<std::size_t>(d);
  if (in.size() != at + 2 * dd * 8 + held * (9 + 8 * static_cast<std::size_t>(d)) + 4) return corrupt("wrong size");
  p.index = index;
  p.dimension = static_cast<int>(d);
  p.box.resize(dd);
  p.held_box.resize(dd);
  for (double& v : p.box) get(in, at, v);
  for (double& v : p.held_box) get(in, at, v);
  p.ids.resize(held);
  std::memcpy(p.ids.data(), in.data() + at, held * 8);
  at += held * 8;
  p.own.assign(in.data() + at, in.data() + at + held);
  at += held;
  p.coords.resize(held * d);
  std::memcpy(p.coords.data(), in.data() + at, held * d * 8);
  for (std::size_t k = 1; k < held; ++k) {
    if (p.ids[k] <= p.ids[k - 1]) return corrupt("ids not ascending");
  }
  return p;
}

Status write_file_durably(const std::string& path, const std::string& bytes) {
  if (const int error = data_dir::write_file(path, bytes); error != 0) {
    return internal_error(path + ": cannot write: " + std::strerror(error));
  }
  return Status::ok();
}

Result<PointSet> piece_point_set(const Piece& piece) {
  PointSet points(piece.dimension, piece.coords);
  if (Status s = points.validate("piece " + std::to_string(piece.index)); !s.is_ok()) return s;
  return points;
}

std::uint32_t local_index(std::span<const std::uint64_t> ids, std::uint64_t id) {
  const auto it = std::lower_bound(ids.begin(), ids.end(), id);
  if (it == ids.end() || *it != id) return kNotHeld;
  return static_cast<std::uint32_t>(it - ids.begin());
}

void to_global(Star& star, std::span<const std::uint64_t> ids) {
  star.seed = static_cast<std::uint32_t>(ids[star.seed]);
  for (std::uint32_t& v : star.simplices) v = static_cast<std::uint32_t>(ids[v]);
}

void to_global(VoronoiCell& cell, std::span<const std::uint64_t> ids) {
  cell.seed = static_cast<std::uint32_t>(ids[cell.seed]);
  for (std::uint32_t& v : cell.vertex_simplices) v = static_cast<std::uint32_t>(ids[v]);
  for (VoronoiFacet& f : cell.facets) {
    if (f.neighbor >= 0) f.neighbor = static_cast<std::int64_t>(ids[static_cast<std::size_t>(f.neighbor)]);
  }
}

std::string pieces_dir(const std::string& dir, const std::string& set_id) { return data_dir::pieces_dir(dir, set_id); }

Result<PieceManifest> read_manifest(const std::string& dir, const std::string& set_id) {
  const std::string path = data_dir::manifest_file(pieces_dir(dir, set_id));
  auto text = read_whole(path);
  if (!text.is_ok()) return text.status();
  auto m = parse_manifest(text.value(), path);
  if (m.is_ok() && m->set_id != set_id) return invalid_argument(path + ": names set " + m->set_id);
  return m;
}

Result<PieceManifest> store_pieces(const PointSet& points, const std::string& set_id, const std::string& dir,
                                   const PieceOptions& options) {
  namespace fs = std::filesystem;
  if (auto existing = read_manifest(dir, set_id); existing.is_ok()) return existing;
  const int d = points.dimension();
  const std::size_t n = points.size();
  if (d != 2 && d != 3) return invalid_argument("pieces: only 2-d and 3-d sets are kept as pieces");
  const auto dd = static_cast<std::size_t>(d);

  const SpaceSplit split(points, SpaceSplit::default_block_points(d, n));
  const auto nodes = split.nodes_of_at_most(std::max(options.piece_points, SpaceSplit::kLeafPoints));
  const auto P = static_cast<std::uint32_t>(nodes.size());
  std::vector<std::uint32_t> piece_of(n);
  for (std::uint32_t p = 0; p < P; ++p) {
    for (std::uint32_t pos = nodes[p].first; pos < nodes[p].second; ++pos) piece_of[split.point_at(pos)] = p;
  }

  // The 1-ring: every simplex's vertices are in each other's halos across pieces.
  std::vector<std::vector<std::uint32_t>> halo(P);
  MeshOptions mesh;
  mesh.threads = std::max(1u, options.threads);
  mesh.split = &split;
  mesh.star.cancel = options.cancel;
  auto run = mesh_seeds(points, mesh, [&](std::span<const std::uint32_t> simplices, std::uint64_t) {
    for (std::size_t s = 0; s + dd < simplices.size() + 1; s += dd + 1) {
      const std::uint32_t* v = simplices.data() + s;
      for (std::size_t i = 0; i <= dd; ++i) {
        for (std::size_t j = 0; j <= dd; ++j) {
          if (piece_of[v[i]] != piece_of[v[j]]) halo[piece_of[v[i]]].push_back(v[j]);
        }
      }
    }
    return Status::ok();
  });
  if (!run.is_ok()) return run.status();

  PieceManifest manifest;
  manifest.set_id = set_id;
  manifest.dimension = d;
  manifest.count = n;
  manifest.piece_points = options.piece_points;
  manifest.global_box.assign(2 * dd, 0);
  for (std::size_t c = 0; c < dd; ++c) {
    manifest.global_box[c] = INFINITY;
    manifest.global_box[dd + c] = -INFINITY;
  }
  for (std::size_t i = 0; i < n; ++i) {
    for (std::size_t c = 0; c < dd; ++c) {
      manifest.global_box[c] = std::min(manifest.global_box[c], points.point(i)[c]);
      manifest.global_box[dd + c] = std::max(manifest.global_box[dd + c], points.point(i)[c]);
    }
  }
  manifest.pieces.resize(P);
  std::vector<double> held_boxes(P * 2 * dd);
  for (std::uint32_t p = 0; p < P; ++p) {
    PieceEntry& e = manifest.pieces[p];
    e.start = nodes[p].first;
    e.count = nodes[p].second - nodes[p].first;
    e.box.assign(2 * dd, 0);
    for (std::size_t c = 0; c < dd; ++c) {
      e.box[c] = INFINITY;
      e.box[dd + c] = -INFINITY;
    }
    for (std::uint32_t pos = nodes[p].first; pos < nodes[p].second; ++pos) {
      const double* x = points.point(split.point_at(pos));
      for (std::size_t c = 0; c < dd; ++c) {
        e.box[c] = std::min(e.box[c], x[c]);
        e.box[dd + c] = std::max(e.box[dd + c], x[c]);
      }
    }
    e.held_box = held_box_of(e.box, e.count, manifest.global_box);
    std::copy(e.held_box.begin(), e.held_box.end(), held_boxes.begin() + p * 2 * dd);
  }
  // Every point inside a held box (closed) joins that piece's halo.
  for (std::uint32_t i = 0; i < n; ++i) {
    const double* x = points.point(i);
    for (std::uint32_t p = 0; p < P; ++p) {
      if (p == piece_of[i]) continue;
      if (in_box({held_boxes.data() + p * 2 * dd, 2 * dd}, x)) halo[p].push_back(i);
    }
  }

  const std::string final_dir = pieces_dir(dir, set_id);
  const std::string tmp_dir = data_dir::temp_name(dir + "/pieces", "pieces");
  std::error_code ec;
  fs::create_directories(tmp_dir, ec);
  if (ec) return internal_error(tmp_dir + ": cannot create: " + ec.message());
  auto cleanup = [&](Status s) {
    std::error_code ignored;
    fs::remove_all(tmp_dir, ignored);
    return s;
  };
  std::vector<std::uint32_t> owners(piece_of);
  for (std::uint32_t p = 0; p < P; ++p) {
    if (options.cancel != nullptr && options.cancel->load(std::memory_order_relaxed)) {
      return cleanup(Status{Code::kCancelled, "pieces: cancelled"});
    }
    Piece piece;
    piece.index = p;
    piece.dimension = d;
    piece.set_count = n;
    piece.start = manifest.pieces[p].start;
    piece.box = manifest.pieces[p].box;
    piece.held_box = manifest.pieces[p].held_box;
    std::vector<std::uint32_t>& h = halo[p];
    for (std::uint32_t pos = nodes[p].first; pos < nodes[p].second; ++pos) h.push_back(split.point_at(pos));
    std::sort(h.begin(), h.end());
    h.erase(std::unique(h.begin(), h.end()), h.end());
    piece.ids.assign(h.begin(), h.end());
    piece.own.resize(h.size());
    piece.coords.resize(h.size() * dd);
    for (std::size_t k = 0; k < h.size(); ++k) {
      piece.own[k] = piece_of[h[k]] == p ? 1 : 0;
      std::copy(points.point(h[k]), points.point(h[k]) + dd, piece.coords.begin() + k * dd);
    }
    std::vector<std::uint32_t>().swap(h);
    const std::string bytes = piece_bytes(piece, P);
    manifest.pieces[p].held = piece.ids.size();
    manifest.pieces[p].bytes = bytes.size();
    std::memcpy(&manifest.pieces[p].crc, bytes.data() + bytes.size() - 4, 4);
    if (Status s = write_file_durably(data_dir::piece_file(tmp_dir, p), bytes); !s.is_ok()) {
      return cleanup(s);
    }
  }
  const std::string owner_bytes(reinterpret_cast<const char*>(owners.data()), owners.size() * 4);
  if (Status s = write_file_durably(data_dir::owners_file(tmp_dir), owner_bytes); !s.is_ok()) return cleanup(s);
  if (Status s = write_file_durably(data_dir::manifest_file(tmp_dir), manifest_text(manifest)); !s.is_ok())
    return cleanup(s);
  if (const int error = data_dir::commit_directory(tmp_dir, final_dir); error != 0) {
    (void)cleanup(Status::ok());
    // Another writer put the same layout in place first: it is the same bytes.
    if (error == EEXIST) return read_manifest(dir, set_id);
    return internal_error(final_dir + ": cannot commit: " + std::strerror(error));
  }
  return manifest;
}

}  // namespace spokemesh
