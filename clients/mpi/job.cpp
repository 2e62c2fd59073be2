#include "job.hpp"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <numeric>
#include <optional>
#include <random>
#include <thread>

#include "cell_output.hpp"
#include "mesh_output.hpp"
#include "output.hpp"
#include "spokemesh/cell_io.hpp"
#include "spokemesh/data_dir.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/pieces.hpp"
#include "spokemesh/space_split.hpp"
#include "spokemesh/voronoi.hpp"
#include "store_output.hpp"

namespace spokemesh::mpi {
namespace {

using cli::Progress;

// ------------------------------------------------------------------ seeds one by one

// One thread's work on a round's seeds: seed() computes, certifies and keeps one
// seed's answer (locally); flush() hands what it kept to the job, under the round's
// lock, after each batch and once more (last) when the thread ends.
class SeedWorker {
 public:
  virtual ~SeedWorker() = default;
  virtual Status seed(std::uint32_t k, StarCertificate& certificate) = 0;
  virtual void flush(bool last) = 0;
};

// The round's pending seeds on `threads` threads, in batches of 64 taken in order
// (neighbouring seeds share their work in the walkers' caches). Seeds not certified go
// to round.refused; on_batch(seeds done so far) is called under the lock.
Status walk_pending(Round& round, unsigned threads, std::mutex& mu,
                    const std::function<std::unique_ptr<SeedWorker>()>& make_worker,
                    const std::function<void(std::uint64_t)>& on_batch) {
  constexpr std::size_t kBatch = 64;
  std::size_t next = 0;
  std::uint64_t seeds_done = 0;
  Status failure;
  std::vector<std::thread> pool;
  for (unsigned t = 0; t < std::max(1u, threads); ++t) {
    pool.emplace_back([&] {
      const std::unique_ptr<SeedWorker> worker = make_worker();
      for (;;) {
        std::size_t from, to;
        {
          std::lock_guard lock(mu);
          if (next >= round.pending.size() || !failure.is_ok()) break;
          from = next;
          to = std::min(round.pending.size(), next + kBatch);
          next = to;
        }
        std::vector<std::pair<std::uint32_t, StarCertificate>> refused_here;
        Status s;
        for (std::size_t i = from; i < to && s.is_ok(); ++i) {
          const std::uint32_t k = round.pending[i];
          StarCertificate c;
          s = worker->seed(k, c);
          if (s.is_ok() && !c.certified) refused_here.emplace_back(k, std::move(c));
        }
        std::lock_guard lock(mu);
        if (!s.is_ok() && failure.is_ok()) failure = s;
        for (auto& r : refused_here) round.refused.push_back(std::move(r));
        worker->flush(false);
        seeds_done += to - from;
        if (on_batch) on_batch(seeds_done);
      }
      std::lock_guard lock(mu);
      worker->flush(true);
    });
  }
  for (auto& t : pool) t.join();
  return failure;
}

// ------------------------------------------------------------------ mesh and graph

// Rows of the seeds certified after the first round, at their seed's sweep position.
struct KeptRows {
  std::uint32_t position;
  std::vector<std::uint32_t> rows;  // global indices
};

// (seed, neighbour) pairs in global indices, neighbours ascending: all of them, or only
// those larger than the seed (each Delaunay edge once, as `graph` writes it).
void neighbour_pairs(const LocalSet& local, const Star& star, bool larger_only, std::vector<std::uint32_t>& out) {
  std::vector<std::uint32_t> next;
  for (const std::uint32_t v : star.simplices) {
    if (v > star.seed || (!larger_only && v != star.seed)) next.push_back(v);
  }
  std::sort(next.begin(), next.end());
  next.erase(std::unique(next.begin(), next.end()), next.end());
  for (const std::uint32_t v : next) {
    out.push_back(static_cast<std::uint32_t>(local.global[star.seed]));
    out.push_back(static_cast<std::uint32_t>(local.global[v]));
  }
}

// The rank's sweep over its pieces, as one process sweeps them (merged into the
// largest nodes it owns: TopSplit::sweep_ends), and the options every round's run of
// it shares: built once; when the held points change (their local ids with them) the
// same split is carried over to the new ids (SpaceSplit::remapped), not built again.
// The engine is decided once (kAuto's probe of ties), on the first round's points.
class RankSweep {
 public:
  const SpaceSplit& of(const Round& round, const RunFacts& facts) {
    const std::size_t owned = round.split.owned.size();
    if (sweep_ && swept_ids_ == round.local.local_of_own && sweep_->size() == round.local.points.size()) return *sweep_;
    if (sweep_) {
      std::vector<std::uint32_t> id_of(sweep_->size(), 0);
      for (std::size_t k = 0; k < owned; ++k) id_of[swept_ids_[k]] = round.local.local_of_own[k];
      sweep_ = sweep_->remapped(round.local.points, id_of);
    } else {
      std::vector<std::uint32_t> members(owned);
      for (std::size_t k = 0; k < owned; ++k) members[k] = round.local.local_of_own[k];
      sweep_.emplace(round.local.points, members, round.split.sweep_ends,
                     SpaceSplit::default_block_points(facts.d, facts.n));
      position_of_own_.resize(owned);
      for (std::size_t k = 0; k < owned; ++k) position_of_own_[k] = sweep_->position_of(round.local.local_of_own[k]);
    }
    swept_ids_ = round.local.local_of_own;
    return *sweep_;
  }
  // Owned point k's sweep position (once of() has run).
  std::uint32_t position_of_own(std::uint32_t k) const { return position_of_own_[k]; }

