#include "mesh_output.hpp"

#include <string_view>
#include <vector>

#include "output.hpp"

namespace spokemesh::mpi {

Status write_mesh_sections(Comm& comm, const std::string& path, MeshWriter::Format format, int d, std::uint64_t n,
                           std::span<const double> box, std::span<const double> slice_coords, std::uint64_t my_rows,
                           const RowVisitor& for_each_row, const std::function<const double*(std::uint32_t)>& point) {
  const auto dd = static_cast<std::size_t>(d);
  const std::uint64_t rows = comm.allreduce<std::uint64_t>(my_rows, MPI_SUM);
  const std::uint64_t row_base = comm.exscan_sum<std::uint64_t>(my_rows);
  const std::uint64_t first = slice_begin(n, comm.rank, comm.size);
  const std::size_t my_points = slice_coords.size() / dd;
  const MeshFileLayout layout(format, d, n, rows, box);
  const auto& sections = layout.sections();

  // This rank's part of section k, handed to `emit` a few MB at a time.
  auto produce = [&](std::size_t k, const std::function<void(const std::string&)>& emit) {
    constexpr std::size_t kChunk = std::size_t{8} << 20;
    const MeshFileLayout::Section& sec = sections[k];
    std::string out;
    auto flush = [&](bool force) {
      if (out.size() >= kChunk || (force && !out.empty())) {
        emit(out);
        out.clear();
      }
    };
    if (sec.kind == MeshFileLayout::Section::kText) {
      if (comm.rank == 0) out = sec.text;
    } else if (sec.kind == MeshFileLayout::Section::kPoints) {
      for (std::size_t i = 0; i < my_points; ++i) {
        layout.point_line(sec.variant, out, first + i, slice_coords.data() + i * dd);
        flush(false);
      }
    } else {
      std::uint64_t index = row_base;
      for_each_row([&](std::span<const std::uint32_t> row) {
        layout.row_line(sec.variant, out, row.data(), index++, point);
        flush(false);
      });
    }
    flush(true);
  };

  // Sizes first: where each rank's part of each section goes.
  const std::size_t count = sections.size();
  std::vector<std::uint64_t> mine(count, 0), before(count, 0), total(count, 0);
  for (std::size_t k = 0; k < count; ++k) produce(k, [&](const std::string& piece) { mine[k] += piece.size(); });
  MPI_Exscan(mine.data(), before.data(), static_cast<int>(count), MPI_UINT64_T, MPI_SUM, comm.comm);
  if (comm.rank == 0) std::fill(before.begin(), before.end(), 0);
  MPI_Allreduce(mine.data(), total.data(), static_cast<int>(count), MPI_UINT64_T, MPI_SUM, comm.comm);
  std::vector<std::uint64_t> at(count, 0);
  for (std::size_t k = 0, start = 0; k < count; start += total[k], ++k) at[k] = start + before[k];

  return write_file(comm, path, [&](const WriteAt& write_at) {
    Status s;
    for (std::size_t k = 0; k < count; ++k) {
      std::uint64_t done = 0;
      produce(k, [&](const std::string& piece) {
        if (s.is_ok()) s = write_at(at[k] + done, piece);
        done += piece.size();
      });
      if (s.is_ok() && done != mine[k])
        s = internal_error(path + ": internal error: a part changed size while written");
    }
    return s;
  });
}

}  // namespace spokemesh::mpi
