#include "spokemesh/cell_io.hpp"
#include "spokemesh/io.hpp"

#include <unistd.h>
#include <zip.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <vector>

namespace spokemesh {

namespace {

std::string directory_of(const std::string& path) {
  const std::size_t slash = path.rfind('/');
  return slash == std::string::npos ? "." : slash == 0 ? "/" : path.substr(0, slash);
}

bool ends_with(const std::string& s, const char* suffix) {
  const std::size_t n = std::strlen(suffix);
  return s.size() >= n && s.compare(s.size() - n, n, suffix) == 0;
}

// An anonymous scratch file in `dir` (created, then unlinked at once: nothing is left
// behind whatever happens to the process).
Result<std::FILE*> scratch_file(const std::string& dir) {
  std::string name = dir + "/.spokemesh-cells.XXXXXX";
  const int fd = ::mkstemp(name.data());
  if (fd < 0) return internal_error("cannot create a scratch file in " + dir + ": " + std::strerror(errno));
  ::unlink(name.c_str());
  std::FILE* f = ::fdopen(fd, "w+b");
  if (f == nullptr) {
    ::close(fd);
    return internal_error("cannot open a scratch file in " + dir + ": " + std::strerror(errno));
  }
  return f;
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

// One .npy array written row by row to a scratch file; the 128-byte header, which
// holds the row count, is written last.
class NpyColumn {
 public:
  NpyColumn(std::string name, std::string descr, int width) : name_(std::move(name)), descr_(std::move(descr)), width_(width) {}
  ~NpyColumn() {
    if (file_ != nullptr) std::fclose(file_);
  }
  NpyColumn(const NpyColumn&) = delete;
  NpyColumn& operator=(const NpyColumn&) = delete;

  Status open(const std::string& dir) {
    auto f = scratch_file(dir);
    if (!f.is_ok()) return f.status();
    file_ = f.value();
    const char zeros[kHeader] = {};
    return put(zeros, kHeader, 0);
  }
  template <class T>
  Status append(const T* values, std::size_t count) {
    return put(values, sizeof(T) * count, count / static_cast<std::size_t>(width_));
  }
  // Writes the header; the file then holds the whole .npy, and is handed over.
  Result<std::FILE*> finish() {
    const std::string header = width_ == 1 ? npy_vector_header(descr_, rows_) : npy_header(descr_, rows_, static_cast<std::uint64_t>(width_));
    if (std::fseek(file_, 0, SEEK_SET) != 0 || std::fwrite(header.data(), 1, header.size(), file_) != header.size() ||
        std::fflush(file_) != 0 || std::fseek(file_, 0, SEEK_SET) != 0) {
      return internal_error("writing " + name_ + ": " + std::strerror(errno));
    }
    std::FILE* f = file_;
    file_ = nullptr;
    return f;
  }
  const std::string& name() const { return name_; }

 private:
  static constexpr std::size_t kHeader = kNpyHeaderBytes;  // a multiple of 64, as the format asks
  Status put(const void* data, std::size_t bytes, std::uint64_t rows) {
    if (bytes != 0 && std::fwrite(data, 1, bytes, file_) != bytes) {
      return internal_error("writing " + name_ + ": " + std::strerror(errno));
    }
    rows_ += rows;
    return Status::ok();
  }
  std::string name_, descr_;
  int width_;
  std::FILE* file_ = nullptr;
  std::uint64_t rows_ = 0;
};

class NpzCellWriter final : public CellWriter {
 public:
  NpzCellWriter(std::string path, int d)
      : path_(std::move(path)),
        d_(d),
        volume_("volume.npy", "<f8", 1),
        centroid_("centroid.npy", "<f8", d),
        bounded_("bounded.npy", "|b1", 1),
        ptr_("facet_ptr.npy", "<i8", 1),
        neighbor_("facet_neighbor.npy", "<i8", 1),
        area_("facet_area.npy", "<f8", 1),
        normal_("facet_normal.npy", "<f8", d) {}

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
      if (s.is_ok()) s = centroid_.append(c.centroid.empty() ? nan.data() : c.centroid.data(), static_cast<std::size_t>(d_));
      if (s.is_ok()) s = bounded_.append(&b, 1);
      for (const VoronoiFacet& f : c.facets) {
        if (s.is_ok()) s = neighbor_.append(&f.neighbor, 1);
        if (s.is_ok()) s = area_.append(&f.area, 1);
        if (s.is_ok()) s = normal_.append(f.normal.data(), static_cast<std::size_t>(d_));
      }
      facets_ += static_cast<std::int64_t>(c.facets.size());
      if (s.is_ok()) s = ptr_.append(&facets_, 1);
      if (!s.is_ok()) return s;
    }
    return Status::ok();
  }

