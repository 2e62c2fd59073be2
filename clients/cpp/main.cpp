// spokemesh: exact Delaunay meshes and Voronoi cells of point files.
//
// Exit codes: 0 success, 1 failure (including an invalid mesh for `check`),
// 2 bad usage or bad input.
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "spokemesh/approx.hpp"
#include "spokemesh/cell_io.hpp"
#include "spokemesh/cells.hpp"
#include "spokemesh/graph.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/units.hpp"
#include "spokemesh/validate.hpp"
#include "spokemesh/voronoi.hpp"
#include "cell_print.hpp"
#ifdef SPOKEMESH_REMOTE
#include "remote.hpp"
#endif

namespace {

using namespace spokemesh;
using Clock = std::chrono::steady_clock;

constexpr int kExitOk = 0, kExitFailure = 1, kExitUsage = 2;

int report(const Status& status) {
  std::cerr << "spokemesh: " << status.message() << "\n";
  return (status.code() == Code::kInvalidArgument || status.code() == Code::kOutOfRange) ? kExitUsage : kExitFailure;
}

// A validated point set with its tree; `original` maps indices back when
// duplicates were merged.
struct Loaded {
  PointSet points;
  std::size_t input_count = 0;          // points in the file, before merging duplicates
  std::vector<std::uint32_t> original;  // empty: identity
  std::unique_ptr<KdTree> tree;

  std::uint32_t to_original(std::uint32_t i) const { return original.empty() ? i : original[i]; }
};

// approximate: accepts any dimension up to kMaxApproxDimension (the exact affine-span
// check runs only where exact meshing is defined, d <= kMaxDimension).
Result<std::unique_ptr<Loaded>> load(const std::string& path, bool merge_duplicates, bool approximate = false) {
  auto points = read_points(path);
  if (!points.is_ok()) return points.status();
  auto loaded = std::make_unique<Loaded>();
  loaded->points = std::move(points).value();
  loaded->input_count = loaded->points.size();
  if (merge_duplicates) {
    const std::vector<std::uint32_t> map = loaded->points.merge_duplicates();
    loaded->original.assign(loaded->points.size(), 0);
    for (std::size_t i = map.size(); i-- > 0;) loaded->original[map[i]] = static_cast<std::uint32_t>(i);
  }
  const int d = loaded->points.dimension();
  if (!approximate && d > kMaxDimension) {
    return invalid_argument(path + ": dimension " + std::to_string(d) + " is above the exact limit " +
                            std::to_string(kMaxDimension) + "; use --approx for a certified approximate Delaunay graph");
  }
  Status valid = approximate ? loaded->points.validate(path, kMaxApproxDimension, d <= kMaxDimension)
                             : loaded->points.validate(path);
  if (!valid.is_ok() && valid.reason() == "DUPLICATE_POINTS") {
    return invalid_argument(valid.message() + " (use --merge-duplicates to map duplicates to their first occurrence)");
  }
  if (!valid.is_ok()) return valid;
  loaded->tree = std::make_unique<KdTree>(loaded->points);
  return loaded;
}

// Maps a user's seed (an input index) to the internal index.
Result<std::uint32_t> internal_seed(const Loaded& loaded, std::int64_t seed) {
  if (seed < 0 || static_cast<std::size_t>(seed) >= loaded.input_count) {
    return out_of_range("seed " + std::to_string(seed) + " is out of range (the input has " +
                        std::to_string(loaded.input_count) + " points)");
  }
  if (loaded.original.empty()) return static_cast<std::uint32_t>(seed);
  // With merged duplicates, a seed maps to its first occurrence.
  for (std::size_t i = 0; i < loaded.original.size(); ++i) {
    if (loaded.original[i] == static_cast<std::uint32_t>(seed)) return static_cast<std::uint32_t>(i);
  }
  return invalid_argument("seed " + std::to_string(seed) + " duplicates an earlier point; use the first occurrence");
}

struct ApproxFlags {
  bool enabled = false;
  std::uint32_t misses = 100;
  std::uint32_t max_vertices = 20000;
  std::string mode = "rsd";

