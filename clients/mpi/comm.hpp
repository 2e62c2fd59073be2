// The few collective steps spokemesh-mpi is made of, over Open MPI 4.1 (MPI 3.1):
// typed reductions, byte exchanges in pieces under 2 GiB (no large-count calls in
// 4.1), one Status agreed by every rank, and the job's traffic counters for --stats.
//
// Thread safety: MPI is initialised with MPI_THREAD_FUNNELED; every call here is made
// from the main thread.
#pragma once

#include <mpi.h>

#include <algorithm>
#include <climits>
#include <cstdint>
#include <cstring>
#include <string>
#include <type_traits>
#include <vector>

#include "spokemesh/status.hpp"

namespace spokemesh::mpi {

struct Comm {
  MPI_Comm comm = MPI_COMM_WORLD;
  int rank = 0, size = 1;
  std::uint64_t bytes_sent = 0, bytes_received = 0;  // point and row exchanges

  static Comm world() {
    Comm c;
    MPI_Comm_rank(MPI_COMM_WORLD, &c.rank);
    MPI_Comm_size(MPI_COMM_WORLD, &c.size);
    return c;
  }

  template <class T>
  static MPI_Datatype type() {
    if constexpr (std::is_same_v<T, double>)
      return MPI_DOUBLE;
    else if constexpr (std::is_same_v<T, std::uint64_t>)
      return MPI_UINT64_T;
    else if constexpr (std::is_same_v<T, std::int64_t>)
      return MPI_INT64_T;
    else if constexpr (std::is_same_v<T, std::uint32_t>)
      return MPI_UINT32_T;
    else if constexpr (std::is_same_v<T, int>)
      return MPI_INT;
    else
      static_assert(sizeof(T) == 0, "no MPI type");
  }

  template <class T>
  void allreduce(std::vector<T>& v, MPI_Op op) const {
    if (!v.empty()) MPI_Allreduce(MPI_IN_PLACE, v.data(), static_cast<int>(v.size()), type<T>(), op, comm);
  }
  template <class T>
  T allreduce(T v, MPI_Op op) const {
    MPI_Allreduce(MPI_IN_PLACE, &v, 1, type<T>(), op, comm);
    return v;
  }
  template <class T>
  T exscan_sum(T v) const {
    T out{};
    MPI_Exscan(&v, &out, 1, type<T>(), MPI_SUM, comm);
    return rank == 0 ? T{} : out;
  }
  // Element by element: the sums over the ranks before this one.
  template <class T>
  std::vector<T> exscan_sum(const std::vector<T>& v) const {
    std::vector<T> out(v.size(), T{});
    if (!v.empty()) MPI_Exscan(v.data(), out.data(), static_cast<int>(v.size()), type<T>(), MPI_SUM, comm);
    if (rank == 0) std::fill(out.begin(), out.end(), T{});
    return out;
  }

  // Every rank's bytes, concatenated in rank order (sizes of each in `counts`).
  std::vector<char> allgather_bytes(const std::vector<char>& mine, std::vector<std::uint64_t>& counts) const {
    counts.assign(static_cast<std::size_t>(size), 0);
    const std::uint64_t n = mine.size();
    MPI_Allgather(&n, 1, MPI_UINT64_T, counts.data(), 1, MPI_UINT64_T, comm);
    std::vector<int> c(static_cast<std::size_t>(size)), at(static_cast<std::size_t>(size));
    std::uint64_t total = 0;
    for (int r = 0; r < size; ++r) {
      c[static_cast<std::size_t>(r)] = static_cast<int>(counts[static_cast<std::size_t>(r)]);
      at[static_cast<std::size_t>(r)] = static_cast<int>(total);
      total += counts[static_cast<std::size_t>(r)];
    }
    std::vector<char> all(total);
    MPI_Allgatherv(mine.data(), static_cast<int>(n), MPI_CHAR, all.data(), c.data(), at.data(), MPI_CHAR, comm);
    return all;
  }

