// Reading point files and writing mesh files.
//
// Points: text (one point per line, numbers separated by whitespace and/or commas,
// '#' starts a comment, blank lines ignored) or NumPy .npy (float64 or float32,
// C order, shape (n, d)). Errors name the file and the line or index.
//
// Meshes, chosen by extension: .simplices / .txt (one simplex per line, d + 1
// zero-based indices), .npy (int64, shape (m, d + 1)), .vtu (VTK XML) and .msh
// (Gmsh 2.2 ASCII) for d = 2, 3, .svg for d = 2. MeshWriter writes to a temporary
// file beside the target and renames it into place on commit(), so an interrupted
// run never leaves a partial mesh; destroying an uncommitted writer removes it.
//
// Thread safety: functions are reentrant; a MeshWriter is used by one thread.
#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

// Reads points by extension (.npy, else text). Does not validate geometry. The rule
// every route follows (the CLI, spokemesh-mpi, the Python module, the page; README "Input"):
// text has one point a line, numbers separated by blanks, commas or semicolons, `#`
// starting a comment, blank lines skipped, and a first line of fields none of which is
// a number (a header) skipped; .npy holds a C-order (n, d) array of float64, float32,
// int64, int32 or int16, little-endian, integers exact (|v| <= 2^53). Coordinates are
// finite with magnitude at most 1e100.
Result<PointSet> read_points(const std::string& path);
Result<PointSet> parse_text_points(const std::string& text, const std::string& source);
Result<PointSet> parse_npy_points(const std::string& bytes, const std::string& source);

// A .npy of points as stored: for readers that take rows in slices (spokemesh-mpi
// reads its share with MPI-IO). `head`: the file's first bytes (enough for the header;
// 64 KiB always is for version 1), `file_size`: its size. Errors as read_points.
struct NpyPoints {
  std::uint64_t count = 0;
  int dimension = 0;
  int item_bytes = 8;           // float64 (8) or float32 (4); integers: 8, 4 or 2
  std::size_t data_offset = 0;  // where row 0 begins
  bool integer = false;         // int64, int32 or int16 (exact in double up to 2^53)
};
Result<NpyPoints> npy_points_layout(const std::string& head, std::uint64_t file_size, const std::string& source);
// Rows [first_row, first_row + rows) from their bytes at `data`, as float64; errors name
// the element as read_points does.
Status decode_npy_rows(const NpyPoints& layout, const char* data, std::uint64_t first_row, std::uint64_t rows,
                       std::vector<double>& out, const std::string& source);

// The 128-byte header MeshWriter and CellWriter write before .npy rows (version 1.0,
// C order): of a (rows, cols) array, of a (rows,) vector, or of a shape given as the
// text between its parentheses.
constexpr std::size_t kNpyHeaderBytes = 128;
std::string npy_header(const std::string& descr, std::uint64_t rows, std::uint64_t cols);
std::string npy_vector_header(const std::string& descr, std::uint64_t rows);
std::string npy_header_of_shape(const std::string& descr, const std::string& shape);

// Weights of weighted points, one per point in the points' order: text (one
// number a line; '#' comments and blank lines as for points) or .npy (float64 or
// float32, shape (n,) or (n, 1)). kPowerWeight: CGAL's convention, the power weight w
// (the squared radius; any finite real, |w| <= kMaxWeight); kRadius: Voro++'s, a radius
// r >= 0 (|r| <= kMaxCoordinate), returned as the weight r * r rounded to double.
// Errors (INVALID_ARGUMENT) name the file and the line or index: a non-number, more
// than one number on a line, a non-finite or out-of-range value, a negative radius, or
// a count other than `count` (the number of points). kValue: a value at each point
// (spokemesh interpolate), read and checked as a power weight, named "value".
enum class WeightKind { kPowerWeight, kRadius, kValue };
inline constexpr double kMaxWeight = 1e200;  // keeps |p - q|^2 - w finite in double (d <= 1024)
Result<std::vector<double>> read_weights(const std::string& path, std::size_t count, WeightKind kind);
Result<std::vector<double>> parse_text_weights(const std::string& text, const std::string& source, std::size_t count,
                                               WeightKind kind);
// Weights (or radii, squared) given as values in memory (an array from Python or a
// request), checked as the readers check them: errors name `source` and the index.
Result<std::vector<double>> weights_from_values(std::span<const double> values, const std::string& source,
                                                std::size_t count, WeightKind kind);
Result<std::vector<double>> parse_npy_weights(const std::string& bytes, const std::string& source, std::size_t count,
                                              WeightKind kind);

