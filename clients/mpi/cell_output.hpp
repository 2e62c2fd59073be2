// spokemesh-mpi's cells: a rank's certified cells as records, kept on disk, sent in
// bounded rounds to the rank whose slice of the index range holds their seeds, and
// written there into the CLI's .npz (cell_io.hpp: volume, centroid, bounded,
// facet_ptr, facet_neighbor, facet_area, facet_normal) at offsets computed from every
// rank's counts, the zip container around them as libzip makes it (npz.hpp). Memory
// stays bounded whatever the number of cells: records go through temporary files, and
// a rank sends 8 MB of records a round and holds one bucket of its slice (about 16 MB
// of records) at a time.
//
// Thread safety: CellRecords is used by one thread; CellSpool::take by one thread at
// a time (the caller locks); write_cells_npz is collective (main thread).
#pragma once

#include <cstdint>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "comm.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh::mpi {

// Cells measured (volume, centroid, facets' neighbours, areas and normals), in global
// indices, as bytes. A record: seed (u32), facets (u32), bounded (u8), volume,
// centroid (d doubles; NaN when empty), then per facet its neighbour (i64: an index,
// or -1 - k for wall k), area and normal (d doubles).
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
      put<std::int64_t>(bytes_, f.is_wall() ? f.neighbor
                                            : static_cast<std::int64_t>(global(static_cast<std::uint32_t>(f.neighbor))));
      put<double>(bytes_, f.area);
      for (int c = 0; c < d_; ++c) put<double>(bytes_, f.normal[static_cast<std::size_t>(c)]);
    }
  }
  std::vector<char>& bytes() { return bytes_; }
  std::size_t size() const { return bytes_.size(); }

 private:
  int d_;
  std::vector<char> bytes_;
};

// A rank's records on disk (an anonymous temporary file), with the bytes bound for
// each rank's slice.
class CellSpool {
 public:
  CellSpool(int d, std::uint64_t n, int ranks) : d_(d), n_(n), to_rank_(static_cast<std::size_t>(ranks)), file_(std::tmpfile()) {}
  ~CellSpool() {
    if (file_ != nullptr) std::fclose(file_);
  }
  CellSpool(const CellSpool&) = delete;
  CellSpool& operator=(const CellSpool&) = delete;
  // Moves the records' bytes to the file.
  void take(CellRecords& records);
  bool ok() const { return file_ != nullptr && std::ferror(file_) == 0; }

 private:
  friend Status write_cells_npz(Comm& comm, const std::string& path, std::uint64_t n, CellSpool& spool,
                                struct CellsWritten& written);
  int d_;
  std::uint64_t n_;
  std::vector<std::uint64_t> to_rank_;
  std::uint64_t bytes_ = 0;
  std::FILE* file_;
};

struct CellsWritten {
  std::uint64_t facets = 0;  // in all
  double volume = 0;         // the cells' volumes summed in seed order (as the CLI sums)
};

// Sends the records to their slices' ranks (slice_begin), checks that every seed of
// the set came exactly once, and writes PATH (under a temporary name, renamed once
// every rank succeeded). Collective.
Status write_cells_npz(Comm& comm, const std::string& path, std::uint64_t n, CellSpool& spool, CellsWritten& written);

// A record's size from its facet count.
inline std::size_t cell_record_bytes(int d, std::uint32_t facets) {
  const auto dd = static_cast<std::size_t>(d);
  return 4 + 4 + 1 + 8 * (1 + dd) + facets * 8 * (2 + dd);
}

// What a record at `p` starts with, and its size.
struct CellRecordHead {
  std::uint32_t seed, facets;
  std::size_t bytes;
};
inline CellRecordHead cell_record_head(int d, const char* p) {
  CellRecordHead h;
  h.seed = get<std::uint32_t>(p);
  h.facets = get<std::uint32_t>(p);
  h.bytes = cell_record_bytes(d, h.facets);
  return h;
}

}  // namespace spokemesh::mpi
