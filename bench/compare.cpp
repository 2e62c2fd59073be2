// spokemesh vs CGAL vs Qhull on the same generated inputs, in one run.
//
//   build/bin/spokemesh_compare [--threads N] [--quick] [--only CONFIG]
//
// For each configuration it generates uniform random points in [0,1]^d (fixed
// seed), then times: spokemesh's whole mesh (library, N threads, simplices counted
// and discarded); CGAL's Delaunay_triangulation_2/_3 (d = 2, 3) and the dD
// Delaunay_triangulation with Epick_d (d >= 3); Qhull's `qdelaunay Qt` (the process,
// reading the points from a file: input parsing is included, output is only the
// simplex count). CGAL and Qhull are single-threaded. Every run also checks that
// the three agree on the simplex count.
#include <CGAL/Delaunay_triangulation.h>
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Epick_d.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "inputs.hpp"
#include "spokemesh/mesh.hpp"

namespace {

using spokemesh::bench::grid;
using spokemesh::bench::Kind;
using spokemesh::bench::uniform;
using Clock = std::chrono::steady_clock;
double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// A configuration: uniform random points, or a grid of `side`^d points whose axis
// values are written the way users write them (inputs.hpp).
struct Config {
  std::string name;
  int d;
  std::size_t n;  // points (for grids: side^d)
  bool cgal_dd;
  bool qhull;
  Kind kind = Kind::kUniform;
  int side = 0;  // grids: points per axis
};

std::vector<double> points_of(const Config& c) {
  return c.kind == Kind::kUniform ? uniform(c.d, c.n, 2016 + c.d) : grid(c.d, c.side, c.kind, 2016 + c.d);
}

spokemesh::StarStats g_last_stats;  // of the last spokemesh run, for the per-point counts

std::pair<double, std::size_t> time_spokemesh(const spokemesh::PointSet& ps, unsigned threads) {
  const auto t0 = Clock::now();
  const spokemesh::KdTree tree(ps);
  spokemesh::MeshOptions options;
  options.threads = threads;
  auto r = spokemesh::mesh_seeds(tree, options,
                                 [](std::span<const std::uint32_t>, std::uint64_t) { return spokemesh::Status::ok(); });
  if (r.is_ok()) g_last_stats = r.value().star;
  return {since(t0), r.is_ok() ? r.value().simplices : 0};
}

std::pair<double, std::size_t> time_cgal_low(const spokemesh::PointSet& ps) {
  using K = CGAL::Exact_predicates_inexact_constructions_kernel;
  const auto t0 = Clock::now();
  if (ps.dimension() == 2) {
    std::vector<K::Point_2> p;
    for (std::size_t i = 0; i < ps.size(); ++i) p.emplace_back(ps.point(i)[0], ps.point(i)[1]);
    CGAL::Delaunay_triangulation_2<K> dt(p.begin(), p.end());
    return {since(t0), dt.number_of_faces()};
  }
  std::vector<K::Point_3> p;
  for (std::size_t i = 0; i < ps.size(); ++i) p.emplace_back(ps.point(i)[0], ps.point(i)[1], ps.point(i)[2]);
  CGAL::Delaunay_triangulation_3<K> dt(p.begin(), p.end());
  return {since(t0), dt.number_of_finite_cells()};
}

std::pair<double, std::size_t> time_cgal_dd(const spokemesh::PointSet& ps) {
  using K = CGAL::Epick_d<CGAL::Dynamic_dimension_tag>;
  const int d = ps.dimension();
  const auto t0 = Clock::now();
  std::vector<K::Point_d> p;
  for (std::size_t i = 0; i < ps.size(); ++i) p.emplace_back(d, ps.point(i), ps.point(i) + d);
  CGAL::Delaunay_triangulation<K> dt(d);
  dt.insert(p.begin(), p.end());
  return {since(t0), dt.number_of_finite_full_cells()};
}

std::pair<double, std::size_t> time_qhull(const spokemesh::PointSet& ps) {
  const std::string path = "/tmp/spokemesh_bench_" + std::to_string(::getpid()) + ".txt";
  {
    std::ofstream f(path);
    f.precision(17);
    f << ps.dimension() << "\n" << ps.size() << "\n";
    for (std::size_t i = 0; i < ps.size(); ++i) {
      for (int c = 0; c < ps.dimension(); ++c) f << ps.point(i)[c] << (c + 1 == ps.dimension() ? "\n" : " ");
    }
  }
  const auto t0 = Clock::now();
  std::FILE* p = ::popen(("qdelaunay Qt i < " + path + " | head -1").c_str(), "r");
  std::size_t count = 0;
  if (p != nullptr) {
    if (std::fscanf(p, "%zu", &count) != 1) count = 0;
    ::pclose(p);
  }
  const double t = since(t0);
  std::remove(path.c_str());
  return {t, count};
}

}  // namespace

