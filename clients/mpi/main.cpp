// spokemesh-mpi: one point set meshed by many processes, the same bytes as
// `spokemesh` writes (docs/distributed.md).
//
//   mpirun -np P spokemesh-mpi {mesh|graph} IN -o OUT [flags]
//
// Every rank reads a slice of IN (MPI-IO for .npy; rank 0 reads text and scatters);
// the ranks cut the set together into the nodes of SpaceSplit's recursion and deal
// them out in order; each rank fetches the others' points in a halo around its own,
// meshes its points' stars (RSD, the single-process sweep) and keeps the stars it can
// certify (certify.hpp); the others fetch a halo twice as deep, in rounds, until a
// reduction says none is left. Rows go to their place in the file by MPI-IO at computed
// offsets, written under a temporary name that rank 0 renames into OUT only after
// every rank succeeded.
//
// Exit codes (the CLI's): 0 success, 1 failure, 2 bad usage or bad input.
#include <malloc.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <numeric>
#include <optional>
#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstring>
#include <cstdio>
#include <fstream>
#include <functional>
#include <string_view>
#include <iostream>
#include <map>
#include <mutex>
#include <set>
#include <nlohmann/json.hpp>
#include <thread>

#include "commands.hpp"
#include "comm.hpp"
#include "split.hpp"
#include "spokemesh/certify.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/space_split.hpp"
#include "spokemesh/star.hpp"