  ApproxOptions options(std::uint64_t random_seed) const {
    ApproxOptions o;
    o.mode = mode == "spokes" ? ApproxOptions::Mode::kSpokes : ApproxOptions::Mode::kRsd;
    o.max_misses = misses;
    o.max_vertices = max_vertices;
    o.random_seed = random_seed;
    return o;
  }
};

void add_approx_flags(CLI::App* cmd, ApproxFlags& f) {
  cmd->add_flag("--approx", f.enabled,
                "Certified approximate neighbours (any dimension): every edge is a true Delaunay edge, some may be missed");
  cmd->add_option("--misses", f.misses, "With --approx: stop after this many consecutive misses (the paper's M)")
      ->capture_default_str()
      ->check(CLI::Range(1u, 1000000u));
  cmd->add_option("--mode", f.mode, "With --approx: rsd (Recursive Spoke Darts walk) or spokes (plain Spoke Darts)")
      ->capture_default_str()
      ->check(CLI::IsMember({"rsd", "spokes"}));
  cmd->add_option("--max-vertices", f.max_vertices, "With --approx: at most this many Voronoi vertices (or rays) per seed")
      ->capture_default_str()
      ->check(CLI::Range(1u, 100000000u));
}

struct Common {
  unsigned threads = std::max(1u, std::thread::hardware_concurrency());
  bool quiet = false;
  bool merge_duplicates = false;
  std::uint64_t random_seed = 0x5eed;
  std::size_t cache_mb = 1024;  // FacetCache cap for whole meshes
};

class Progress {
 public:
  Progress(bool quiet, std::uint64_t total, const char* what = "meshing")
      : quiet_(quiet), total_(total), tty_(::isatty(2) != 0), what_(what) {}

  void update(std::uint64_t done, std::uint64_t simplices) {
    if (quiet_) return;
    const double elapsed = seconds();
    if (elapsed < 2.0) return;
    const double interval = tty_ ? 0.2 : 5.0;
    if (elapsed - last_ < interval) return;
    last_ = elapsed;
    char line[160];
    std::snprintf(line, sizeof line, "%s: %llu/%llu seeds (%.0f%%), %llu simplices, %.1f s", what_,
                  static_cast<unsigned long long>(done), static_cast<unsigned long long>(total_),
                  total_ ? 100.0 * done / total_ : 100.0, static_cast<unsigned long long>(simplices), elapsed);
    if (simplices == 0) {  // the graph command counts seeds only
      std::snprintf(line, sizeof line, "%s: %llu/%llu seeds (%.0f%%), %.1f s", what_,
                    static_cast<unsigned long long>(done), static_cast<unsigned long long>(total_),
                    total_ ? 100.0 * done / total_ : 100.0, elapsed);
    }
    if (tty_) std::fprintf(stderr, "\r%s\033[K", line);
    else std::fprintf(stderr, "%s\n", line);
    drawn_ = tty_;
  }
  void finish() {
    if (drawn_) std::fprintf(stderr, "\r\033[K");
  }
  double seconds() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }

 private:
  bool quiet_;
  std::uint64_t total_;
  bool tty_;
  const char* what_;
  bool drawn_ = false;
  double last_ = 0;
  Clock::time_point start_ = Clock::now();
};

// An output that is the input file itself (same path, a link, another spelling) would
// destroy the input when the result is renamed into place: refused up front.
Status check_not_input(const std::string& input, const std::string& output) {
  struct stat in {}, out {};
  if (::stat(input.c_str(), &in) == 0 && ::stat(output.c_str(), &out) == 0 && in.st_dev == out.st_dev &&
      in.st_ino == out.st_ino) {
    return invalid_argument("-o " + output + " is the input file " + input +
                            "; writing it would overwrite the input: choose another output file");
  }
  return Status::ok();
}