  // Sends out[r] to rank r and returns what every rank sent here, concatenated in
  // rank order. Rounds of MPI_Alltoallv, each under 1 GiB from any one rank to another,
  // so that counts fit an int.
  std::vector<char> alltoall_bytes(const std::vector<std::vector<char>>& out) {
    const auto p = static_cast<std::size_t>(size);
    std::vector<std::uint64_t> send_total(p), recv_total(p);
    for (std::size_t r = 0; r < p; ++r) send_total[r] = out[r].size();
    MPI_Alltoall(send_total.data(), 1, MPI_UINT64_T, recv_total.data(), 1, MPI_UINT64_T, comm);
    std::uint64_t received = 0;
    std::vector<std::uint64_t> recv_at(p);
    for (std::size_t r = 0; r < p; ++r) {
      recv_at[r] = received;
      received += recv_total[r];
      if (r != static_cast<std::size_t>(rank)) {
        bytes_sent += send_total[r];
        bytes_received += recv_total[r];
      }
    }
    std::vector<char> in(received);
    constexpr std::uint64_t kPiece = std::uint64_t{1} << 30;
    std::uint64_t most = 0;
    for (std::size_t r = 0; r < p; ++r) most = std::max({most, send_total[r], recv_total[r]});
    const std::uint64_t rounds = allreduce<std::uint64_t>((most + kPiece - 1) / kPiece, MPI_MAX);
    std::vector<int> sc(p), sd(p), rc(p), rd(p);
    std::vector<char> sendbuf, recvbuf;
    for (std::uint64_t round = 0; round < rounds; ++round) {
      sendbuf.clear();
      int rtotal = 0;
      for (std::size_t r = 0; r < p; ++r) {
        const std::uint64_t from = std::min(send_total[r], round * kPiece), to = std::min(send_total[r], from + kPiece);
        sd[r] = static_cast<int>(sendbuf.size());
        sc[r] = static_cast<int>(to - from);
        sendbuf.insert(sendbuf.end(), out[r].begin() + static_cast<std::ptrdiff_t>(from),
                       out[r].begin() + static_cast<std::ptrdiff_t>(to));
        const std::uint64_t rfrom = std::min(recv_total[r], round * kPiece);
        const std::uint64_t rto = std::min(recv_total[r], rfrom + kPiece);
        rd[r] = rtotal;
        rc[r] = static_cast<int>(rto - rfrom);
        rtotal += rc[r];
      }
      recvbuf.resize(static_cast<std::size_t>(rtotal));
      MPI_Alltoallv(sendbuf.data(), sc.data(), sd.data(), MPI_CHAR, recvbuf.data(), rc.data(), rd.data(), MPI_CHAR,
                    comm);
      for (std::size_t r = 0; r < p; ++r) {
        const std::uint64_t rfrom = std::min(recv_total[r], round * kPiece);
        std::memcpy(in.data() + recv_at[r] + rfrom, recvbuf.data() + rd[r], static_cast<std::size_t>(rc[r]));
      }
    }
    return in;
  }

  // The status every rank agrees on: OK if every rank's is; else the failure of the
  // lowest rank that failed (so an error in the input is reported once, and the first
  // one in file order when ranks read consecutive slices).
  Status agree(const Status& mine) const {
    const int failed = mine.is_ok() ? size : rank;
    const int first = allreduce<int>(failed, MPI_MIN);
    if (first == size) return Status::ok();
    int code = static_cast<int>(mine.code());
    MPI_Bcast(&code, 1, MPI_INT, first, comm);
    std::string text = rank == first ? mine.message() : std::string();
    std::uint64_t len = text.size();
    MPI_Bcast(&len, 1, MPI_UINT64_T, first, comm);
    text.resize(len);
    MPI_Bcast(text.data(), static_cast<int>(len), MPI_CHAR, first, comm);
    return Status{static_cast<Code>(code), text};
  }
};

// The ranks' slices of the index range [0, n): rank r reads, and writes the results of,
// indices [slice_begin(n, r, P), slice_begin(n, r + 1, P)).
inline std::uint64_t slice_begin(std::uint64_t n, int rank, int size) {
  // (n < 2^32 and P < 2^20: the product fits 64 bits.)
  return n * static_cast<std::uint64_t>(rank) / static_cast<std::uint64_t>(size);
}
// The rank whose slice holds index i.
inline int slice_owner(std::uint64_t n, std::uint64_t i, int size) {
  int r = static_cast<int>(i * static_cast<std::uint64_t>(size) / n);
  while (r + 1 < size && slice_begin(n, r + 1, size) <= i) ++r;
  while (r > 0 && slice_begin(n, r, size) > i) --r;
  return r;
}

// Appending and reading plain values in byte buffers.
template <class T>
void put(std::vector<char>& out, const T& v) {
  const auto* p = reinterpret_cast<const char*>(&v);
  out.insert(out.end(), p, p + sizeof(T));
}
template <class T>
T get(const char*& at) {
  T v;
  std::memcpy(&v, at, sizeof(T));
  at += sizeof(T);
  return v;
}

}  // namespace spokemesh::mpi
