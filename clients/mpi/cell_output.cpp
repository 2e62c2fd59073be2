#include "cell_output.hpp"

#include <zlib.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>
#include <memory>
#include <string_view>

#include "output.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/zip_layout.hpp"

namespace spokemesh::mpi {

namespace {

// One member of the archive: its name, npy header and data size, and this rank's part
// of the data.
struct Member {
  std::string name, header;
  std::uint64_t data_bytes = 0;  // in all ranks
  std::uint64_t part_at = 0;     // this rank's part: offset within the data, and size
  std::uint64_t part_bytes = 0;
};

using File = std::unique_ptr<std::FILE, int (*)(std::FILE*)>;

constexpr std::uint64_t kRoundBytes = std::uint64_t{8} << 20;    // records a rank sends per round
constexpr std::uint64_t kBucketBytes = std::uint64_t{16} << 20;  // records a rank holds while writing

}  // namespace

void read_cell_record(int d, bool geometry, const char* record, VoronoiCell& cell) {
  const auto dd = static_cast<std::size_t>(d);
  const CellRecordView r = view_cell_record(d, geometry, record);
  cell.seed = r.seed;
  cell.dimension = d;
  cell.bounded = *r.bounded != 0;
  const char* p = r.volume;
  cell.volume = get<double>(p);
  cell.centroid.resize(dd);
  for (double& c : cell.centroid) c = get<double>(p);
  cell.facets.resize(r.facets);
  for (VoronoiFacet& f : cell.facets) {
    f.neighbor = get<std::int64_t>(p);
    f.area = get<double>(p);
    f.normal.resize(dd);
    for (double& c : f.normal) c = get<double>(p);
    f.vertices.clear();
  }
  cell.vertices.resize(geometry ? r.vertices * dd : 0);
  if (!geometry) return;
  for (double& c : cell.vertices) c = get<double>(p);
  for (VoronoiFacet& f : cell.facets) f.vertices.resize(get<std::uint32_t>(p));
  for (VoronoiFacet& f : cell.facets) {
    for (std::uint32_t& v : f.vertices) v = get<std::uint32_t>(p);
  }
}

void CellSpool::take(CellRecords& records) {
  std::vector<char>& b = records.bytes();
  for (std::size_t at = 0; at < b.size();) {
    const CellRecordView h = view_cell_record(d_, geometry_, b.data() + at);
    to_rank_[static_cast<std::size_t>(slice_owner(n_, h.seed, static_cast<int>(to_rank_.size())))] += h.bytes;
    at += h.bytes;
  }
  if (file_ != nullptr && !b.empty()) std::fwrite(b.data(), 1, b.size(), file_);
  bytes_ += b.size();
  b.clear();
}

Result<std::unique_ptr<SliceCells>> SliceCells::gather(Comm& comm, CellSpool& spool,
                                                       const std::function<void(const char*)>& observe) {
  auto slice = std::make_unique<SliceCells>();
  const int d = slice->d_ = spool.d_;
  const bool geometry = slice->geometry_ = spool.geometry_;
  const std::uint64_t n = spool.n_;
  const std::uint64_t first = slice->first_ = slice_begin(n, comm.rank, comm.size);
  const std::uint64_t last = slice->last_ = slice_begin(n, comm.rank + 1, comm.size);
  const std::uint64_t cells = last - first;
  Status status;
  if (!spool.ok())
    status = internal_error("cannot write the temporary file of cells (" + std::string(std::strerror(errno)) + ")");
  if (Status s = comm.agree(status); !s.is_ok()) return s;

  // The slice's records go to buckets of consecutive seeds on disk, each small enough
  // to hold while it is written.
  std::vector<std::uint64_t> incoming(static_cast<std::size_t>(comm.size));
  MPI_Alltoall(spool.to_rank_.data(), 1, MPI_UINT64_T, incoming.data(), 1, MPI_UINT64_T, comm.comm);
  std::uint64_t total_in = 0;
  for (const std::uint64_t b : incoming) total_in += b;
  const std::uint64_t buckets = std::clamp<std::uint64_t>((total_in + kBucketBytes - 1) / kBucketBytes, 1, 4096);
  std::vector<File>& bucket = slice->buckets_;
  for (std::uint64_t b = 0; b < buckets && status.is_ok(); ++b) {
    bucket.emplace_back(std::tmpfile(), &std::fclose);
    if (bucket.back() == nullptr)
      status = internal_error("cannot create a temporary file (" + std::string(std::strerror(errno)) + ")");
  }
  if (Status s = comm.agree(status); !s.is_ok()) return s;
  auto bucket_of = [&](std::uint64_t seed) { return (seed - first) * buckets / cells; };

  // Rounds of at most kRoundBytes from each rank.
  const std::uint64_t rounds = comm.allreduce<std::uint64_t>((spool.bytes_ + kRoundBytes - 1) / kRoundBytes, MPI_MAX);
  if (spool.file_ != nullptr) std::rewind(spool.file_);
  std::vector<char> chunk;
  std::vector<bool> seen(cells, false);
  std::uint64_t left = spool.bytes_;
  for (std::uint64_t round = 0; round < rounds; ++round) {
    const std::size_t carried = chunk.size();
    const std::uint64_t want = std::min(left, kRoundBytes);
    chunk.resize(carried + want);
    if (want != 0 && std::fread(chunk.data() + carried, 1, want, spool.file_) != want && status.is_ok()) {
      status = internal_error("cannot read back the temporary file of cells");
    }
    left -= want;
    std::vector<std::vector<char>> outgoing(static_cast<std::size_t>(comm.size));
    std::size_t at = 0;
    while (status.is_ok() && at + 16 <= chunk.size()) {
      const CellRecordView h = view_cell_record(d, geometry, chunk.data() + at);
      if (at + h.bytes > chunk.size()) break;  // the rest comes with the next round
      std::vector<char>& to = outgoing[static_cast<std::size_t>(slice_owner(n, h.seed, comm.size))];
      to.insert(to.end(), chunk.data() + at, chunk.data() + at + h.bytes);
      at += h.bytes;
    }
    chunk.erase(chunk.begin(), chunk.begin() + static_cast<std::ptrdiff_t>(at));
    const std::vector<char> in = comm.alltoall_bytes(outgoing);
    for (std::size_t from = 0; from < in.size() && status.is_ok();) {
      const CellRecordView r = view_cell_record(d, geometry, in.data() + from);
      const std::uint32_t seed = r.seed, facets = r.facets;
      const std::size_t size = r.bytes;
      if (seed < first || seed >= last || seen[seed - first]) {
        status = internal_error("internal error: cell " + std::to_string(seed) + " sent to the wrong rank or twice");
        break;
      }
      seen[seed - first] = true;
      slice->facets_ += facets;
      if (observe) observe(in.data() + from);
      if (std::fwrite(in.data() + from, 1, size, bucket[bucket_of(seed)].get()) != size) {
        status = internal_error("cannot write a temporary file of cells (" + std::string(std::strerror(errno)) + ")");
      }
      from += size;
    }
  }
  if (status.is_ok() && (!chunk.empty() || left != 0)) status = internal_error("internal error: cells left unsent");
  for (std::uint64_t i = 0; i < cells && status.is_ok(); ++i) {
    if (!seen[i]) status = internal_error("internal error: no rank computed cell " + std::to_string(first + i));
  }
  if (Status s = comm.agree(status); !s.is_ok()) return s;
  return slice;
}

Status SliceCells::for_each(const std::function<Status(const char*)>& f) {
  std::vector<char> held;
  std::vector<const char*> in_order;
  for (File& file : buckets_) {
    const long size = std::ftell(file.get());
    held.resize(static_cast<std::size_t>(std::max(0L, size)));
    std::rewind(file.get());
    if (!held.empty() && std::fread(held.data(), 1, held.size(), file.get()) != held.size()) {
      return internal_error("cannot read back a temporary file of cells");
    }
    file.reset();  // (its disk space goes now)
    in_order.clear();
    for (std::size_t from = 0; from < held.size();) {
      in_order.push_back(held.data() + from);
      from += view_cell_record(d_, geometry_, held.data() + from).bytes;
    }
    std::sort(in_order.begin(), in_order.end(),
              [](const char* x, const char* y) { return get<std::uint32_t>(x) < get<std::uint32_t>(y); });
    for (const char* c : in_order) {
      if (Status s = f(c); !s.is_ok()) return s;
    }
  }
  buckets_.clear();
  return Status::ok();
}

namespace {

// The volumes summed in seed order, passed from rank to rank: the CLI's sum, bit for
// bit. Collective.
double sum_in_seed_order(Comm& comm, const std::vector<double>& volumes) {
  double sum = 0;
  if (comm.rank > 0) MPI_Recv(&sum, 1, MPI_DOUBLE, comm.rank - 1, 7, comm.comm, MPI_STATUS_IGNORE);
  for (const double v : volumes) sum += v;
  if (comm.rank + 1 < comm.size) MPI_Send(&sum, 1, MPI_DOUBLE, comm.rank + 1, 7, comm.comm);
  MPI_Bcast(&sum, 1, MPI_DOUBLE, comm.size - 1, comm.comm);
  return sum;
}

}  // namespace

Status write_cells_npz(Comm& comm, const std::string& path, std::uint64_t n, SliceCells& slice, CellsWritten& written) {
  const int d = slice.d();
  const auto dd = static_cast<std::size_t>(d);
  const std::uint64_t first = slice.first(), cells = slice.cells(), my_facets = slice.facets();
  const std::uint64_t facets_before = comm.exscan_sum<std::uint64_t>(my_facets);
  const std::uint64_t facets_total = comm.allreduce<std::uint64_t>(my_facets, MPI_SUM);
  written.facets = facets_total;
  // The members, as NpzCellWriter writes them.
  std::array<Member, 7> m;
  m[0] = {"volume.npy", npy_vector_header("<f8", n), 8 * n, 8 * first, 8 * cells};
  m[1] = {"centroid.npy", npy_header("<f8", n, dd), 8 * dd * n, 8 * dd * first, 8 * dd * cells};
  m[2] = {"bounded.npy", npy_vector_header("|b1", n), n, first, cells};
  // facet_ptr: n + 1 entries; rank 0's part also holds the leading 0.
  m[3] = {"facet_ptr.npy", npy_vector_header("<i8", n + 1), 8 * (n + 1), comm.rank == 0 ? 0 : 8 * (first + 1),
          8 * (cells + (comm.rank == 0 ? 1 : 0))};
  m[4] = {"facet_neighbor.npy", npy_vector_header("<i8", facets_total), 8 * facets_total, 8 * facets_before,
          8 * my_facets};
  m[5] = {"facet_area.npy", npy_vector_header("<f8", facets_total), 8 * facets_total, 8 * facets_before, 8 * my_facets};
  m[6] = {"facet_normal.npy", npy_header("<f8", facets_total, dd), 8 * dd * facets_total, 8 * dd * facets_before,
          8 * dd * my_facets};
  std::vector<ZipMember> zip(m.size());
  std::uint64_t offset = 0;
  for (std::size_t k = 0; k < m.size(); ++k) {
    zip[k].name = m[k].name;
    zip[k].size = m[k].header.size() + m[k].data_bytes;
    zip[k].offset = offset;
    offset += zip_local_header_size(zip[k].name, zip[k].size) + zip[k].size;
  }
  const std::uint64_t directory_at = offset;

  std::vector<double> volumes;  // the slice's, in seed order (for the summary's sum)
  volumes.reserve(cells);
  Status done = write_file(comm, path, [&](const WriteAt& write_at) {
    Status s;
    std::array<uLong, 7> crc{};
    std::array<std::uint64_t, 7> at{}, wrote{};
    for (std::size_t k = 0; k < m.size(); ++k) {
      crc[k] = crc32(0L, Z_NULL, 0);
      at[k] = zip[k].offset + zip_local_header_size(zip[k].name, zip[k].size) + m[k].header.size() + m[k].part_at;
    }
    auto emit = [&](std::size_t k, const std::string& piece) {
      if (piece.empty()) return;
      crc[k] = crc32_z(crc[k], reinterpret_cast<const Bytef*>(piece.data()), piece.size());
      if (s.is_ok()) s = write_at(at[k] + wrote[k], piece);
      wrote[k] += piece.size();
    };
    std::int64_t ptr = static_cast<std::int64_t>(facets_before);
    if (comm.rank == 0) {
      const std::int64_t zero = 0;
      emit(3, std::string(reinterpret_cast<const char*>(&zero), 8));
    }
    std::array<std::string, 7> piece;
    auto flush = [&] {
      for (std::size_t k = 0; k < m.size(); ++k) {
        emit(k, piece[k]);
        piece[k].clear();
      }
    };
    std::size_t held = 0;
    if (s.is_ok())
      s = slice.for_each([&](const char* c) {
        const CellRecordView r = view_cell_record(d, false, c);  // (an .npz's records carry no geometry)
        const std::size_t facet_bytes = 8 * (2 + dd);
        piece[0].append(r.volume, 8);
        piece[1].append(r.centroid, 8 * dd);
        piece[2].append(r.bounded, 1);
        ptr += r.facets;
        piece[3].append(reinterpret_cast<const char*>(&ptr), 8);
        for (std::uint32_t f = 0; f < r.facets; ++f) {
          const char* q = r.facet + f * facet_bytes;
          piece[4].append(q, 8);
          piece[5].append(q + 8, 8);
          piece[6].append(q + 16, 8 * dd);
        }
        const char* volume = r.volume;
        volumes.push_back(get<double>(volume));
        held += r.bytes;
        if (held >= kBucketBytes) {
          flush();
          held = 0;
        }
        return s;
      });
    flush();
    for (std::size_t k = 0; k < m.size() && s.is_ok(); ++k) {
      if (wrote[k] != m[k].part_bytes) s = internal_error(path + ": internal error: a part changed size");
    }
    // Rank 0 combines the parts' CRCs in rank order after the header's, and writes the
    // local headers and the central directory.
    std::vector<std::uint64_t> crcs(2 * m.size());  // (crc, length) per member
    for (std::size_t k = 0; k < m.size(); ++k) {
      crcs[2 * k] = crc[k];
      crcs[2 * k + 1] = wrote[k];
    }
    std::vector<std::uint64_t> all(comm.rank == 0 ? crcs.size() * static_cast<std::size_t>(comm.size) : 0);
    MPI_Gather(crcs.data(), static_cast<int>(crcs.size()), MPI_UINT64_T, all.data(), static_cast<int>(crcs.size()),
               MPI_UINT64_T, 0, comm.comm);
    if (comm.rank == 0) {
      for (std::size_t k = 0; k < m.size() && s.is_ok(); ++k) {
        uLong c = crc32_z(crc32(0L, Z_NULL, 0), reinterpret_cast<const Bytef*>(m[k].header.data()), m[k].header.size());
        for (int r = 0; r < comm.size; ++r) {
          const std::uint64_t* part = &all[static_cast<std::size_t>(r) * crcs.size() + 2 * k];
          c = crc32_combine64(c, static_cast<uLong>(part[0]), static_cast<z_off64_t>(part[1]));
        }
        zip[k].crc = static_cast<std::uint32_t>(c);
        s = write_at(zip[k].offset, zip_local_header(zip[k]));
        if (s.is_ok()) s = write_at(zip[k].offset + zip_local_header_size(zip[k].name, zip[k].size), m[k].header);
      }
      if (s.is_ok()) s = write_at(directory_at, zip_central_directory(zip, directory_at));
    }
    return s;
  });
  if (!done.is_ok()) return done;
  written.volume = sum_in_seed_order(comm, volumes);
  return Status::ok();
}

Status write_cells_sections(Comm& comm, const std::string& path, CellWriter::Format format, SliceCells& slice,
                            const CellTally& tally, CellsWritten& written) {
  const CellFileLayout layout(format, slice.d());
  const auto parts = static_cast<std::size_t>(layout.parts());
  written.facets = comm.allreduce<std::uint64_t>(slice.facets(), MPI_SUM);
  // The counts before this rank's cells, and the totals.
  std::vector<std::int64_t> counts = {tally.cells, tally.points, tally.connectivity, tally.face_values};
  const std::vector<std::int64_t> before_counts = comm.exscan_sum(counts);
  comm.allreduce(counts, MPI_SUM);
  std::vector<double> lows = {tally.lo[0], tally.lo[1], tally.min_volume},
                      highs = {tally.hi[0], tally.hi[1], tally.max_volume};
  comm.allreduce(lows, MPI_MIN);
  comm.allreduce(highs, MPI_MAX);
  CellTally before, totals;
  before.cells = before_counts[0], before.points = before_counts[1];
  before.connectivity = before_counts[2], before.face_values = before_counts[3];
  totals.cells = counts[0], totals.points = counts[1], totals.connectivity = counts[2], totals.face_values = counts[3];
  totals.lo[0] = lows[0], totals.lo[1] = lows[1], totals.min_volume = lows[2];
  totals.hi[0] = highs[0], totals.hi[1] = highs[1], totals.max_volume = highs[2];

  // This rank's lines, part by part, on disk until their offsets are known.
  Status status;
  std::vector<File> part_files;
  for (std::size_t k = 0; k < parts && status.is_ok(); ++k) {
    part_files.emplace_back(std::tmpfile(), &std::fclose);
    if (part_files.back() == nullptr)
      status = internal_error("cannot create a temporary file (" + std::string(std::strerror(errno)) + ")");
  }
  std::vector<std::string> lines(parts);
  std::vector<std::uint64_t> part_bytes(parts, 0);
  auto flush = [&](std::size_t threshold) {
    for (std::size_t k = 0; k < parts; ++k) {
      if (lines[k].size() < threshold || lines[k].empty()) continue;
      if (std::fwrite(lines[k].data(), 1, lines[k].size(), part_files[k].get()) != lines[k].size()) {
        return internal_error("cannot write a temporary file of cells (" + std::string(std::strerror(errno)) + ")");
      }
      part_bytes[k] += lines[k].size();
      lines[k].clear();
    }
    return Status::ok();
  };
  std::vector<double> volumes;
  volumes.reserve(slice.cells());
  VoronoiCell cell;
  if (status.is_ok())
    status = slice.for_each([&](const char* record) {
      read_cell_record(slice.d(), true, record, cell);
      volumes.push_back(cell.volume);
      layout.lines(cell, before, totals, lines.data());
      return flush(1 << 20);
    });
  if (status.is_ok()) status = flush(1);
  if (Status s = comm.agree(status); !s.is_ok()) return s;

  // The file: rank 0 writes the text; each part is every rank's lines in rank order.
  const std::vector<std::uint64_t> part_before = comm.exscan_sum(part_bytes);
  std::vector<std::uint64_t> part_total = part_bytes;
  comm.allreduce(part_total, MPI_SUM);
  Status done = write_file(comm, path, [&](const WriteAt& write_at) {
    Status s;
    std::uint64_t at = 0;
    std::vector<char> buffer(std::size_t{8} << 20);
    for (const CellFileLayout::Section& section : layout.sections(totals)) {
      if (!section.lines) {
        if (comm.rank == 0 && s.is_ok()) s = write_at(at, section.text);
        at += section.text.size();
        continue;
      }
      const auto k = static_cast<std::size_t>(section.part);
      std::FILE* f = part_files[k].get();
      std::rewind(f);
      for (std::uint64_t done_bytes = 0; done_bytes < part_bytes[k] && s.is_ok();) {
        const std::size_t want =
            static_cast<std::size_t>(std::min<std::uint64_t>(buffer.size(), part_bytes[k] - done_bytes));
        if (std::fread(buffer.data(), 1, want, f) != want) {
          s = internal_error("cannot read back a temporary file of cells");
          break;
        }
        s = write_at(at + part_before[k] + done_bytes, std::string_view(buffer.data(), want));
        done_bytes += want;
      }
      at += part_total[k];
    }
    return s;
  });
  if (!done.is_ok()) return done;
  written.volume = sum_in_seed_order(comm, volumes);
  return Status::ok();
}

}  // namespace spokemesh::mpi