  // A run of the sweep over the round's held points, certified against what the rank
  // lacks; later rounds take only the pending seeds (`seeds`, filled here). Deferred
  // seeds go to round.refused.
  MeshOptions options(Round& round, const RunFacts& facts, const cli::WholeCommands& w, std::mutex& mu,
                      std::vector<std::uint32_t>& seeds) {
    const SpaceSplit& sweep = of(round, facts);
    MeshOptions o;
    o.threads = w.common.threads;
    o.split = &sweep;
    o.sweep_end = sweep.swept();
    o.star.random_seed = w.common.random_seed;
    o.facet_cache_bytes = w.common.cache_mb << 20;
    o.engine = facts.engine;
    if (!engine_) engine_ = engine_for(round.local.points, sweep, o);
    o.engine = *engine_;
    o.held = &round.held;
    o.defer = [&round, &mu](std::uint32_t seed, StarCertificate c) {
      std::lock_guard lock(mu);
      round.refused.emplace_back(round.own_of_local[seed], std::move(c));
    };
    seeds.clear();
    if (round.number > 1) {
      for (const std::uint32_t k : round.pending) seeds.push_back(round.local.local_of_own[k]);
      std::sort(seeds.begin(), seeds.end());
      o.seeds = seeds;
    }
    return o;
  }
  // The engine the rounds take (once a run's options were made).
  MeshEngine engine() const { return engine_.value_or(MeshEngine::kStars); }

 private:
  std::optional<SpaceSplit> sweep_;
  std::optional<MeshEngine> engine_;
  std::vector<std::uint32_t> swept_ids_;  // the owned points' local ids it was made for
  std::vector<std::uint32_t> position_of_own_;
};

// Calls its argument with each of the rank's rows, in file order.
using RowEmitter = std::function<void(std::span<const std::uint32_t>)>;

// Mesh and graph: stars, the first round by the single-process sweep over the rank's
// pieces, later rounds star by star; text and .npy files written the same way.
class StarJob : public Job {
 public:
  using Job::Job;

  Status compute(Round& round) override { return sweep(round); }
  void defer_first_round(const Round& round) override { sweep_positions(round); }

 protected:
  // Row width: mesh d + 1 indices, graph 2.
  virtual std::size_t width() const = 0;
  // A certified star's rows in global indices.
  virtual void rows_of(const LocalSet& local, const Star& star, std::vector<std::uint32_t>& out) const = 0;
  // The first round's rows: mesh takes them from the sweep's sink, in sweep order
  // (keep_swept); graph from each accepted star (keep_accepted, under the lock).
  virtual bool rows_from_sink() const = 0;
  virtual Status keep_swept(const LocalSet& /*local*/, const SpaceSplit& /*sweep*/,
                            std::span<const std::uint32_t> /*block*/) {
    return Status::ok();
  }
  virtual void keep_accepted(std::vector<std::uint32_t>& /*rows*/) {}
  // A later round's rows from the sink (mesh): each seed's kept at its position (a
  // row's first vertex is its owner, the seed).
  void keep_late(const LocalSet& local, const SpaceSplit& sweep, std::span<const std::uint32_t> block) {
    const std::size_t w1 = width();
    for (std::size_t i = 0; i < block.size(); i += w1) {
      if (!keeps_seed(local.global[block[i]])) continue;
      if (i == 0 || block[i] != block[i - w1]) done_.push_back({sweep.position_of(block[i]), {}});
      for (std::size_t j = 0; j < w1; ++j)
        done_.back().rows.push_back(static_cast<std::uint32_t>(local.global[block[i + j]]));
    }
  }
  virtual bool keeps_seed(std::uint64_t /*global*/) const { return true; }

