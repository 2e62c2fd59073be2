// Writing Voronoi cells (docs/cells.md) and reading halfspace domains.
//
// CellWriter, by extension:
//   .npz (any d): NumPy arrays for n cells in seed order and m facets in all:
//       volume (n) float64, centroid (n, d) float64, bounded (n) bool,
//       facet_ptr (n + 1) int64 (cell i's facets are [facet_ptr[i], facet_ptr[i+1])),
//       facet_neighbor (m) int64 (the neighbour's index, or -1 - k for domain wall k),
//       facet_area (m) float64, facet_normal (m, d) float64 (unit, outward).
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

#include <memory>
#include <span>
#include <string>

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
  static Result<std::unique_ptr<CellWriter>> open(const std::string& path, int dimension);
  virtual ~CellWriter() = default;
  // Whether the format needs the cells' vertices (else measures suffice).
  virtual bool needs_vertices() const = 0;
  // Appends cells (consecutive seeds, from 0).
  virtual Status write(std::span<const VoronoiCell> cells) = 0;
  virtual Status commit() = 0;
};

Result<Domain> read_halfspaces(const std::string& path, int dimension);

}  // namespace spokemesh