// Reads a mesh (.npy int64/int32, else text) of simplices with `width` indices each.
Result<std::vector<std::uint32_t>> read_simplices(const std::string& path, int width);

class MeshWriter {
 public:
  enum class Format { kText, kNpy, kVtu, kMsh, kSvg };

  // Opens a writer for `path`; refuses formats that do not fit the dimension.
  static Result<std::unique_ptr<MeshWriter>> open(const std::string& path, const PointSet& points);
  // Index tuples of a fixed width (e.g. graph edges: width 2), as text or .npy.
  // `shape` only carries the width: a PointSet of dimension width - 1, no points.
  static Result<std::unique_ptr<MeshWriter>> open_tuples(const std::string& path, const PointSet& shape);
  static Result<Format> format_for(const std::string& path, int dimension);

  virtual ~MeshWriter();
  // Appends simplices ((d + 1) indices each).
  virtual Status write(std::span<const std::uint32_t> simplices) = 0;
  // Finishes the file and renames it into place.
  Status commit();

 protected:
  MeshWriter(std::string path, const PointSet& points, std::FILE* file, std::string temp_path);
  virtual Status finish() = 0;
  Status check_stream(const char* what);

  std::string path_;
  const PointSet& points_;
  std::FILE* file_;
  std::string temp_path_;
  bool committed_ = false;
};

// A Delaunay triangulation of the flat torus (periodic.hpp), by extension:
//   .npz: simplices (m, d + 1) int64, and offsets (m, d + 1, d) int32: vertex v of
//         simplex s stands at points[simplices[s, v]] + offsets[s, v] * (HI - LO);
//   .txt / .simplices: a comment line saying so, then one simplex a line: its d + 1
//         point indices, then each vertex's d offsets in turn;
//   .vtu (2-d, 3-d): for ParaView, the simplices whole: the points, then a copy of each
//         image a simplex uses (point + offset (HI - LO)), which the cells reference;
//         the point data `point_index` maps every copy to its point.
// Written to scratch files and renamed into place on commit(), as MeshWriter does.
// Thread safety: used by one thread.
class PeriodicBox;
class PeriodicMeshWriter {
 public:
  // INVALID_ARGUMENT for other extensions (naming the ones that carry offsets).
  // points and box (borrowed until commit()): needed for .vtu only.
  static Result<std::unique_ptr<PeriodicMeshWriter>> open(const std::string& path, int dimension,
                                                          const PointSet* points = nullptr,
                                                          const PeriodicBox* box = nullptr);
  virtual ~PeriodicMeshWriter() = default;
  // Appends simplices: (d + 1) indices and (d + 1) d offsets each.
  virtual Status write(std::span<const std::uint32_t> simplices, std::span<const std::int32_t> offsets) = 0;
  // Forgets everything written so far (a run repeated with a wider margin).
  virtual Status restart() = 0;
  virtual Status commit() = 0;
};

// The .vtu, .msh and .svg mesh files as a sequence of sections, each fixed text, one
// line per point (in index order) or one line per simplex (in the rows' order), so
// that a writer holding only part of the points and rows (spokemesh-mpi: its slice of
// the index range, its part of the sweep) writes, section by section at computed
// offsets, the bytes MeshWriter writes.
//
// Thread safety: immutable; the format functions are const.
class MeshFileLayout {
 public:
  struct Section {
    enum Kind { kText, kPoints, kRows } kind;
    std::string text;  // kText
    int variant = 0;   // which line a point or row gets (the format's own)
  };
  // n points, `simplices` rows; box: the points' bounding box (d lows, d highs; .svg
  // scales by it).
  MeshFileLayout(MeshWriter::Format format, int d, std::uint64_t n, std::uint64_t simplices,
                 std::span<const double> box);
  const std::vector<Section>& sections() const { return sections_; }
  // Appends point i's line (p: its d coordinates) for a kPoints section.
  void point_line(int variant, std::string& out, std::uint64_t i, const double* p) const;
  // Appends the line of row `index` (0-based in the file), vertices s (d + 1), for a
  // kRows section; `point(v)` gives vertex v's coordinates (.svg draws them).
  void row_line(int variant, std::string& out, const std::uint32_t* s, std::uint64_t index,
                const std::function<const double*(std::uint32_t)>& point) const;

 private:
  MeshWriter::Format format_;
  int d_;
  std::uint64_t n_;
  std::vector<Section> sections_;
  double lo_[2] = {0, 0}, hi_[2] = {0, 0}, scale_ = 1, radius_ = 1;
};

// "i j k\n" lines for simplices (or any fixed-width index tuples).
void append_index_lines(std::string& out, std::span<const std::uint32_t> tuples, int width);

}  // namespace spokemesh