  Status commit() override {
    int error = 0;
    // libzip writes the archive under a temporary name and renames it on zip_close.
    zip_t* zip = zip_open(path_.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &error);
    if (zip == nullptr) {
      zip_error_t e;
      zip_error_init_with_code(&e, error);
      Status s = internal_error("cannot create " + path_ + ": " + zip_error_strerror(&e));
      zip_error_fini(&e);
      return s;
    }
    for (NpyColumn* c : columns()) {
      auto file = c->finish();
      if (!file.is_ok()) {
        zip_discard(zip);
        return file.status();
      }
      zip_source_t* source = zip_source_filep(zip, file.value(), 0, -1);  // owns the FILE*
      if (source == nullptr) {
        std::fclose(file.value());
        Status s = internal_error("writing " + path_ + ": " + zip_strerror(zip));
        zip_discard(zip);
        return s;
      }
      const zip_int64_t index = zip_file_add(zip, c->name().c_str(), source, ZIP_FL_OVERWRITE);
      // A fixed time stamp (1980-01-02, the start of zip's range in any time zone),
      // so that the same cells make the same bytes.
      if (index < 0 || zip_set_file_compression(zip, static_cast<zip_uint64_t>(index), ZIP_CM_STORE, 0) != 0 ||
          zip_file_set_mtime(zip, static_cast<zip_uint64_t>(index), 315619200, 0) != 0) {
        if (index < 0) zip_source_free(source);
        Status s = internal_error("writing " + path_ + ": " + zip_strerror(zip));
        zip_discard(zip);
        return s;
      }
    }
    if (zip_close(zip) != 0) {
      Status s = internal_error("writing " + path_ + ": " + zip_strerror(zip));
      zip_discard(zip);
      return s;
    }
    return Status::ok();
  }

 private:
  std::vector<NpyColumn*> columns() { return {&volume_, &centroid_, &bounded_, &ptr_, &neighbor_, &area_, &normal_}; }
  std::string path_;
  int d_;
  NpyColumn volume_, centroid_, bounded_, ptr_, neighbor_, area_, normal_;
  std::int64_t facets_ = 0;
};

// VTK XML unstructured grid, ASCII. Each array goes to its own scratch file, since
// the piece's header needs the totals; commit() writes header, arrays and footer.
class VtuCellWriter final : public CellWriter {
 public:
  VtuCellWriter(std::string path, int d) : path_(std::move(path)), d_(d) {}

  Status open() {
    const std::string dir = directory_of(path_);
    for (Part& p : parts()) {
      auto f = scratch_file(dir);
      if (!f.is_ok()) return f.status();
      p.file = f.value();
    }
    return Status::ok();
  }
  ~VtuCellWriter() override {
    for (Part& p : parts()) {
      if (p.file != nullptr) std::fclose(p.file);
    }
  }
  bool needs_vertices() const override { return true; }

  Status write(std::span<const VoronoiCell> cells) override {
    for (const VoronoiCell& c : cells) {
      if (!c.bounded) {
        ++skipped_;
        continue;
      }
      const std::size_t k = c.vertex_count();
      const std::int64_t first = points_;
      for (std::size_t v = 0; v < k; ++v) {
        const double* x = &c.vertices[v * d_];
        std::fprintf(points_f(), "%.17g %.17g %.17g\n", x[0], x[1], d_ == 3 ? x[2] : 0.0);
      }
      points_ += static_cast<std::int64_t>(k);
      for (std::size_t v = 0; v < k; ++v) {
        std::fprintf(part(kConnectivity), "%lld ", static_cast<long long>(first + static_cast<std::int64_t>(v)));
      }
      connectivity_ += static_cast<std::int64_t>(k);
      std::fprintf(part(kOffsets), "%lld\n", static_cast<long long>(connectivity_));
      std::fprintf(part(kTypes), "%d\n", d_ == 2 ? 7 : 42);  // VTK_POLYGON, VTK_POLYHEDRON
      std::fprintf(part(kSeed), "%u\n", c.seed);
      std::fprintf(part(kVolume), "%.17g\n", c.volume);
      if (d_ == 3) {
        std::size_t faces = 0;
        for (const VoronoiFacet& f : c.facets) faces += f.vertices.size() >= 3 ? 1 : 0;
        std::fprintf(part(kFaces), "%zu\n", faces);
        face_values_ += 1;
        for (const VoronoiFacet& f : c.facets) {
          if (f.vertices.size() < 3) continue;  // a facet of measure zero
          std::fprintf(part(kFaces), "%zu", f.vertices.size());
          for (const std::uint32_t v : f.vertices) std::fprintf(part(kFaces), " %lld", static_cast<long long>(first + v));
          std::fprintf(part(kFaces), "\n");
          face_values_ += 1 + static_cast<std::int64_t>(f.vertices.size());
        }
        std::fprintf(part(kFaceOffsets), "%lld\n", static_cast<long long>(face_values_));
      }
      ++cells_;
    }
    for (Part& p : parts()) {
      if (std::ferror(p.file)) return internal_error("writing " + path_ + ": " + std::strerror(errno));
    }
    return Status::ok();
  }

