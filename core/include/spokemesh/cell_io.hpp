// Writing Voronoi cells (docs/cells.md) and reading halfspace domains.
//
// CellWriter, by extension:
//   .npz (any d): NumPy arrays for n cells in seed order and m facets in all:
//       volume (n) float64, centroid (n, d) float64, bounded (n) bool,
//       facet_ptr (n + 1) int64 (cell i's facets are [facet_ptr[i], facet_ptr[i+1])),
//       facet_neighbor (m) int64 (the neighbour's index, or -1 - k for domain wall k),
//       facet_area (m) float64, facet_normal (m, d) float64 (unit, outward);
//       on a torus (periodic.hpp) also facet_offset (m, d) int32, the offset of the
//       neighbour's image across each facet (VoronoiCell::facet_offsets).
//   .vtu (VTK XML, d = 2 or 3): one polygon (2-d) or polyhedron (3-d) per bounded
//       cell, with cell data seed (Int64) and volume (Float64); vertices are not shared
//       between cells.
//   .svg (d = 2): a picture, each bounded cell a polygon shaded by its area (light:
//       small, dark: large) with its centroid as a dot.
// Arrays are streamed to unlinked temporary files beside the output, so memory stays
// bounded whatever n; commit() assembles the file under a temporary name and renames
// it into place, so an interrupted run never leaves a partial file.
//
// Halfspace files: one wall per line, "a_1 ... a_d b" meaning a . x <= b (whitespace
// or commas; '#' comments; blank lines ignored). Errors name the file and line.
//
// Thread safety: a CellWriter is used by one thread.
#pragma once

#include <cmath>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/domain.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh {

class CellWriter {
 public:
  enum class Format { kNpz, kVtu, kSvg };
  // The format for `path` by its extension; refuses an unknown extension, .vtu outside
  // 2-d and 3-d, and .svg outside 2-d (INVALID_ARGUMENT).
  static Result<Format> format_for(const std::string& path, int dimension);
  // Refuses what format_for refuses.
  // periodic: the cells carry facet offsets (written to .npz as facet_offset).
  static Result<std::unique_ptr<CellWriter>> open(const std::string& path, int dimension, bool periodic = false);
  virtual ~CellWriter() = default;
  // Whether the format needs the cells' vertices (else measures suffice).
  virtual bool needs_vertices() const = 0;
  // Appends cells (consecutive seeds, from 0).
  virtual Status write(std::span<const VoronoiCell> cells) = 0;
  virtual Status commit() = 0;
};

// The text of .vtu and .svg cell files as sections: fixed text, and the cells' lines
// in seed order in `parts()` streams (a .vtu's arrays; an .svg's polygons and dots).
// CellWriter makes its files from it, and spokemesh-mpi's ranks make the same bytes
// (each writing its slice's lines at offsets computed from every rank's sizes).
//
// A cell's lines depend on the cells before it only through counts (a .vtu numbers
// the vertices and face values after the earlier cells'), and on all cells through
// totals (a .vtu's header counts points and cells; an .svg is scaled to the cells'
// extent and shaded by the range of their areas): both are a CellTally.
//
// Thread safety: value type; const methods may be called from any thread.
struct CellTally {
  std::int64_t cells = 0, points = 0, connectivity = 0, face_values = 0;  // add
  double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};    // min, max (.svg)
  double min_volume = INFINITY, max_volume = -INFINITY;                   // min, max (.svg)
};

class CellFileLayout {
 public:
  struct Section {
    bool lines = false;  // false: `text`; true: every cell's lines of stream `part`
    std::string text;
    int part = 0;
  };
  // format: .vtu (d = 2 or 3) or .svg (d = 2).
  CellFileLayout(CellWriter::Format format, int d);
  int parts() const { return parts_; }
  // Whether the file shows the cell at all (.vtu: bounded cells; .svg: bounded with 3
  // or more vertices); a cell not shown has no lines and adds nothing to a tally.
  bool shows(const VoronoiCell& cell) const;
  // Adds the cell to `tally`.
  void add(const VoronoiCell& cell, CellTally& tally) const;
  // Appends the cell's lines to out[0 .. parts()), and adds it to `before` (the tally
  // of the cells before it). `totals`: the tally of every cell in the file.
  void lines(const VoronoiCell& cell, CellTally& before, const CellTally& totals, std::string* out) const;
  // The file: text and the parts, in order.
  std::vector<Section> sections(const CellTally& totals) const;

 private:
  CellWriter::Format format_;
  int d_, parts_;
};

Result<Domain> read_halfspaces(const std::string& path, int dimension);

}  // namespace spokemesh
