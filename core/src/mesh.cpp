#include "spokemesh/mesh.hpp"

#include <algorithm>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

namespace spokemesh {

std::span<const std::uint32_t> owned_simplices(const Star& star) {
  const std::size_t w = static_cast<std::size_t>(star.dimension) + 1;
  std::size_t first = 0;
  while (first < star.size() && star.simplex(first)[0] != star.seed) ++first;
  return std::span<const std::uint32_t>(star.simplices).subspan(first * w);
}

namespace {

struct Block {
  bool done = false;
  Status status;
  std::vector<std::uint32_t> simplices;
};

}  // namespace

Result<MeshStats> mesh_seeds(const KdTree& tree, const MeshOptions& options, const SimplexSink& sink) {
  const std::uint64_t n = tree.points().size();
  const std::uint64_t begin = std::min<std::uint64_t>(options.seed_begin, n);
  const std::uint64_t end = std::clamp<std::uint64_t>(options.seed_end, begin, n);
  const unsigned threads = std::max(1u, options.threads);
  const int d = tree.points().dimension();
  // Blocks small enough to balance, to show progress and to bound the work a stalled
  // reader leaves buffered, large enough to amortise. In 2-d, whose stars are cheapest
  // and most bound by memory latency, larger blocks keep the leaf order below dense, so
  // consecutive stars (and the workers' concurrent blocks, swept in the same order)
  // touch the same tree nodes and points (measured: bench/README.md, "Tuning
  // history"). A 2-d block of at most 131,072 seeds buffers about 3 MB of triangles.
  const std::uint64_t per_thread = d == 2 ? 4 : 64;
  const std::uint64_t block = options.block_size != 0
                                  ? options.block_size
                                  : std::clamp<std::uint64_t>((end - begin) / (threads * per_thread) + 1, 1,
                                                              d == 2 ? 131072 : d == 3 ? 4096 : 256);
  const std::uint64_t blocks = (end - begin + block - 1) / block;
  // Blocks in flight beyond the next one to write: 4 per worker, and no more seeds
  // than 4 blocks of 32,768 per worker (this caps the large 2-d blocks), so that a
  // slow reader leaves at most a few MB of simplices buffered.
  const std::uint64_t window =
      std::max<std::uint64_t>(threads, std::min<std::uint64_t>(4ull * threads, 4ull * threads * 32768 / block));

  // Shared by every worker's walker: a facet wrapped in one star answers the same
  // wrap in the stars of its other vertices (in 2-d, posted per point).
  std::optional<RunCache> cache;
  if (options.facet_cache_bytes != 0) {
    cache.emplace(d, static_cast<std::uint32_t>(n), static_cast<std::uint32_t>(begin), static_cast<std::uint32_t>(end),
                  options.facet_cache_bytes, static_cast<std::uint32_t>(block));
  }
  StarOptions star_options = options.star;
  if (cache && cache->enabled()) star_options.cache = &*cache;

  std::mutex mu;
  std::condition_variable worker_cv, writer_cv;
  std::deque<Block> ring;  // ring[i] is block (written + i)
  std::uint64_t written = 0, next_block = 0;
  bool stop = false;
  MeshStats total;

  auto worker = [&] {
    StarWalker walker(tree, star_options);
    Star star;
    std::vector<std::uint32_t> out, found, order;
    std::vector<std::uint64_t> keys;
    std::vector<std::pair<std::size_t, std::size_t>> extent;  // per seed of the block: its simplices in `found`
    for (;;) {
      std::uint64_t b;
      {
        std::unique_lock lock(mu);
        worker_cv.wait(lock, [&] { return stop || next_block >= blocks || next_block < written + window; });
        if (stop || next_block >= blocks) break;
        b = next_block++;
        if (ring.size() <= b - written) ring.resize(b - written + 1);
      }
      // The block's seeds in the tree's leaf order, so that consecutive stars query
      // nearby parts of the tree and the point set (memory latency, not arithmetic,
      // bounds a 2-d star); their owned simplices are then put back in seed order.
      const std::uint64_t lo = begin + b * block, hi = std::min(end, lo + block);
      // Sorted as (rank, seed) words: a comparator that looked the ranks up cost a
      // random read per comparison.
      keys.resize(hi - lo);
      for (std::uint64_t s = lo; s < hi; ++s) {
        keys[s - lo] = std::uint64_t{tree.leaf_rank(static_cast<std::uint32_t>(s))} << 32 | s;
      }
      std::sort(keys.begin(), keys.end());
      order.resize(hi - lo);
      for (std::size_t i = 0; i < keys.size(); ++i) order[i] = static_cast<std::uint32_t>(keys[i]);
      found.clear();
      extent.resize(hi - lo);
      Status status;
      for (std::size_t i = 0; i < order.size(); ++i) {
        // The next seeds' start entries are loads at random: begin them early, in two
        // steps since the entry's place is itself read from memory.
        if (i + 4 < order.size()) walker.prefetch(order[i + 4]);
        if (i + 2 < order.size()) walker.prefetch_start(order[i + 2]);
        const std::uint32_t s = order[i];
        status = walker.compute(s, star, StarPart::kOwned);
        if (!status.is_ok()) break;
        const auto owned = owned_simplices(star);
        extent[s - lo] = {found.size(), owned.size()};
        found.insert(found.end(), owned.begin(), owned.end());
      }
      out.clear();
      if (status.is_ok()) {
        out.reserve(found.size());  // exactly: a large block's doubling would overshoot by MBs
        for (const auto& [at, size] : extent) {
          out.insert(out.end(), found.begin() + static_cast<std::ptrdiff_t>(at),
                     found.begin() + static_cast<std::ptrdiff_t>(at + size));
        }
      }
      std::lock_guard lock(mu);
      Block& slot = ring[b - written];
      slot.done = true;
      slot.status = std::move(status);
      slot.simplices.swap(out);
      writer_cv.notify_one();
    }
    std::lock_guard lock(mu);
    total.star += walker.stats();
  };

  std::vector<std::thread> pool;
  pool.reserve(threads);
  for (unsigned t = 0; t < threads; ++t) pool.emplace_back(worker);

  Status failure;
  std::vector<std::uint32_t> current;
  while (written < blocks) {
    {
      std::unique_lock lock(mu);
      writer_cv.wait(lock, [&] { return !ring.empty() && ring.front().done; });
      current.swap(ring.front().simplices);
      failure = std::move(ring.front().status);
      ring.pop_front();
      ++written;
      worker_cv.notify_all();
    }
    if (failure.is_ok()) {
      total.simplices += current.size() / static_cast<std::size_t>(d + 1);
      const std::uint64_t seeds_done = std::min<std::uint64_t>(written * block, end - begin);
      failure = sink(current, seeds_done);
    }
    if (!failure.is_ok()) {
      std::lock_guard lock(mu);
      stop = true;
      worker_cv.notify_all();
      break;
    }
  }
  for (auto& t : pool) t.join();
  if (!failure.is_ok()) return failure;
  total.seeds = end - begin;
  total.facet_cache_bytes = cache ? cache->reserved_bytes() : 0;
  return total;
}

}  // namespace spokemesh