  Status commit() override {
    const std::string temp = path_ + ".partial";
    std::FILE* out = std::fopen(temp.c_str(), "wb");
    if (out == nullptr) return internal_error("cannot create " + temp + ": " + std::strerror(errno));
    std::fprintf(out,
                 "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" "
                 "header_type=\"UInt64\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"%lld\" NumberOfCells=\"%lld\">\n",
                 static_cast<long long>(points_), static_cast<long long>(cells_));
    auto array = [&](const char* head, int which) {
      std::fprintf(out, "%s\n", head);
      std::FILE* f = parts()[which].file;
      std::fflush(f);
      std::rewind(f);
      char buf[1 << 16];
      std::size_t got;
      while ((got = std::fread(buf, 1, sizeof buf, f)) > 0) std::fwrite(buf, 1, got, out);
      std::fprintf(out, "\n</DataArray>\n");
    };
    std::fprintf(out, "<Points>\n");
    array("<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">", kPoints);
    std::fprintf(out, "</Points>\n<Cells>\n");
    array("<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">", kConnectivity);
    array("<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">", kOffsets);
    array("<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">", kTypes);
    if (d_ == 3) {
      array("<DataArray type=\"Int64\" Name=\"faces\" format=\"ascii\">", kFaces);
      array("<DataArray type=\"Int64\" Name=\"faceoffsets\" format=\"ascii\">", kFaceOffsets);
    }
    std::fprintf(out, "</Cells>\n<CellData Scalars=\"volume\">\n");
    array("<DataArray type=\"Int64\" Name=\"seed\" format=\"ascii\">", kSeed);
    array("<DataArray type=\"Float64\" Name=\"volume\" format=\"ascii\">", kVolume);
    std::fprintf(out, "</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    return close_and_rename(out, temp, path_);
  }

 private:
  enum { kPoints, kConnectivity, kOffsets, kTypes, kFaces, kFaceOffsets, kSeed, kVolume, kParts };
  struct Part {
    std::FILE* file = nullptr;
  };
  std::array<Part, kParts>& parts() { return parts_; }
  std::FILE* part(int which) { return parts_[which].file; }
  std::FILE* points_f() { return parts_[kPoints].file; }
  std::string path_;
  int d_;
  std::array<Part, kParts> parts_{};
  std::int64_t points_ = 0, connectivity_ = 0, face_values_ = 0, cells_ = 0, skipped_ = 0;
};

// 2-d cells as an SVG picture: each bounded cell a polygon shaded by its area
// (light: small, dark: large), its centroid a dot. Polygons are spooled to a scratch
// file (area, then the points), since the picture's extent and the shading's range
// are known only at the end.
class SvgCellWriter final : public CellWriter {
 public:
  explicit SvgCellWriter(std::string path) : path_(std::move(path)) {}
  ~SvgCellWriter() override {
    if (spool_ != nullptr) std::fclose(spool_);
  }
  Status open() {
    auto f = scratch_file(directory_of(path_));
    if (!f.is_ok()) return f.status();
    spool_ = f.value();
    return Status::ok();
  }
  bool needs_vertices() const override { return true; }

  Status write(std::span<const VoronoiCell> cells) override {
    for (const VoronoiCell& c : cells) {
      if (!c.bounded || c.vertex_count() < 3) continue;
      std::fprintf(spool_, "%.17g %.17g %.17g", c.volume, c.centroid[0], c.centroid[1]);
      for (std::size_t v = 0; v < c.vertex_count(); ++v) {
        const double x = c.vertices[2 * v], y = c.vertices[2 * v + 1];
        std::fprintf(spool_, " %.9g,%.9g", x, y);
        lo_[0] = std::min(lo_[0], x), lo_[1] = std::min(lo_[1], y);
        hi_[0] = std::max(hi_[0], x), hi_[1] = std::max(hi_[1], y);
      }
      std::fprintf(spool_, "\n");
      min_ = std::min(min_, c.volume);
      max_ = std::max(max_, c.volume);
    }
    if (std::ferror(spool_)) return internal_error("writing " + path_ + ": " + std::strerror(errno));
    return Status::ok();
  }

  Status commit() override {
    const std::string temp = path_ + ".partial";
    std::FILE* out = std::fopen(temp.c_str(), "wb");
    if (out == nullptr) return internal_error("cannot create " + temp + ": " + std::strerror(errno));
    const double w = std::max(hi_[0] - lo_[0], 1e-300), h = std::max(hi_[1] - lo_[1], 1e-300);
    const double size = 800, scale = size / std::max(w, h);
    std::fprintf(out,
                 "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" viewBox=\"0 0 %.0f %.0f\">\n"
                 "<g transform=\"translate(0 %.0f) scale(%.17g %.17g) translate(%.17g %.17g)\" stroke=\"#333\" "
                 "stroke-width=\"%.9g\" stroke-linejoin=\"round\">\n",
                 w * scale, h * scale, w * scale, h * scale, h * scale, scale, -scale, -lo_[0], -lo_[1], 0.75 / scale);
    std::fflush(spool_);
    std::rewind(spool_);
    std::string dots;
    char* line = nullptr;
    std::size_t cap = 0;
    while (::getline(&line, &cap, spool_) > 0) {
      double volume = 0, cx = 0, cy = 0;
      int used = 0;
      if (std::sscanf(line, "%lf %lf %lf%n", &volume, &cx, &cy, &used) != 3) continue;
      const double t = max_ > min_ ? (volume - min_) / (max_ - min_) : 0.5;
      const int shade = static_cast<int>(235 - 150 * t);  // light small cells, darker large ones
      std::string pts(line + used);
      while (!pts.empty() && (pts.back() == '\n' || pts.back() == ' ')) pts.pop_back();
      std::fprintf(out, "<polygon fill=\"rgb(%d,%d,255)\" points=\"%s\"/>\n", shade, shade, pts.c_str() + 1);
      char dot[160];
      std::snprintf(dot, sizeof dot, "<circle cx=\"%.9g\" cy=\"%.9g\" r=\"%.9g\"/>\n", cx, cy, 1.5 / scale);
      dots += dot;
    }
    std::free(line);
    std::fprintf(out, "</g>\n<g transform=\"translate(0 %.0f) scale(%.17g %.17g) translate(%.17g %.17g)\" fill=\"#c00\">\n%s</g>\n</svg>\n",
                 h * scale, scale, -scale, -lo_[0], -lo_[1], dots.c_str());
    return close_and_rename(out, temp, path_);
  }

 private:
  std::string path_;
  std::FILE* spool_ = nullptr;
  double lo_[2] = {INFINITY, INFINITY}, hi_[2] = {-INFINITY, -INFINITY};
  double min_ = INFINITY, max_ = -INFINITY;
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

Result<std::unique_ptr<CellWriter>> CellWriter::open(const std::string& path, int dimension) {
  auto format = format_for(path, dimension);
  if (!format.is_ok()) return format.status();
  std::unique_ptr<CellWriter> writer;
  Status s;
  if (format.value() == Format::kNpz) {
    auto w = std::make_unique<NpzCellWriter>(path, dimension);
    s = w->open();
    writer = std::move(w);
  } else if (format.value() == Format::kVtu) {
    auto w = std::make_unique<VtuCellWriter>(path, dimension);
    s = w->open();
    writer = std::move(w);
  } else {
    auto w = std::make_unique<SvgCellWriter>(path);
    s = w->open();
    writer = std::move(w);
  }
  if (!s.is_ok()) return s;
  return writer;
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
      if (*end != '\0') return invalid_argument(path + ":" + std::to_string(number) + ": '" + item + "' is not a number");
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
