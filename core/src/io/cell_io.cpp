#include "spokemesh/cell_io.hpp"
#include "spokemesh/io.hpp"

#include "io/npz.hpp"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

namespace spokemesh {

namespace {

bool ends_with(const std::string& s, const char* suffix) {
  const std::size_t n = std::strlen(suffix);
  return s.size() >= n && s.compare(s.size() - n, n, suffix) == 0;
}

// Closes `out` (written to `temp`) and renames it to `path`; on any failure removes
// the temporary file, so no partial output is left behind.
Status close_and_rename(std::FILE* out, const std::string& temp, const std::string& path) {
  const bool failed = std::ferror(out) != 0;
  if (std::fclose(out) != 0 || failed) {
    std::remove(temp.c_str());
    return internal_error("writing " + temp + ": " + std::strerror(errno));
  }
  if (std::rename(temp.c_str(), path.c_str()) != 0) {
    std::remove(temp.c_str());
    return internal_error("cannot rename " + temp + " to " + path + ": " + std::strerror(errno));
  }
  return Status::ok();
}

class NpzCellWriter final : public CellWriter {
 public:
  NpzCellWriter(std::string path, int d, bool periodic)
      : path_(std::move(path)),
        d_(d),
        periodic_(periodic),
        volume_("volume.npy", "<f8", 1),
        centroid_("centroid.npy", "<f8", d),
        bounded_("bounded.npy", "|b1", 1),
        ptr_("facet_ptr.npy", "<i8", 1),
        neighbor_("facet_neighbor.npy", "<i8", 1),
        area_("facet_area.npy", "<f8", 1),
        normal_("facet_normal.npy", "<f8", d),
        offset_("facet_offset.npy", "<i4", d) {}

  Status open() {
    const std::string dir = directory_of(path_);
    for (NpyColumn* c : columns()) {
      if (Status s = c->open(dir); !s.is_ok()) return s;
    }
    const std::int64_t zero = 0;
    return ptr_.append(&zero, 1);
  }
  bool needs_vertices() const override { return false; }

  Status write(std::span<const VoronoiCell> cells) override {
    std::vector<double> nan(static_cast<std::size_t>(d_), std::nan(""));
    for (const VoronoiCell& c : cells) {
      const std::uint8_t b = c.bounded ? 1 : 0;
      Status s = volume_.append(&c.volume, 1);
      if (s.is_ok())
        s = centroid_.append(c.centroid.empty() ? nan.data() : c.centroid.data(), static_cast<std::size_t>(d_));
      if (s.is_ok()) s = bounded_.append(&b, 1);
      for (const VoronoiFacet& f : c.facets) {
        if (s.is_ok()) s = neighbor_.append(&f.neighbor, 1);
        if (s.is_ok()) s = area_.append(&f.area, 1);
        if (s.is_ok()) s = normal_.append(f.normal.data(), static_cast<std::size_t>(d_));
      }
      if (s.is_ok() && periodic_) s = offset_.append(c.facet_offsets.data(), c.facet_offsets.size());
      facets_ += static_cast<std::int64_t>(c.facets.size());
      if (s.is_ok()) s = ptr_.append(&facets_, 1);
      if (!s.is_ok()) return s;
    }
    return Status::ok();
  }

  Status commit() override { return write_npz(path_, columns()); }

 private:
  std::vector<NpyColumn*> columns() {
    std::vector<NpyColumn*> all{&volume_, &centroid_, &bounded_, &ptr_, &neighbor_, &area_, &normal_};
    if (periodic_) all.push_back(&offset_);
    return all;
  }
  std::string path_;
  int d_;
  bool periodic_;
  NpyColumn volume_, centroid_, bounded_, ptr_, neighbor_, area_, normal_, offset_;
  std::int64_t facets_ = 0;
};

// .vtu and .svg cells (CellFileLayout). Each part's lines go to a scratch file, since
// the fixed text before them needs the totals; commit() writes the sections in order.
// A .vtu cell's lines are written as the cell comes (they depend only on the cells
// before it); an .svg's need the totals, so its cells are spooled first (area,
// centroid and vertices, in binary) and their lines written at commit().
class SectionedCellWriter final : public CellWriter {
 public:
  SectionedCellWriter(std::string path, Format format, int d)
      : path_(std::move(path)), format_(format), layout_(format, d) {}
  ~SectionedCellWriter() override {
    for (std::FILE* f : parts_) std::fclose(f);
    if (spool_ != nullptr) std::fclose(spool_);
  }
  Status open() {
    const std::string dir = directory_of(path_);
    for (int k = 0; k < layout_.parts(); ++k) {
      auto f = scratch_file(dir);
      if (!f.is_ok()) return f.status();
      parts_.push_back(f.value());
    }
    lines_.resize(parts_.size());
    if (format_ == Format::kSvg) {
      auto f = scratch_file(dir);
      if (!f.is_ok()) return f.status();
      spool_ = f.value();
    }
    return Status::ok();
  }
  bool needs_vertices() const override { return true; }

