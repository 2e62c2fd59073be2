// insert_points (mesh.hpp): a whole mesh brought up to date with new points by
// recomputing the stars that change, in the whole set's sweep order.
#include <algorithm>
#include <atomic>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "spokemesh/mesh.hpp"

namespace spokemesh {

namespace {

// Computes the stars of `seeds` (part `part`) on `threads` workers; `use(i, star)` is
// called for seeds[i] on the worker that computed it. The first error stops the run.
template <class Use>
Status for_each_star(const KdTree& tree, const MeshOptions& options, const std::vector<std::uint32_t>& seeds,
                     StarPart part, Use&& use) {
  std::atomic<std::size_t> next{0};
  std::mutex mu;
  Status failure;
  auto work = [&] {
    StarWalker walker(tree, options.star);
    Star star;
    for (;;) {
      const std::size_t i = next.fetch_add(1);
      if (i >= seeds.size()) return;
      Status s = walker.compute(seeds[i], star, part);
      if (!s.is_ok()) {
        std::lock_guard lock(mu);
        if (failure.is_ok()) failure = std::move(s);
        next = seeds.size();
        return;
      }
      use(i, star);
    }
  };
  const unsigned threads = std::max(1u, std::min<unsigned>(options.threads, static_cast<unsigned>(seeds.size())));
  std::vector<std::thread> pool;
  for (unsigned t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (std::thread& t : pool) t.join();
  return failure;
}

}  // namespace

Result<InsertStats> insert_points(const KdTree& tree, const SpaceSplit& split, std::uint32_t n_old,
                                  std::span<const std::uint32_t> old_rows, const MeshOptions& options,
                                  std::vector<std::uint32_t>& out) {
  const PointSet& points = tree.points();
  const auto n = static_cast<std::uint32_t>(points.size());
  const auto w = static_cast<std::size_t>(points.dimension()) + 1;
  if (n_old >= n) {
    return invalid_argument("insert_points: " + std::to_string(n_old) + " old points of " + std::to_string(n) +
                            "; nothing to insert");
  }
  // The old rows by owner (the first vertex): where each owner's run starts.
  std::vector<std::uint64_t> first_row(n_old, ~std::uint64_t{0});
  std::vector<std::uint32_t> row_count(n_old, 0);
  const std::size_t m_old = old_rows.size() / w;
  for (std::size_t r = 0; r < m_old; ++r) {
    const std::uint32_t owner = old_rows[r * w];
    if (owner >= n_old) {
      return invalid_argument("insert_points: row " + std::to_string(r) + " names point " + std::to_string(owner) +
                              ", not one of the " + std::to_string(n_old) + " old points");
    }
    if (row_count[owner]++ == 0) first_row[owner] = r;
  }

  // Many new points change most stars: then the whole sweep, whose stars share their
  // wraps, is faster than stars one by one (3-d 1M on 2 threads: adding 10% star by
  // star took 1.8x the whole mesh's time). The estimate: each new point changes the
  // stars of its neighbours, about 6 in 2-d, 15 in 3-d, more above.
  const std::uint64_t n_new = n - n_old;
  const int d = points.dimension();
  const std::uint64_t degree = d == 2 ? 6 : d == 3 ? 15 : std::uint64_t{3} << d;
  if (n_new * (1 + degree) > n / 3) {
    MeshOptions whole;
    whole.threads = options.threads;
    whole.star = options.star;
    whole.split = &split;
    out.clear();
    auto run = mesh_seeds(tree, whole, [&](std::span<const std::uint32_t> block, std::uint64_t) {
      out.insert(out.end(), block.begin(), block.end());
      return Status::ok();
    });
    if (!run.is_ok()) return run.status();
    InsertStats stats;
    stats.stars = n;
    stats.whole = true;
    return stats;
  }
  // The new points' stars (every simplex: their vertices are the old points whose
  // stars change), then the changed old points' owned parts.
  std::vector<std::uint32_t> seeds;
  for (std::uint32_t i = n_old; i < n; ++i) seeds.push_back(i);
  std::vector<std::vector<std::uint32_t>> rows_of(n - n_old);  // owned rows of seeds[i]
  std::unique_ptr<std::atomic<std::uint8_t>[]> changed(new std::atomic<std::uint8_t>[n_old]);
  for (std::uint32_t v = 0; v < n_old; ++v) changed[v].store(0, std::memory_order_relaxed);
  Status s = for_each_star(tree, options, seeds, StarPart::kAll, [&](std::size_t i, const Star& star) {
    const auto owned = owned_simplices(star);
    rows_of[i].assign(owned.begin(), owned.end());
    for (const std::uint32_t v : star.simplices) {
      if (v < n_old) changed[v].store(1, std::memory_order_relaxed);  // (read after the workers join)
    }
  });
  if (!s.is_ok()) return s;
  std::vector<std::uint32_t> old_seeds;
  for (std::uint32_t v = 0; v < n_old; ++v) {
    if (changed[v].load(std::memory_order_relaxed) != 0) old_seeds.push_back(v);
  }
  std::vector<std::vector<std::uint32_t>> old_rows_of(old_seeds.size());
  s = for_each_star(tree, options, old_seeds, StarPart::kOwned, [&](std::size_t i, const Star& star) {
    old_rows_of[i].assign(star.simplices.begin(), star.simplices.end());
  });
  if (!s.is_ok()) return s;

  // The rows in the whole set's sweep order.
  std::vector<std::uint32_t> redone(n_old, ~0u);  // index into old_rows_of
  for (std::size_t i = 0; i < old_seeds.size(); ++i) redone[old_seeds[i]] = static_cast<std::uint32_t>(i);
  InsertStats stats;
  stats.stars = seeds.size() + old_seeds.size();
  out.clear();
  for (const std::uint32_t seed : split.order()) {
    if (seed >= n_old) {
      const std::vector<std::uint32_t>& r = rows_of[seed - n_old];
      out.insert(out.end(), r.begin(), r.end());
    } else if (redone[seed] != ~0u) {
      const std::vector<std::uint32_t>& r = old_rows_of[redone[seed]];
      out.insert(out.end(), r.begin(), r.end());
    } else if (row_count[seed] != 0) {
      const auto from = old_rows.begin() + static_cast<std::ptrdiff_t>(first_row[seed] * w);
      out.insert(out.end(), from, from + static_cast<std::ptrdiff_t>(row_count[seed] * w));
      stats.rows_kept += row_count[seed];
    }
  }
  return stats;
}

}  // namespace spokemesh