int run_mesh(const Common& common, const std::string& input, const std::string& output, const std::string& seeds) {
  if (Status s = check_not_input(input, output); !s.is_ok()) return report(s);
  auto loaded_or = load(input, common.merge_duplicates);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  const Loaded& loaded = *loaded_or.value();
  const std::size_t n = loaded.points.size();

  MeshOptions options;
  options.threads = common.threads;
  options.star.random_seed = common.random_seed;
  options.facet_cache_bytes = common.cache_mb << 20;
  if (!seeds.empty()) {
    const auto colon = seeds.find(':');
    try {
      if (colon == std::string::npos) throw std::invalid_argument("no colon");
      options.seed_begin = colon == 0 ? 0u : static_cast<std::uint32_t>(std::stoull(seeds.substr(0, colon)));
      options.seed_end = colon + 1 == seeds.size() ? static_cast<std::uint32_t>(n)
                                                   : static_cast<std::uint32_t>(std::stoull(seeds.substr(colon + 1)));
    } catch (const std::exception&) {
      return report(invalid_argument("--seeds: expected A:B (seeds A..B-1), got '" + seeds + "'"));
    }
    if (options.seed_begin > options.seed_end || options.seed_end > n) {
      return report(invalid_argument("--seeds " + seeds + ": need 0 <= A <= B <= " + std::to_string(n)));
    }
    if (!loaded.original.empty()) return report(invalid_argument("--seeds cannot be combined with --merge-duplicates"));
  }
  auto writer_or = MeshWriter::open(output, loaded.points);
  if (!writer_or.is_ok()) return report(writer_or.status());
  MeshWriter& writer = *writer_or.value();

  Progress progress(common.quiet, std::min<std::uint64_t>(options.seed_end, n) - options.seed_begin);
  std::uint64_t written = 0;
  std::vector<std::uint32_t> mapped;
  auto result = mesh_seeds(*loaded.tree, options, [&](std::span<const std::uint32_t> block, std::uint64_t done) {
    written += block.size() / (loaded.points.dimension() + 1);
    progress.update(done, written);
    if (loaded.original.empty()) return writer.write(block);
    mapped.assign(block.begin(), block.end());
    for (auto& v : mapped) v = loaded.to_original(v);
    return writer.write(mapped);
  });
  progress.finish();
  if (!result.is_ok()) return report(result.status());
  if (Status s = writer.commit(); !s.is_ok()) return report(s);
  if (!common.quiet) {
    const double t = progress.seconds();
    // What the stars shared, at most at once: the sweep's front (docs/algorithm.md).
    std::fprintf(stderr, "spokemesh: %zu points, %llu simplices, %.2f s, %.0f simplices/s, %.1f MB shared -> %s\n", n,
                 static_cast<unsigned long long>(result.value().simplices), t,
                 t > 0 ? result.value().simplices / t : 0.0,
                 static_cast<double>(result.value().facet_cache_bytes) / (1 << 20), output.c_str());
  }
  return kExitOk;
}

// Loads, computes the star of one seed, and hands it to `use`.
template <class Use>
int with_star(const Common& common, const std::string& input, std::int64_t seed, Use&& use) {
  auto loaded_or = load(input, common.merge_duplicates);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  const Loaded& loaded = *loaded_or.value();
  auto internal = internal_seed(loaded, seed);
  if (!internal.is_ok()) return report(internal.status());
  StarOptions options;
  options.random_seed = common.random_seed;
  StarWalker walker(*loaded.tree, options);
  Star star;
  if (Status s = walker.compute(internal.value(), star); !s.is_ok()) return report(s);
  return use(loaded, star);  // internal indices; printers map them with to_original()
}

// The domain of `cell` and `cells`: --box, --halfspaces, or (for `cells`, when
// `default_box`) the points' bounding box; none for an unclipped `cell`.
struct DomainFlags {
  std::string box, halfspaces;
};

Result<std::optional<Domain>> domain_for(const DomainFlags& flags, const PointSet& points, bool default_box) {
  const int d = points.dimension();
  if (!flags.box.empty() && !flags.halfspaces.empty()) return invalid_argument("--box and --halfspaces exclude each other");
  if (!flags.box.empty()) {
    auto box = Domain::parse_box(flags.box);
    if (!box.is_ok()) return box.status();
    if (box->dimension() != d) {
      return invalid_argument("--box: " + std::to_string(2 * box->dimension()) + " values describe a " +
                              std::to_string(box->dimension()) + "-d box; the points are " + std::to_string(d) +
                              "-d (give LO1,...,LOd,HI1,...,HId)");
    }
    return std::optional<Domain>(std::move(box).value());
  }
  if (!flags.halfspaces.empty()) {
    auto h = read_halfspaces(flags.halfspaces, d);
    if (!h.is_ok()) return h.status();
    return std::optional<Domain>(std::move(h).value());
  }
  if (default_box) return std::optional<Domain>(Domain::bounding_box(points));
  return std::optional<Domain>();
}

