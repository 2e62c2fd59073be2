// Recall of certified approximate Delaunay neighbours (RSD walk with a miss budget,
// and plain Spoke Darts) against an exact LP oracle, as a function of the budget M.
//
//   build/bin/spokemesh_recall [--large] [--seeds K] [--only NAME[,NAME...]] [--svg FILE]
//
// Data: uniform points in d = 4, 6, 8, 12, and points near a random smooth k-manifold
// (k = 2..4) in D = 16, 32, 64 with small noise; n = 1,000 (and 10,000 with --large).
// For K sampled seeds per set: the exact neighbours (the tests' LP oracle,
// tests/lp_oracle.hpp: GLPK with Clarkson-style row generation), then for each M and
// mode: recall, precision (always 1: every reported edge is checked against the
// oracle), degree, and mean / p99 time per seed on one thread. Prints a table; --svg
// draws recall against M.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "lp_oracle.hpp"
#include "spokemesh/approx.hpp"

using namespace spokemesh;

namespace {

struct Dataset {
  std::string name;
  int d = 0;
  std::size_t n = 0;
  std::vector<double> coords;
};

Dataset uniform(int d, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  Dataset s{"uniform " + std::to_string(d) + "-d", d, n, std::vector<double>(n * d)};
  for (double& v : s.coords) v = u(rng);
  return s;
}

// Points near a random smooth k-manifold in R^D: random Fourier features of a latent
// point in [0, 1]^k, plus Gaussian noise of relative size 1e-2.
Dataset manifold(int k, int D, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0, 1);
  std::uniform_real_distribution<double> u(0, 1);
  const int features = 4;
  std::vector<double> freq(static_cast<std::size_t>(D * features * k)), phase(static_cast<std::size_t>(D * features)),
      amp(static_cast<std::size_t>(D * features));
  for (double& v : freq) v = 2.0 * g(rng);
  for (double& v : phase) v = 6.283185307179586 * u(rng);
  for (double& v : amp) v = g(rng) / std::sqrt(static_cast<double>(features));
  Dataset s{std::to_string(k) + "-manifold in " + std::to_string(D) + "-d", D, n, std::vector<double>(n * D)};
  std::vector<double> latent(static_cast<std::size_t>(k));
  for (std::size_t i = 0; i < n; ++i) {
    for (double& v : latent) v = u(rng);
    for (int j = 0; j < D; ++j) {
      double x = 0;
      for (int f = 0; f < features; ++f) {
        double arg = phase[static_cast<std::size_t>(j * features + f)];
        for (int c = 0; c < k; ++c) arg += freq[static_cast<std::size_t>((j * features + f) * k + c)] * latent[c];
        x += amp[static_cast<std::size_t>(j * features + f)] * std::sin(arg);
      }
      s.coords[i * D + j] = x + 0.01 * g(rng);
    }
  }
  return s;
}

struct Measurement {
  std::string set, mode;
  std::uint32_t budget = 0;
  double recall = 0, degree = 0, truth_degree = 0, mean_ms = 0, p99_ms = 0;
  bool precise = true;
};

}  // namespace

