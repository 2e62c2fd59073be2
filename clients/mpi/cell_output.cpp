#include "cell_output.hpp"

#include <zlib.h>

#include <array>
#include <string_view>

#include "npz.hpp"
#include "output.hpp"
#include "spokemesh/io.hpp"

namespace spokemesh::mpi {

namespace {

// A record's size from its facet count.
std::size_t record_bytes(int d, std::uint32_t facets) {
  const auto dd = static_cast<std::size_t>(d);
  return 4 + 4 + 1 + 8 * (1 + dd) + facets * 8 * (2 + dd);
}

// One member of the archive: its name, npy header and data size, and this rank's part
// of the data (produced piece by piece).
struct Member {
  std::string name, header;
  std::uint64_t data_bytes = 0;  // in all ranks
  std::uint64_t part_at = 0;     // this rank's part: offset within the data, and size
  std::uint64_t part_bytes = 0;
};

}  // namespace

Status write_cells_npz(Comm& comm, const std::string& path, std::uint64_t n, CellRecords& records,
                       CellsWritten& written) {
  const int d = records.dimension();
  const auto dd = static_cast<std::size_t>(d);
  const std::uint64_t first = slice_begin(n, comm.rank, comm.size), last = slice_begin(n, comm.rank + 1, comm.size);

  // Each record to the rank whose slice holds its seed.
  std::vector<std::vector<char>> outgoing(static_cast<std::size_t>(comm.size));
  {
    const std::vector<char>& mine = records.bytes();
    for (std::size_t at = 0; at < mine.size();) {
      const char* p = mine.data() + at;
      const std::uint32_t seed = get<std::uint32_t>(p);
      const std::uint32_t facets = get<std::uint32_t>(p);
      const std::size_t size = record_bytes(d, facets);
      const int r = slice_owner(n, seed, comm.size);
      std::vector<char>& to = outgoing[static_cast<std::size_t>(r)];
      to.insert(to.end(), mine.data() + at, mine.data() + at + size);
      at += size;
    }
    records.bytes() = {};
  }
  const std::vector<char> in = comm.alltoall_bytes(outgoing);
  outgoing = {};

  // The slice's records by seed.
  Status status;
  std::vector<const char*> cell(last - first, nullptr);
  std::uint64_t my_facets = 0;
  for (std::size_t at = 0; at < in.size();) {
    const char* p = in.data() + at;
    const std::uint32_t seed = get<std::uint32_t>(p);
    const std::uint32_t facets = get<std::uint32_t>(p);
    if (seed < first || seed >= last || cell[seed - first] != nullptr) {
      status = internal_error("internal error: cell " + std::to_string(seed) + " sent to the wrong rank or twice");
      break;
    }
    cell[seed - first] = in.data() + at;
    my_facets += facets;
    at += record_bytes(d, facets);
  }
  for (std::size_t i = 0; i < cell.size() && status.is_ok(); ++i) {
    if (cell[i] == nullptr) status = internal_error("internal error: no rank computed cell " + std::to_string(first + i));
  }
  if (Status s = comm.agree(status); !s.is_ok()) return s;
  const std::uint64_t facets_before = comm.exscan_sum<std::uint64_t>(my_facets);
  const std::uint64_t facets_total = comm.allreduce<std::uint64_t>(my_facets, MPI_SUM);
  written.facets = facets_total;

  // The volumes summed in seed order, passed from rank to rank: the CLI's sum, bit for bit.
  {
    double sum = 0;
    if (comm.rank > 0) MPI_Recv(&sum, 1, MPI_DOUBLE, comm.rank - 1, 7, comm.comm, MPI_STATUS_IGNORE);
    for (const char* c : cell) {
      const char* p = c + 9;
      sum += get<double>(p);
    }
    if (comm.rank + 1 < comm.size) MPI_Send(&sum, 1, MPI_DOUBLE, comm.rank + 1, 7, comm.comm);
    MPI_Bcast(&sum, 1, MPI_DOUBLE, comm.size - 1, comm.comm);
    written.volume = sum;
  }

  // The members, as NpzCellWriter writes them.
  const std::uint64_t cells = last - first;
  std::array<Member, 7> m;
  m[0] = {"volume.npy", npy_vector_header("<f8", n), 8 * n, 8 * first, 8 * cells};
  m[1] = {"centroid.npy", npy_header("<f8", n, dd), 8 * dd * n, 8 * dd * first, 8 * dd * cells};
  m[2] = {"bounded.npy", npy_vector_header("|b1", n), n, first, cells};
  // facet_ptr: n + 1 entries; rank 0's part also holds the leading 0.
  m[3] = {"facet_ptr.npy", npy_vector_header("<i8", n + 1), 8 * (n + 1), comm.rank == 0 ? 0 : 8 * (first + 1),
          8 * (cells + (comm.rank == 0 ? 1 : 0))};
  m[4] = {"facet_neighbor.npy", npy_vector_header("<i8", facets_total), 8 * facets_total, 8 * facets_before, 8 * my_facets};
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

  // This rank's part of member k, a few MB at a time.
  auto produce = [&](std::size_t k, const std::function<void(std::string_view)>& emit) {
    std::string chunk;
    constexpr std::size_t kChunk = std::size_t{4} << 20;
    auto flush = [&](bool force) {
      if (chunk.size() >= kChunk || (force && !chunk.empty())) {
        emit(chunk);
        chunk.clear();
      }
    };
    auto put_raw = [&](const void* p, std::size_t bytes) { chunk.append(static_cast<const char*>(p), bytes); };
    std::int64_t ptr = static_cast<std::int64_t>(facets_before);
    if (k == 3 && comm.rank == 0) {
      const std::int64_t zero = 0;
      put_raw(&zero, 8);
    }
    for (const char* c : cell) {
      const char* p = c + 4;
      const std::uint32_t facets = get<std::uint32_t>(p);
      const char* bounded = p;
      const char* volume = p + 1;
      const char* centroid = volume + 8;
      const char* facet = centroid + 8 * dd;
      const std::size_t facet_bytes = 8 * (2 + dd);
      switch (k) {
        case 0: put_raw(volume, 8); break;
        case 1: put_raw(centroid, 8 * dd); break;
        case 2: put_raw(bounded, 1); break;
        case 3:
          ptr += facets;
          put_raw(&ptr, 8);
          break;
        default:
          for (std::uint32_t f = 0; f < facets; ++f) {
            const char* q = facet + f * facet_bytes;
            if (k == 4) put_raw(q, 8);
            else if (k == 5) put_raw(q + 8, 8);
            else put_raw(q + 16, 8 * dd);
          }
      }
      flush(false);
    }
    flush(true);
  };

  return write_file(comm, path, [&](const WriteAt& write_at) {
    Status s;
    // The data, each rank its parts, with their CRC-32s.
    std::vector<std::uint64_t> crcs(2 * m.size());  // (crc, length) per member
    for (std::size_t k = 0; k < m.size(); ++k) {
      uLong crc = crc32(0L, Z_NULL, 0);
      std::uint64_t at = zip[k].offset + zip_local_header_size(zip[k].name, zip[k].size) + m[k].header.size() + m[k].part_at;
      std::uint64_t done = 0;
      produce(k, [&](std::string_view piece) {
        crc = crc32_z(crc, reinterpret_cast<const Bytef*>(piece.data()), piece.size());
        if (s.is_ok()) s = write_at(at + done, piece);
        done += piece.size();
      });
      if (s.is_ok() && done != m[k].part_bytes) s = internal_error(path + ": internal error: a part changed size");
      crcs[2 * k] = crc;
      crcs[2 * k + 1] = done;
    }
    // Rank 0 combines the parts' CRCs in rank order after the header's, and writes the
    // local headers and the central directory.
    std::vector<std::uint64_t> all(comm.rank == 0 ? crcs.size() * static_cast<std::size_t>(comm.size) : 0);
    MPI_Gather(crcs.data(), static_cast<int>(crcs.size()), MPI_UINT64_T, all.data(), static_cast<int>(crcs.size()),
               MPI_UINT64_T, 0, comm.comm);
    if (comm.rank == 0) {
      for (std::size_t k = 0; k < m.size() && s.is_ok(); ++k) {
        uLong crc = crc32_z(crc32(0L, Z_NULL, 0), reinterpret_cast<const Bytef*>(m[k].header.data()), m[k].header.size());
        for (int r = 0; r < comm.size; ++r) {
          const std::uint64_t* part = &all[static_cast<std::size_t>(r) * crcs.size() + 2 * k];
          crc = crc32_combine64(crc, static_cast<uLong>(part[0]), static_cast<z_off64_t>(part[1]));
        }
        zip[k].crc = static_cast<std::uint32_t>(crc);
        s = write_at(zip[k].offset, zip_local_header(zip[k]));
        if (s.is_ok()) s = write_at(zip[k].offset + zip_local_header_size(zip[k].name, zip[k].size), m[k].header);
      }
      if (s.is_ok()) s = write_at(directory_at, zip_central_directory(zip, directory_at));
    }
    return s;
  });
}

}  // namespace spokemesh::mpi