int main(int argc, char** argv) {
  unsigned threads = 2;
  bool quick = false, grids = false;
  std::string only;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--threads" && i + 1 < argc)
      threads = static_cast<unsigned>(std::stoul(argv[++i]));
    else if (a == "--quick")
      quick = true;
    else if (a == "--grids")
      grids = true;
    else if (a == "--only" && i + 1 < argc)
      only = argv[++i];
    else {
      std::fprintf(stderr, "usage: spokemesh_compare [--threads N] [--quick] [--grids] [--only NAME]\n");
      return 2;
    }
  }
  auto g = [](int d, int side, Kind kind, const char* how) {
    std::size_t n = 1;
    for (int c = 0; c < d; ++c) n *= static_cast<std::size_t>(side);
    return Config{std::to_string(d) + "d-" + std::to_string(side) + "-" + how, d, n, d >= 4, d >= 4, kind, side};
  };
  const std::vector<Config> grid_configs = {
      g(3, 25, Kind::kGridInteger, "int"),   g(3, 25, Kind::kGridDyadic, "dyadic"),
      g(3, 25, Kind::kGridDecimal, "dec"),   g(3, 25, Kind::kGridLinspace, "lin"),
      g(3, 25, Kind::kGridJittered, "jit"),  g(3, 50, Kind::kGridLinspace, "lin"),
      g(3, 50, Kind::kGridInteger, "int"),   g(3, 50, Kind::kGridJittered, "jit"),
      g(3, 100, Kind::kGridLinspace, "lin"), g(2, 1000, Kind::kGridLinspace, "lin"),
      g(2, 1000, Kind::kGridInteger, "int"), g(2, 1000, Kind::kGridJittered, "jit"),
      g(4, 10, Kind::kGridInteger, "int"),   g(4, 10, Kind::kGridLinspace, "lin"),
      g(4, 10, Kind::kGridJittered, "jit"),
  };
  const std::vector<Config> configs =
      grids   ? grid_configs
      : quick ? std::vector<Config>{{"2d-100k", 2, 100000, false, true},
                                    {"3d-20k", 3, 20000, true, true},
                                    {"4d-2k", 4, 2000, true, true}}
              : std::vector<Config>{{"2d-1M", 2, 1000000, false, true},  {"3d-200k", 3, 200000, false, true},
                                    {"3d-1M", 3, 1000000, false, false}, {"4d-20k", 4, 20000, true, true},
                                    {"5d-5k", 5, 5000, true, true},      {"6d-2k", 6, 2000, true, true}};
  std::printf("%-14s %9s %12s | %10s %10s %10s %10s | %9s %9s | %8s %8s\n", "config", "points", "simplices",
              "spokemesh", "CGAL 2/3", "CGAL dD", "Qhull", "vs best", "agree", "wraps/pt", "exact/pt");
  for (const Config& c : configs) {
    if (!only.empty() && c.name != only) continue;
    spokemesh::PointSet ps(c.d, points_of(c));
    if (!ps.validate(c.name).is_ok()) return 1;
    const auto ours = time_spokemesh(ps, threads);
    std::pair<double, std::size_t> low{0, 0}, dd{0, 0}, qh{0, 0};
    if (c.d <= 3) low = time_cgal_low(ps);
    if (c.cgal_dd) dd = time_cgal_dd(ps);
    if (c.qhull) qh = time_qhull(ps);
    double best = 1e300;
    for (double t : {low.first, dd.first, qh.first}) {
      if (t > 0) best = std::min(best, t);
    }
    // On grids only CGAL's count must agree: Qhull's Qt triangulates each cospherical
    // facet its own way, and a cube (4-d: a tesseract) has triangulations of
    // different sizes. CGAL's perturbation is ours (test_mesh checks the simplices).
    const bool ties = c.kind != Kind::kUniform && c.kind != Kind::kGridJittered;
    bool agree = true;
    for (std::size_t m : {low.second, dd.second, ties ? std::size_t{0} : qh.second}) {
      if (m != 0 && m != ours.second) agree = false;
    }
    auto cell = [](double t) { return t > 0 ? std::to_string(t).substr(0, 6) + " s" : std::string("-"); };
    const double per_point = 1.0 / static_cast<double>(c.n);
    std::printf("%-14s %9zu %12zu | %10s %10s %10s %10s | %8.2fx %9s | %8.2f %8.2f\n", c.name.c_str(), c.n, ours.second,
                cell(ours.first).c_str(), cell(low.first).c_str(), cell(dd.first).c_str(), cell(qh.first).c_str(),
                ours.first / best, agree ? "yes" : "NO", static_cast<double>(g_last_stats.wraps) * per_point,
                static_cast<double>(g_last_stats.exact_fallbacks) * per_point);
    std::fflush(stdout);
  }
  std::printf("(spokemesh with %u threads; CGAL and Qhull single-threaded; 'vs best' = our time / fastest other)\n",
              threads);
  return 0;
}
