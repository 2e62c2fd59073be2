// Per-seed latency of one star, in process, against a warm tree: what a server
// request for one seed costs once its point set is loaded.
//
//   build/bin/spokemesh_latency [--quick] [--kept] [--samples N] [--only uniform|linspace] [--candidates K]
//
// For each input (3-d uniform 1M points, 3-d linspace grid 50^3; --quick: 100k and
// 25^3) it builds the k-d tree, warms one walker on 1,000 seeds, then times
// `StarWalker::compute` on N random seeds (fixed seed, default 20,000), one at a time,
// without the whole-mesh FacetCache (a single request has none). Prints p50, p90,
// p99, max and mean in microseconds, and the mean simplices per star.
//
// --kept: instead, the triangulation of every point is built (triangulate_whole, as a
// server keeps it with --keep-triangulations) and each sample reads a star from it with
// a fresh WholeStarReader and computes its circumcentres: what a kept star's request
// costs in the engine.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "inputs.hpp"
#include "spokemesh/circumcentre.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/star.hpp"

namespace {

using Clock = std::chrono::steady_clock;

struct Input {
  std::string name;
  std::vector<double> coords;
};

int run(const Input& input, std::size_t samples, std::size_t candidates, bool kept) {
  spokemesh::PointSet ps(3, input.coords);
  if (spokemesh::Status s = ps.validate(input.name); !s.is_ok()) {
    std::fprintf(stderr, "%s\n", s.message().c_str());
    return 1;
  }
  const auto t0 = Clock::now();
  const spokemesh::KdTree tree(ps);
  std::shared_ptr<const spokemesh::WholeTriangulation> whole;
  if (kept) {
    auto built = spokemesh::triangulate_whole(ps);
    if (!built.is_ok()) return std::fprintf(stderr, "%s\n", built.status().message().c_str()), 1;
    whole = std::move(built).value();
  }
  const double build_s = std::chrono::duration<double>(Clock::now() - t0).count();
  spokemesh::StarWalker walker(tree, spokemesh::StarOptions{.initial_candidates = candidates});
  spokemesh::Star star;
  std::vector<double> centres;
  // One sample: a walked star, or (kept) a star read with a fresh reader and its
  // circumcentres, as the server's request does.
  auto one = [&](std::uint32_t seed) {
    if (!kept) return walker.compute(seed, star);
    spokemesh::WholeStarReader reader(*whole);
    if (spokemesh::Status s = reader.star(seed, star); !s.is_ok()) return s;
    centres.resize(star.size() * 3);
    for (std::size_t k = 0; k < star.size(); ++k) {
      spokemesh::circumcentre(ps, star.simplex(k), 4, nullptr, centres.data() + 3 * k);
    }
    return spokemesh::Status::ok();
  };
  std::mt19937_64 rng(2016);
  std::uniform_int_distribution<std::uint32_t> pick(0, static_cast<std::uint32_t>(ps.size() - 1));
  for (int i = 0; i < 1000; ++i) {
    if (!one(pick(rng)).is_ok()) return 1;
  }
  std::vector<double> us(samples);
  std::size_t simplices = 0;
  for (std::size_t i = 0; i < samples; ++i) {
    const std::uint32_t seed = pick(rng);
    const auto start = Clock::now();
    const spokemesh::Status s = one(seed);
    us[i] = std::chrono::duration<double, std::micro>(Clock::now() - start).count();
    if (!s.is_ok()) return 1;
    simplices += star.size();
  }
  double mean = 0;
  for (const double t : us) mean += t;
  mean /= static_cast<double>(samples);
  std::sort(us.begin(), us.end());
  auto at = [&](double q) {
    return us[std::min(samples - 1, static_cast<std::size_t>(q * static_cast<double>(samples)))];
  };
  std::printf("%-22s %9zu %7.2f s | %8.1f %8.1f %8.1f %9.1f %8.1f | %6.1f\n", input.name.c_str(), ps.size(), build_s,
              at(0.5), at(0.9), at(0.99), us.back(), mean,
              static_cast<double>(simplices) / static_cast<double>(samples));
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  bool quick = false;
  std::size_t samples = 20000;
  std::string only;
  std::size_t candidates = 0;  // the walker's default
  bool kept = false;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--quick") == 0) {
      quick = true;
    } else if (std::strcmp(argv[i], "--kept") == 0) {
      kept = true;
    } else if (std::strcmp(argv[i], "--samples") == 0 && i + 1 < argc) {
      samples = std::max<std::size_t>(1, std::stoul(argv[++i]));
    } else if (std::strcmp(argv[i], "--candidates") == 0 && i + 1 < argc) {
      candidates = std::stoul(argv[++i]);
    } else if (std::strcmp(argv[i], "--only") == 0 && i + 1 < argc) {
      only = argv[++i];
    } else {
      std::fprintf(
          stderr,
          "usage: spokemesh_latency [--quick] [--kept] [--samples N] [--only uniform|linspace] [--candidates K]\n");
      return 2;
    }
  }
  using spokemesh::bench::Kind;
  const std::vector<Input> inputs = {
      {quick ? "3-d uniform 100k" : "3-d uniform 1M", spokemesh::bench::uniform(3, quick ? 100000 : 1000000, 2019)},
      {quick ? "3-d linspace 25^3" : "3-d linspace 50^3",
       spokemesh::bench::grid(3, quick ? 25 : 50, Kind::kGridLinspace, 2019)},
  };
  std::printf("%-22s %9s %9s | %8s %8s %8s %9s %8s | %6s\n", "input", "points", "tree", "p50 us", "p90 us", "p99 us",
              "max us", "mean us", "simpl.");
  for (const Input& input : inputs) {
    if (!only.empty() && input.name.find(only) == std::string::npos) continue;
    if (run(input, samples, candidates, kept) != 0) return 1;
  }
  return 0;
}