int run_cell(const Common& common, const std::string& input, std::int64_t seed, bool json, const DomainFlags& flags) {
  return with_star(common, input, seed, [&](const Loaded& loaded, Star& star) {
    auto domain = domain_for(flags, loaded.points, false);
    if (!domain.is_ok()) return report(domain.status());
    VoronoiCell cell;
    if (domain.value().has_value()) {
      // The builder `cells` uses, so that both print the same cell.
      StarOptions options;
      options.random_seed = common.random_seed;
      ClippedCellBuilder builder(*loaded.tree, *domain.value(), options);
      auto clipped = builder.cell(star.seed);
      if (!clipped.is_ok()) return report(clipped.status());
      cell = std::move(clipped).value();
    } else {
      cell = voronoi_cell(loaded.points, star);
    }
    // Original indices (duplicates merged away map to first occurrences).
    cli::print_cell(cell, static_cast<std::uint64_t>(seed), json, [&](std::uint32_t i) { return loaded.to_original(i); });
    return kExitOk;
  });
}

int run_cells(const Common& common, const std::string& input, const std::string& output, const DomainFlags& flags) {
  if (Status s = check_not_input(input, output); !s.is_ok()) return report(s);
  auto loaded_or = load(input, false);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  const Loaded& loaded = *loaded_or.value();
  auto domain = domain_for(flags, loaded.points, true);
  if (!domain.is_ok()) return report(domain.status());
  auto writer = CellWriter::open(output, loaded.points.dimension());
  if (!writer.is_ok()) return report(writer.status());
  CellsOptions options;
  options.threads = common.threads;
  options.star.random_seed = common.random_seed;
  options.measures_only = !writer.value()->needs_vertices();
  options.facet_cache_bytes = common.cache_mb << 20;
  Progress progress(common.quiet, loaded.points.size(), "cells");
  std::uint64_t facets = 0;
  double volume = 0;
  Status status = compute_cells(*loaded.tree, &*domain.value(), options, [&](std::span<const VoronoiCell> cells, std::uint64_t done) {
    for (const VoronoiCell& c : cells) {
      facets += c.facets.size();
      volume += c.volume;
    }
    progress.update(done, 0);
    return writer.value()->write(cells);
  });
  progress.finish();
  if (status.is_ok()) status = writer.value()->commit();
  if (!status.is_ok()) return report(status);
  if (!common.quiet) {
    std::fprintf(stderr, "spokemesh: %zu cells in %s, %llu facets, total volume %.17g, %.2f s -> %s\n",
                 loaded.points.size(), domain.value()->describe().c_str(), static_cast<unsigned long long>(facets), volume,
                 progress.seconds(), output.c_str());
  }
  return kExitOk;
}

int run_check(const std::string& input, const std::string& mesh_path) {
  auto loaded_or = load(input, false);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  const Loaded& loaded = *loaded_or.value();
  auto simplices = read_simplices(mesh_path, loaded.points.dimension() + 1);
  if (!simplices.is_ok()) return report(simplices.status());
  const MeshCheck check = check_mesh(*loaded.tree, simplices.value());
  if (check.valid) {
    std::printf("valid: %zu simplices, %zu interior facets, %zu hull facets\n", check.simplices, check.interior_facets,
                check.hull_facets);
    return kExitOk;
  }
  std::printf("INVALID: %zu simplices\n", check.simplices);
  for (const auto& v : check.violations) std::printf("  %s\n", v.c_str());
  return kExitFailure;
}