  Status write(std::span<const VoronoiCell> cells) override {
    for (const VoronoiCell& c : cells) {
      if (!layout_.shows(c)) continue;
      if (format_ == Format::kSvg) {
        layout_.add(c, totals_);
        const double head[4] = {c.volume, c.centroid[0], c.centroid[1], static_cast<double>(c.vertex_count())};
        std::fwrite(head, sizeof(double), 4, spool_);
        std::fwrite(c.vertices.data(), sizeof(double), c.vertices.size(), spool_);
      } else {
        // (A .vtu's lines read only the tally before the cell: the running one.)
        layout_.lines(c, totals_, totals_, lines_.data());
      }
    }
    if (spool_ != nullptr && std::ferror(spool_))
      return internal_error("writing " + path_ + ": " + std::strerror(errno));
    return flush_lines(1 << 20);
  }

  Status commit() override {
    if (format_ == Format::kSvg) {
      std::fflush(spool_);
      std::rewind(spool_);
      VoronoiCell c;
      c.dimension = 2;
      c.bounded = true;
      c.centroid.resize(2);
      CellTally before;
      double head[4];
      while (std::fread(head, sizeof(double), 4, spool_) == 4) {
        c.volume = head[0], c.centroid[0] = head[1], c.centroid[1] = head[2];
        c.vertices.resize(2 * static_cast<std::size_t>(head[3]));
        if (std::fread(c.vertices.data(), sizeof(double), c.vertices.size(), spool_) != c.vertices.size()) {
          return internal_error("reading back the cells of " + path_);
        }
        layout_.lines(c, before, totals_, lines_.data());
        if (Status s = flush_lines(1 << 20); !s.is_ok()) return s;
      }
    }
    if (Status s = flush_lines(0); !s.is_ok()) return s;
    const std::string temp = path_ + ".partial";
    std::FILE* out = std::fopen(temp.c_str(), "wb");
    if (out == nullptr) return internal_error("cannot create " + temp + ": " + std::strerror(errno));
    for (const CellFileLayout::Section& section : layout_.sections(totals_)) {
      if (!section.lines) {
        std::fwrite(section.text.data(), 1, section.text.size(), out);
        continue;
      }
      std::FILE* f = parts_[static_cast<std::size_t>(section.part)];
      std::fflush(f);
      std::rewind(f);
      char buf[1 << 16];
      std::size_t got;
      while ((got = std::fread(buf, 1, sizeof buf, f)) > 0) std::fwrite(buf, 1, got, out);
    }
    return close_and_rename(out, temp, path_);
  }

 private:
  // Moves the lines held to the parts' files once they pass `threshold` bytes.
  Status flush_lines(std::size_t threshold) {
    for (std::size_t k = 0; k < parts_.size(); ++k) {
      if (lines_[k].size() <= threshold && threshold != 0) continue;
      if (!lines_[k].empty() && std::fwrite(lines_[k].data(), 1, lines_[k].size(), parts_[k]) != lines_[k].size()) {
        return internal_error("writing " + path_ + ": " + std::strerror(errno));
      }
      lines_[k].clear();
    }
    return Status::ok();
  }