namespace {

using namespace spokemesh;
using namespace spokemesh::cli;
using spokemesh::mpi::Comm;
using spokemesh::mpi::Points;
using spokemesh::mpi::TopSplit;
using Clock = std::chrono::steady_clock;

constexpr const char* kProgram = "spokemesh-mpi";

// ------------------------------------------------------------------ reading

// This rank's rows of IN: [first, first + count) of n, d coordinates each.
struct Slice {
  std::uint64_t n = 0, first = 0;
  Points points;
};

std::uint64_t slice_begin(std::uint64_t n, int rank, int size) {
  // (n < 2^32 and P < 2^20: the product fits 64 bits.)
  return n * static_cast<std::uint64_t>(rank) / static_cast<std::uint64_t>(size);
}

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
    if (f == nullptr) readable = invalid_argument(path + ": cannot open for reading (" + std::strerror(errno) + ")");
    else std::fclose(f);
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
    if (l.is_ok()) layout = l.value();
    else status = l.status();
  }
  if (status.is_ok()) {
    out.n = layout.count;
    out.first = slice_begin(out.n, comm.rank, comm.size);
    const std::uint64_t rows = slice_begin(out.n, comm.rank + 1, comm.size) - out.first;
    const std::uint64_t row_bytes = static_cast<std::uint64_t>(layout.dimension) * static_cast<std::uint64_t>(layout.item_bytes);
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
    if (read.is_ok()) all = std::move(read).value();
    else status = read.status();
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

// What PointSet::validate checks of a whole set, on slices: the dimension, the count
// and the affine span (the union of the slices' affine bases spans what the set
// spans). Duplicates are found by the split.
Status check_set(Comm& comm, const Slice& slice, const std::string& path) {
  const int d = slice.points.d;
  Status status;
  if (d < 2 || d > 3) {
    status = invalid_argument(path + ": dimension " + std::to_string(d) +
                              " is not supported by spokemesh-mpi (2 or 3; mesh higher dimensions on one process "
                              "with spokemesh)");
  } else if (slice.n < static_cast<std::uint64_t>(d) + 1) {
    status = invalid_argument(path + ": " + std::to_string(slice.n) + " points given; a " + std::to_string(d) +
                              "-d mesh needs at least " + std::to_string(d + 1));
  } else if (slice.n > 0xFFFFFFF0u) {
    status = invalid_argument(path + ": more than 2^32 - 16 points");
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

// ------------------------------------------------------------------ halos

// The rank's points (owned, then the others' fetched so far) and what it has asked for.
class Halo {
 public:
  Halo(Comm& comm, const TopSplit& split, std::vector<double> global_box)
      : comm_(comm), split_(split), d_(split.owned.d), global_(std::move(global_box)) {
    const std::size_t pieces = split.owned_nodes.size();
    held_.resize(pieces);
    depth_.resize(pieces);
    for (std::size_t p = 0; p < pieces; ++p) {
      const std::vector<double>& b = split.nodes[split.owned_nodes[p]].box;
      // A first halo of about 2.5 mean spacings of the node's points (a star's balls
      // reach about twice the spacing), or none when asked (tests of the rounds).
      double volume = 1, widest = 0;
      for (int c = 0; c < d_; ++c) {
        const double side = b[static_cast<std::size_t>(d_ + c)] - b[static_cast<std::size_t>(c)];
        widest = std::max(widest, side);
        volume *= side;
      }
      const double count = static_cast<double>(split.nodes[split.owned_nodes[p]].count);
      const double spacing = volume > 0 ? std::pow(volume / count, 1.0 / d_) : widest / count;
      spacing_.push_back(std::max(spacing, widest * 1e-9));
      depth_[p] = first_halo_factor_ * spacing_[p];
      held_[p] = grown(p);
    }
  }

  static void set_first_halo_factor(double f) { first_halo_factor_ = f; }

  std::span<const double> held_box(std::size_t piece) const { return held_[piece]; }
  // Boxes covering every point of the set that piece's seeds do not see: the other
  // ranks' nodes less the piece's held box.
  std::vector<double> unheld(std::size_t piece) const {
    std::vector<double> out;
    const std::vector<double>& q = held_[piece];
    const auto d = static_cast<std::size_t>(d_);
    for (const mpi::TopNode& node : split_.nodes) {
      if (node.owner == comm_.rank) continue;
      std::vector<double> rest = node.box;  // what is left of the node's box
      bool empty = false;
      for (std::size_t c = 0; c < d && !empty; ++c) {
        if (rest[c] < q[c]) {  // the part below the held box along c
          std::vector<double> part = rest;
          part[d + c] = std::min(rest[d + c], q[c]);
          out.insert(out.end(), part.begin(), part.end());
        }
        if (rest[d + c] > q[d + c]) {
          std::vector<double> part = rest;
          part[c] = std::max(rest[c], q[d + c]);
          out.insert(out.end(), part.begin(), part.end());
        }
        rest[c] = std::max(rest[c], q[c]);
        rest[d + c] = std::min(rest[d + c], q[d + c]);
        empty = rest[c] > rest[d + c];
      }
    }
    return out;
  }
  // The held boxes of the given pieces, as requests for fetch().
  std::vector<double> requests_of(const std::vector<std::size_t>& pieces) const {
    std::vector<double> out;
    for (const std::size_t p : pieces) out.insert(out.end(), held_[p].begin(), held_[p].end());
    return out;
  }

  // Exchanges this round's requests: boxes (2 d doubles each), every point inside
  // wanted; and hull facets (d points, the inner apex, then a box: (d + 3) d doubles
  // each), every point inside the box beyond or on the facet's plane wanted. Every rank answers each other
  // rank's requests with the points of its own that it has not sent that rank before,
  // found in `held_tree` (the round's tree of the held points; own_of_held maps its
  // indices to the rank's own points, kNone for the others') or, without one, in a
  // tree of its own points built for this exchange.
  static constexpr std::uint32_t kNone = 0xFFFFFFFFu;
  void fetch(const std::vector<double>& boxes, const std::vector<double>& facets, const std::vector<double>& balls,
             const KdTree* held_tree = nullptr, const std::vector<std::uint32_t>* own_of_held = nullptr) {
    const auto d = static_cast<std::size_t>(d_);
    std::vector<char> mine;
    for (const std::vector<double>* list : {&boxes, &facets, &balls}) {
      mpi::put<std::uint64_t>(mine, list->size());
      for (const double v : *list) mpi::put<double>(mine, v);
    }
    std::vector<std::uint64_t> sizes;
    const std::vector<char> all = comm_.allgather_bytes(mine, sizes);
    std::vector<std::vector<char>> outgoing(static_cast<std::size_t>(comm_.size));
    const Points& own = split_.owned;
    if (sent_.empty()) sent_.resize(static_cast<std::size_t>(comm_.size));
    // A tree of this rank's own points answers the requests; built for this exchange
    // and dropped after it, when the round's own structures are gone (it would
    // otherwise be the largest thing a rank keeps between rounds).
    bool asked = false;
    for (int r = 0; r < comm_.size; ++r) asked |= r != comm_.rank && sizes[static_cast<std::size_t>(r)] > 16;
    PointSet own_points;
    std::unique_ptr<KdTree> own_tree;
    const KdTree* search = held_tree;
    if (search == nullptr && asked && own.size() != 0) {
      own_points = PointSet(d_, std::vector<double>(own.coords));
      own_tree = std::make_unique<KdTree>(own_points);
      search = own_tree.get();
    }
    // The rank's own index of a point of the searched tree, or kNone.
    auto own_index = [&](std::uint32_t id) { return held_tree == nullptr ? id : (*own_of_held)[id]; };
    const char* at = all.data();
    for (int r = 0; r < comm_.size; ++r) {
      std::vector<double> box_list(mpi::get<std::uint64_t>(at));
      for (double& v : box_list) v = mpi::get<double>(at);
      std::vector<double> facet_list(mpi::get<std::uint64_t>(at));
      for (double& v : facet_list) v = mpi::get<double>(at);
      std::vector<double> ball_list(mpi::get<std::uint64_t>(at));
      for (double& v : ball_list) v = mpi::get<double>(at);
      if (r == comm_.rank || search == nullptr) continue;
      std::vector<char>& sent = sent_[static_cast<std::size_t>(r)];
      if (sent.empty()) sent.assign(own.size(), 0);
      std::vector<char>& o = outgoing[static_cast<std::size_t>(r)];
      auto give = [&](std::uint32_t id) {
        const std::uint32_t k = own_index(id);
        if (k == kNone || sent[k] != 0) return;
        sent[k] = 1;
        mpi::put<std::uint64_t>(o, own.ids[k]);
        for (std::size_t c = 0; c < d; ++c) mpi::put<double>(o, own.point(k)[c]);
      };
      for (std::size_t b = 0; b + 2 * d <= box_list.size(); b += 2 * d) {
        const double* q = &box_list[b];
        search->find_first(
            [&](const float* lo, const float* hi) {
              for (std::size_t c = 0; c < d; ++c) {
                if (static_cast<double>(hi[c]) < q[c] || static_cast<double>(lo[c]) > q[d + c]) return false;
              }
              return true;
            },
            [&](std::uint32_t k, const double* x) {
              if (contains(q, x)) give(k);
              return false;  // every one, not the first
            });
      }
      // Balls: every point within the radius, and a relative 1e-9 more (beyond the
      // radius search's rounding), so that no point on a sphere is missed.
      std::vector<std::pair<std::uint32_t, double>> found;
      for (std::size_t b = 0; b + d + 1 <= ball_list.size(); b += d + 1) {
        const double radius = ball_list[b + d] * (1 + 1e-9);
        search->within(&ball_list[b], radius * radius, found);
        for (const auto& [k, dist2] : found) give(k);
      }
      const std::size_t facet_words = (d + 3) * d;
      for (std::size_t f = 0; f + facet_words <= facet_list.size(); f += facet_words) {
        std::array<const double*, 3> vertex{};
        for (std::size_t v = 0; v < d; ++v) vertex[v] = &facet_list[f + v * d];
        const double* inner = &facet_list[f + d * d];
        const double* region = &facet_list[f + (d + 1) * d];
        search->find_first(
            [&](const float* lo, const float* hi) {
              double box[6];
              for (std::size_t c = 0; c < d; ++c) {
                box[c] = lo[c];
                box[d + c] = hi[c];
                if (box[d + c] < region[c] || box[c] > region[d + c]) return false;
              }
              return StarCertifier::may_be_beyond(d_, vertex.data(), inner, box);
            },
            [&](std::uint32_t k, const double* x) {
              if (contains(region, x) && StarCertifier::may_be_beyond_point(d_, vertex.data(), inner, x)) give(k);
              return false;
            });
      }
    }
    const std::vector<char> in = comm_.alltoall_bytes(outgoing);
    ghosts_.d = d_;
    for (const char* p = in.data(); p < in.data() + in.size();) {
      ghosts_.ids.push_back(mpi::get<std::uint64_t>(p));
      for (int c = 0; c < d_; ++c) ghosts_.coords.push_back(mpi::get<double>(p));
    }
  }

  const Points& ghosts() const { return ghosts_; }

 private:
  std::vector<double> grown(std::size_t p) const {
    std::vector<double> q = split_.nodes[split_.owned_nodes[p]].box;
    const auto d = static_cast<std::size_t>(d_);
    for (std::size_t c = 0; c < d; ++c) {
      q[c] = std::max(global_[c], q[c] - depth_[p]);
      q[d + c] = std::min(global_[d + c], q[d + c] + depth_[p]);
    }
    return q;
  }
  bool meets(const std::vector<double>& a, const std::vector<double>& b) const {
    const auto d = static_cast<std::size_t>(d_);
    for (std::size_t c = 0; c < d; ++c) {
      if (a[d + c] < b[c] || b[d + c] < a[c]) return false;
    }
    return true;
  }
  bool contains(const std::vector<double>& q, const double* x) const {
    const auto d = static_cast<std::size_t>(d_);
    for (std::size_t c = 0; c < d; ++c) {
      if (x[c] < q[c] || x[c] > q[d + c]) return false;
    }
    return true;
  }

  bool contains(const double* q, const double* x) const {
    const auto d = static_cast<std::size_t>(d_);
    for (std::size_t c = 0; c < d; ++c) {
      if (x[c] < q[c] || x[c] > q[d + c]) return false;
    }
    return true;
  }

  static inline double first_halo_factor_ = 2.5;
  Comm& comm_;
  const TopSplit& split_;
  int d_;
  std::vector<double> global_;
  std::vector<std::vector<double>> held_;
  std::vector<double> depth_, spacing_;
  Points ghosts_;
  std::vector<std::vector<char>> sent_;  // per rank: which owned points it has had
};

// The held points as one PointSet in global index order (so that every comparison of
// indices, and so every row, is as on one process).
struct LocalSet {
  PointSet points;
  std::vector<std::uint64_t> global;        // local index -> global index
  std::vector<std::uint32_t> local_of_own;  // owned k -> local index
  std::vector<std::int32_t> piece_of;       // local index -> owned piece, -1 for ghosts
};

LocalSet gather_local(const TopSplit& split, const Points& ghosts) {
  const Points& own = split.owned;
  const std::size_t n_own = own.size(), total = n_own + ghosts.size();
  const auto d = static_cast<std::size_t>(own.d);
  std::vector<std::pair<std::uint64_t, std::int64_t>> order(total);  // (global, own k or -1 - ghost k)
  for (std::size_t k = 0; k < n_own; ++k) order[k] = {own.ids[k], static_cast<std::int64_t>(k)};
  for (std::size_t k = 0; k < ghosts.size(); ++k) order[n_own + k] = {ghosts.ids[k], -1 - static_cast<std::int64_t>(k)};
  std::sort(order.begin(), order.end());
  LocalSet out;
  std::vector<double> coords(total * d);
  out.global.resize(total);
  out.local_of_own.resize(n_own);
  out.piece_of.assign(total, -1);
  std::vector<std::int32_t> piece_of_own(n_own);
  std::uint32_t begin = 0;
  for (std::size_t p = 0; p < split.piece_ends.size(); ++p) {
    for (std::uint32_t k = begin; k < split.piece_ends[p]; ++k) piece_of_own[k] = static_cast<std::int32_t>(p);
    begin = split.piece_ends[p];
  }
  for (std::size_t i = 0; i < total; ++i) {
    out.global[i] = order[i].first;
    const double* from;
    if (order[i].second >= 0) {
      const auto k = static_cast<std::size_t>(order[i].second);
      from = own.point(k);
      out.local_of_own[k] = static_cast<std::uint32_t>(i);
      out.piece_of[i] = piece_of_own[k];
    } else {
      from = ghosts.point(static_cast<std::size_t>(-1 - order[i].second));
    }
    std::copy(from, from + d, &coords[i * d]);
  }
  out.points = PointSet(own.d, std::move(coords));
  return out;
}

// ------------------------------------------------------------------ writing

// Writes every rank's part at its offset (after rank 0's `header`; every rank gives
// its size as header_bytes) into a temporary file beside `path`, renamed into place by
// rank 0 once every rank succeeded. A rank's part is `body_bytes` long and produced
// piece by piece by `body`, which hands each piece to the writer it is given (pieces
// of at most a few MB: nothing of the size of the output is held).
using PieceWriter = std::function<Status(std::string_view)>;
Status write_ordered(Comm& comm, const std::string& path, std::uint64_t header_bytes, const std::string& header,
                     std::uint64_t body_bytes, const std::function<Status(const PieceWriter&)>& body) {
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
  if (comm.rank == 0 && !header.empty()) status = write_at(0, header);
  std::uint64_t at = header_bytes + comm.exscan_sum<std::uint64_t>(body_bytes);
  const std::uint64_t end = at + body_bytes;
  if (status.is_ok()) {
    status = body([&](std::string_view piece) {
      Status s = write_at(at, piece);
      at += piece.size();
      return s;
    });
  }
  if (status.is_ok() && at != end) status = internal_error(path + ": internal error: a part changed size while written");
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

// Rows kept on disk until the end (an anonymous temporary file, as the CLI spools
// .vtu): each row's d + 1 indices, then its owner's sweep position.
class Spool {
 public:
  explicit Spool(std::size_t width) : width_(width), file_(std::tmpfile()) {}
  ~Spool() {
    if (file_ != nullptr) std::fclose(file_);
  }
  Spool(const Spool&) = delete;
  Spool& operator=(const Spool&) = delete;
  bool ok() const { return file_ != nullptr && std::ferror(file_) == 0; }
  void append(std::span<const std::uint32_t> words) {
    if (file_ != nullptr) std::fwrite(words.data(), sizeof(std::uint32_t), words.size(), file_);
    rows_ += words.size() / (width_ + 1);
  }
  std::uint64_t rows() const { return rows_; }
  // Calls f(row, position) for every row in order.
  template <class F>
  void for_each(F&& f) {
    if (file_ == nullptr) return;
    std::fflush(file_);
    std::rewind(file_);
    std::vector<std::uint32_t> chunk((width_ + 1) * 65536);
    for (;;) {
      const std::size_t got = std::fread(chunk.data(), sizeof(std::uint32_t), chunk.size(), file_);
      for (std::size_t at = 0; at + width_ + 1 <= got; at += width_ + 1) {
        f(std::span<const std::uint32_t>(chunk.data() + at, width_), chunk[at + width_]);
      }
      if (got < chunk.size()) break;
    }
  }

 private:
  std::size_t width_;
  std::FILE* file_;
  std::uint64_t rows_ = 0;
};

// ------------------------------------------------------------------ the run

struct RankStats {
  std::uint64_t owned = 0, ghosts = 0, rounds = 0, bytes_sent = 0, bytes_received = 0, peak_rss = 0;
  double seconds = 0;
};

// Debugging aid (SPOKEMESH_MPI_DEBUG): the peak so far at a named point.
void note_peak(const Comm& comm, const char* where) {
  if (std::getenv("SPOKEMESH_MPI_DEBUG") == nullptr) return;
  rusage u{};
  ::getrusage(RUSAGE_SELF, &u);
  static const auto t0 = Clock::now();
  std::fprintf(stderr, "rank %d peak %ld MB at %s, %.2f s\n", comm.rank, u.ru_maxrss / 1024, where,
               std::chrono::duration<double>(Clock::now() - t0).count());
}

std::uint64_t peak_rss_bytes() {
  rusage u{};
  ::getrusage(RUSAGE_SELF, &u);
  return static_cast<std::uint64_t>(u.ru_maxrss) * 1024;
}

enum class Job { kMesh, kGraph };

int run(Comm& comm, Job job, const WholeCommands& w, const std::string& stats_path) {
  const auto start = Clock::now();
  const std::string& input = w.input;
  const bool quiet = w.common.quiet || comm.rank != 0;
  auto report_all = [&](const Status& s) {
    if (comm.rank == 0) return report(s, kProgram);
    return exit_code(s);
  };
  // Usage checks, alike on every rank.
  Status usage;
  if (w.common.merge_duplicates) usage = invalid_argument("--merge-duplicates: spokemesh-mpi does not merge duplicates; remove them, or mesh on one process with spokemesh");
  if (job == Job::kGraph && w.approx.enabled) usage = invalid_argument("--approx: spokemesh-mpi computes exact graphs only; approximate graphs run on one process (spokemesh graph --approx)");
  {
    auto format = MeshWriter::format_for(w.output, 3);
    if (usage.is_ok() && format.is_ok() && format.value() != MeshWriter::Format::kText &&
        format.value() != MeshWriter::Format::kNpy) {
      usage = invalid_argument(w.output + ": spokemesh-mpi writes text (.simplices, .txt, .edges) and .npy; write "
                               ".vtu, .msh and .svg on one process with spokemesh");
    } else if (usage.is_ok() && !format.is_ok()) {
      usage = format.status();
    }
  }
  if (usage.is_ok() && comm.rank == 0) usage = check_not_input(input, w.output);
  if (usage.is_ok() && comm.rank == 0) {
    // The CLI opens its output before meshing: a run that cannot write says so first.
    const std::string probe = w.output + ".spokemesh-mpi-probe-" + std::to_string(::getpid());
    if (std::FILE* f = std::fopen(probe.c_str(), "wb"); f != nullptr) {
      std::fclose(f);
      std::remove(probe.c_str());
    } else {
      usage = invalid_argument(w.output + ": cannot open for writing (" + std::strerror(errno) + ")");
    }
  }
  if (Status s = comm.agree(usage); !s.is_ok()) return report_all(s);

  note_peak(comm, "start");
  const bool npy = input.size() >= 4 && input.compare(input.size() - 4, 4, ".npy") == 0;
  auto slice_or = npy ? read_npy_slice(comm, input) : read_text_slice(comm, input);
  if (!slice_or.is_ok()) return report_all(slice_or.status());
  Slice slice = std::move(slice_or).value();
  if (Status s = check_set(comm, slice, input); !s.is_ok()) return report_all(s);
  const int d = slice.points.d;
  const auto dd = static_cast<std::size_t>(d);
  const std::uint64_t n = slice.n;
  std::pair<std::uint32_t, std::uint32_t> seed_range{0, static_cast<std::uint32_t>(n)};
  if (job == Job::kMesh && !w.seeds.empty()) {
    auto range = parse_seed_range(w.seeds, n);
    if (!range.is_ok()) return report_all(range.status());
    seed_range = range.value();
  }
  // The whole set's box (the halos stop at it).
  std::vector<double> global_box(2 * dd, std::numeric_limits<double>::infinity());
  for (std::size_t k = 0; k < slice.points.size(); ++k) {
    for (std::size_t c = 0; c < dd; ++c) {
      global_box[c] = std::min(global_box[c], slice.points.point(k)[c]);
      global_box[dd + c] = std::min(global_box[dd + c], -slice.points.point(k)[c]);
    }
  }
  comm.allreduce(global_box, MPI_MIN);
  for (std::size_t c = 0; c < dd; ++c) global_box[dd + c] = -global_box[dd + c];

  // The top of the split, dealt out: nodes of at most n / (32 P) points keep every
  // rank within 1/32 of its share.
  // (One process takes the whole set as one piece.)
  const std::uint64_t target =
      comm.size == 1 ? n
                     : std::max<std::uint64_t>(SpaceSplit::kLeafPoints, (n + 32ull * static_cast<unsigned>(comm.size) - 1) /
                                                                            (32ull * static_cast<unsigned>(comm.size)));
  auto split_or = mpi::split_across_ranks(comm, std::move(slice.points), n, target, input);
  if (!split_or.is_ok()) return report_all(split_or.status());
  const TopSplit split = std::move(split_or).value();
  note_peak(comm, "split");
  const std::size_t owned = split.owned.size();

  Halo halo(comm, split, global_box);
  std::vector<std::size_t> all_pieces(split.owned_nodes.size());
  std::iota(all_pieces.begin(), all_pieces.end(), std::size_t{0});
  halo.fetch(halo.requests_of(all_pieces), {}, {});

  // Rows of certified seeds, by the owner's sweep position; stars refused are done again
  // with more points, in rounds.
  struct Rows {
    std::uint32_t position;
    std::vector<std::uint32_t> rows;  // global indices
  };
  std::vector<Rows> done;          // seeds certified after the first round
  std::vector<std::uint32_t> rows;  // graph: the edges found
  Spool spool(job == Job::kMesh ? dd + 1 : 2);  // mesh: the first round's rows, in sweep order
  std::vector<std::uint32_t> position_of_own(owned);
  // What a refused seed asks for: the box around its uncertified balls (doubling each
  // round it is refused again), and its hull facets' outer sides.
  std::map<std::uint32_t, std::vector<double>> reach;  // owned k -> box
  std::map<std::uint32_t, std::vector<double>> asked_balls;  // owned k -> balls fetched (d + 1 doubles each)
  std::set<std::vector<std::uint64_t>> known_hull;       // facets (global indices) whose outer side was fetched
  // The region of each asked hull facet's outer side fetched so far: it doubles round by
  // round; once it holds the whole set's box, the facet is known (a true hull facet's
  // outer side is empty, so the answers stay empty and cheap).
  std::map<std::vector<std::uint64_t>, std::vector<double>> hull_region;
  std::vector<std::uint32_t> pending;                    // owned k refused in the last round
  RankStats stats;
  std::mutex mu;
  Status failure;
  Progress progress(quiet, owned, "meshing (rank 0's share)");
  const std::size_t w1 = job == Job::kMesh ? dd + 1 : 2;

  // Emits the certified star's rows (mesh: its owned simplices; graph: edges to larger
  // indices), in global indices.
  auto rows_of = [&](const LocalSet& local, const Star& star, std::vector<std::uint32_t>& out) {
    const auto to_global = [&](std::uint32_t v) { return static_cast<std::uint32_t>(local.global[v]); };
    if (job == Job::kMesh) {
      const std::uint64_t g = local.global[star.seed];
      if (g < seed_range.first || g >= seed_range.second) return;
      for (const std::uint32_t v : owned_simplices(star)) out.push_back(to_global(v));
    } else {
      std::vector<std::uint32_t> next;
      for (const std::uint32_t v : star.simplices) {
        if (v > star.seed) next.push_back(v);
      }
      std::sort(next.begin(), next.end());
      next.erase(std::unique(next.begin(), next.end()), next.end());
      for (const std::uint32_t v : next) {
        out.push_back(to_global(star.seed));
        out.push_back(to_global(v));
      }
    }
  };
  auto covers_all = [&](const std::vector<double>& box) {
    for (std::size_t c = 0; c < dd; ++c) {
      if (box[c] > global_box[c] || box[dd + c] < global_box[dd + c]) return false;
    }
    return true;
  };

  // The held points and their tree, kept from round to round until new points
  // arrive (the rounds of hull facets mostly fetch none); the tree also answers the
  // other ranks' requests.
  std::optional<LocalSet> held_set;
  std::unique_ptr<KdTree> held_tree;
  std::vector<std::uint32_t> own_of_local;
  std::size_t ghosts_held = 0;
  bool spans = false;
  for (int round = 1;; ++round) {
    stats.rounds = static_cast<std::uint64_t>(round);
    std::vector<double> boxes, facets, balls;  // this round's requests
    std::vector<std::vector<std::uint64_t>> asked;
    std::uint64_t left = 0;
    {
    if (!held_set || halo.ghosts().size() != ghosts_held) {
      held_tree.reset();
      held_set.reset();
      held_set.emplace(gather_local(split, halo.ghosts()));
      ghosts_held = halo.ghosts().size();
      PointSet& fresh = held_set->points;
      spans = fresh.size() > dd && fresh.validate(input, 3, false).is_ok() && fresh.check_affine_span(input).is_ok();
      own_of_local.assign(fresh.size(), Halo::kNone);
      for (std::size_t k = 0; k < owned; ++k) own_of_local[held_set->local_of_own[k]] = static_cast<std::uint32_t>(k);
      if (round > 1 && spans) held_tree = std::make_unique<KdTree>(fresh);
    }
    LocalSet& local = *held_set;
    PointSet& points = local.points;
    std::vector<std::vector<double>> unheld(split.owned_nodes.size());
    for (std::size_t p = 0; p < unheld.size(); ++p) unheld[p] = halo.unheld(p);
    std::vector<std::pair<std::uint32_t, StarCertificate>> refused;  // owned k
    const StarCertifier certifier(points, global_box);
    auto is_known = [&](std::span<const std::uint32_t> facet) {
      std::vector<std::uint64_t> key(facet.size());
      for (std::size_t i = 0; i < facet.size(); ++i) key[i] = local.global[facet[i]];
      return known_hull.count(key) != 0;
    };
    auto certify = [&](const Star& star) {
      const std::uint32_t k = own_of_local[star.seed];
      const auto piece = static_cast<std::size_t>(local.piece_of[star.seed]);
      std::vector<double> held(halo.held_box(piece).begin(), halo.held_box(piece).end());
      bool everything = false;
      if (const auto it = reach.find(k); it != reach.end()) {
        held.insert(held.end(), it->second.begin(), it->second.end());
        everything = covers_all(it->second);
      }
      const std::vector<double> none;
      const auto fetched = asked_balls.find(k);
      return certifier.certify(star, held, fetched != asked_balls.end() ? fetched->second : none,
                               everything ? none : unheld[piece], is_known);
    };
    if (owned != 0 && spans) {
      if (round == 1) {
        // The first round is the single-process sweep over this rank's pieces.
        std::vector<std::uint32_t> members(owned);
        for (std::size_t k = 0; k < owned; ++k) members[k] = local.local_of_own[k];
        const SpaceSplit sweep(points, members, split.piece_ends, SpaceSplit::default_block_points(d, n));
        for (std::size_t k = 0; k < owned; ++k) position_of_own[k] = sweep.position_of(local.local_of_own[k]);
        note_peak(comm, "local split");
        held_tree = std::make_unique<KdTree>(points);
        const KdTree& tree = *held_tree;
        note_peak(comm, "tree");
        MeshOptions options;
        options.threads = w.common.threads;
        options.split = &sweep;
        options.sweep_end = sweep.swept();
        options.star.random_seed = w.common.random_seed;
        options.facet_cache_bytes = w.common.cache_mb << 20;
        // The stars share their wraps (the sweep's memo): a wrap a refused star found
        // is still one of the held points' Delaunay triangulation, which every star
        // here is computed in.
        options.accept = [&](const Star& star) {
          StarCertificate c = certify(star);
          if (c.certified && job == Job::kMesh) return true;  // its rows come through the sink
          std::vector<std::uint32_t> out;
          if (c.certified) rows_of(local, star, out);
          std::lock_guard lock(mu);
          if (!c.certified) {
            refused.emplace_back(own_of_local[star.seed], std::move(c));
            return false;
          }
          rows.insert(rows.end(), out.begin(), out.end());
          return true;
        };
        std::uint64_t written = 0;
        auto result = mesh_seeds(tree, options, [&](std::span<const std::uint32_t> block, std::uint64_t seeds_done) {
          progress.update(seeds_done, written);
          if (job != Job::kMesh) return Status::ok();
          std::vector<std::uint32_t> words;
          words.reserve(block.size() / w1 * (w1 + 1));
          for (std::size_t i = 0; i < block.size(); i += w1) {
            const std::uint64_t g = local.global[block[i]];
            if (g < seed_range.first || g >= seed_range.second) continue;
            for (std::size_t j = 0; j < w1; ++j) words.push_back(static_cast<std::uint32_t>(local.global[block[i + j]]));
            words.push_back(sweep.position_of(block[i]));
            ++written;
          }
          spool.append(words);
          return spool.ok() ? Status::ok() : internal_error("cannot write the temporary spool file");
        });
        if (!result.is_ok()) failure = result.status();
        note_peak(comm, "mesh");
      } else {
        // Later rounds: only the refused seeds, each star on its own.
        const KdTree& tree = *held_tree;
        std::vector<std::thread> pool;
        std::size_t next = 0;
        for (unsigned t = 0; t < std::max(1u, w.common.threads); ++t) {
          pool.emplace_back([&] {
            StarOptions star_options;
            star_options.random_seed = w.common.random_seed;
            StarWalker walker(tree, star_options);
            Star star;
            std::vector<std::uint32_t> out;
            for (;;) {
              std::uint32_t k;
              {
                std::lock_guard lock(mu);
                if (next >= pending.size() || !failure.is_ok()) return;
                k = pending[next++];
              }
              Status s = walker.compute(local.local_of_own[k], star, StarPart::kAll);
              StarCertificate c;
              if (s.is_ok()) c = certify(star);
              out.clear();
              if (c.certified) rows_of(local, star, out);
              std::lock_guard lock(mu);
              if (!s.is_ok()) {
                failure = s;
                return;
              }
              if (c.certified) {
                done.push_back({position_of_own[k], out});
              } else {
                refused.emplace_back(k, std::move(c));
              }
            }
          });
        }
        for (auto& t : pool) t.join();
      }
    } else if (owned != 0) {
      // Too few held points to span the space: every star waits for more.
      if (round == 1) {
        std::vector<std::uint32_t> members(owned);
        for (std::size_t k = 0; k < owned; ++k) members[k] = local.local_of_own[k];
        const SpaceSplit sweep(points, members, split.piece_ends, SpaceSplit::default_block_points(d, n));
        for (std::size_t k = 0; k < owned; ++k) position_of_own[k] = sweep.position_of(local.local_of_own[k]);
        for (std::size_t k = 0; k < owned; ++k) pending.push_back(static_cast<std::uint32_t>(k));
      }
      for (const std::uint32_t k : pending) {
        StarCertificate c;
        const double* x = split.owned.point(k);
        c.reach.assign(x, x + d);
        c.reach.insert(c.reach.end(), x, x + d);
        refused.emplace_back(k, std::move(c));
      }
    }
    stats.ghosts = halo.ghosts().size();
    if (Status s = comm.agree(failure); !s.is_ok()) return report_all(s);
    pending.clear();
    for (auto& [k, c] : refused) {
      pending.push_back(k);
      if (!c.balls.empty()) {
        std::vector<double>& mine = asked_balls[k];
        mine.insert(mine.end(), c.balls.begin(), c.balls.end());
        balls.insert(balls.end(), c.balls.begin(), c.balls.end());
      }
      if (!c.reach.empty()) {
        // The new box holds the balls that failed and, refused again, twice the last
        // box around the seed: the boxes grow until every ball fits (or the whole set
        // is held).
        std::vector<double>& box = reach[k];
        const double* x = split.owned.point(k);
        if (!box.empty()) {
          for (std::size_t c2 = 0; c2 < dd; ++c2) {
            const double half = std::max(x[c2] - box[c2], box[dd + c2] - x[c2]);
            c.reach[c2] = std::min(c.reach[c2], x[c2] - 2 * half);
            c.reach[dd + c2] = std::max(c.reach[dd + c2], x[c2] + 2 * half);
          }
        } else {
          // A first box a little beyond the balls, so that a ball grown by a new point
          // of it is often still inside.
          for (std::size_t c2 = 0; c2 < dd; ++c2) {
            const double pad = (c.reach[dd + c2] - c.reach[c2]) * 0.25;
            c.reach[c2] -= pad;
            c.reach[dd + c2] += pad;
          }
        }
        box = c.reach;
        boxes.insert(boxes.end(), box.begin(), box.end());
      }
      for (std::size_t f = 0; f + dd + 1 <= c.hull_facets.size(); f += dd + 1) {
        std::vector<std::uint64_t> key(dd);
        for (std::size_t v = 0; v < dd; ++v) {
          const std::uint32_t local_v = c.hull_facets[f + v];
          key[v] = local.global[local_v];
          facets.insert(facets.end(), points.point(local_v), points.point(local_v) + d);
        }
        const std::uint32_t apex = c.hull_facets[f + dd];
        facets.insert(facets.end(), points.point(apex), points.point(apex) + d);
        std::vector<double>& region = hull_region[key];
        const double* x = split.owned.point(k);
        // A first region of four times the facet's size around the seed (a facet facing
        // other points fetches what lies just beyond it), growing fourfold while it is
        // asked again (a true hull facet's answers are empty, so only rounds are spent).
        std::vector<double> last = region;
        const bool last_was_asked = !last.empty();
        if (last.empty()) {
          last.assign(x, x + d);
          last.insert(last.end(), x, x + d);
          for (std::size_t v = 0; v <= dd; ++v) {
            const double* p = points.point(c.hull_facets[f + v]);
            for (std::size_t c2 = 0; c2 < dd; ++c2) {
              last[c2] = std::min(last[c2], p[c2]);
              last[dd + c2] = std::max(last[dd + c2], p[c2]);
            }
          }
        }
        region.assign(2 * dd, 0);
        for (std::size_t c2 = 0; c2 < dd; ++c2) {
          const double half = std::max({x[c2] - last[c2], last[dd + c2] - x[c2], 0.0});
          // Asked again, the facet is likely a true hull facet, whose answers stay
          // empty however large the region: 16x.
          const double grow = last_was_asked ? 16 : 4;
          region[c2] = x[c2] - grow * half;
          region[dd + c2] = x[c2] + grow * half;
        }
        facets.insert(facets.end(), region.begin(), region.end());
        if (covers_all(region)) asked.push_back(std::move(key));
      }
    }
    std::sort(pending.begin(), pending.end());
    pending.erase(std::unique(pending.begin(), pending.end()), pending.end());
    left = comm.allreduce<std::uint64_t>(pending.size(), MPI_SUM);
    if (std::getenv("SPOKEMESH_MPI_DEBUG") != nullptr) {
      std::fprintf(stderr,
                   "rank %d round %d: %zu owned, %zu held, %zu refused (all ranks: %llu), %zu boxes, %zu balls, %zu "
                   "facets asked\n",
                   comm.rank, round, owned, points.size(), pending.size(), static_cast<unsigned long long>(left),
                   boxes.size() / (2 * dd), balls.size() / (dd + 1), facets.size() / ((dd + 3) * dd));
    }
    }
    if (left == 0) break;
    halo.fetch(boxes, facets, balls, held_tree.get(), &own_of_local);
    // Every point beyond or on an asked facet's plane is held now: if the facet is
    // still on the hull of the held points, it is on the whole set's.
    for (auto& key : asked) known_hull.insert(std::move(key));
  }
  progress.finish();

  // The rows in order (mesh: the first round's, with the later rounds' seeds in
  // place), handed to `emit` one by one.
  std::vector<std::pair<std::uint32_t, std::uint32_t>> edges;
  std::function<void(const std::function<void(std::span<const std::uint32_t>)>&)> for_each_row;
  std::uint64_t my_rows = 0;
  if (job == Job::kMesh) {
    std::sort(done.begin(), done.end(), [](const Rows& a, const Rows& b) { return a.position < b.position; });
    for (const Rows& r : done) my_rows += r.rows.size() / w1;
    my_rows += spool.rows();
    for_each_row = [&](const std::function<void(std::span<const std::uint32_t>)>& emit) {
      std::size_t next_done = 0;
      auto late = [&](const Rows& r) {
        for (std::size_t i = 0; i < r.rows.size(); i += w1) emit(std::span<const std::uint32_t>(r.rows.data() + i, w1));
      };
      spool.for_each([&](std::span<const std::uint32_t> row, std::uint32_t position) {
        while (next_done < done.size() && done[next_done].position < position) late(done[next_done++]);
        emit(row);
      });
      while (next_done < done.size()) late(done[next_done++]);
    };
  } else {
    // Edges to the rank holding their first index's slice of the index range, sorted
    // there: the file is then the ranks' parts in order.
    for (const Rows& r : done) rows.insert(rows.end(), r.rows.begin(), r.rows.end());
    done = {};
    std::vector<std::vector<char>> outgoing(static_cast<std::size_t>(comm.size));
    for (std::size_t i = 0; i < rows.size(); i += 2) {
      int r = static_cast<int>(std::uint64_t{rows[i]} * static_cast<std::uint64_t>(comm.size) / n);
      while (r + 1 < comm.size && slice_begin(n, r + 1, comm.size) <= rows[i]) ++r;
      while (r > 0 && slice_begin(n, r, comm.size) > rows[i]) --r;
      mpi::put<std::uint32_t>(outgoing[static_cast<std::size_t>(r)], rows[i]);
      mpi::put<std::uint32_t>(outgoing[static_cast<std::size_t>(r)], rows[i + 1]);
    }
    rows = {};
    const std::vector<char> in = comm.alltoall_bytes(outgoing);
    outgoing = {};
    edges.resize(in.size() / 8);
    const char* at = in.data();
    for (auto& e : edges) {
      e.first = mpi::get<std::uint32_t>(at);
      e.second = mpi::get<std::uint32_t>(at);
    }
    std::sort(edges.begin(), edges.end());
    my_rows = edges.size();
    for_each_row = [&](const std::function<void(std::span<const std::uint32_t>)>& emit) {
      for (const auto& e : edges) {
        const std::uint32_t pair[2] = {e.first, e.second};
        emit(pair);
      }
    };
  }

  note_peak(comm, "rounds done");
  // The file: the CLI's bytes, sized in a first pass over the rows and written in a
  // second, a few MB at a time.
  const std::uint64_t total_rows = comm.allreduce<std::uint64_t>(my_rows, MPI_SUM);
  auto format = MeshWriter::format_for(w.output, d);
  const bool as_npy = format.is_ok() && format.value() == MeshWriter::Format::kNpy;
  std::string header;
  std::uint64_t header_bytes = 0, body_bytes = 0;
  if (as_npy) {
    if (comm.rank == 0) header = npy_header("<i8", total_rows, w1);
    header_bytes = kNpyHeaderBytes;
    body_bytes = my_rows * w1 * sizeof(std::int64_t);
  } else {
    std::string line;
    for_each_row([&](std::span<const std::uint32_t> row) {
      line.clear();
      append_index_lines(line, row, static_cast<int>(w1));
      body_bytes += line.size();
    });
  }
  Status written = write_ordered(comm, w.output, header_bytes, header, body_bytes, [&](const PieceWriter& put_piece) {
    constexpr std::size_t kChunk = std::size_t{8} << 20;
    std::string chunk;
    Status s;
    for_each_row([&](std::span<const std::uint32_t> row) {
      if (!s.is_ok()) return;
      if (as_npy) {
        for (const std::uint32_t v : row) {
          const std::int64_t wide = v;
          chunk.append(reinterpret_cast<const char*>(&wide), sizeof wide);  // little-endian host, as MeshWriter
        }
      } else {
        append_index_lines(chunk, row, static_cast<int>(w1));
      }
      if (chunk.size() >= kChunk) {
        s = put_piece(chunk);
        chunk.clear();
      }
    });
    if (s.is_ok() && !chunk.empty()) s = put_piece(chunk);
    return s;
  });
  if (!written.is_ok()) return report_all(written);
  note_peak(comm, "written");

  stats.owned = owned;
  stats.bytes_sent = comm.bytes_sent;
  stats.bytes_received = comm.bytes_received;
  stats.peak_rss = peak_rss_bytes();
  stats.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  std::vector<double> mine{static_cast<double>(stats.owned),      static_cast<double>(stats.ghosts),
                           static_cast<double>(stats.rounds),     static_cast<double>(stats.bytes_sent),
                           static_cast<double>(stats.bytes_received), static_cast<double>(stats.peak_rss),
                           stats.seconds};
  std::vector<double> every(comm.rank == 0 ? mine.size() * static_cast<std::size_t>(comm.size) : 0);
  MPI_Gather(mine.data(), static_cast<int>(mine.size()), MPI_DOUBLE, every.data(), static_cast<int>(mine.size()),
             MPI_DOUBLE, 0, comm.comm);
  Status stats_status;
  if (comm.rank == 0) {
    std::uint64_t ghosts = 0, most_rounds = 0;
    nlohmann::json ranks = nlohmann::json::array();
    for (int r = 0; r < comm.size; ++r) {
      const double* v = &every[static_cast<std::size_t>(r) * mine.size()];
      ghosts += static_cast<std::uint64_t>(v[1]);
      most_rounds = std::max(most_rounds, static_cast<std::uint64_t>(v[2]));
      ranks.push_back({{"rank", r},
                       {"owned", static_cast<std::uint64_t>(v[0])},
                       {"ghosts", static_cast<std::uint64_t>(v[1])},
                       {"rounds", static_cast<std::uint64_t>(v[2])},
                       {"bytes_sent", static_cast<std::uint64_t>(v[3])},
                       {"bytes_received", static_cast<std::uint64_t>(v[4])},
                       {"peak_rss_bytes", static_cast<std::uint64_t>(v[5])},
                       {"seconds", v[6]}});
    }
    if (!stats_path.empty()) {
      std::ofstream out(stats_path);
      out << nlohmann::json{{"ranks", ranks}, {"joint_levels", split.joint_levels}, {"select_rounds", split.select_rounds}}.dump(2)
          << "\n";
      if (!out) stats_status = internal_error("--stats: cannot write " + stats_path);
    }
    if (!w.common.quiet) {
      const double t = std::chrono::duration<double>(Clock::now() - start).count();
      if (job == Job::kMesh) {
        std::fprintf(stderr,
                     "spokemesh-mpi: %llu points, %llu simplices, %.2f s on %d processes (%llu halo points, %llu "
                     "rounds) -> %s\n",
                     static_cast<unsigned long long>(n), static_cast<unsigned long long>(total_rows), t, comm.size,
                     static_cast<unsigned long long>(ghosts), static_cast<unsigned long long>(most_rounds),
                     w.output.c_str());
      } else {
        print_graph_summary(n, total_rows, false, t, w.output);
      }
    }
  }
  if (Status s = comm.agree(stats_status); !s.is_ok()) return report_all(s);
  return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  ::mallopt(M_MMAP_THRESHOLD, 4 << 20);  // as the CLI (main.cpp there says why)
  // A file-size limit (ulimit -f) makes writes fail with EFBIG, reported as a full
  // disk is, instead of killing the process.
  std::signal(SIGXFSZ, SIG_IGN);
  int provided = 0;
  MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided);
  Comm comm = Comm::world();
  CLI::App app{"spokemesh-mpi: the Delaunay mesh or graph of one point set by many processes (Open MPI), the same "
               "bytes as spokemesh writes.\nRun as: mpirun -np P spokemesh-mpi {mesh|graph} INPUT -o OUTPUT [flags]"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "spokemesh-mpi 0.1.0");
  WholeCommands w;
  w.common.threads = 1;  // one worker per process unless asked: mpirun places processes on cores
  define_whole_commands(app, w, /*one_process=*/false);
  std::string stats_path;
  double first_halo = 2.5;
  for (CLI::App* cmd : {w.mesh, w.graph}) {
    cmd->add_option("--stats", stats_path,
                    "Write JSON {\"ranks\": [{rank, owned, ghosts, rounds, bytes_sent, bytes_received, "
                    "peak_rss_bytes, seconds}]}");
    cmd->add_option("--first-halo", first_halo,
                    "Depth of the first halo in mean point spacings (deeper halos are fetched in rounds where stars "
                    "need them; 0 starts from none)")
        ->capture_default_str()
        ->check(CLI::Range(0.0, 1000.0));
  }
  w.cells->group("");  // not distributed yet: hidden, and refused below
  int code = kExitOk;
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (comm.rank == 0) {
      code = app.exit(e);
    } else {
      code = e.get_exit_code();
    }
    if (code != 0) code = kExitUsage;
    MPI_Finalize();
    return code;
  }
  Halo::set_first_halo_factor(first_halo);
  if (*w.cells) {
    if (comm.rank == 0) {
      report(invalid_argument("cells: not distributed yet; compute cells on one process with spokemesh cells"), kProgram);
    }
    code = kExitUsage;
  } else {
    code = run(comm, *w.mesh ? Job::kMesh : Job::kGraph, w, stats_path);
  }
  MPI_Finalize();
  return code;
}
