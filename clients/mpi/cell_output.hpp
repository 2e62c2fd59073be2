// spokemesh-mpi's cells: a rank's certified cells as records, sent to the rank whose
// slice of the index range holds their seeds, and written there into the CLI's .npz
// (cell_io.hpp: volume, centroid, bounded, facet_ptr, facet_neighbor, facet_area,
// facet_normal) at offsets computed from every rank's counts, the zip container
// around them as libzip makes it (npz.hpp).
//
// Thread safety: CellRecords is used by one thread at a time; write_cells_npz is
// collective (main thread).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "comm.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh::mpi {

// Cells measured (volume, centroid, facets' neighbours, areas and normals), in global
// indices. A record: seed (u32), facets (u32), bounded (u8), volume, centroid (d
// doubles; NaN when empty), then per facet its neighbour (i64: an index, or -1 - k for
// wall k), area and normal (d doubles).
class CellRecords {
 public:
  explicit CellRecords(int d) : d_(d) {}
  // `global(i)` maps the cell's point indices to global ones.
  template <class Global>
  void add(const VoronoiCell& cell, std::uint64_t seed, Global&& global) {
    put<std::uint32_t>(bytes_, static_cast<std::uint32_t>(seed));
    put<std::uint32_t>(bytes_, static_cast<std::uint32_t>(cell.facets.size()));
    put<std::uint8_t>(bytes_, cell.bounded ? 1 : 0);
    put<double>(bytes_, cell.volume);
    for (int c = 0; c < d_; ++c) {
      put<double>(bytes_, cell.centroid.empty() ? std::numeric_limits<double>::quiet_NaN()
                                                : cell.centroid[static_cast<std::size_t>(c)]);
    }
    for (const VoronoiFacet& f : cell.facets) {
      put<std::int64_t>(bytes_, f.is_wall() ? f.neighbor : static_cast<std::int64_t>(global(static_cast<std::uint32_t>(f.neighbor))));
      put<double>(bytes_, f.area);
      for (int c = 0; c < d_; ++c) put<double>(bytes_, f.normal[static_cast<std::size_t>(c)]);
    }
  }
  void append(const CellRecords& other) { bytes_.insert(bytes_.end(), other.bytes_.begin(), other.bytes_.end()); }
  std::vector<char>& bytes() { return bytes_; }
  int dimension() const { return d_; }

 private:
  int d_;
  std::vector<char> bytes_;
};

struct CellsWritten {
  std::uint64_t facets = 0;  // in all
  double volume = 0;         // the cells' volumes summed in seed order (as the CLI sums)
};

// Sends the records to their slices' ranks (slice_begin), checks that every seed of
// the set came exactly once, and writes PATH (under a temporary name, renamed once
// every rank succeeded). Collective; `records` is consumed.
Status write_cells_npz(Comm& comm, const std::string& path, std::uint64_t n, CellRecords& records,
                       CellsWritten& written);

}  // namespace spokemesh::mpi