int main(int argc, char** argv) {
  bool large = false;
  int seeds = 10;
  std::string only, svg;
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    if (arg == "--large")
      large = true;
    else if (arg == "--seeds" && a + 1 < argc)
      seeds = std::atoi(argv[++a]);
    else if (arg == "--only" && a + 1 < argc)
      only = argv[++a];
    else if (arg == "--svg" && a + 1 < argc)
      svg = argv[++a];
    else {
      std::fprintf(stderr, "usage: spokemesh_recall [--large] [--seeds K] [--only NAME] [--svg FILE]\n");
      return 2;
    }
  }
  std::vector<std::size_t> sizes = {1000};
  if (large) sizes.push_back(10000);
  std::vector<Dataset> sets;
  for (std::size_t n : sizes) {
    for (int d : {4, 6, 8, 12}) sets.push_back(uniform(d, n, 100 + d));
    sets.push_back(manifold(2, 16, n, 216));
    sets.push_back(manifold(3, 32, n, 332));
    sets.push_back(manifold(4, 64, n, 464));
  }
  const std::vector<std::uint32_t> budgets = {10, 30, 100, 300};
  std::vector<Measurement> rows;
  std::printf("%-24s %6s %-6s %5s %7s %9s %8s %9s %9s\n", "set", "n", "mode", "M", "recall", "precision", "degree",
              "mean ms", "p99 ms");
  for (const Dataset& s : sets) {
    const std::string label = s.name + " n=" + std::to_string(s.n);
    if (!only.empty()) {  // comma-separated substrings of "<set> n=<n>"
      bool wanted = false;
      std::size_t at = 0;
      while (at <= only.size()) {
        const std::size_t comma = std::min(only.find(',', at), only.size());
        wanted = wanted || label.find(only.substr(at, comma - at)) != std::string::npos;
        at = comma + 1;
      }
      if (!wanted) continue;
    }
    PointSet ps(s.d, s.coords);
    if (Status st = ps.validate(s.name, kMaxApproxDimension, s.d <= kMaxDimension); !st.is_ok()) {
      std::fprintf(stderr, "%s\n", st.message().c_str());
      return 1;
    }
    KdTree tree(ps);
    std::mt19937_64 rng(7);
    std::vector<std::uint32_t> sample;
    for (int k = 0; k < seeds; ++k) sample.push_back(static_cast<std::uint32_t>(rng() % s.n));
    std::vector<std::vector<std::uint32_t>> truth;
    const auto t0 = std::chrono::steady_clock::now();
    for (std::uint32_t seed : sample) truth.push_back(testing::lp_delaunay_neighbors(s.coords, s.d, seed));
    const double oracle_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    double truth_degree = 0;
    for (const auto& t : truth) truth_degree += static_cast<double>(t.size()) / sample.size();
    std::fprintf(stderr, "%s: exact degree %.1f (oracle %.1f s for %d seeds)\n", label.c_str(), truth_degree, oracle_s,
                 seeds);
    for (auto mode : {ApproxOptions::Mode::kRsd, ApproxOptions::Mode::kSpokes}) {
      for (std::uint32_t budget : budgets) {
        ApproxOptions o;
        o.mode = mode;
        o.max_misses = budget;
        o.max_vertices = 1000000;
        ApproxWalker walker(tree, o);
        Measurement row{label, mode == ApproxOptions::Mode::kRsd ? "rsd" : "spokes", budget};
        std::vector<double> ms;
        double found = 0, total = 0;
        for (std::size_t k = 0; k < sample.size(); ++k) {
          ApproxNeighbors a;
          const auto start = std::chrono::steady_clock::now();
          if (Status st = walker.compute(sample[k], a); !st.is_ok()) {
            std::fprintf(stderr, "%s\n", st.message().c_str());
            return 1;
          }
          ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
          for (std::uint32_t v : a.neighbors) {
            if (!std::binary_search(truth[k].begin(), truth[k].end(), v)) {
              row.precise = false;
              std::fprintf(stderr, "%s: seed %u: reported neighbour %u is not in the oracle's set\n", label.c_str(),
                           sample[k], v);
            }
          }
          found += static_cast<double>(a.neighbors.size());
          total += static_cast<double>(truth[k].size());
          row.degree += static_cast<double>(a.neighbors.size()) / sample.size();
        }
        std::sort(ms.begin(), ms.end());
        for (double m : ms) row.mean_ms += m / ms.size();
        row.p99_ms = ms[std::min(ms.size() - 1, static_cast<std::size_t>(std::ceil(0.99 * ms.size())) - 1)];
        row.recall = total > 0 ? found / total : 1;
        row.truth_degree = truth_degree;
        std::printf("%-24s %6zu %-6s %5u %7.4f %9s %8.1f %9.2f %9.2f\n", s.name.c_str(), s.n, row.mode.c_str(), budget,
                    row.recall, row.precise ? "1" : "VIOLATED", row.degree, row.mean_ms, row.p99_ms);
        std::fflush(stdout);
        rows.push_back(row);
        if (!row.precise) return 1;  // a reported non-edge is a bug, never a result
      }
    }
  }
  if (!svg.empty()) {
    // Recall against M (log scale), one line per set and mode.
    std::ofstream f(svg);
    const double W = 760, H = 420, L = 60, R = 250, T = 20, B = 50;
    auto X = [&](double m) { return L + (std::log10(m) - 1) / (std::log10(300.0) - 1) * (W - L - R); };
    auto Y = [&](double r) { return T + (1 - r) * (H - T - B); };
    f << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << W << "\" height=\"" << H
      << "\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
    for (double r = 0; r <= 1.0001; r += 0.2) {
      f << "<line x1=\"" << L << "\" x2=\"" << W - R << "\" y1=\"" << Y(r) << "\" y2=\"" << Y(r)
        << "\" stroke=\"#ddd\"/><text x=\"" << L - 8 << "\" y=\"" << Y(r) + 4 << "\" text-anchor=\"end\">" << r
        << "</text>\n";
    }
    for (std::uint32_t m : budgets) {
      f << "<text x=\"" << X(m) << "\" y=\"" << H - B + 18 << "\" text-anchor=\"middle\">" << m << "</text>\n";
    }
    f << "<text x=\"" << (L + W - R) / 2 << "\" y=\"" << H - 10
      << "\" text-anchor=\"middle\">consecutive-miss budget M</text>\n";
    f << "<text x=\"14\" y=\"" << (T + H - B) / 2 << "\" transform=\"rotate(-90 14 " << (T + H - B) / 2
      << ")\" text-anchor=\"middle\">recall</text>\n";
    const char* colours[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
                             "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939", "#8c6d31", "#843c39"};
    int series = 0;
    for (std::size_t i = 0; i < rows.size(); i += budgets.size(), ++series) {
      std::string points;
      for (std::size_t k = 0; k < budgets.size(); ++k) {
        points += std::to_string(X(rows[i + k].budget)) + "," + std::to_string(Y(rows[i + k].recall)) + " ";
      }
      const char* colour = colours[(series / 2) % 14];
      f << "<polyline fill=\"none\" stroke=\"" << colour << "\" stroke-width=\"2\""
        << (rows[i].mode == "spokes" ? " stroke-dasharray=\"5,4\"" : "") << " points=\"" << points << "\"/>\n";
      f << "<text x=\"" << W - R + 8 << "\" y=\"" << T + 14 * series + 10 << "\" fill=\"" << colour << "\">"
        << rows[i].set << " " << rows[i].mode << "</text>\n";
    }
    f << "</svg>\n";
  }
  return 0;
}
