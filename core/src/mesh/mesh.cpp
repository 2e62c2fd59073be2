#include "spokemesh/mesh.hpp"

#include "base/dimension.hpp"

#include <algorithm>
#include <atomic>
#include <memory>
#include <optional>
#include <vector>

#include "mesh/delaunay_sweep.hpp"
#include "mesh/ordered_run.hpp"
#include "spokemesh/front_cache.hpp"

namespace spokemesh {

std::span<const std::uint32_t> owned_simplices(const Star& star) {
  const std::size_t w = static_cast<std::size_t>(star.dimension) + 1;
  std::size_t first = 0;
  while (first < star.size() && star.simplex(first)[0] != star.seed) ++first;
  return std::span<const std::uint32_t>(star.simplices).subspan(first * w);
}

namespace {

// A block's rows, as a worker hands them on.
struct MeshedBlock {
  std::uint64_t seeds = 0;  // seeds of the run in the block
  std::vector<std::uint32_t> simplices;
};

}  // namespace

MeshEngine engine_for(const PointSet& points, const SpaceSplit& split, const MeshOptions& options) {
  if (options.engine == MeshEngine::kStars || !detail::triangulation_sweep_applies(points, options)) {
    return MeshEngine::kStars;
  }
  if (options.engine == MeshEngine::kTriangulations) return MeshEngine::kTriangulations;
  return detail::ties_dominate(points, split) ? MeshEngine::kStars : MeshEngine::kTriangulations;
}

namespace {

// The run's sweep: the caller's split, or one built into `own` from the points and
// the block size (8 bytes a point while the run lasts, 32 to 72 more while it is built).
Result<const SpaceSplit*> sweep_split(const PointSet& points, const MeshOptions& options,
                                      std::optional<SpaceSplit>& own) {
  if (options.split == nullptr) {
    own.emplace(points, options.block_size != 0 ? options.block_size
                                                : SpaceSplit::default_block_points(points.dimension(), points.size()));
  }
  const SpaceSplit* split = options.split != nullptr ? options.split : &*own;
  if (split->size() != points.size())
    return invalid_argument("mesh_seeds: the sweep's split is over another point set");
  return split;
}

Status triangulations_refused() {
  return invalid_argument("mesh_seeds: local triangulations mesh unweighted, non-periodic 2-d and 3-d sets only");
}

}  // namespace

Result<MeshStats> mesh_seeds(const PointSet& points, const MeshOptions& options, const SimplexSink& sink) {
  std::optional<SpaceSplit> own_split;
  auto split_or = sweep_split(points, options, own_split);
  if (!split_or.is_ok()) return split_or.status();
  const SpaceSplit& split = *split_or.value();
  MeshOptions decided = options;
  decided.split = &split;
  decided.engine = engine_for(points, split, options);
  if (decided.engine == MeshEngine::kTriangulations) return detail::triangulation_sweep(points, split, decided, sink);
  if (options.engine == MeshEngine::kTriangulations) return triangulations_refused();
  const KdTree tree(points);
  return mesh_seeds(tree, decided, sink);
}

Result<MeshStats> mesh_seeds(const KdTree& tree, const MeshOptions& options, const SimplexSink& sink) {
  const std::uint64_t n = tree.points().size();
  const auto begin = static_cast<std::uint32_t>(std::min<std::uint64_t>(options.seed_begin, n));
  const auto end = static_cast<std::uint32_t>(std::clamp<std::uint64_t>(options.seed_end, begin, n));
  const unsigned threads = std::max(1u, options.threads);
  const int d = tree.points().dimension();
  // The sweep: blocks of space in SpaceSplit's order, each meshed by one worker with
  // its seeds in that order. The rows come out in that order, which depends on the
  // point set alone (not on the block size or the thread count).
  std::optional<SpaceSplit> own_split;
  auto split_or = sweep_split(tree.points(), options, own_split);
  if (!split_or.is_ok()) return split_or.status();
  const SpaceSplit& blocks = *split_or.value();
  if (engine_for(tree.points(), blocks, options) == MeshEngine::kTriangulations) {
    return detail::triangulation_sweep(tree, blocks, options, sink);
  }
  if (options.engine == MeshEngine::kTriangulations) return triangulations_refused();
  std::uint32_t block_points = 1;
  for (std::uint32_t b = 0; b < blocks.block_count(); ++b)
    block_points = std::max(block_points, blocks.end(b) - blocks.begin(b));
  const auto sweep_begin = static_cast<std::uint32_t>(std::min<std::uint64_t>(options.sweep_begin, n));
  const auto sweep_end = static_cast<std::uint32_t>(std::clamp<std::uint64_t>(options.sweep_end, sweep_begin, n));
  const RunOrder run{begin, end, 1, &blocks, sweep_begin, sweep_end};
  // The blocks that meet the sweep range.
  const std::uint32_t first_block = sweep_begin < sweep_end ? blocks.block_of(sweep_begin) : 0;
  const std::uint64_t count =
      begin < end && sweep_begin < sweep_end ? blocks.block_of(sweep_end - 1) + 1 - first_block : 0;
  // Blocks in flight beyond the next one to write: 4 per worker, and no more points
  // than 4 blocks of 32,768 per worker (this caps the large 2-d blocks), so that a
  // slow reader leaves at most a few MB of simplices buffered.
  const std::uint64_t window =
      std::max<std::uint64_t>(threads, std::min<std::uint64_t>(4ull * threads, 4ull * threads * 32768 / block_points));

  // What the stars share (see front_cache.hpp; in 2-d, the EdgeCache's posts per point).
  std::optional<EdgeCache> edges;
  std::optional<FrontMail> mail;
  if (options.facet_cache_bytes != 0 && count != 0) {
    if (detail::policy(d).ring_walk) {
      edges.emplace(static_cast<std::uint32_t>(n), run, options.facet_cache_bytes);
      if (!edges->enabled()) edges.reset();
    } else {
      mail.emplace(d, blocks, options.facet_cache_bytes);
    }
  }

  MeshStats total;
  std::size_t worker_bytes = 0;  // the workers' tables, each at its largest
  const HeldRegion* held = options.held != nullptr && !options.held->holds_all() ? options.held : nullptr;
  std::atomic<std::uint64_t> deferred{0};
  // A worker: one StarWalker, and with a front its block table.
  struct Worker {
    const SpaceSplit& blocks;
    const MeshOptions& options;
    const RunOrder& run;  // its seeds, and its sweep range [rank_begin, rank_end)
    std::uint32_t first_block;
    MeshStats& total;
    std::size_t& worker_bytes;
    std::optional<FrontCache> front;
    std::optional<StarWalker> walker;
    Star star;
    std::size_t front_bytes = 0;
    const HeldRegion* held;  // MeshOptions::held when it lacks points, else null
    const PointSet& tree_points;
    std::atomic<std::uint64_t>& deferred;

    Status operator()(std::uint64_t b, MeshedBlock& out) {
      const auto block = static_cast<std::uint32_t>(first_block + b);
      const std::uint32_t lo = std::max(blocks.begin(block), run.rank_begin);
      const std::uint32_t hi = std::min(blocks.end(block), run.rank_end);
      if (front) front->begin_block(block);
      out.simplices.clear();
      out.seeds = 0;
      Status status;
      for (std::uint32_t r = lo; r < hi; ++r) {
        // The next seeds' points are loads at random (input order): begin them early.
        // (A block's starts are in its worker's table, already in the CPU's caches.)
        if (r + 4 < hi) walker->prefetch(blocks.point_at(r + 4));
        const std::uint32_t s = blocks.point_at(r);
        if (s < run.begin || s >= run.end) continue;
        if (!options.seeds.empty() && !std::binary_search(options.seeds.begin(), options.seeds.end(), s)) continue;
        ++out.seeds;
        // Over held points (MeshOptions::held) the whole star is certified first.
        const StarPart part = options.accept    ? options.accept_part
                              : held != nullptr ? StarPart::kWhole
                                                : StarPart::kOwned;
        status = walker->compute(s, star, part);
        if (!status.is_ok()) break;
        if (held != nullptr) {
          StarCertificate c = held->certify(tree_points, star);
          if (!c.certified) {
            deferred.fetch_add(1, std::memory_order_relaxed);
            if (options.defer) options.defer(s, std::move(c));
            continue;
          }
        }
        if (options.accept && !options.accept(star)) continue;
        const auto owned = owned_simplices(star);
        out.simplices.insert(out.simplices.end(), owned.begin(), owned.end());
      }
      if (front) {
        front->end_block();
        front_bytes = std::max(front_bytes, front->held_bytes());
      }
      return status;
    }
    void finish() {
      total.star += walker->stats();
      worker_bytes += front_bytes;
    }
  };
  auto make_worker = [&] {
    auto w = std::unique_ptr<Worker>(new Worker{
        blocks, options, run, first_block, total, worker_bytes, {}, {}, {}, 0, held, tree.points(), deferred});
    if (mail) w->front.emplace(d, blocks, *mail, run);
    StarOptions star_options = options.star;
    star_options.facets = w->front ? &*w->front : nullptr;
    star_options.edges = edges ? &*edges : nullptr;
    w->walker.emplace(tree, star_options);
    return w;
  };
  std::uint64_t written = 0, seeds_done = 0;
  const Status failure =
      detail::run_in_order<MeshedBlock>(count, threads, window, make_worker, [&](MeshedBlock& block) -> Status {
        ++written;
        // Every seed before the next block to write is done: its 2-d posts can go.
        if (edges)
          edges->release_before(written < count ? blocks.begin(static_cast<std::uint32_t>(first_block + written))
                                                : static_cast<std::uint32_t>(n));
        seeds_done += block.seeds;
        total.simplices += block.simplices.size() / static_cast<std::size_t>(d + 1);
        return sink(block.simplices, seeds_done);
      });
  if (!failure.is_ok()) return failure;
  total.seeds = seeds_done;
  total.deferred = deferred.load();
  total.front_peak_bytes = mail ? mail->peak_bytes() : 0;
  total.facet_cache_bytes = edges ? edges->resident_peak_bytes() : total.front_peak_bytes + worker_bytes;
  return total;
}

std::uint64_t expected_simplices(int d, std::uint64_t n) {
  return static_cast<std::uint64_t>(detail::policy(d).simplices_per_point * static_cast<double>(n));
}

}  // namespace spokemesh
