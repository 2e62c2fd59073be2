#include "output.hpp"

#include <unistd.h>

#include <algorithm>

namespace spokemesh::mpi {

Status write_file(Comm& comm, const std::string& path, const std::function<Status(const WriteAt&)>& body) {
  std::string temp;
  if (comm.rank == 0) {
    temp = path + ".spokemesh-mpi-" + std::to_string(::getpid()) + ".tmp";
    std::remove(temp.c_str());
  }
  std::uint64_t len = temp.size();
  MPI_Bcast(&len, 1, MPI_UINT64_T, 0, comm.comm);
  temp.resize(len);
  MPI_Bcast(temp.data(), static_cast<int>(len), MPI_CHAR, 0, comm.comm);
  MPI_File file;
  if (MPI_File_open(comm.comm, temp.c_str(), MPI_MODE_CREATE | MPI_MODE_WRONLY, MPI_INFO_NULL, &file) != MPI_SUCCESS) {
    return comm.agree(internal_error(path + ": cannot create " + temp));
  }
  Status status;
  auto write_at = [&](std::uint64_t at, std::string_view bytes) {
    constexpr std::size_t kPiece = std::size_t{1} << 30;  // under 2 GiB a call (no large counts in 4.1)
    for (std::size_t from = 0; from < bytes.size() && status.is_ok(); from += kPiece) {
      const std::size_t count = std::min(kPiece, bytes.size() - from);
      MPI_Status st;
      const int rc = MPI_File_write_at(file, static_cast<MPI_Offset>(at + from), bytes.data() + from,
                                       static_cast<int>(count), MPI_CHAR, &st);
      if (rc != MPI_SUCCESS) {
        char text[MPI_MAX_ERROR_STRING];
        int text_len = 0;
        MPI_Error_string(rc, text, &text_len);
        status = internal_error(path + ": write failed (" + std::string(text, static_cast<std::size_t>(text_len)) +
                                "); " + path + " is left as it was");
      }
    }
    return status;
  };
  {
    Status s = body(write_at);
    if (status.is_ok()) status = s;
  }
  if (MPI_File_close(&file) != MPI_SUCCESS && status.is_ok()) status = internal_error(path + ": close failed");
  status = comm.agree(status);
  if (comm.rank == 0) {
    if (status.is_ok() && std::rename(temp.c_str(), path.c_str()) != 0) {
      status = internal_error(path + ": cannot rename " + temp + " into place");
    }
    if (!status.is_ok()) std::remove(temp.c_str());
  }
  return comm.agree(status);
}

Status write_ordered(Comm& comm, const std::string& path, std::uint64_t header_bytes, const std::string& header,
                     std::uint64_t body_bytes, const std::function<Status(const PieceWriter&)>& body) {
  std::uint64_t at = header_bytes + comm.exscan_sum<std::uint64_t>(body_bytes);
  const std::uint64_t end = at + body_bytes;
  return write_file(comm, path, [&](const WriteAt& write_at) {
    Status status;
    if (comm.rank == 0 && !header.empty()) status = write_at(0, header);
    if (status.is_ok()) {
      status = body([&](std::string_view piece) {
        Status s = write_at(at, piece);
        at += piece.size();
        return s;
      });
    }
    if (status.is_ok() && at != end)
      status = internal_error(path + ": internal error: a part changed size while written");
    return status;
  });
}

}  // namespace spokemesh::mpi
