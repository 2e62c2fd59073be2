#include "store_output.hpp"

#include <fcntl.h>
#include <openssl/evp.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

#include "spokemesh/data_dir.hpp"

namespace spokemesh::mpi {
namespace {

// Slices travel to rank 0 in messages of at most this many bytes (MPI counts are int).
constexpr std::size_t kMessageBytes = std::size_t{64} << 20;

}  // namespace

Result<std::pair<std::string, std::string>> write_set_file(Comm& comm, const std::string& dir, int d, std::uint64_t n,
                                                           std::span<const double> slice_coords) {
  const char* bytes = reinterpret_cast<const char*>(slice_coords.data());
  const std::size_t size = slice_coords.size() * sizeof(double);
  Status status;
  std::string id, tmp;
  if (comm.rank != 0) {
    // Sent when rank 0 asks for this rank's slice (the ranks in order), in messages
    // ended by an empty one.
    int go = 0;
    MPI_Recv(&go, 1, MPI_INT, 0, 7, comm.comm, MPI_STATUS_IGNORE);
    for (std::size_t at = 0; at < size;) {
      const std::size_t step = std::min(kMessageBytes, size - at);
      MPI_Send(bytes + at, static_cast<int>(step), MPI_CHAR, 0, 8, comm.comm);
      at += step;
    }
    MPI_Send(bytes, 0, MPI_CHAR, 0, 8, comm.comm);
  } else {
    tmp = data_dir::temp_name(dir, "mpi");
    const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    EVP_MD_CTX* sha = EVP_MD_CTX_new();
    EVP_DigestInit_ex(sha, EVP_sha256(), nullptr);
    bool ok = fd >= 0;
    std::string header(12, '\0');
    const auto d32 = static_cast<std::uint32_t>(d);
    std::memcpy(header.data(), &d32, 4);
    std::memcpy(header.data() + 4, &n, 8);
    auto take = [&](const char* data, std::size_t count) {
      EVP_DigestUpdate(sha, data, count);
      ok = ok && data_dir::write_all(fd, data, count) == 0;
    };
    take(header.data(), header.size());
    take(bytes, size);
    std::vector<char> buffer(kMessageBytes);
    for (int r = 1; r < comm.size; ++r) {
      int go = 1;
      MPI_Send(&go, 1, MPI_INT, r, 7, comm.comm);
      for (;;) {
        MPI_Status st;
        MPI_Recv(buffer.data(), static_cast<int>(buffer.size()), MPI_CHAR, r, 8, comm.comm, &st);
        int got = 0;
        MPI_Get_count(&st, MPI_CHAR, &got);
        if (got == 0) break;
        take(buffer.data(), static_cast<std::size_t>(got));
      }
    }
    unsigned char digest[32];
    unsigned int length = 0;
    EVP_DigestFinal_ex(sha, digest, &length);
    EVP_MD_CTX_free(sha);
    char hex[65];
    for (int i = 0; i < 32; ++i) std::snprintf(hex + 2 * i, 3, "%02x", digest[i]);
    id.assign(hex, 64);
    ok = ok && ::fsync(fd) == 0;
    if (fd >= 0) ::close(fd);
    if (!ok) {
      ::unlink(tmp.c_str());
      status = internal_error(dir + ": cannot write the set's file (" + std::strerror(errno) + ")");
    }
  }
  if (Status s = comm.agree(status); !s.is_ok()) return s;
  std::uint64_t lengths[2] = {id.size(), tmp.size()};
  MPI_Bcast(lengths, 2, MPI_UINT64_T, 0, comm.comm);
  id.resize(lengths[0]);
  tmp.resize(lengths[1]);
  MPI_Bcast(id.data(), static_cast<int>(lengths[0]), MPI_CHAR, 0, comm.comm);
  MPI_Bcast(tmp.data(), static_cast<int>(lengths[1]), MPI_CHAR, 0, comm.comm);
  return std::make_pair(id, tmp);
}

Status write_owner_map(Comm& comm, const std::string& path, std::uint64_t n,
                       const std::vector<std::pair<std::uint64_t, std::uint32_t>>& mine) {
  std::vector<std::vector<char>> outgoing(static_cast<std::size_t>(comm.size));
  for (const auto& [point, piece] : mine) {
    auto& to = outgoing[static_cast<std::size_t>(slice_owner(n, point, comm.size))];
    put<std::uint64_t>(to, point);
    put<std::uint32_t>(to, piece);
  }
  const std::vector<char> in = comm.alltoall_bytes(outgoing);
  outgoing = {};
  const std::uint64_t begin = slice_begin(n, comm.rank, comm.size), end = slice_begin(n, comm.rank + 1, comm.size);
  std::vector<std::uint32_t> slice(end - begin, 0xFFFFFFFFu);
  for (const char* at = in.data(); at < in.data() + in.size();) {
    const auto point = get<std::uint64_t>(at);
    slice[point - begin] = get<std::uint32_t>(at);
  }
  Status status;
  for (const std::uint32_t piece : slice) {
    if (piece == 0xFFFFFFFFu) {
      status = internal_error(path + ": a point of this rank's slice has no piece");
      break;
    }
  }
  if (status.is_ok()) {
    // Rank 0 sizes the file first (the others wait), then every rank writes its slice.
    if (comm.rank == 0) {
      const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
      if (fd < 0 || ::ftruncate(fd, static_cast<off_t>(n * 4)) != 0) {
        status = internal_error(path + ": cannot create: " + std::strerror(errno));
      }
      if (fd >= 0) ::close(fd);
    }
  }
  if (Status s = comm.agree(status); !s.is_ok()) return s;
  const int fd = ::open(path.c_str(), O_WRONLY | O_CLOEXEC);
  const std::size_t size = slice.size() * 4;
  const char* data = reinterpret_cast<const char*>(slice.data());
  for (std::size_t done = 0; fd >= 0 && done < size && status.is_ok();) {
    const ssize_t w = ::pwrite(fd, data + done, size - done, static_cast<off_t>(begin * 4 + done));
    if (w < 0 && errno != EINTR) status = internal_error(path + ": write failed: " + std::strerror(errno));
    if (w > 0) done += static_cast<std::size_t>(w);
  }
  if (fd < 0 || ::fsync(fd) != 0) status = internal_error(path + ": cannot write: " + std::strerror(errno));
  if (fd >= 0) ::close(fd);
  return comm.agree(status);
}

}  // namespace spokemesh::mpi
