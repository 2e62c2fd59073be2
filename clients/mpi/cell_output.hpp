// spokemesh-mpi's cells: a rank's certified cells as records, kept on disk, sent in
// bounded rounds to the rank whose slice of the index range holds their seeds, and
// written there into the CLI's file at offsets computed from every rank's counts:
// the .npz's arrays (cell_io.hpp: volume, centroid, bounded, facet_ptr,
// facet_neighbor, facet_area, facet_normal) in the core's zip layout
// (spokemesh/zip_layout.hpp, the CLI's writer too), or the .vtu's or .svg's sections (CellFileLayout). Memory stays
// bounded whatever the number of cells: records go through temporary files, and a rank sends 8 MB of records a round
// and holds one bucket of its slice (about 16 MB of records) at a time.
//
// Thread safety: CellRecords is used by one thread; CellSpool::take by one thread at
// a time (the caller locks); SliceCells and the writers are collective (main thread).
#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "comm.hpp"
#include "spokemesh/cell_io.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh::mpi {

// A record: seed, facets, vertices, loop values (u32 each: the last two 0 without
// geometry), bounded (u8), volume, centroid (d doubles; NaN when empty), per facet
// its neighbour (i64: an index, or -1 - k for wall k), area and normal (d doubles);
// then, with geometry (.vtu, .svg), the vertices (d doubles each), each facet's
// vertex count (u32) and the facets' vertex indices (u32, into the cell's vertices).
inline std::size_t cell_record_bytes(int d, bool geometry, std::uint32_t facets, std::uint32_t vertices,
                                     std::uint32_t loop_values) {
  const auto dd = static_cast<std::size_t>(d);
  const std::size_t measures = 16 + 1 + 8 * (1 + dd) + std::size_t{facets} * 8 * (2 + dd);
  return geometry ? measures + std::size_t{vertices} * 8 * dd + 4 * (std::size_t{facets} + loop_values) : measures;
}

// A record at `p`, read in place: its counts, size, and where its fields start.
struct CellRecordView {
  std::uint32_t seed, facets, vertices, loop_values;
  std::size_t bytes;
  const char* bounded;   // u8
  const char* volume;    // double
  const char* centroid;  // d doubles
  const char* facet;     // per facet: neighbour (i64), area, normal (d doubles)
  const char* geometry;  // vertices (d doubles each), facet vertex counts, their indices
};
inline CellRecordView view_cell_record(int d, bool geometry, const char* p) {
  CellRecordView v;
  v.seed = get<std::uint32_t>(p);
  v.facets = get<std::uint32_t>(p);
  v.vertices = get<std::uint32_t>(p);
  v.loop_values = get<std::uint32_t>(p);
  v.bytes = cell_record_bytes(d, geometry, v.facets, v.vertices, v.loop_values);
  v.bounded = p;
  v.volume = p + 1;
  v.centroid = v.volume + 8;
  v.facet = v.centroid + 8 * static_cast<std::size_t>(d);
  v.geometry = v.facet + std::size_t{v.facets} * 8 * (2 + static_cast<std::size_t>(d));
  return v;
}

// The cell a record holds (its indices global), for the CellFileLayout's lines.
void read_cell_record(int d, bool geometry, const char* p, VoronoiCell& cell);