int run_approx_neighbors(const Common& common, const ApproxFlags& flags, const std::string& input, std::int64_t seed) {
  auto loaded_or = load(input, common.merge_duplicates, true);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  const Loaded& loaded = *loaded_or.value();
  auto internal = internal_seed(loaded, seed);
  if (!internal.is_ok()) return report(internal.status());
  ApproxWalker walker(*loaded.tree, flags.options(common.random_seed));
  ApproxNeighbors result;
  const auto start = Clock::now();
  if (Status s = walker.compute(internal.value(), result); !s.is_ok()) return report(s);
  const double ms = std::chrono::duration<double, std::milli>(Clock::now() - start).count();
  for (std::uint32_t v : result.neighbors) std::printf("%u\n", loaded.to_original(v));
  std::fprintf(stderr,
               "spokemesh: %zu certified neighbours (approximate, %s): %llu %s visited, %llu consecutive misses at "
               "the end%s, %.1f ms\n",
               result.neighbors.size(), flags.mode.c_str(), static_cast<unsigned long long>(result.vertices),
               flags.mode == "spokes" ? "rays" : "Voronoi vertices", static_cast<unsigned long long>(result.misses),
               result.exhausted ? " (complete: every point found or refuted)" : "", ms);
  return kExitOk;
}

int run_graph(const Common& common, const ApproxFlags& flags, const std::string& input, const std::string& output) {
  if (Status s = check_not_input(input, output); !s.is_ok()) return report(s);
  auto loaded_or = load(input, common.merge_duplicates, flags.enabled);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  const Loaded& loaded = *loaded_or.value();
  const PointSet edge_shape(1, {});  // width 2
  auto writer = MeshWriter::open_tuples(output, edge_shape);
  if (!writer.is_ok()) return report(writer.status());
  GraphOptions options;
  options.approximate = flags.enabled;
  options.approx = flags.options(common.random_seed);
  options.star.random_seed = common.random_seed;
  options.threads = common.threads;
  Progress progress(common.quiet, loaded.points.size(), "graph");
  options.progress = [&](std::uint64_t done) { progress.update(done, 0); };
  GraphStats stats;
  auto edges = delaunay_graph(*loaded.tree, options, &stats);
  progress.finish();
  if (!edges.is_ok()) return report(edges.status());
  std::vector<std::uint32_t> flat;
  flat.reserve(edges->size() * 2);
  for (auto [i, j] : edges.value()) {
    std::uint32_t a = loaded.to_original(i), b = loaded.to_original(j);
    flat.push_back(std::min(a, b));
    flat.push_back(std::max(a, b));
  }
  if (Status s = writer.value()->write(flat); !s.is_ok()) return report(s);
  if (Status s = writer.value()->commit(); !s.is_ok()) return report(s);
  if (!common.quiet) {
    const double t = progress.seconds();
    std::fprintf(stderr, "spokemesh: %zu points, %zu %s edges, mean degree %.2f, %.2f s -> %s\n", loaded.points.size(),
                 edges->size(), flags.enabled ? "certified (approximate)" : "exact",
                 2.0 * static_cast<double>(edges->size()) / static_cast<double>(loaded.points.size()), t,
                 output.c_str());
  }
  return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"spokemesh: exact Delaunay meshes and Voronoi cells by Recursive Spoke Darts.\n"
               "Points are text (one point per line) or .npy (float64/float32, shape (n, d)); indices are 0-based."};
  app.require_subcommand(1);
  app.fallthrough();  // global options (--server, --deadline, ...) may follow the command
  app.set_version_flag("--version", "spokemesh 0.1.0");
  Common common;
  auto add_common = [&](CLI::App* cmd) {
    cmd->add_flag("--merge-duplicates", common.merge_duplicates,
                  "Map exact duplicate points to their first occurrence instead of refusing them");
    cmd->add_option("--random-seed", common.random_seed, "Seed for the random spoke directions (the result does not depend on it)")
        ->capture_default_str();
  };

  std::string input, output, seeds, mesh_path;
  std::int64_t seed = -1;
  bool json = false;

  // Remote mode: --server HOST:PORT sends the commands to a spokemesh-server, and
  // INPUT becomes a point-set id (from `upload`).
  std::string server, deadline_text = "60s", token_file, tls_ca, tls_cert, tls_key, display_name;
  unsigned shards = 4;
  app.add_option("--server", server, "Run against a spokemesh-server at HOST:PORT (gRPC); INPUT is then a point-set id")
      ->group("Remote mode");
  app.add_option("--deadline", deadline_text, "Deadline of each remote call (e.g. 500ms, 30s, 5m)")
      ->capture_default_str()
      ->group("Remote mode");
  app.add_option("--token-file", token_file, "File with the server's bearer token (or set SPOKEMESH_TOKEN)")
      ->group("Remote mode");
  app.add_option("--tls-ca", tls_ca, "Use TLS, trusting this PEM CA bundle")->group("Remote mode");
  app.add_option("--tls-cert", tls_cert, "Client certificate (PEM) for mutual TLS")->group("Remote mode");
  app.add_option("--tls-key", tls_key, "Client private key (PEM) for mutual TLS")->group("Remote mode");

  auto* mesh = app.add_subcommand("mesh", "Mesh a point file (the whole Delaunay mesh, or the simplices owned by --seeds)");
  mesh->add_option("INPUT", input, "Point file (.txt/.csv/.xyz text or .npy)")->required();
  mesh->add_option("-o,--output", output,
                   "Mesh file: .simplices/.txt (indices), .npy (int64), .vtu or .msh (2-d/3-d), .svg (2-d)")
      ->required();
  mesh->add_option("--threads", common.threads, "Worker threads")->capture_default_str()->check(CLI::Range(1u, 1024u));
  mesh->add_option("--seeds", seeds,
                   "Only the simplices owned by seeds A..B-1 (A:B); owner = smallest vertex index. Rows are in sweep "
                   "order (the k-d tree's leaf order; the same for any --threads): sort them for lexicographic order");
  mesh->add_option("--cache-mb", common.cache_mb,
                   "Memory cap (MiB) on the front: facets shared with blocks still to come (2-d: 64 bytes per point); "
                   "0 = none (same output, slower)")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{0}, std::size_t{1} << 24));
  mesh->add_flag("-q,--quiet", common.quiet, "No progress or summary on stderr");
  mesh->add_option("--shards", shards, "Remote mode: shards fetched in parallel")
      ->capture_default_str()
      ->check(CLI::Range(1u, 4096u));
  add_common(mesh);

  auto* star = app.add_subcommand("star", "Print the Delaunay simplices incident to one seed, one per line");
  star->add_option("INPUT", input, "Point file")->required();
  star->add_option("--seed", seed, "Seed index (0-based)")->required();
  add_common(star);

  ApproxFlags approx_flags;
  auto* neighbors = app.add_subcommand("neighbors", "Print the Delaunay neighbours of one seed, one per line");
  neighbors->add_option("INPUT", input, "Point file")->required();
  neighbors->add_option("--seed", seed, "Seed index (0-based)")->required();
  add_approx_flags(neighbors, approx_flags);
  add_common(neighbors);

  auto* graph = app.add_subcommand("graph", "Write the Delaunay graph: one edge \"i j\" per line (i < j, sorted), or .npy");
  graph->add_option("INPUT", input, "Point file")->required();
  graph->add_option("-o,--output", output, "Edge file: .edges/.txt (text) or .npy (int64, shape (m, 2))")->required();
  graph->add_option("--threads", common.threads, "Worker threads")->capture_default_str()->check(CLI::Range(1u, 1024u));
  graph->add_flag("-q,--quiet", common.quiet, "No progress or summary on stderr");
  add_approx_flags(graph, approx_flags);
  add_common(graph);

  auto* cell = app.add_subcommand("cell", "Print the Voronoi cell of one seed: vertices, facets, boundedness, volume");
  cell->add_option("INPUT", input, "Point file")->required();
  cell->add_option("--seed", seed, "Seed index (0-based)")->required();
  cell->add_flag("--json", json, "Print JSON instead of text");
  DomainFlags domain_flags;
  auto add_domain = [&](CLI::App* cmd, const char* none) {
    cmd->add_option("--box", domain_flags.box,
                    std::string("Clip to the box LO1,...,LOd,HI1,...,HId (walls 0..d-1 low, d..2d-1 high); ") + none);
    cmd->add_option("--halfspaces", domain_flags.halfspaces,
                    "Clip to the convex domain given by a file of walls, one per line: a_1 ... a_d b for a.x <= b");
  };
  add_domain(cell, "default: unclipped");
  add_common(cell);

  auto* cells = app.add_subcommand(
      "cells", "Write every Voronoi cell clipped to a domain, with volume, centroid and facet areas/normals/neighbours");
  cells->add_option("INPUT", input, "Point file")->required();
  cells->add_option("-o,--output", output, ".npz (NumPy arrays, any d), .vtu (ParaView polygons/polyhedra, 2-d/3-d) or .svg (a 2-d picture)")
      ->required();
  add_domain(cells, "default: the points' bounding box");
  cells->add_option("--threads", common.threads, "Worker threads")->capture_default_str()->check(CLI::Range(1u, 1024u));
  cells->add_flag("-q,--quiet", common.quiet, "No progress or summary on stderr");
  std::size_t cells_cache_mb = 256;
  cells->add_option("--cache-mb", cells_cache_mb,
                    "Memory cap (MiB) for sharing wraps between the seeds' stars; 0 = none (same cells, slower)")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{0}, std::size_t{1} << 24));
  cells->add_option("--random-seed", common.random_seed, "Seed for the random spoke directions (the result does not depend on it)")
      ->capture_default_str();

  auto* check = app.add_subcommand("check", "Validate a mesh of a point file independently (exit 0 only if it is the Delaunay mesh)");
  check->add_option("INPUT", input, "Point file")->required();
  check->add_option("MESH", mesh_path, "Mesh file (.simplices/.txt or .npy)")->required();

  auto* upload = app.add_subcommand("upload", "Remote mode: upload a point file; prints its id");
  upload->add_option("INPUT", input, "Point file (.txt/.csv/.xyz text or .npy)")->required();
  upload->add_option("--name", display_name, "Display name stored with the point set");
  upload->add_flag("-q,--quiet", common.quiet, "Print only the id");
  auto* batch = app.add_subcommand(
      "batch", "Remote mode: stars, neighbours or cells of many seeds in one call; one JSON object per line");
  std::string batch_kind, seeds_text, seeds_file;
  batch->add_option("ID", input, "Point-set id")->required();
  batch->add_option("KIND", batch_kind, "stars, neighbors or cells")->required()->check(CLI::IsMember({"stars", "neighbors", "cells"}));
  batch->add_option("--seeds", seeds_text, "Comma-separated seed indices, e.g. 0,5,17");
  batch->add_option("--seeds-file", seeds_file, "File of seed indices (whitespace or commas)");
  add_domain(batch, "cells only; default: unclipped");
  add_approx_flags(batch, approx_flags);
  auto* health = app.add_subcommand("health", "Remote mode: ask the server's gRPC health service (exit 0 if SERVING)");
  auto* list = app.add_subcommand("list", "Remote mode: list the stored point sets");
  auto* del = app.add_subcommand("delete", "Remote mode: delete a stored point set");
  del->add_option("ID", input, "Point-set id")->required();

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return kExitUsage;
  }

  const bool remote_only = *upload || *health || *list || *del || *batch;
  if (!server.empty()) {
#ifdef SPOKEMESH_REMOTE
    remote::RemoteOptions o;
    o.server = server;
    o.tls_ca = tls_ca;
    o.tls_cert = tls_cert;
    o.tls_key = tls_key;
    o.quiet = common.quiet;
    if (tls_cert.empty() != tls_key.empty()) return report(invalid_argument("--tls-cert and --tls-key go together"));
    if (!tls_cert.empty() && tls_ca.empty()) return report(invalid_argument("--tls-cert needs --tls-ca"));
    {
      auto deadline = parse_duration(deadline_text, "--deadline");
      if (!deadline.is_ok()) return report(deadline.status());
      o.deadline = deadline.value();
    }
    if (!token_file.empty()) {
      std::FILE* f = std::fopen(token_file.c_str(), "rb");
      if (f == nullptr) return report(invalid_argument("--token-file: cannot read " + token_file));
      char buf[4096];
      const std::size_t got = std::fread(buf, 1, sizeof buf, f);
      std::fclose(f);
      o.token.assign(buf, got);
    } else if (const char* env = std::getenv("SPOKEMESH_TOKEN")) {
      o.token = env;
    }
    while (!o.token.empty() && std::isspace(static_cast<unsigned char>(o.token.back()))) o.token.pop_back();
    if (seed < -1) return report(out_of_range("--seed: " + std::to_string(seed) + " is negative"));
    const auto s = static_cast<std::uint64_t>(seed);
    if (*upload) return remote::upload(o, input, display_name);
    if (*batch) {
      std::string text = seeds_text;
      if (!seeds_file.empty()) {
        std::ifstream in(seeds_file);
        if (!in) return report(invalid_argument("--seeds-file: cannot read " + seeds_file));
        text.append(",").append(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
      }
      std::vector<std::uint64_t> seed_list;
      std::string item;
      for (char ch : text + ",") {
        if (ch == ',' || std::isspace(static_cast<unsigned char>(ch))) {
          if (item.empty()) continue;
          char* end = nullptr;
          const unsigned long long v = std::strtoull(item.c_str(), &end, 10);
          if (*end != '\0' || item[0] == '-') {
            return report(invalid_argument("--seeds: '" + item + "' (seed " + std::to_string(seed_list.size()) +
                                           ") is not a seed index"));
          }
          seed_list.push_back(v);
          item.clear();
        } else {
          item += ch;
        }
      }
      if (seed_list.empty()) return report(invalid_argument("batch: give seeds with --seeds or --seeds-file"));
      const std::string mode = !approx_flags.enabled ? "exact" : approx_flags.mode == "spokes" ? "spokes" : "approximate";
      return remote::batch(o, input, batch_kind, seed_list, mode, approx_flags.enabled ? approx_flags.misses : 0,
                           approx_flags.enabled ? approx_flags.max_vertices : 0, domain_flags.box,
                           domain_flags.halfspaces);
    }
    if (*health) return remote::health(o);
    if (*list) return remote::list(o);
    if (*del) return remote::remove(o, input);
    if (*star) return remote::star(o, input, s);
    if (*neighbors) {
      const std::string mode = !approx_flags.enabled ? "exact" : approx_flags.mode == "spokes" ? "spokes" : "approximate";
      return remote::neighbors(o, input, s, mode, approx_flags.enabled ? approx_flags.misses : 0,
                               approx_flags.enabled ? approx_flags.max_vertices : 0);
    }
    if (*cell) return remote::cell(o, input, s, json, domain_flags.box, domain_flags.halfspaces);
    if (*cells) return remote::cells(o, input, output, domain_flags.box, domain_flags.halfspaces);
    if (*mesh) {
      if (!seeds.empty()) return report(invalid_argument("--seeds is local only; remote meshes are split with --shards"));
      return remote::mesh(o, input, output, shards);
    }
#else
    return report(invalid_argument("--server: this build has no remote mode (built without SPOKEMESH_BUILD_SERVICE)"));
#endif
  }
  if (remote_only) {
    return report(invalid_argument(std::string(app.get_subcommands().front()->get_name()) +
                                   ": needs --server HOST:PORT (a spokemesh-server)"));
  }
  if (*mesh) return run_mesh(common, input, output, seeds);
  if (*star) {
    return with_star(common, input, seed, [](const Loaded& loaded, Star& s) {
      for (auto& v : s.simplices) v = loaded.to_original(v);
      std::string out;
      append_index_lines(out, s.simplices, s.dimension + 1);
      std::fwrite(out.data(), 1, out.size(), stdout);
      return kExitOk;
    });
  }
  if (*graph) return run_graph(common, approx_flags, input, output);
  if (*neighbors && approx_flags.enabled) return run_approx_neighbors(common, approx_flags, input, seed);
  if (*neighbors) {
    return with_star(common, input, seed, [](const Loaded& loaded, Star& s) {
      for (std::uint32_t v : star_neighbors(s)) std::printf("%u\n", loaded.to_original(v));
      return kExitOk;
    });
  }
  if (*cell) return run_cell(common, input, seed, json, domain_flags);
  if (*cells) {
    common.cache_mb = cells_cache_mb;
    return run_cells(common, input, output, domain_flags);
  }
  if (*check) return run_check(input, mesh_path);
  return kExitUsage;
}