  std::string path_;
  Format format_;
  CellFileLayout layout_;
  std::vector<std::FILE*> parts_;
  std::vector<std::string> lines_;
  std::FILE* spool_ = nullptr;
  CellTally totals_;
};

}  // namespace

Result<CellWriter::Format> CellWriter::format_for(const std::string& path, int dimension) {
  if (ends_with(path, ".npz")) return Format::kNpz;
  if (ends_with(path, ".vtu")) {
    if (dimension != 2 && dimension != 3) {
      return invalid_argument(path + ": .vtu cells are 2-d polygons or 3-d polyhedra; these points are " +
                              std::to_string(dimension) + "-d (use .npz)");
    }
    return Format::kVtu;
  }
  if (ends_with(path, ".svg")) {
    if (dimension != 2) {
      return invalid_argument(path + ": .svg pictures are of 2-d cells; these points are " + std::to_string(dimension) +
                              "-d (use .npz or .vtu)");
    }
    return Format::kSvg;
  }
  return invalid_argument(path + ": unknown cell format (use .npz, .vtu in 2-d and 3-d, or .svg in 2-d)");
}

Result<std::unique_ptr<CellWriter>> CellWriter::open(const std::string& path, int dimension, bool periodic) {
  auto format = format_for(path, dimension);
  if (!format.is_ok()) return format.status();
  std::unique_ptr<CellWriter> writer;
  Status s;
  if (format.value() == Format::kNpz) {
    auto w = std::make_unique<NpzCellWriter>(path, dimension, periodic);
    s = w->open();
    writer = std::move(w);
  } else {
    auto w = std::make_unique<SectionedCellWriter>(path, format.value(), dimension);
    s = w->open();
    writer = std::move(w);
  }
  if (!s.is_ok()) return s;
  return writer;
}

CellFileLayout::CellFileLayout(CellWriter::Format format, int d)
    : format_(format),
      d_(d),
      parts_(format == CellWriter::Format::kSvg ? 2
             : d == 3                           ? 8
                                                : 6) {}

bool CellFileLayout::shows(const VoronoiCell& cell) const {
  // A hidden (weighted) seed's cell is empty: nothing to draw.
  return cell.bounded && !cell.hidden && (format_ != CellWriter::Format::kSvg || cell.vertex_count() >= 3);
}

void CellFileLayout::add(const VoronoiCell& c, CellTally& t) const {
  if (!shows(c)) return;
  const std::size_t k = c.vertex_count();
  t.cells += 1;
  t.points += static_cast<std::int64_t>(k);
  t.connectivity += static_cast<std::int64_t>(k);
  if (format_ == CellWriter::Format::kSvg) {
    for (std::size_t v = 0; v < k; ++v) {
      const double x = c.vertices[2 * v], y = c.vertices[2 * v + 1];
      t.lo[0] = std::min(t.lo[0], x), t.lo[1] = std::min(t.lo[1], y);
      t.hi[0] = std::max(t.hi[0], x), t.hi[1] = std::max(t.hi[1], y);
    }
    t.min_volume = std::min(t.min_volume, c.volume);
    t.max_volume = std::max(t.max_volume, c.volume);
  } else if (d_ == 3) {
    t.face_values += 1;
    for (const VoronoiFacet& f : c.facets) {
      if (f.vertices.size() >= 3) t.face_values += 1 + static_cast<std::int64_t>(f.vertices.size());
    }
  }
}

namespace {

// An .svg's scale: 800 pixels across its longer side.
struct SvgFrame {
  double w, h, scale;
  explicit SvgFrame(const CellTally& t)
      : w(std::max(t.hi[0] - t.lo[0], 1e-300)), h(std::max(t.hi[1] - t.lo[1], 1e-300)), scale(800 / std::max(w, h)) {}
};

template <class... Args>
void append_format(std::string& out, const char* format, Args... args) {
  char buf[256];
  const int n = std::snprintf(buf, sizeof buf, format, args...);
  if (n < static_cast<int>(sizeof buf)) {
    out.append(buf, static_cast<std::size_t>(n));
    return;
  }
  const std::size_t at = out.size();
  out.resize(at + static_cast<std::size_t>(n) + 1);
  std::snprintf(out.data() + at, static_cast<std::size_t>(n) + 1, format, args...);
  out.resize(at + static_cast<std::size_t>(n));
}

}  // namespace

void CellFileLayout::lines(const VoronoiCell& c, CellTally& before, const CellTally& totals, std::string* out) const {
  if (!shows(c)) return;
  const std::size_t k = c.vertex_count();
  if (format_ == CellWriter::Format::kSvg) {
    const SvgFrame frame(totals);
    const double t = totals.max_volume > totals.min_volume
                         ? (c.volume - totals.min_volume) / (totals.max_volume - totals.min_volume)
                         : 0.5;
    const int shade = static_cast<int>(235 - 150 * t);  // light small cells, darker large ones
    append_format(out[0], "<polygon fill=\"rgb(%d,%d,255)\" points=\"", shade, shade);
    for (std::size_t v = 0; v < k; ++v) {
      append_format(out[0], v == 0 ? "%.9g,%.9g" : " %.9g,%.9g", c.vertices[2 * v], c.vertices[2 * v + 1]);
    }
    out[0] += "\"/>\n";
    append_format(out[1], "<circle cx=\"%.9g\" cy=\"%.9g\" r=\"%.9g\"/>\n", c.centroid[0], c.centroid[1],
                  1.5 / frame.scale);
    add(c, before);
    return;
  }
  // .vtu parts: points, connectivity, offsets, types, [faces, faceoffsets,] seed, volume.
  const std::int64_t first = before.points;
  for (std::size_t v = 0; v < k; ++v) {
    const double* x = &c.vertices[v * static_cast<std::size_t>(d_)];
    append_format(out[0], "%.17g %.17g %.17g\n", x[0], x[1], d_ == 3 ? x[2] : 0.0);
  }
  for (std::size_t v = 0; v < k; ++v)
    append_format(out[1], "%lld ", static_cast<long long>(first + static_cast<std::int64_t>(v)));
  add(c, before);
  append_format(out[2], "%lld\n", static_cast<long long>(before.connectivity));
  append_format(out[3], "%d\n", d_ == 2 ? 7 : 42);  // VTK_POLYGON, VTK_POLYHEDRON
  int next = 4;
  if (d_ == 3) {
    std::size_t faces = 0;
    for (const VoronoiFacet& f : c.facets) faces += f.vertices.size() >= 3 ? 1 : 0;
    append_format(out[4], "%zu\n", faces);
    for (const VoronoiFacet& f : c.facets) {
      if (f.vertices.size() < 3) continue;  // a facet of measure zero
      append_format(out[4], "%zu", f.vertices.size());
      for (const std::uint32_t v : f.vertices) append_format(out[4], " %lld", static_cast<long long>(first + v));
      out[4] += "\n";
    }
    append_format(out[5], "%lld\n", static_cast<long long>(before.face_values));
    next = 6;
  }
  append_format(out[next], "%u\n", c.seed);
  append_format(out[next + 1], "%.17g\n", c.volume);
}

std::vector<CellFileLayout::Section> CellFileLayout::sections(const CellTally& totals) const {
  std::vector<Section> s;
  auto text = [&](std::string t) {
    if (!s.empty() && !s.back().lines) {
      s.back().text += t;
    } else {
      s.push_back({false, std::move(t), 0});
    }
  };
  auto part = [&](int k) { s.push_back({true, {}, k}); };
  if (format_ == CellWriter::Format::kSvg) {
    const SvgFrame f(totals);
    std::string head;
    append_format(
        head, "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" viewBox=\"0 0 %.0f %.0f\">\n",
        f.w * f.scale, f.h * f.scale, f.w * f.scale, f.h * f.scale);
    const std::string frame = [&] {
      std::string g;
      append_format(g, "<g transform=\"translate(0 %.0f) scale(%.17g %.17g) translate(%.17g %.17g)\"", f.h * f.scale,
                    f.scale, -f.scale, -totals.lo[0], -totals.lo[1]);
      return g;
    }();
    head += frame;
    append_format(head, " stroke=\"#333\" stroke-width=\"%.9g\" stroke-linejoin=\"round\">\n", 0.75 / f.scale);
    text(head);
    part(0);
    text("</g>\n" + frame + " fill=\"#c00\">\n");
    part(1);
    text("</g>\n</svg>\n");
    return s;
  }
  std::string head;
  append_format(
      head,
      "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" "
      "header_type=\"UInt64\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"%lld\" NumberOfCells=\"%lld\">\n",
      static_cast<long long>(totals.points), static_cast<long long>(totals.cells));
  text(head + "<Points>\n");
  int k = 0;
  auto array = [&](const char* head_line) {
    text(std::string(head_line) + "\n");
    part(k++);
    text("\n</DataArray>\n");
  };
  array("<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">");
  text("</Points>\n<Cells>\n");
  array("<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">");
  array("<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">");
  array("<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">");
  if (d_ == 3) {
    array("<DataArray type=\"Int64\" Name=\"faces\" format=\"ascii\">");
    array("<DataArray type=\"Int64\" Name=\"faceoffsets\" format=\"ascii\">");
  }
  text("</Cells>\n<CellData Scalars=\"volume\">\n");
  array("<DataArray type=\"Int64\" Name=\"seed\" format=\"ascii\">");
  array("<DataArray type=\"Float64\" Name=\"volume\" format=\"ascii\">");
  text("</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
  return s;
}

Result<Domain> read_halfspaces(const std::string& path, int dimension) {
  std::ifstream in(path);
  if (!in) return invalid_argument(path + ": cannot read the halfspace file");
  std::vector<double> normals, offsets;
  std::string line;
  for (std::size_t number = 1; std::getline(in, line); ++number) {
    if (const std::size_t hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    for (char& c : line) {
      if (c == ',') c = ' ';
    }
    std::istringstream fields(line);
    std::vector<double> values;
    std::string item;
    while (fields >> item) {
      char* end = nullptr;
      const double v = std::strtod(item.c_str(), &end);
      if (*end != '\0')
        return invalid_argument(path + ":" + std::to_string(number) + ": '" + item + "' is not a number");
      values.push_back(v);
    }
    if (values.empty()) continue;
    if (values.size() != static_cast<std::size_t>(dimension) + 1) {
      return invalid_argument(path + ":" + std::to_string(number) + ": " + std::to_string(values.size()) +
                              " values; a wall of " + std::to_string(dimension) + "-d points needs " +
                              std::to_string(dimension + 1) + " (a_1 ... a_d b for a . x <= b)");
    }
    normals.insert(normals.end(), values.begin(), values.end() - 1);
    offsets.push_back(values.back());
  }
  auto domain = Domain::halfspaces(dimension, std::move(normals), std::move(offsets));
  if (!domain.is_ok()) return invalid_argument(path + ": " + domain.status().message());
  return domain;
}

}  // namespace spokemesh
