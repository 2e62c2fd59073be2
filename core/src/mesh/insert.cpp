// insert_points (mesh.hpp): a whole mesh brought up to date with new points by
// recomputing the stars that change, in the whole set's sweep order.
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <memory>
#include <mutex>
#include <numeric>
#include <thread>
#include <vector>

#include "spokemesh/circumcentre.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh {

namespace {

// insert_points walks kProbeSeeds new points first, stopped after kProbeShare of
// what the whole mesh would cost (about kMeshSecondsPerPoint[d] a point, one thread),
// and walks the others too when all of them would cost at most kWalksShareAtMost of it.
constexpr std::size_t kProbeSeeds = 16;
constexpr double kProbeShare = 0.02;
constexpr double kMeshSecondsPerPoint[4] = {0, 0, 1.5e-6, 5e-6};
constexpr double kWalksShareAtMost = 0.25;

// Runs work(t, threads) on `threads` threads (t = 0 on the calling one) and joins them.
template <class Work>
void on_threads(unsigned threads, Work&& work) {
  threads = std::max(1u, threads);
  std::vector<std::thread> pool;
  for (unsigned t = 1; t < threads; ++t) pool.emplace_back([&, t] { work(t, threads); });
  work(0u, threads);
  for (std::thread& t : pool) t.join();
}

// Computes the stars of `seeds` (part `part`) on `threads` workers; `use(i, star)` is
// called for seeds[i] on the worker that computed it. The first error stops the run.
template <class Use>
Status for_each_star(const KdTree& tree, const MeshOptions& options, const std::vector<std::uint32_t>& seeds,
                     StarPart part, Use&& use) {
  std::atomic<std::size_t> next{0};
  std::mutex mu;
  Status failure;
  auto work = [&](unsigned, unsigned) {
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
  on_threads(std::min<unsigned>(options.threads, static_cast<unsigned>(seeds.size())), work);
  return failure;
}

}  // namespace

Result<InsertStats> insert_points(const KdTree& tree, const SpaceSplit& split, std::uint32_t n_old,
                                  std::span<const std::uint32_t> old_rows, const MeshOptions& options, Rows& out) {
  return insert_points(
      tree, [&]() -> const SpaceSplit& { return split; }, n_old, old_rows, options, out);
}

Result<InsertStats> insert_points(const KdTree& tree, const std::function<const SpaceSplit&()>& split_when_needed,
                                  std::uint32_t n_old, std::span<const std::uint32_t> old_rows,
                                  const MeshOptions& options, Rows& out) {
  const PointSet& points = tree.points();
  const auto n = static_cast<std::uint32_t>(points.size());
  const auto w = static_cast<std::size_t>(points.dimension()) + 1;
  if (n_old >= n) {
    return invalid_argument("insert_points: " + std::to_string(n_old) + " old points of " + std::to_string(n) +
                            "; nothing to insert");
  }
  if (!options.star.weights.empty()) {
    // Which old stars a new point changes is decided by circumspheres here, not by
    // power spheres (and a new point can hide an old one): not for weighted sets yet.
    return invalid_argument("insert_points: weighted points are not supported yet; mesh the whole set");
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

  // Many new points: then the whole sweep, whose stars share their wraps, is faster
  // than the new points' stars one by one and the filtering of their neighbours' rows.
  // Measured on 2 threads, 1M points: in 3-d adding 10% took 0.52x the whole sweep and
  // 50% 1.46x; in 2-d 10% 0.81x, 30% 1.6x. So the sweep beyond a fifth new (3-d) or an
  // eighth (2-d, and above 3-d, where one-by-one stars lose more to shared wraps).
  const std::uint64_t n_new = n - n_old;
  const int d = points.dimension();
  auto sweep_whole = [&]() -> Result<InsertStats> {
    MeshOptions whole;
    whole.threads = options.threads;
    whole.star = options.star;
    whole.split = &split_when_needed();
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
  };
  const bool triangulations = (d == 2 || d == 3) && options.star.cover == nullptr;
  if (n_new > n / (d == 3 ? 5 : 8) || (triangulations && options.engine == MeshEngine::kTriangulations)) {
    return sweep_whole();
  }
  // The new points' stars: every simplex that is new (a new simplex has a new vertex),
  // and their vertices are the old points whose stars change.
  std::vector<std::uint32_t> seeds;
  for (std::uint32_t i = n_old; i < n; ++i) seeds.push_back(i);
  std::vector<std::vector<std::uint32_t>> rows_of(n - n_old);    // owned rows of seeds[i]
  std::vector<std::vector<std::uint32_t>> gained_of(n - n_old);  // rows with an old owner, from seeds[i]'s star
  std::unique_ptr<std::atomic<std::uint8_t>[]> changed(new std::atomic<std::uint8_t>[n_old]);
  for (std::uint32_t v = 0; v < n_old; ++v) changed[v].store(0, std::memory_order_relaxed);
  auto use_star = [&](std::size_t i, const Star& star) {
    const auto owned = owned_simplices(star);
    rows_of[i].assign(owned.begin(), owned.end());
    const std::uint32_t q = seeds[i];
    for (std::size_t r = 0; r < star.simplices.size(); r += w) {
      const std::uint32_t* row = &star.simplices[r];
      std::uint32_t smallest_new = n;
      for (std::size_t j = 0; j < w; ++j) {
        if (row[j] < n_old) {
          changed[row[j]].store(1, std::memory_order_relaxed);  // (read after the workers join)
        } else {
          smallest_new = std::min(smallest_new, row[j]);
        }
      }
      // Each new simplex with an old owner once: from its smallest new vertex's star.
      if (row[0] < n_old && smallest_new == q) gained_of[i].insert(gained_of[i].end(), row, row + w);
    }
  };
  // The new points' stars are walked where that costs little against meshing the
  // whole set (uniform points: about 100 us a star; the sweep's split, built meanwhile on
  // another thread, is waited for only when the rows are put in order); a probe of
  // kProbeSeeds new points, spread over them and stopped at a deadline, says so.
  // Elsewhere (2-d and 3-d surfaces, scans, contour lines: a walk of many ms, on a
  // sphere's surface seconds) the whole set is meshed again by the local triangulations,
  // which was measured faster there than any part of it (the new stars by the sweep
  // restricted to them, then the changed old ones: 1.1x-2x a rebuild, as their regions
  // or the triangulation of every point are built anyway). Weighted sets are refused
  // above; periodic covers and 4-d and up walk.
  std::vector<std::uint32_t> rest;
  if (triangulations && options.engine == MeshEngine::kAuto) {
    const double whole_seconds = kMeshSecondsPerPoint[d] * static_cast<double>(n);
    const auto start = std::chrono::steady_clock::now();
    StarOptions probe_options = options.star;
    probe_options.deadline = start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                         std::chrono::duration<double>(kProbeShare * whole_seconds));
    StarWalker walker(tree, probe_options);
    Star star;
    std::vector<std::uint8_t> probed(seeds.size(), 0);
    const std::size_t step = std::max<std::size_t>(1, seeds.size() / kProbeSeeds);
    std::size_t walked = 0;
    for (std::size_t i = 0; i < seeds.size() && walked < kProbeSeeds; i += step) {
      const Status st = walker.compute(seeds[i], star, StarPart::kAll);
      if (st.code() == Code::kDeadlineExceeded) return sweep_whole();
      if (!st.is_ok()) return st;
      use_star(i, star);
      probed[i] = 1;
      ++walked;
    }
    const double mean =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() / static_cast<double>(walked);
    if (mean * static_cast<double>(seeds.size()) > kWalksShareAtMost * whole_seconds) return sweep_whole();
    for (std::size_t i = 0; i < seeds.size(); ++i) {
      if (probed[i] == 0) rest.push_back(seeds[i]);
    }
  } else {
    rest = seeds;
  }
  if (Status s = for_each_star(tree, options, rest, StarPart::kAll,
                               [&](std::size_t i, const Star& star) { use_star(rest[i] - n_old, star); });
      !s.is_ok()) {
    return s;
  }
  std::vector<std::uint32_t> old_seeds;
  std::vector<std::uint32_t> redone(n_old, ~0u);  // index into old_seeds
  for (std::uint32_t v = 0; v < n_old; ++v) {
    if (changed[v].load(std::memory_order_relaxed) == 0) continue;
    redone[v] = static_cast<std::uint32_t>(old_seeds.size());
    old_seeds.push_back(v);
  }
  std::vector<std::vector<std::uint32_t>> old_rows_of(old_seeds.size());
  for (const std::vector<std::uint32_t>& g : gained_of) {
    for (std::size_t r = 0; r < g.size(); r += w) {
      std::vector<std::uint32_t>& to = old_rows_of[redone[g[r]]];
      to.insert(to.end(), g.begin() + static_cast<std::ptrdiff_t>(r), g.begin() + static_cast<std::ptrdiff_t>(r + w));
    }
  }
  gained_of = {};

  // A changed old point's owned rows: its old ones that are still Delaunay, and the new
  // ones it owns. An old simplex stays unless a new point lies in its circumsphere (no
  // old one does: it was Delaunay among them), and one that goes changes the stars of
  // all its vertices, so only simplices whose vertices all changed are tested: the new
  // points within the circumsphere grown by a margin far above the circumcentre's error
  // (voronoi.hpp: 1e-12 of the radius), each decided by the exact perturbed test. Rows
  // then in the star's order: lexicographic by their sorted indices.
  const Predicates predicates(points);
  // The new points alone, for the circumsphere queries (a small tree: ids - n_old).
  const PointSet new_points(d,
                            std::vector<double>(points.coordinates().begin() + static_cast<std::ptrdiff_t>(n_old) * d,
                                                points.coordinates().end()));
  const KdTree new_tree(new_points);
  std::atomic<std::size_t> next{0};
  std::vector<std::uint8_t> same_rows(old_seeds.size(), 0);  // written by one worker each
  auto work = [&](unsigned, unsigned) {
    std::vector<std::pair<std::uint32_t, double>> near;
    std::vector<std::uint32_t> kept;
    std::vector<std::size_t> order;
    std::vector<std::array<std::uint32_t, kMaxDimension + 1>> keys;
    for (;;) {
      const std::size_t i = next.fetch_add(1);
      if (i >= old_seeds.size()) return;
      const std::uint32_t v = old_seeds[i];
      std::vector<std::uint32_t>& rows = old_rows_of[i];
      const std::size_t gained = rows.size();
      std::size_t kept_rows = 0;
      for (std::uint32_t r = 0; r < row_count[v]; ++r) {
        const std::uint32_t* row = &old_rows[(first_row[v] + r) * w];
        bool all_changed = true;
        for (std::size_t j = 0; j < w && all_changed; ++j)
          all_changed = changed[row[j]].load(std::memory_order_relaxed) != 0;
        bool killed = false;
        if (all_changed) {
          const std::vector<double> c = circumcentre(points, row, static_cast<int>(w));
          double r2 = 0;
          for (int k = 0; k < d; ++k) {
            const double dx = points.point(row[0])[k] - c[static_cast<std::size_t>(k)];
            r2 += dx * dx;
          }
          const double reach = std::sqrt(r2) * (1 + 1e-9) + 1e-300;
          near.clear();
          new_tree.within(c.data(), reach * reach, near);
          for (const auto& [q, dist2] : near) {
            if (predicates.side_of_sphere(std::span<const std::uint32_t>(row, w), n_old + q) < 0) {
              killed = true;
              break;
            }
          }
        }
        if (!killed) {
          rows.insert(rows.end(), row, row + w);
          ++kept_rows;
        }
      }
      if (gained == 0 && kept_rows == row_count[v]) {
        // Its star changed, not its own rows: they are taken from old_rows as they are.
        std::vector<std::uint32_t>().swap(rows);
        same_rows[i] = 1;
        continue;
      }
      if (gained == 0) continue;
      // In the star's order, lexicographic by sorted indices: the kept old rows are in
      // it already, the gained ones (a few) are sorted and merged in.
      const std::size_t m = rows.size() / w;
      keys.resize(m);
      for (std::size_t k = 0; k < m; ++k) {
        keys[k].fill(0);
        std::copy_n(&rows[k * w], w, keys[k].begin());
        std::sort(keys[k].begin(), keys[k].begin() + static_cast<std::ptrdiff_t>(w));
      }
      order.resize(m);
      std::iota(order.begin(), order.end(), std::size_t{0});
      const auto by_key = [&](std::size_t x, std::size_t y) { return keys[x] < keys[y]; };
      const auto gained_end = order.begin() + static_cast<std::ptrdiff_t>(gained / w);
      std::sort(order.begin(), gained_end, by_key);
      std::inplace_merge(order.begin(), gained_end, order.end(), by_key);
      kept.clear();
      for (const std::size_t k : order) kept.insert(kept.end(), &rows[k * w], &rows[k * w] + w);
      rows.swap(kept);
    }
  };
  on_threads(std::min<unsigned>(options.threads, static_cast<unsigned>(old_seeds.size())), work);

  // The rows in the whole set's sweep order.
  InsertStats stats;
  stats.stars = seeds.size();
  stats.rows_redone = old_seeds.size();
  // Each seed's place in the output, then the copies in parallel (the output is about
  // the mesh's size: a single thread's copying and page faults would show).
  for (std::size_t i = 0; i < old_seeds.size(); ++i) {
    if (same_rows[i] != 0) redone[old_seeds[i]] = ~0u;
  }
  const std::span<const std::uint32_t> order = split_when_needed().order();
  std::vector<std::size_t> at(order.size() + 1, 0);
  for (std::size_t k = 0; k < order.size(); ++k) {
    const std::uint32_t seed = order[k];
    at[k + 1] = at[k] + (seed >= n_old         ? rows_of[seed - n_old].size()
                         : redone[seed] != ~0u ? old_rows_of[redone[seed]].size()
                                               : std::size_t{row_count[seed]} * w);
    if (seed < n_old && redone[seed] == ~0u) stats.rows_kept += row_count[seed];
  }
  out.resize(at.back());
  auto copy = [&](std::size_t from, std::size_t to) {
    for (std::size_t k = from; k < to; ++k) {
      if (at[k + 1] == at[k]) continue;
      const std::uint32_t seed = order[k];
      const std::uint32_t* src = seed >= n_old         ? rows_of[seed - n_old].data()
                                 : redone[seed] != ~0u ? old_rows_of[redone[seed]].data()
                                                       : old_rows.data() + first_row[seed] * w;
      std::copy(src, src + (at[k + 1] - at[k]), out.begin() + static_cast<std::ptrdiff_t>(at[k]));
    }
  };
  on_threads(options.threads,
             [&](unsigned t, unsigned threads) { copy(order.size() * t / threads, order.size() * (t + 1) / threads); });
  return stats;
}

}  // namespace spokemesh
