#include "spokemesh/graph.hpp"

#include <algorithm>
#include <chrono>
#include <mutex>
#include <thread>

#include "spokemesh/mesh.hpp"
#include "spokemesh/star.hpp"

namespace spokemesh {

namespace {

// The exact graph from the whole mesh's sweep (mesh_seeds: in 2-d and 3-d the local
// triangulations with certified stars): each seed's whole star is offered to `accept`,
// which keeps the edges to its larger neighbours and emits no rows.
Result<Edges> graph_by_sweep(const KdTree& tree, const GraphOptions& options) {
  MeshOptions mesh;
  mesh.threads = std::max(1u, options.threads);
  mesh.star = options.star;
  mesh.star.cancel = options.cancel;
  std::mutex mu;
  Edges edges;
  mesh.accept = [&](const Star& star) {
    const std::vector<std::uint32_t> next = star_neighbors(star);
    const auto larger = std::upper_bound(next.begin(), next.end(), star.seed);
    std::lock_guard lock(mu);
    for (auto it = larger; it != next.end(); ++it) edges.emplace_back(star.seed, *it);
    return false;  // no rows
  };
  auto run = mesh_seeds(tree, mesh, [&](std::span<const std::uint32_t>, std::uint64_t seeds_done) {
    if (options.progress) options.progress(seeds_done);
    return Status::ok();
  });
  if (!run.is_ok()) {
    if (run.status().code() == Code::kCancelled) return cancelled("graph computation cancelled");
    return run.status();
  }
  std::sort(edges.begin(), edges.end());
  return edges;
}

}  // namespace

Result<Edges> delaunay_graph(const KdTree& tree, const GraphOptions& options, GraphStats* stats) {
  const PointSet& ps = tree.points();
  const std::size_t n = ps.size();
  if (!options.approximate && ps.dimension() > kMaxDimension) {
    return invalid_argument("exact Delaunay graphs are limited to d <= " + std::to_string(kMaxDimension) +
                            " (this point set is " + std::to_string(ps.dimension()) +
                            "-d); use the approximate graph (--approx)");
  }
  // Exact graphs of sets the local triangulations mesh (2-d, 3-d, unweighted, not
  // periodic): their stars, certified locally; on closed surfaces and scans a star walk
  // per seed cost up to a hundred times more.
  if (!options.approximate && (ps.dimension() == 2 || ps.dimension() == 3) && options.star.weights.empty() &&
      options.star.cover == nullptr) {
    return graph_by_sweep(tree, options);
  }
  const unsigned threads = std::max(1u, options.threads);
  // Seeds in small chunks from a shared counter; each worker keeps its own edges.
  constexpr std::uint32_t kChunk = 16;
  std::atomic<std::uint32_t> next{0};
  std::atomic<std::uint64_t> done{0};
  std::vector<Edges> parts(threads);
  std::vector<Status> failures(threads);  // each written by its worker only
  std::atomic<bool> failed{false};        // what the progress loop may read
  std::vector<GraphStats> part_stats(threads);
  auto stop = [&] { return options.cancel != nullptr && options.cancel->load(std::memory_order_relaxed); };
  auto work = [&](unsigned w) {
    Edges& edges = parts[w];
    StarOptions star_options = options.star;
    star_options.cancel = options.cancel;
    ApproxOptions approx_options = options.approx;
    approx_options.cancel = options.cancel;
    std::unique_ptr<StarWalker> exact;
    std::unique_ptr<ApproxWalker> approx;
    if (options.approximate)
      approx = std::make_unique<ApproxWalker>(tree, approx_options);
    else
      exact = std::make_unique<StarWalker>(tree, star_options);
    Star star;
    ApproxNeighbors neighbors;
    for (;;) {
      const std::uint32_t begin = next.fetch_add(kChunk);
      if (begin >= n || stop()) return;
      const std::uint32_t end = static_cast<std::uint32_t>(std::min<std::size_t>(n, begin + std::size_t{kChunk}));
      for (std::uint32_t seed = begin; seed < end; ++seed) {
        if (options.approximate) {
          if (Status s = approx->compute(seed, neighbors); !s.is_ok()) {
            failures[w] = s;
            failed = true;
            return;
          }
          part_stats[w].vertices += neighbors.vertices;
          part_stats[w].uncertified += neighbors.uncertified;
          for (std::uint32_t v : neighbors.neighbors) edges.emplace_back(std::min(seed, v), std::max(seed, v));
        } else {
          if (Status s = exact->compute(seed, star); !s.is_ok()) {
            failures[w] = s;
            failed = true;
            return;
          }
          // Exact edges are symmetric: keep each once, from its smaller endpoint.
          for (std::uint32_t v : star_neighbors(star)) {
            if (v > seed) edges.emplace_back(seed, v);
          }
        }
      }
      done += end - begin;
    }
  };
  std::vector<std::thread> pool;
  for (unsigned w = 1; w < threads; ++w) pool.emplace_back(work, w);
  std::thread main_worker(work, 0u);
  if (options.progress) {
    while (done.load() < n && !stop() && !failed.load()) {
      options.progress(done.load());
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
  }
  main_worker.join();
  for (auto& t : pool) t.join();
  for (const Status& f : failures) {
    if (!f.is_ok()) return f;
  }
  if (stop()) return cancelled("graph computation cancelled");
  Edges edges;
  for (Edges& p : parts) edges.insert(edges.end(), p.begin(), p.end());
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  if (stats != nullptr) {
    for (const GraphStats& s : part_stats) {
      stats->vertices += s.vertices;
      stats->uncertified += s.uncertified;
    }
  }
  return edges;
}

}  // namespace spokemesh
