// spokemesh-mpi: one point set meshed by many processes, the same bytes as
// `spokemesh` writes (docs/distributed.md).
//
//   mpirun -np P spokemesh-mpi {mesh|graph|cells} IN -o OUT [flags]
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
#include "halo.hpp"
#include "output.hpp"
#include "mesh_output.hpp"
#include "cell_output.hpp"
#include "split.hpp"
#include "spokemesh/cell_io.hpp"
#include "spokemesh/cells.hpp"
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
using spokemesh::mpi::Halo;
using spokemesh::mpi::LocalSet;
using spokemesh::mpi::PieceWriter;
using spokemesh::mpi::Spool;
using spokemesh::mpi::CellRecords;
using spokemesh::mpi::gather_local;
using spokemesh::mpi::write_ordered;
using spokemesh::mpi::slice_begin;
using Clock = std::chrono::steady_clock;

constexpr const char* kProgram = "spokemesh-mpi";

// ------------------------------------------------------------------ reading

// This rank's rows of IN: [first, first + count) of n, d coordinates each.
struct Slice {
  std::uint64_t n = 0, first = 0;
  Points points;
};

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

enum class Job { kMesh, kGraph, kCells };

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
  if (job == Job::kCells) {
    // (The dimension is not known yet: 2 admits every extension; checked once read.)
    auto format = CellWriter::format_for(w.output, 2);
    if (!format.is_ok()) usage = format.status();
  } else {
    // (The dimension is not known yet: .svg is checked against it once read.)
    auto format = MeshWriter::format_for(w.output, 2);
    if (usage.is_ok() && !format.is_ok()) {
      usage = format.status();
    } else if (usage.is_ok() && job == Job::kGraph && format.value() != MeshWriter::Format::kText &&
               format.value() != MeshWriter::Format::kNpy) {
      usage = invalid_argument(w.output + ": graphs are written as text (.edges, .txt) or .npy");
    }
  }
  auto engine = parse_engine(w.engine);
  if (usage.is_ok() && !engine.is_ok()) usage = engine.status();
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
  // .vtu, .msh and .svg list the points in index order: this rank keeps its slice's.
  MeshWriter::Format mesh_format = MeshWriter::Format::kText;
  if (job == Job::kMesh) {
    auto format = MeshWriter::format_for(w.output, d);
    if (Status s = comm.agree(format.status()); !s.is_ok()) return report_all(s);
    mesh_format = format.value();
  }
  CellWriter::Format cell_format = CellWriter::Format::kNpz;
  if (job == Job::kCells) {
    auto format = CellWriter::format_for(w.output, d);
    if (Status s = comm.agree(format.status()); !s.is_ok()) return report_all(s);
    cell_format = format.value();
  }
  // .vtu and .svg cells are drawn: their records carry vertices and facet loops.
  const bool cell_geometry = cell_format != CellWriter::Format::kNpz;
  const bool sections = mesh_format == MeshWriter::Format::kVtu || mesh_format == MeshWriter::Format::kMsh ||
                        mesh_format == MeshWriter::Format::kSvg;
  const std::vector<double> slice_coords = sections ? slice.points.coords : std::vector<double>();
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
  // cells: the domain, by default the whole set's bounding box (the CLI's).
  std::optional<Domain> domain;
  if (job == Job::kCells) {
    auto whole = Domain::box(std::vector<double>(global_box.begin(), global_box.begin() + d),
                             std::vector<double>(global_box.begin() + d, global_box.end()));
    Result<std::optional<Domain>> chosen =
        whole.is_ok() ? domain_for(w.domain, d, std::optional<Domain>(std::move(whole).value()))
                      : Result<std::optional<Domain>>(whole.status());
    if (Status s = comm.agree(chosen.status()); !s.is_ok()) return report_all(s);
    domain = std::move(chosen).value();
  }

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
  if (job == Job::kCells) {
    // A seed outside the domain: the lowest one's error, as the CLI reports it.
    std::uint64_t outside = n;
    for (std::size_t k = 0; k < owned; ++k) {
      if (split.owned.ids[k] < outside && domain->violated_wall(split.owned.point(k))) outside = split.owned.ids[k];
    }
    const std::uint64_t lowest = comm.allreduce<std::uint64_t>(outside, MPI_MIN);
    Status mine;
    for (std::size_t k = 0; k < owned && lowest < n; ++k) {
      if (split.owned.ids[k] == lowest) mine = check_seed_in_domain(split.owned.point(k), lowest, *domain);
    }
    if (Status s = comm.agree(mine); !s.is_ok()) return report_all(s);
  }

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
  mpi::CellSpool cell_spool(d, cell_geometry, n, comm.size);            // cells: the certified ones, on disk
  RankStats stats;
  std::mutex mu;
  Status failure;
  Progress progress(quiet, owned, job == Job::kCells ? "cells (rank 0's share)" : "meshing (rank 0's share)");
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
      if ((round > 1 || job == Job::kCells) && spans) held_tree = std::make_unique<KdTree>(fresh);
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
    // What a seed's certificate may count on: the boxes and balls fetched for it (every
    // point inside them held), and the boxes that may hold points it does not have
    // (none once its reach covers the whole set, or once this rank holds every point).
    const bool holds_all = points.size() == n;
    struct Regions {
      std::vector<double> held;
      std::span<const double> balls, unheld;
    };
    auto regions_of = [&](std::uint32_t k, std::uint32_t seed) {
      Regions r;
      const auto piece = static_cast<std::size_t>(local.piece_of[seed]);
      r.held.assign(halo.held_box(piece).begin(), halo.held_box(piece).end());
      bool everything = holds_all;
      if (const auto it = reach.find(k); it != reach.end()) {
        r.held.insert(r.held.end(), it->second.begin(), it->second.end());
        everything = covers_all(it->second);
      }
      if (const auto it = asked_balls.find(k); it != asked_balls.end()) r.balls = it->second;
      if (!everything) r.unheld = unheld[piece];
      return r;
    };
    auto certify = [&](const Star& star) {
      const Regions r = regions_of(own_of_local[star.seed], star.seed);
      return certifier.certify(star, r.held, r.balls, r.unheld, is_known);
    };
    // A cell is the whole set's when the points within the distance that decided it
    // are all held (then the whole set's builder takes the same points in the same
    // order) and, built from a star, the star is the whole set's.
    auto certify_cell = [&](std::uint32_t k, std::uint32_t seed, const ClippedCellBuilder& builder) {
      StarCertificate c;
      c.certified = true;
      if (const double r2 = builder.last_reach2(); r2 > 0) {
        const Regions r = regions_of(k, seed);
        // (nanoflann's distances are within kDistanceMargin of the exact ones.)
        const double want = r2 * (1 + 4 * kDistanceMargin);
        if (!certifier.ball_is_held(seed, want, r.held, r.balls, r.unheld)) {
          c.certified = false;
          const double* x = points.point(seed);
          if (std::isfinite(want)) {
            c.balls.assign(x, x + d);
            c.balls.push_back(std::sqrt(want) * (1 + 1e-12));
          } else {
            c.reach = global_box;  // it rested on there being no other points: all of them
          }
        }
      }
      if (const Star* star = builder.last_star()) {
        StarCertificate s = certify(*star);
        c.certified = c.certified && s.certified;
        c.balls.insert(c.balls.end(), s.balls.begin(), s.balls.end());
        if (c.reach.empty()) c.reach = std::move(s.reach);
        c.hull_facets = std::move(s.hull_facets);
      }
      return c;
    };
    if (owned != 0 && spans) {
      if (round == 1 && job != Job::kCells) {
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
        options.engine = engine.value();
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
        // Later rounds: only the refused seeds, each star on its own; cells: every
        // seed, in the first round in the tree's order (neighbours share their work in
        // the caches), each cell certified by what decided it.
        const KdTree& tree = *held_tree;
        if (job == Job::kCells && round == 1) {
          pending.resize(owned);
          std::iota(pending.begin(), pending.end(), 0u);
          std::sort(pending.begin(), pending.end(), [&](std::uint32_t a, std::uint32_t b) {
            return tree.leaf_rank(local.local_of_own[a]) < tree.leaf_rank(local.local_of_own[b]);
          });
        }
        std::vector<std::thread> pool;
        std::size_t next = 0;
        std::uint64_t seeds_done = 0;
        for (unsigned t = 0; t < std::max(1u, w.common.threads); ++t) {
          pool.emplace_back([&] {
            StarOptions star_options;
            star_options.random_seed = w.common.random_seed;
            std::optional<StarWalker> walker;
            std::optional<ClippedCellBuilder> builder;
            if (job == Job::kCells) {
              builder.emplace(tree, *domain, star_options);
              builder->set_measures_only(!cell_geometry);
            } else {
              walker.emplace(tree, star_options);
            }
            Star star;
            VoronoiCell cell;
            CellRecords found(d, cell_geometry);
            std::vector<std::uint32_t> out;
            constexpr std::size_t kBatch = 64;
            for (;;) {
              std::size_t from, to;
              {
                std::lock_guard lock(mu);
                if (next >= pending.size() || !failure.is_ok()) break;
                from = next;
                to = std::min(pending.size(), next + kBatch);
                next = to;
              }
              std::vector<std::pair<std::uint32_t, StarCertificate>> refused_here;
              std::vector<Rows> done_here;
              Status s;
              for (std::size_t i = from; i < to && s.is_ok(); ++i) {
                const std::uint32_t k = pending[i];
                const std::uint32_t seed = local.local_of_own[k];
                StarCertificate c;
                if (job == Job::kCells) {
                  s = builder->cell(seed, cell);
                  if (s.is_ok()) c = certify_cell(k, seed, *builder);
                  if (c.certified) found.add(cell, local.global[seed], [&](std::uint32_t v) { return local.global[v]; });
                } else {
                  s = walker->compute(seed, star, StarPart::kAll);
                  if (s.is_ok()) c = certify(star);
                  if (c.certified) {
                    out.clear();
                    rows_of(local, star, out);
                    done_here.push_back({position_of_own[k], out});
                  }
                }
                if (s.is_ok() && !c.certified) refused_here.emplace_back(k, std::move(c));
              }
              std::lock_guard lock(mu);
              if (!s.is_ok() && failure.is_ok()) failure = s;
              for (auto& r : refused_here) refused.push_back(std::move(r));
              for (auto& r : done_here) done.push_back(std::move(r));
              if (found.size() >= (std::size_t{1} << 20)) cell_spool.take(found);
              seeds_done += to - from;
              if (job == Job::kCells && round == 1) progress.update(seeds_done, 0);
            }
            std::lock_guard lock(mu);
            cell_spool.take(found);
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

  std::uint64_t total_rows = 0;
  mpi::CellsWritten cells_written;
  if (job == Job::kCells) {
    note_peak(comm, "cells computed");
    held_tree.reset();  // (what the rounds held goes before the cells move)
    held_set.reset();
    // Each cell to the rank whose slice of the index range holds its seed, written
    // there into the file.
    CellTally tally;
    std::optional<CellFileLayout> layout;
    VoronoiCell arriving;
    if (cell_geometry) layout.emplace(cell_format, d);
    auto gathered = mpi::SliceCells::gather(comm, cell_spool, [&](const char* record) {
      if (!layout) return;
      mpi::read_cell_record(d, true, record, arriving);
      layout->add(arriving, tally);
    });
    if (!gathered.is_ok()) return report_all(gathered.status());
    mpi::SliceCells& cells = *gathered.value();
    Status s = cell_geometry ? mpi::write_cells_sections(comm, w.output, cell_format, cells, tally, cells_written)
                             : mpi::write_cells_npz(comm, w.output, n, cells, cells_written);
    if (!s.is_ok()) return report_all(s);
  } else {

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
        const int r = mpi::slice_owner(n, rows[i], comm.size);
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
    // The file: the CLI's bytes. .vtu, .msh and .svg section by section; text and .npy
    // sized in a first pass over the rows and written in a second, a few MB at a time.
    total_rows = comm.allreduce<std::uint64_t>(my_rows, MPI_SUM);
    if (sections) {
      const LocalSet& held = *held_set;
      const auto point = [&](std::uint32_t v) {
        const auto at = std::lower_bound(held.global.begin(), held.global.end(), std::uint64_t{v});
        return held.points.point(static_cast<std::size_t>(at - held.global.begin()));
      };
      Status written = mpi::write_mesh_sections(comm, w.output, mesh_format, d, n, global_box, slice_coords, my_rows,
                                                for_each_row, point);
      if (!written.is_ok()) return report_all(written);
    } else {
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
    }
  }
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
      } else if (job == Job::kCells) {
        print_cells_summary(n, domain->describe(), cells_written.facets, cells_written.volume, t, w.output);
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
  CLI::App app{"spokemesh-mpi: the Delaunay mesh, graph or clipped Voronoi cells of one point set by many processes "
               "(Open MPI), the same bytes as spokemesh writes.\nRun as: mpirun -np P spokemesh-mpi {mesh|graph|cells} "
               "INPUT -o OUTPUT [flags]"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "spokemesh-mpi 0.1.0");
  WholeCommands w;
  w.common.threads = 1;  // one worker per process unless asked: mpirun places processes on cores
  define_whole_commands(app, w, /*one_process=*/false);
  std::string stats_path;
  double first_halo = 2.5;
  for (CLI::App* cmd : {w.mesh, w.graph, w.cells}) {
    cmd->add_option("--stats", stats_path,
                    "Write JSON {\"ranks\": [{rank, owned, ghosts, rounds, bytes_sent, bytes_received, "
                    "peak_rss_bytes, seconds}]}");
    cmd->add_option("--first-halo", first_halo,
                    "Depth of the first halo in mean point spacings (deeper halos are fetched in rounds where stars "
                    "need them; 0 starts from none)")
        ->capture_default_str()
        ->check(CLI::Range(0.0, 1000.0));
  }
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
  if (!w.common.periodic.empty()) {
    if (comm.rank == 0) {
      report(invalid_argument("--periodic is not supported by spokemesh-mpi yet: use spokemesh"), kProgram);
    }
    MPI_Finalize();
    return kExitUsage;
  }
  if (w.common.weighted()) {
    // The halos certify stars with circumspheres, not power spheres (issue 28).
    if (comm.rank == 0) {
      report(invalid_argument("--weights and --radii are not supported by spokemesh-mpi yet: use spokemesh"), kProgram);
    }
    MPI_Finalize();
    return kExitUsage;
  }
  Halo::set_first_halo_factor(first_halo);
  code = run(comm, *w.mesh ? Job::kMesh : *w.graph ? Job::kGraph : Job::kCells, w, stats_path);
  MPI_Finalize();
  return code;
}