  // Writes text or .npy rows: sized in a first pass over the rows, written in a second,
  // a few MB at a time (the CLI's bytes). Collective.
  Status write_rows(Comm& comm, std::uint64_t my_rows, std::uint64_t total_rows,
                    const std::function<void(const RowEmitter&)>& for_each_row) const {
    const std::size_t w1 = width();
    auto format = MeshWriter::format_for(w_.output, facts_.d);
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
    return write_ordered(comm, w_.output, header_bytes, header, body_bytes, [&](const PieceWriter& put_piece) {
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
  }

  std::vector<KeptRows> done_;  // seeds certified after the first round
  std::mutex mu_;

 private:
  void sweep_positions(const Round& round) { sweep_.of(round, facts_); }
  RankSweep sweep_;

  // Every round: the single-process sweep over the rank's pieces (round 1: every seed;
  // later rounds: the seeds refused so far), each star certified against what the rank
  // lacks (round.held: MeshOptions::held), cell by cell where local triangulations
  // compute it. A star that is not certified is deferred to round.refused with the
  // balls and hull facets to fetch. The stars share their wraps (the sweep's memo): a
  // wrap a refused star found is still one of the held points' Delaunay
  // triangulation, which every star here is computed in.
  Status sweep(Round& round) {
    // (A later round with nothing pending here: an empty `seeds` would mean all of them.)
    if (round.number > 1 && round.pending.empty()) return Status::ok();
    std::vector<std::uint32_t> seeds;
    MeshOptions options = sweep_.options(round, facts_, w_, mu_, seeds);
    const SpaceSplit& sweep = sweep_.of(round, facts_);
    if (!round.tree) round.tree = std::make_unique<KdTree>(round.local.points);
    const bool first = round.number == 1;
    // A mesh takes its rows from the sink (in sweep order; later rounds' rows are kept
    // seed by seed with their positions); graphs and stores from each star.
    if (!rows_from_sink()) {
      options.accept = [&](const Star& star) {
        std::vector<std::uint32_t> out;
        rows_of(round.local, star, out);
        std::lock_guard lock(mu_);
        if (first) {
          keep_accepted(out);
        } else {
          done_.push_back({sweep_.position_of_own(round.own_of_local[star.seed]), std::move(out)});
        }
        return true;
      };
    }
    auto result = mesh_seeds(*round.tree, options, [&](std::span<const std::uint32_t> block, std::uint64_t seeds_done) {
      if (first) round.progress.update(seeds_done, swept_rows_);
      if (!rows_from_sink()) return Status::ok();
      if (first) return keep_swept(round.local, sweep, block);
      keep_late(round.local, sweep, block);
      return Status::ok();
    });
    if (!result.is_ok()) return result.status();
    sphere_queries_ += result->star.sphere_queries + result->triangulation.ball_queries;
    return Status::ok();
  }

 public:
  std::uint64_t sphere_queries() const override { return sphere_queries_; }

 private:
  std::uint64_t sphere_queries_ = 0;

 protected:
  std::uint64_t swept_rows_ = 0;  // rows the sweep has kept (mesh), for the progress line
};

class MeshJob final : public StarJob {
 public:
  explicit MeshJob(const cli::WholeCommands& w) : StarJob(w) {}

  Status check_usage() const override {
    // (The dimension is not known yet: .svg is checked against it once read.)
    return MeshWriter::format_for(w_.output, 2).status();
  }
  Status prepare(Comm& comm, const RunFacts& facts) override {
    facts_ = facts;
    auto format = MeshWriter::format_for(w_.output, facts.d);
    if (Status s = comm.agree(format.status()); !s.is_ok()) return s;
    format_ = format.value();
    seed_range_ = {0, static_cast<std::uint32_t>(facts.n)};
    if (!w_.seeds.empty()) {
      auto range = cli::parse_seed_range(w_.seeds, facts.n);
      if (!range.is_ok()) return range.status();
      seed_range_ = range.value();
    }
    spool_ = std::make_unique<Spool>(width());
    return Status::ok();
  }
  // .vtu, .msh and .svg list the points in index order: each rank writes its slice's.
  bool lists_points() const override {
    return format_ == MeshWriter::Format::kVtu || format_ == MeshWriter::Format::kMsh ||
           format_ == MeshWriter::Format::kSvg;
  }

  Status write(Comm& comm, std::unique_ptr<KdTree>& /*tree*/, std::unique_ptr<LocalSet>& held,
               std::span<const double> slice_coords) override {
    // The first round's rows from the spool, with the later rounds' seeds in place.
    const std::size_t w1 = width();
    std::sort(done_.begin(), done_.end(), [](const KeptRows& a, const KeptRows& b) { return a.position < b.position; });
    std::uint64_t my_rows = spool_->rows();
    for (const KeptRows& r : done_) my_rows += r.rows.size() / w1;
    auto for_each_row = [&](const RowEmitter& emit) {
      std::size_t next_done = 0;
      auto late = [&](const KeptRows& r) {
        for (std::size_t i = 0; i < r.rows.size(); i += w1) emit(std::span<const std::uint32_t>(r.rows.data() + i, w1));
      };
      spool_->for_each([&](std::span<const std::uint32_t> row, std::uint32_t position) {
        while (next_done < done_.size() && done_[next_done].position < position) late(done_[next_done++]);
        emit(row);
      });
      while (next_done < done_.size()) late(done_[next_done++]);
    };
    total_rows_ = comm.allreduce<std::uint64_t>(my_rows, MPI_SUM);
    if (!lists_points()) return write_rows(comm, my_rows, total_rows_, for_each_row);
    // .vtu, .msh and .svg section by section; a row's vertices are held points.
    const LocalSet& points = *held;
    const auto point = [&](std::uint32_t v) {
      const auto at = std::lower_bound(points.global.begin(), points.global.end(), std::uint64_t{v});
      return points.points.point(static_cast<std::size_t>(at - points.global.begin()));
    };
    return write_mesh_sections(comm, w_.output, format_, facts_.d, facts_.n, facts_.global_box, slice_coords, my_rows,
                               for_each_row, point);
  }

  void print_summary(double seconds, std::uint64_t halo_points, std::uint64_t rounds, int ranks) const override {
    std::fprintf(stderr,
                 "spokemesh-mpi: %llu points, %llu simplices, %.2f s on %d processes (%llu halo points, %llu "
                 "rounds) -> %s\n",
                 static_cast<unsigned long long>(facts_.n), static_cast<unsigned long long>(total_rows_), seconds,
                 ranks, static_cast<unsigned long long>(halo_points), static_cast<unsigned long long>(rounds),
                 w_.output.c_str());
  }

 protected:
  std::size_t width() const override { return static_cast<std::size_t>(facts_.d) + 1; }
  bool in_range(std::uint64_t g) const { return g >= seed_range_.first && g < seed_range_.second; }
  bool keeps_seed(std::uint64_t g) const override { return in_range(g); }
  // The star's owned simplices, when its seed is in --seeds' range.
  void rows_of(const LocalSet& local, const Star& star, std::vector<std::uint32_t>& out) const override {
    if (!in_range(local.global[star.seed])) return;
    for (const std::uint32_t v : owned_simplices(star)) out.push_back(static_cast<std::uint32_t>(local.global[v]));
  }
  bool rows_from_sink() const override { return true; }
  // The sweep's rows in global indices, each followed by its seed's sweep position.
  Status keep_swept(const LocalSet& local, const SpaceSplit& sweep, std::span<const std::uint32_t> block) override {
    const std::size_t w1 = width();
    std::vector<std::uint32_t> words;
    words.reserve(block.size() / w1 * (w1 + 1));
    for (std::size_t i = 0; i < block.size(); i += w1) {
      if (!in_range(local.global[block[i]])) continue;
      for (std::size_t j = 0; j < w1; ++j) words.push_back(static_cast<std::uint32_t>(local.global[block[i + j]]));
      words.push_back(sweep.position_of(block[i]));
      ++swept_rows_;
    }
    spool_->append(words);
    return spool_->ok() ? Status::ok() : internal_error("cannot write the temporary spool file");
  }

 private:
  MeshWriter::Format format_ = MeshWriter::Format::kText;
  std::pair<std::uint32_t, std::uint32_t> seed_range_{0, 0};
  std::unique_ptr<Spool> spool_;  // the first round's rows, in sweep order
  std::uint64_t total_rows_ = 0;
};

class GraphJob final : public StarJob {
 public:
  explicit GraphJob(const cli::WholeCommands& w) : StarJob(w) {}

  Status check_usage() const override {
    if (w_.approx.enabled) {
      return invalid_argument(
          "--approx: spokemesh-mpi computes exact graphs only; approximate graphs run on one process (spokemesh "
          "graph --approx)");
    }
    auto format = MeshWriter::format_for(w_.output, 2);
    if (!format.is_ok()) return format.status();
    if (format.value() != MeshWriter::Format::kText && format.value() != MeshWriter::Format::kNpy) {
      return invalid_argument(w_.output + ": graphs are written as text (.edges, .txt) or .npy");
    }
    return Status::ok();
  }
  Status prepare(Comm& /*comm*/, const RunFacts& facts) override {
    facts_ = facts;
    return Status::ok();
  }

  // Edges go to the rank holding their first index's slice of the index range, sorted
  // there: the file is then the ranks' parts in order.
  Status write(Comm& comm, std::unique_ptr<KdTree>& /*tree*/, std::unique_ptr<LocalSet>& /*held*/,
               std::span<const double> /*slice_coords*/) override {
    for (const KeptRows& r : done_) rows_.insert(rows_.end(), r.rows.begin(), r.rows.end());
    done_ = {};
    std::vector<std::vector<char>> outgoing(static_cast<std::size_t>(comm.size));
    for (std::size_t i = 0; i < rows_.size(); i += 2) {
      const int r = slice_owner(facts_.n, rows_[i], comm.size);
      put<std::uint32_t>(outgoing[static_cast<std::size_t>(r)], rows_[i]);
      put<std::uint32_t>(outgoing[static_cast<std::size_t>(r)], rows_[i + 1]);
    }
    rows_ = {};
    const std::vector<char> in = comm.alltoall_bytes(outgoing);
    outgoing = {};
    std::vector<std::pair<std::uint32_t, std::uint32_t>> edges(in.size() / 8);
    const char* at = in.data();
    for (auto& e : edges) {
      e.first = get<std::uint32_t>(at);
      e.second = get<std::uint32_t>(at);
    }
    std::sort(edges.begin(), edges.end());
    total_rows_ = comm.allreduce<std::uint64_t>(edges.size(), MPI_SUM);
    return write_rows(comm, edges.size(), total_rows_, [&](const RowEmitter& emit) {
      for (const auto& e : edges) {
        const std::uint32_t pair[2] = {e.first, e.second};
        emit(pair);
      }
    });
  }

  void print_summary(double seconds, std::uint64_t /*halo_points*/, std::uint64_t /*rounds*/,
                     int /*ranks*/) const override {
    cli::print_graph_summary(facts_.n, total_rows_, false, seconds, w_.output);
  }

 protected:
  std::size_t width() const override { return 2; }
  // Edges from the seed to its larger neighbours.
  void rows_of(const LocalSet& local, const Star& star, std::vector<std::uint32_t>& out) const override {
    neighbour_pairs(local, star, /*larger_only=*/true, out);
  }
  bool rows_from_sink() const override { return false; }
  void keep_accepted(std::vector<std::uint32_t>& rows) override { rows_.insert(rows_.end(), rows.begin(), rows.end()); }

 private:
  std::vector<std::uint32_t> rows_;  // the edges of the first round's stars
  std::uint64_t total_rows_ = 0;
};

// ------------------------------------------------------------------ cells

// Cells seed by seed in every round (the first in the tree's order, so that neighbours
// share their work in the caches), each certified by what decided it, spooled on disk
// and sent to the rank whose slice of the index range holds their seeds.
class CellsJob final : public Job {
 public:
  explicit CellsJob(const cli::WholeCommands& w) : Job(w) {}

  Status check_usage() const override {
    // (The dimension is not known yet: 2 admits every extension; checked once read.)
    return CellWriter::format_for(w_.output, 2).status();
  }
  const char* progress_label() const override { return "cells (rank 0's share)"; }
  Status prepare(Comm& comm, const RunFacts& facts) override {
    facts_ = facts;
    const int d = facts.d;
    auto format = CellWriter::format_for(w_.output, d);
    if (Status s = comm.agree(format.status()); !s.is_ok()) return s;
    format_ = format.value();
    // The domain: by default the whole set's bounding box (the CLI's).
    const std::vector<double>& box = facts.global_box;
    auto whole =
        Domain::box(std::vector<double>(box.begin(), box.begin() + d), std::vector<double>(box.begin() + d, box.end()));
    Result<std::optional<Domain>> chosen =
        whole.is_ok() ? cli::domain_for(w_.domain, d, std::optional<Domain>(std::move(whole).value()))
                      : Result<std::optional<Domain>>(whole.status());
    if (Status s = comm.agree(chosen.status()); !s.is_ok()) return s;
    domain_ = std::move(chosen).value();
    if (!w_.domain.shape.empty()) {
      // A domain of any shape, read by every rank: cells are clipped to its box (from
      // the whole set's box, as the CLI's) and intersected with it, measures only.
      Status st = Status::ok();
      auto shape = cli::read_domain(w_.domain.shape);
      if (!shape.is_ok()) {
        st = shape.status();
      } else if (shape->dimension() != d) {
        st = invalid_argument("--domain " + w_.domain.shape + " is " + std::to_string(shape->dimension()) +
                              "-d; the points are " + std::to_string(d) + "-d");
      } else if (geometry()) {
        st = invalid_argument("-o " + w_.output + ": cells in a domain of any shape are written as measures: use .npz");
      } else if (!w_.common.weights.empty() || !w_.common.radii.empty()) {
        st = invalid_argument("--domain: cells of weighted points in a domain of any shape are not supported yet");
      }
      if (Status s = comm.agree(st); !s.is_ok()) return s;
      shape_.emplace(std::move(shape).value());
      auto shape_box = ShapeClipper::box(std::vector<double>(box.begin(), box.begin() + d),
                                         std::vector<double>(box.begin() + d, box.end()), *shape_);
      if (Status s = comm.agree(shape_box.status()); !s.is_ok()) return s;
      domain_ = std::move(shape_box).value();
    }
    spool_ = std::make_unique<CellSpool>(d, geometry(), facts.n, comm.size);
    return Status::ok();
  }
  // A seed outside the domain: the lowest one's error, as the CLI reports it.
  Status check_seeds(Comm& comm, const TopSplit& split) override {
    const std::uint64_t n = facts_.n;
    const std::size_t owned = split.owned.size();
    std::uint64_t outside = n;
    for (std::size_t k = 0; k < owned; ++k) {
      if (split.owned.ids[k] < outside && domain_->violated_wall(split.owned.point(k))) outside = split.owned.ids[k];
    }
    const std::uint64_t lowest = comm.allreduce<std::uint64_t>(outside, MPI_MIN);
    Status mine;
    for (std::size_t k = 0; k < owned && lowest < n; ++k) {
      if (split.owned.ids[k] == lowest) mine = check_seed_in_domain(split.owned.point(k), lowest, *domain_);
    }
    return comm.agree(mine);
  }
  bool tree_in_first_round() const override { return true; }

  Status compute(Round& round) override {
    const KdTree& tree = *round.tree;
    if (round.number == 1) {
      round.pending.resize(round.split.owned.size());
      std::iota(round.pending.begin(), round.pending.end(), 0u);
      std::sort(round.pending.begin(), round.pending.end(), [&](std::uint32_t a, std::uint32_t b) {
        return tree.leaf_rank(round.local.local_of_own[a]) < tree.leaf_rank(round.local.local_of_own[b]);
      });
      // Stars from the rank's sweep or walked, as one process decides it for its seeds
      // (plan_cell_stars, on a sample of the rank's): the same cells either way.
      std::vector<std::uint32_t> sample;
      const std::size_t owned = round.pending.size(), step = std::max<std::size_t>(1, owned / 64);
      for (std::size_t k = 0; k < owned && sample.size() < 64; k += step) sample.push_back(round.local.local_of_own[k]);
      CellsOptions o;
      o.threads = w_.common.threads;
      o.star = star_options();
      plan_ = plan_cell_stars(tree, &*domain_, o, sample, owned);
    }
    if (plan_.triangulate && round.number == 1) {
      std::vector<std::uint32_t> none;
      sweep_.options(round, facts_, w_, mu_, none);  // decides the engine
      by_sweep_ = sweep_.engine() == MeshEngine::kTriangulations;
    }
    if (by_sweep_) return cells_by_sweep(round);
    std::function<void(std::uint64_t)> on_batch;
    if (round.number == 1) on_batch = [&](std::uint64_t done) { round.progress.update(done, 0); };
    return walk_pending(
        round, w_.common.threads, mu_,
        [&]() -> std::unique_ptr<SeedWorker> { return std::make_unique<CellWorker>(*this, round, tree); }, on_batch);
  }

  Status write(Comm& comm, std::unique_ptr<KdTree>& tree, std::unique_ptr<LocalSet>& held,
               std::span<const double> /*slice_coords*/) override {
    tree.reset();  // (what the rounds held goes before the cells move)
    held.reset();
    // Each cell to the rank whose slice of the index range holds its seed, written
    // there into the file.
    CellTally tally;
    std::optional<CellFileLayout> layout;
    VoronoiCell arriving;
    if (geometry()) layout.emplace(format_, facts_.d);
    auto gathered = SliceCells::gather(comm, *spool_, [&](const char* record) {
      if (!layout) return;
      read_cell_record(facts_.d, true, record, arriving);
      layout->add(arriving, tally);
    });
    if (!gathered.is_ok()) return gathered.status();
    SliceCells& cells = *gathered.value();
    return geometry() ? write_cells_sections(comm, w_.output, format_, cells, tally, written_)
                      : write_cells_npz(comm, w_.output, facts_.n, cells, written_);
  }

  void print_summary(double seconds, std::uint64_t /*halo_points*/, std::uint64_t /*rounds*/,
                     int /*ranks*/) const override {
    cli::print_cells_summary(facts_.n, shape_ ? shape_->describe() : domain_->describe(), written_.facets,
                             written_.volume, seconds, w_.output);
  }

 private:
  // .vtu and .svg cells are drawn: their records carry vertices and facet loops.
  bool geometry() const { return format_ != CellWriter::Format::kNpz; }

  // The round's seeds by the rank's sweep (local triangulations, certified against what
  // the rank lacks): each certified star is handed to a cell builder as its star (the
  // direct route first where it applies, certified by its reach; the star's route
  // otherwise, certified with the star), so each cell is the one process's.
  Status cells_by_sweep(Round& round) {
    if (round.number > 1 && round.pending.empty()) return Status::ok();
    const KdTree& tree = *round.tree;
    std::vector<std::uint32_t> seeds;
    MeshOptions options = sweep_.options(round, facts_, w_, mu_, seeds);
    options.accept_part = StarPart::kAll;
    // A builder per worker thread, taken from a pool for each star.
    std::vector<std::unique_ptr<CellWorker>> idle, all;
    std::mutex pool_mu;
    Status failure;
    options.accept = [&](const Star& star) {
      std::unique_ptr<CellWorker> worker;
      {
        std::lock_guard lock(pool_mu);
        if (!idle.empty()) {
          worker = std::move(idle.back());
          idle.pop_back();
        }
      }
      if (!worker) worker = std::make_unique<CellWorker>(*this, round, tree);
      const std::uint32_t k = round.own_of_local[star.seed];
      StarCertificate c;
      Status s = worker->from_star(k, star, plan_.skip_doomed, c);
      std::lock_guard lock(pool_mu);
      if (!s.is_ok() && failure.is_ok()) failure = s;
      if (s.is_ok() && !c.certified) {
        std::lock_guard refused(mu_);
        round.refused.emplace_back(k, std::move(c));
      }
      idle.push_back(std::move(worker));
      return false;  // no rows
    };
    auto result = mesh_seeds(tree, options, [&](std::span<const std::uint32_t>, std::uint64_t seeds_done) {
      if (round.number == 1) round.progress.update(seeds_done, 0);
      return Status::ok();
    });
    for (auto& worker : idle) worker->flush(true);
    if (!failure.is_ok()) return failure;
    return result.status();
  }

  class CellWorker : public SeedWorker {
   public:
    CellWorker(CellsJob& job, const Round& round, const KdTree& tree)
        : job_(job),
          round_(round),
          builder_(tree, *job.domain_, job.star_options()),
          found_(job.facts_.d, job.geometry()) {
      builder_.set_measures_only(!job.geometry() && !job.shape_);
      if (job.shape_) shape_.emplace(tree.points(), *job.shape_);
    }
    Status seed(std::uint32_t k, StarCertificate& c) override {
      const std::uint32_t seed = round_.local.local_of_own[k];
      Status s = builder_.cell(seed, cell_);
      if (!s.is_ok()) return s;
      c = round_.certify.cell(k, seed, builder_);
      // The intersection with a shape depends on the convex cell and its neighbours'
      // points only, which the certificate holds: the CLI's bytes.
      if (c.certified && shape_) shape_->clip(seed, cell_);
      if (c.certified)
        found_.add(cell_, round_.local.global[seed], [&](std::uint32_t v) { return round_.local.global[v]; });
      return Status::ok();
    }
    void flush(bool last) override {
      if (last || found_.size() >= (std::size_t{1} << 20)) job_.spool_->take(found_);
    }
    // The cell of owned point k from its certified star (a run of the rank's sweep).
    Status from_star(std::uint32_t k, const Star& star, bool skip_doomed, StarCertificate& c) {
      GivenStar given(star);
      builder_.set_stars(&given, skip_doomed);
      const std::uint32_t seed = star.seed;
      Status s = builder_.cell(seed, cell_);
      builder_.set_stars(nullptr);
      if (!s.is_ok()) return s;
      // From the star: certified with it. Directly: by what decided it.
      if (builder_.last_star() != nullptr) {
        c.certified = true;
      } else {
        c = round_.certify.cell(k, seed, builder_);
      }
      if (c.certified && shape_) shape_->clip(seed, cell_);
      if (c.certified)
        found_.add(cell_, round_.local.global[seed], [&](std::uint32_t v) { return round_.local.global[v]; });
      if (found_.size() >= (std::size_t{1} << 20)) {
        std::lock_guard lock(job_.mu_);
        job_.spool_->take(found_);
      }
      return Status::ok();
    }

   private:
    // The one star a run has just certified, as a builder's StarSource.
    class GivenStar final : public StarSource {
     public:
      explicit GivenStar(const Star& star) : star_(star) {}
      Status star(std::uint32_t seed, Star& out) override {
        if (seed != star_.seed) return internal_error("a star was asked of another seed");
        out = star_;
        return Status::ok();
      }

     private:
      const Star& star_;
    };

    CellsJob& job_;
    const Round& round_;
    ClippedCellBuilder builder_;
    std::optional<ShapeClipper> shape_;
    VoronoiCell cell_;
    CellRecords found_;
  };

  CellWriter::Format format_ = CellWriter::Format::kNpz;
  CellStarPlan plan_;      // where the stars come from (plan_cell_stars)
  RankSweep sweep_;        // the rank's sweep, when its stars serve
  bool by_sweep_ = false;  // the stars come from the rank's sweep (local triangulations)
  std::optional<Domain> domain_;
  std::optional<ShapeDomain> shape_;  // --domain FILE
  std::unique_ptr<CellSpool> spool_;  // the certified cells, on disk
  CellsWritten written_;
  std::mutex mu_;
};

// ------------------------------------------------------------------ store

// `store`: the set kept as pieces in a server's data directory (pieces.hpp), the same
// bytes as spokemesh-server writes for an upload of the same points, whatever P. The
// split is cut into the pieces themselves; each piece's halo is its points' Delaunay
// neighbours (from their certified stars) and every point inside its held box
// (fetched after the rounds).
class StoreJob final : public StarJob {
 public:
  StoreJob(const cli::WholeCommands& w, StoreSettings settings) : StarJob(w), settings_(std::move(settings)) {}

  Status check_usage() const override {
    if (settings_.data_dir.empty()) return invalid_argument("--data-dir: the servers' data directory is required");
    std::error_code ec;
    if (!std::filesystem::is_directory(settings_.data_dir, ec)) {
      return invalid_argument("--data-dir: " + settings_.data_dir + " is not a directory");
    }
    return Status::ok();
  }
  const char* progress_label() const override { return "finding the pieces' halos (rank 0's share)"; }
  Status prepare(Comm& /*comm*/, const RunFacts& facts) override {
    facts_ = facts;
    if (facts.d != 2 && facts.d != 3) {
      return invalid_argument(w_.input + ": " + std::to_string(facts.d) +
                              "-d; sets are kept as pieces in 2-d and 3-d (a server holds others whole)");
    }
    return Status::ok();
  }
  Status check_seeds(Comm& /*comm*/, const TopSplit& split) override {
    split_ = &split;
    return Status::ok();
  }
  bool lists_points() const override { return true; }  // the set's file, from the slices
  std::uint64_t split_target(std::uint64_t /*n*/, int /*ranks*/) const override {
    return std::max<std::uint64_t>(settings_.piece_points, SpaceSplit::kLeafPoints);
  }
  std::vector<double> final_boxes(const TopSplit& split) const override {
    std::vector<double> boxes;
    for (const std::uint32_t node : split.owned_nodes) {
      const std::vector<double> held = held_box_of(split.nodes[node].box, split.nodes[node].count, facts_.global_box);
      boxes.insert(boxes.end(), held.begin(), held.end());
    }
    return boxes;
  }

  Status write(Comm& comm, std::unique_ptr<KdTree>& tree, std::unique_ptr<LocalSet>& held,
               std::span<const double> slice_coords) override {
    tree.reset();
    namespace fs = std::filesystem;
    const std::string& dir = settings_.data_dir;
    auto file = write_set_file(comm, dir, facts_.d, facts_.n, slice_coords);
    if (!file.is_ok()) return file.status();
    id_ = file->first;
    const std::string set_file = data_dir::set_file(dir, id_);
    // Already kept as pieces (the same points stored before): nothing more to write.
    int exists = comm.rank == 0 && fs::exists(data_dir::manifest_file(data_dir::pieces_dir(dir, id_))) ? 1 : 0;
    MPI_Bcast(&exists, 1, MPI_INT, 0, comm.comm);
    if (exists != 0) {
      already_ = true;
      Status finished;
      if (comm.rank == 0) finished = finish_set_file(file->second, set_file);
      return comm.agree(finished);
    }
    // The pieces' directory, under a temporary name until complete.
    std::string tmp_dir;
    Status made;
    if (comm.rank == 0) {
      std::error_code ec;
      fs::create_directories(dir + "/pieces", ec);
      tmp_dir = data_dir::temp_name(dir + "/pieces", "mpi");
      fs::create_directories(tmp_dir, ec);
      if (ec) made = internal_error(tmp_dir + ": cannot create: " + ec.message());
    }
    if (Status s = comm.agree(made); !s.is_ok()) return s;
    std::uint64_t length = tmp_dir.size();
    MPI_Bcast(&length, 1, MPI_UINT64_T, 0, comm.comm);
    tmp_dir.resize(length);
    MPI_Bcast(tmp_dir.data(), static_cast<int>(length), MPI_CHAR, 0, comm.comm);

    // Each owned piece: its points, their neighbours in other pieces, and every point
    // inside its held box, in global index order.
    const LocalSet& local = *held;
    const TopSplit& split = *split_;
    const auto dd = static_cast<std::size_t>(facts_.d);
    const auto pieces = static_cast<std::uint32_t>(split.owned_nodes.size());
    const auto total = static_cast<std::uint32_t>(split.nodes.size());
    for (const KeptRows& r : done_) rows_.insert(rows_.end(), r.rows.begin(), r.rows.end());
    done_ = {};
    auto local_of = [&](std::uint64_t g) {
      return static_cast<std::size_t>(std::lower_bound(local.global.begin(), local.global.end(), g) -
                                      local.global.begin());
    };
    std::vector<std::vector<std::uint64_t>> halo(pieces);
    for (std::size_t i = 0; i + 1 < rows_.size(); i += 2) {
      const std::int32_t k = local.piece_of[local_of(rows_[i])];
      const std::size_t v = local_of(rows_[i + 1]);
      if (k >= 0 && local.piece_of[v] != k) halo[static_cast<std::size_t>(k)].push_back(rows_[i + 1]);
    }
    rows_ = {};
    std::vector<std::vector<double>> held_boxes(pieces);
    for (std::uint32_t k = 0; k < pieces; ++k) {
      const TopNode& node = split.nodes[split.owned_nodes[k]];
      held_boxes[k] = held_box_of(node.box, node.count, facts_.global_box);
    }
    for (std::size_t i = 0; i < local.global.size(); ++i) {
      const double* x = local.points.point(i);
      for (std::uint32_t k = 0; k < pieces; ++k) {
        if (local.piece_of[i] == static_cast<std::int32_t>(k)) continue;
        if (in_box(held_boxes[k], x)) halo[k].push_back(local.global[i]);
      }
    }
    std::vector<char> entries;
    std::vector<std::pair<std::uint64_t, std::uint32_t>> owners;
    Status status;
    for (std::uint32_t k = 0; k < pieces && status.is_ok(); ++k) {
      const std::uint32_t node_index = split.owned_nodes[k];
      const TopNode& node = split.nodes[node_index];
      Piece piece;
      piece.index = node_index;
      piece.dimension = facts_.d;
      piece.set_count = facts_.n;
      piece.start = node.start;
      piece.box = node.box;
      piece.held_box = held_boxes[k];
      std::vector<std::uint64_t>& ids = halo[k];
      const std::uint32_t from = k == 0 ? 0 : split.piece_ends[k - 1];
      for (std::uint32_t j = from; j < split.piece_ends[k]; ++j) {
        ids.push_back(split.owned.ids[j]);
        owners.emplace_back(split.owned.ids[j], node_index);
      }
      std::sort(ids.begin(), ids.end());
      ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
      piece.ids = ids;
      piece.own.resize(ids.size());
      piece.coords.resize(ids.size() * dd);
      for (std::size_t j = 0; j < ids.size(); ++j) {
        const std::size_t at = local_of(ids[j]);
        if (at >= local.global.size() || local.global[at] != ids[j]) {
          status = internal_error("piece " + std::to_string(node_index) + ": point " + std::to_string(ids[j]) +
                                  " of its halo is not held");
          break;
        }
        piece.own[j] = local.piece_of[at] == static_cast<std::int32_t>(k) ? 1 : 0;
        std::copy(local.points.point(at), local.points.point(at) + dd, piece.coords.begin() + j * dd);
      }
      std::vector<std::uint64_t>().swap(ids);
      if (!status.is_ok()) break;
      const std::string bytes = piece_bytes(piece, total);
      std::uint32_t crc = 0;
      std::memcpy(&crc, bytes.data() + bytes.size() - 4, 4);
      status = write_file_durably(data_dir::piece_file(tmp_dir, node_index), bytes);
      put<std::uint32_t>(entries, node_index);
      for (std::uint64_t v : {node.start, node.count, static_cast<std::uint64_t>(piece.ids.size()),
                              static_cast<std::uint64_t>(bytes.size())}) {
        put<std::uint64_t>(entries, v);
      }
      put<std::uint32_t>(entries, crc);
      for (double v : piece.box) put<double>(entries, v);
      for (double v : piece.held_box) put<double>(entries, v);
      halo_points_ += piece.ids.size() - node.count;
    }
    if (Status s = comm.agree(status); !s.is_ok()) return cleanup(comm, tmp_dir, file->second, s);
    held.reset();
    if (Status s = write_owner_map(comm, data_dir::owners_file(tmp_dir), facts_.n, owners); !s.is_ok()) {
      return cleanup(comm, tmp_dir, file->second, s);
    }
    owners = {};
    std::vector<std::uint64_t> counts;
    const std::vector<char> all = comm.allgather_bytes(entries, counts);
    halo_points_ = comm.allreduce<std::uint64_t>(halo_points_, MPI_SUM);
    pieces_ = total;
    Status done;
    if (comm.rank == 0) {
      PieceManifest m;
      m.set_id = id_;
      m.dimension = facts_.d;
      m.count = facts_.n;
      m.piece_points = settings_.piece_points;
      m.global_box = facts_.global_box;
      m.pieces.resize(total);
      for (const char* at = all.data(); at < all.data() + all.size();) {
        const auto p = get<std::uint32_t>(at);
        PieceEntry& e = m.pieces[p];
        e.start = get<std::uint64_t>(at);
        e.count = get<std::uint64_t>(at);
        e.held = get<std::uint64_t>(at);
        e.bytes = get<std::uint64_t>(at);
        e.crc = get<std::uint32_t>(at);
        e.box.resize(2 * dd);
        e.held_box.resize(2 * dd);
        for (double& v : e.box) v = get<double>(at);
        for (double& v : e.held_box) v = get<double>(at);
      }
      done = write_file_durably(data_dir::manifest_file(tmp_dir), manifest_text(m));
      if (done.is_ok()) {
        // The data directory's commit rule (data_dir.hpp), as the server's.
        const int error = data_dir::commit_directory(tmp_dir, data_dir::pieces_dir(dir, id_));
        if (error == EEXIST) {
          // Another run stored the same set meanwhile: the same bytes.
          std::error_code ignored;
          fs::remove_all(tmp_dir, ignored);
          already_ = true;
        } else if (error != 0) {
          done = internal_error(data_dir::pieces_dir(dir, id_) + ": cannot commit: " + std::strerror(error));
        }
      }
      if (done.is_ok()) done = finish_set_file(file->second, set_file);
    }
    if (Status s = comm.agree(done); !s.is_ok()) return cleanup(comm, tmp_dir, file->second, s);
    return Status::ok();
  }

  void print_summary(double seconds, std::uint64_t /*halo_points*/, std::uint64_t rounds, int ranks) const override {
    if (already_) {
      std::fprintf(stderr, "spokemesh-mpi: point set %s (%llu points) is already kept as pieces in %s\n", id_.c_str(),
                   static_cast<unsigned long long>(facts_.n), settings_.data_dir.c_str());
      return;
    }
    std::fprintf(stderr,
                 "spokemesh-mpi: stored point set %s: %llu points in %u pieces (%llu halo points), %.2f s on %d "
                 "processes (%llu rounds) -> %s\n",
                 id_.c_str(), static_cast<unsigned long long>(facts_.n), pieces_,
                 static_cast<unsigned long long>(halo_points_), seconds, ranks, static_cast<unsigned long long>(rounds),
                 settings_.data_dir.c_str());
  }

 protected:
  std::size_t width() const override { return 2; }
  // Every neighbour of the seed (the pieces' halos).
  void rows_of(const LocalSet& local, const Star& star, std::vector<std::uint32_t>& out) const override {
    neighbour_pairs(local, star, /*larger_only=*/false, out);
  }
  bool rows_from_sink() const override { return false; }
  void keep_accepted(std::vector<std::uint32_t>& rows) override { rows_.insert(rows_.end(), rows.begin(), rows.end()); }

 private:
  // The set's file in place (rank 0), by the data directory's commit rule: linked from
  // the temporary one, which goes; a server or run that has it already wrote the same
  // bytes.
  static Status finish_set_file(const std::string& tmp, const std::string& set_file) {
    const int error = data_dir::commit_file(tmp, set_file, data_dir::Move::kExclusive);
    if (error == 0 || error == EEXIST) return Status::ok();
    return internal_error(set_file + ": cannot commit: " + std::strerror(error));
  }
  // Nothing half-written is left: the temporary directory and file go (collective).
  static Status cleanup(Comm& comm, const std::string& tmp_dir, const std::string& tmp_file, const Status& s) {
    if (comm.rank == 0) {
      std::error_code ignored;
      std::filesystem::remove_all(tmp_dir, ignored);
      ::unlink(tmp_file.c_str());
    }
    return s;
  }

  StoreSettings settings_;
  const TopSplit* split_ = nullptr;
  std::vector<std::uint32_t> rows_;  // (seed, neighbour) of the first round's stars
  std::string id_;
  bool already_ = false;
  std::uint32_t pieces_ = 0;
  std::uint64_t halo_points_ = 0;
};
}  // namespace

std::uint64_t Job::split_target(std::uint64_t n, int ranks) const {
  const auto p = static_cast<std::uint64_t>(ranks);
  return ranks == 1 ? n : std::max<std::uint64_t>(SpaceSplit::kLeafPoints, (n + 32 * p - 1) / (32 * p));
}

std::unique_ptr<Job> Job::make(JobKind kind, const cli::WholeCommands& commands, const StoreSettings& store) {
  switch (kind) {
    case JobKind::kStore:
      return std::make_unique<StoreJob>(commands, store);
    case JobKind::kMesh:
      return std::make_unique<MeshJob>(commands);
    case JobKind::kGraph:
      return std::make_unique<GraphJob>(commands);
    case JobKind::kCells:
      return std::make_unique<CellsJob>(commands);
  }
  return nullptr;
}

}  // namespace spokemesh::mpi
