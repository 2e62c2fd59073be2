#include "input.hpp"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <vector>

#include "spokemesh/io.hpp"
#include "spokemesh/point_set.hpp"

namespace spokemesh::mpi {
namespace {

Status read_at(MPI_File file, std::uint64_t offset, char* into, std::uint64_t bytes, const std::string& path) {
  constexpr std::uint64_t kPiece = std::uint64_t{1} << 30;  // no large-count calls in Open MPI 4.1
  while (bytes > 0) {
    const std::uint64_t piece = std::min(bytes, kPiece);
    MPI_Status st;
    if (MPI_File_read_at(file, static_cast<MPI_Offset>(offset), into, static_cast<int>(piece), MPI_CHAR, &st) !=
        MPI_SUCCESS) {
      return invalid_argument(path + ": read error");
    }
    int got = 0;
    MPI_Get_count(&st, MPI_CHAR, &got);
    if (static_cast<std::uint64_t>(got) != piece) return invalid_argument(path + ": truncated .npy data");
    offset += piece;
    into += piece;
    bytes -= piece;
  }
  return Status::ok();
}

Result<Slice> read_npy_slice(Comm& comm, const std::string& path) {
  // The CLI's words for a file that cannot be read (rank 0 looks; every rank agrees).
  Status readable;
  if (comm.rank == 0) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (f == nullptr)
      readable = invalid_argument(path + ": cannot open for reading (" + std::strerror(errno) + ")");
    else
      std::fclose(f);
  }
  if (Status s = comm.agree(readable); !s.is_ok()) return s;
  MPI_File file;
  if (MPI_File_open(comm.comm, path.c_str(), MPI_MODE_RDONLY, MPI_INFO_NULL, &file) != MPI_SUCCESS) {
    return invalid_argument(path + ": cannot open");  // every rank fails alike
  }
  Slice out;
  Status status;
  MPI_Offset size = 0;
  MPI_File_get_size(file, &size);
  std::string head(static_cast<std::size_t>(std::min<MPI_Offset>(size, 1 << 16)), '\0');
  status = read_at(file, 0, head.data(), head.size(), path);
  NpyPoints layout;
  if (status.is_ok()) {
    auto l = npy_points_layout(head, static_cast<std::uint64_t>(size), path);
    if (l.is_ok())
      layout = l.value();
    else
      status = l.status();
  }
  if (status.is_ok()) {
    out.n = layout.count;
    out.first = slice_begin(out.n, comm.rank, comm.size);
    const std::uint64_t rows = slice_begin(out.n, comm.rank + 1, comm.size) - out.first;
    const std::uint64_t row_bytes =
        static_cast<std::uint64_t>(layout.dimension) * static_cast<std::uint64_t>(layout.item_bytes);
    std::vector<char> bytes(rows * row_bytes);
    status = read_at(file, layout.data_offset + out.first * row_bytes, bytes.data(), bytes.size(), path);
    out.points.d = layout.dimension;
    if (status.is_ok()) status = decode_npy_rows(layout, bytes.data(), out.first, rows, out.points.coords, path);
    out.points.ids.resize(rows);
    for (std::uint64_t k = 0; k < rows; ++k) out.points.ids[k] = out.first + k;
  }
  MPI_File_close(&file);
  if (Status s = comm.agree(status); !s.is_ok()) return s;
  return out;
}

// Text: rank 0 parses the file (the CLI's reader and errors) and sends each rank its
// slice.
Result<Slice> read_text_slice(Comm& comm, const std::string& path) {
  PointSet all;
  Status status;
  if (comm.rank == 0) {
    auto read = read_points(path);
    if (read.is_ok())
      all = std::move(read).value();
    else
      status = read.status();
  }
  if (Status s = comm.agree(status); !s.is_ok()) return s;
  std::uint64_t shape[2] = {all.size(), static_cast<std::uint64_t>(all.dimension())};
  MPI_Bcast(shape, 2, MPI_UINT64_T, 0, comm.comm);
  Slice out;
  out.n = shape[0];
  out.points.d = static_cast<int>(shape[1]);
  out.first = slice_begin(out.n, comm.rank, comm.size);
  std::vector<std::vector<char>> outgoing(static_cast<std::size_t>(comm.size));
  if (comm.rank == 0) {
    for (int r = 0; r < comm.size; ++r) {
      const std::uint64_t a = slice_begin(out.n, r, comm.size), b = slice_begin(out.n, r + 1, comm.size);
      const char* from = reinterpret_cast<const char*>(all.point(a));
      outgoing[static_cast<std::size_t>(r)].assign(from, from + (b - a) * shape[1] * sizeof(double));
    }
    all = PointSet();
  }
  const std::vector<char> in = comm.alltoall_bytes(outgoing);
  out.points.coords.resize(in.size() / sizeof(double));
  std::memcpy(out.points.coords.data(), in.data(), in.size());
  const std::uint64_t rows = out.points.coords.size() / shape[1];
  out.points.ids.resize(rows);
  for (std::uint64_t k = 0; k < rows; ++k) out.points.ids[k] = out.first + k;
  return out;
}

}  // namespace

Result<Slice> read_slice(Comm& comm, const std::string& path) {
  const bool npy = path.size() >= 4 && path.compare(path.size() - 4, 4, ".npy") == 0;
  return npy ? read_npy_slice(comm, path) : read_text_slice(comm, path);
}

// The union of the slices' affine bases spans what the whole set spans.
Status check_set(Comm& comm, const Slice& slice, const std::string& path) {
  const int d = slice.points.d;
  Status status;
  if (d < 2 || d > 3) {
    status = invalid_argument(path + ": dimension " + std::to_string(d) +
                              " is not supported by spokemesh-mpi (2 or 3; mesh higher dimensions on one process "
                              "with spokemesh)");
  } else {
    status = PointSet::check_count(slice.n, d, path);
  }
  if (!status.is_ok()) return status;  // the same on every rank
  const PointSet mine(d, std::vector<double>(slice.points.coords));
  std::vector<char> basis;
  for (const std::uint32_t k : mine.affine_basis()) {
    const char* p = reinterpret_cast<const char*>(mine.point(k));
    basis.insert(basis.end(), p, p + d * sizeof(double));
  }
  std::vector<std::uint64_t> sizes;
  const std::vector<char> all = comm.allgather_bytes(basis, sizes);
  std::vector<double> coords(all.size() / sizeof(double));
  std::memcpy(coords.data(), all.data(), all.size());
  // The union of the slices' bases spans what the whole set spans: the same check,
  // and the same words, as one process.
  return PointSet(d, std::move(coords)).check_affine_span(path);
}

}  // namespace spokemesh::mpi