// Cells (measures, and with `geometry` vertices and facet loops), in global indices,
// as bytes.
class CellRecords {
 public:
  CellRecords(int d, bool geometry) : d_(d), geometry_(geometry) {}
  // `global(i)` maps the cell's point indices to global ones.
  template <class Global>
  void add(const VoronoiCell& cell, std::uint64_t seed, Global&& global) {
    std::uint32_t loop_values = 0;
    if (geometry_) {
      for (const VoronoiFacet& f : cell.facets) loop_values += static_cast<std::uint32_t>(f.vertices.size());
    }
    put<std::uint32_t>(bytes_, static_cast<std::uint32_t>(seed));
    put<std::uint32_t>(bytes_, static_cast<std::uint32_t>(cell.facets.size()));
    put<std::uint32_t>(bytes_, geometry_ ? static_cast<std::uint32_t>(cell.vertex_count()) : 0);
    put<std::uint32_t>(bytes_, loop_values);
    put<std::uint8_t>(bytes_, cell.bounded ? 1 : 0);
    put<double>(bytes_, cell.volume);
    for (int c = 0; c < d_; ++c) {
      put<double>(bytes_, cell.centroid.empty() ? std::numeric_limits<double>::quiet_NaN()
                                                : cell.centroid[static_cast<std::size_t>(c)]);
    }
    for (const VoronoiFacet& f : cell.facets) {
      put<std::int64_t>(
          bytes_, f.is_wall() ? f.neighbor : static_cast<std::int64_t>(global(static_cast<std::uint32_t>(f.neighbor))));
      put<double>(bytes_, f.area);
      for (int c = 0; c < d_; ++c) put<double>(bytes_, f.normal[static_cast<std::size_t>(c)]);
    }
    if (!geometry_) return;
    for (std::size_t i = 0; i < cell.vertex_count() * static_cast<std::size_t>(d_); ++i)
      put<double>(bytes_, cell.vertices[i]);
    for (const VoronoiFacet& f : cell.facets) put<std::uint32_t>(bytes_, static_cast<std::uint32_t>(f.vertices.size()));
    for (const VoronoiFacet& f : cell.facets) {
      for (const std::uint32_t v : f.vertices) put<std::uint32_t>(bytes_, v);
    }
  }
  std::vector<char>& bytes() { return bytes_; }
  std::size_t size() const { return bytes_.size(); }

 private:
  int d_;
  bool geometry_;
  std::vector<char> bytes_;
};

// A rank's records on disk (an anonymous temporary file), with the bytes bound for
// each rank's slice.
class CellSpool {
 public:
  CellSpool(int d, bool geometry, std::uint64_t n, int ranks)
      : d_(d), geometry_(geometry), n_(n), to_rank_(static_cast<std::size_t>(ranks)), file_(std::tmpfile()) {}
  ~CellSpool() {
    if (file_ != nullptr) std::fclose(file_);
  }
  CellSpool(const CellSpool&) = delete;
  CellSpool& operator=(const CellSpool&) = delete;
  // Moves the records' bytes to the file.
  void take(CellRecords& records);
  bool ok() const { return file_ != nullptr && std::ferror(file_) == 0; }

 private:
  friend class SliceCells;
  int d_;
  bool geometry_;
  std::uint64_t n_;
  std::vector<std::uint64_t> to_rank_;
  std::uint64_t bytes_ = 0;
  std::FILE* file_;
};

struct CellsWritten {
  std::uint64_t facets = 0;  // in all
  double volume = 0;         // the cells' volumes summed in seed order (as the CLI sums)
};

// This rank's slice of the index range (slice_begin) of the cells, after every rank
// sent each record to its seed's slice (checking that every seed came exactly once):
// on disk, in buckets of consecutive seeds.
class SliceCells {
 public:
  // Collective. `observe` sees each record arriving (in no particular order).
  static Result<std::unique_ptr<SliceCells>> gather(Comm& comm, CellSpool& spool,
                                                    const std::function<void(const char*)>& observe = {});
  // Calls f(record) for each record in seed order, reading each bucket once and
  // releasing its disk space after.
  Status for_each(const std::function<Status(const char*)>& f);
  std::uint64_t first() const { return first_; }
  std::uint64_t cells() const { return last_ - first_; }
  std::uint64_t facets() const { return facets_; }  // this slice's
  int d() const { return d_; }
  bool geometry() const { return geometry_; }

 private:
  using File = std::unique_ptr<std::FILE, int (*)(std::FILE*)>;
  int d_ = 0;
  bool geometry_ = false;
  std::uint64_t first_ = 0, last_ = 0, facets_ = 0;
  std::vector<File> buckets_;
};

// Writes PATH (under a temporary name, renamed once every rank succeeded): the .npz,
// or the .vtu or .svg (`format`), of the cells gathered. Collective.
Status write_cells_npz(Comm& comm, const std::string& path, std::uint64_t n, SliceCells& slice, CellsWritten& written);
Status write_cells_sections(Comm& comm, const std::string& path, CellWriter::Format format, SliceCells& slice,
                            const CellTally& tally, CellsWritten& written);

}  // namespace spokemesh::mpi
