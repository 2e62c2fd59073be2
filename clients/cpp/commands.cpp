#include "commands.hpp"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <iostream>
#include <thread>

#include <fstream>
#include <sstream>

#include "geojson_domain.hpp"
#include "spokemesh/cell_io.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/shape_io.hpp"

namespace spokemesh::cli {

int exit_code(const Status& status) {
  if (status.is_ok()) return kExitOk;
  return (status.code() == Code::kInvalidArgument || status.code() == Code::kOutOfRange) ? kExitUsage : kExitFailure;
}

int report(const Status& status, const char* program) {
  std::cerr << program << ": " << status.message() << "\n";
  return exit_code(status);
}

NeighborMode ApproxFlags::neighbor_mode() const {
  if (!enabled) return NeighborMode::kExact;
  auto parsed = parse_neighbor_mode(mode, "--mode");
  return parsed.is_ok() ? parsed.value() : NeighborMode::kApproximate;
}

ApproxOptions ApproxFlags::options(std::uint64_t random_seed) const {
  ApproxOptions o;
  o.mode = approx_walk(enabled ? neighbor_mode() : NeighborMode::kApproximate);
  o.max_misses = misses;
  o.max_vertices = max_vertices;
  o.random_seed = random_seed;
  return o;
}

void add_approx_flags(CLI::App* cmd, ApproxFlags& f) {
  cmd->add_flag(
      "--approx", f.enabled,
      "Certified approximate neighbours (any dimension): every edge is a true Delaunay edge, some may be missed");
  cmd->add_option("--misses", f.misses, "With --approx: stop after this many consecutive misses (the paper's M)")
      ->capture_default_str()
      ->check(CLI::Range(1u, 1000000u));
  cmd->add_option("--mode", f.mode, "With --approx: rsd (Recursive Spoke Darts walk) or spokes (plain Spoke Darts)")
      ->capture_default_str()
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            auto parsed = parse_neighbor_mode(text, "--mode");
            if (!parsed.is_ok()) return parsed.status().message();
            return parsed.value() == NeighborMode::kExact ? "--mode: an approximate walk is rsd or spokes" : "";
          },
          "rsd|spokes"));
  cmd->add_option("--max-vertices", f.max_vertices,
                  "With --approx: at most this many Voronoi vertices (or rays) per seed")
      ->capture_default_str()
      ->check(CLI::Range(1u, 100000000u));
}

void add_common_flags(CLI::App* cmd, Common& common) {
  cmd->add_flag("--merge-duplicates", common.merge_duplicates,
                "Map exact duplicate points to their first occurrence instead of refusing them");
  cmd->add_option("--random-seed", common.random_seed,
                  "Seed for the random spoke directions (the result does not depend on it)")
      ->capture_default_str();
}

void add_weight_flags(CLI::App* cmd, Common& common) {
  auto* weights =
      cmd->add_option("--weights", common.weights,
                      "Power weights, one per point (text: one a line; .npy: shape (n,)): the regular "
                      "(weighted Delaunay) triangulation, CGAL's convention (a weight is a squared radius); "
                      "points whose power cell is empty are hidden and in no simplex");
  auto* radii = cmd->add_option("--radii", common.radii,
                                "Radii, one per point, as Voro++'s -r: --weights with each radius squared");
  weights->excludes(radii);
  radii->excludes(weights);
}

void add_periodic_flag(CLI::App* cmd, Common& common) {
  cmd->add_option("--periodic", common.periodic,
                  "Work on the flat torus of the box LO1,...,LOd,HI1,...,HId (opposite sides identified; every point "
                  "in [LO, HI)). mesh: each simplex once, with its vertices' image offsets (.npz: simplices and "
                  "offsets; text: indices then offsets). cells: the torus's cells, each neighbour's image offset in "
                  ".npz's facet_offset");
}

void add_domain_flags(CLI::App* cmd, DomainFlags& flags, const char* when_absent) {
  cmd->add_option(
      "--box", flags.box,
      std::string("Clip to the box LO1,...,LOd,HI1,...,HId (walls 0..d-1 low, d..2d-1 high); ") + when_absent);
  cmd->add_option("--halfspaces", flags.halfspaces,
                  "Clip to the convex domain given by a file of walls, one per line: a_1 ... a_d b for a.x <= b");
  cmd->add_option("--domain", flags.shape,
                  "Clip to a domain of any shape (docs/cells.md): a closed triangle mesh (.off, .obj, .stl) in 3-d, "
                  "a polygon with holes (.geojson, or .rings: one ring per block of \"x y\" lines) in 2-d; wall k "
                  "is its face k (triangle, or ring edge)");
}

Result<ShapeDomain> read_domain(const std::string& path) {
  if (!is_geojson_path(path)) return read_shape_domain(path);
  std::ifstream in(path, std::ios::binary);
  if (!in) return invalid_argument(path + ": cannot read the domain file");
  std::ostringstream text;
  text << in.rdbuf();
  return parse_geojson_domain(text.str(), path);
}

Result<std::optional<Domain>> domain_for(const DomainFlags& flags, int d, const std::optional<Domain>& bounding_box) {
  if (!flags.box.empty() + !flags.halfspaces.empty() + !flags.shape.empty() > 1)
    return invalid_argument("--box, --halfspaces and --domain exclude each other");
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
  return bounding_box;
}

Status check_not_input(const std::string& input, const std::string& output) {
  struct stat in {
  }, out{};
  if (::stat(input.c_str(), &in) == 0 && ::stat(output.c_str(), &out) == 0 && in.st_dev == out.st_dev &&
      in.st_ino == out.st_ino) {
    return invalid_argument("-o " + output + " is the input file " + input +
                            "; writing it would overwrite the input: choose another output file");
  }
  return Status::ok();
}

void define_whole_commands(CLI::App& app, WholeCommands& w, bool one_process) {
  if (w.common.threads == 0) w.common.threads = std::max(1u, std::thread::hardware_concurrency());
  const char* threads_help = one_process ? "Worker threads" : "Worker threads per process";

  w.mesh = app.add_subcommand("mesh", "Mesh a point file (the whole Delaunay mesh, or the simplices owned by --seeds)");
  w.mesh->add_option("INPUT", w.input, "Point file (.txt/.csv/.xyz text or .npy)")->required();
  w.mesh
      ->add_option("-o,--output", w.output,
                   "Mesh file: .simplices/.txt (indices), .npy (int64), .vtu or .msh (2-d/3-d), .svg (2-d)")
      ->required();
  w.mesh->add_option("--threads", w.common.threads, threads_help)->capture_default_str()->check(CLI::Range(1u, 1024u));
  w.mesh->add_option("--seeds", w.seeds,
                     "Only the simplices owned by seeds A..B-1 (A:B); owner = smallest vertex index. Rows are in sweep "
                     "order (a recursive split of space by counts; the same for any --threads and any number of "
                     "processes): sort them for lexicographic order");
  w.mesh
      ->add_option("--cache-mb", w.common.cache_mb,
                   "Memory cap (MiB) on the front: facets shared with blocks still to come (2-d: 64 bytes per point); "
                   "0 = none (same output, slower)")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{0}, std::size_t{1} << 24));
  w.mesh
      ->add_option("--engine", w.engine,
                   "How the mesh is computed (the rows are the same): auto (local triangulations with certified stars "
                   "in 2-d and 3-d, unweighted and not periodic; stars otherwise), stars (every seed's star walked) or "
                   "triangulations")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "stars", "triangulations"}));
  w.mesh->add_flag("-q,--quiet", w.common.quiet, "No progress or summary on stderr");
  if (one_process) {
    w.mesh->add_option("--shards", w.shards, "Remote mode: shards fetched in parallel")
        ->capture_default_str()
        ->check(CLI::Range(1u, 4096u));
  }
  add_weight_flags(w.mesh, w.common);   // spokemesh-mpi refuses them with a message
  add_periodic_flag(w.mesh, w.common);  // and this
  add_common_flags(w.mesh, w.common);

  w.graph = app.add_subcommand("graph", "Write the Delaunay graph: one edge \"i j\" per line (i < j, sorted), or .npy");
  w.graph->add_option("INPUT", w.input, "Point file")->required();
  w.graph->add_option("-o,--output", w.output, "Edge file: .edges/.txt (text) or .npy (int64, shape (m, 2))")
      ->required();
  w.graph->add_option("--threads", w.common.threads, threads_help)->capture_default_str()->check(CLI::Range(1u, 1024u));
  w.graph->add_flag("-q,--quiet", w.common.quiet, "No progress or summary on stderr");
  add_approx_flags(w.graph, w.approx);
  add_common_flags(w.graph, w.common);
  add_weight_flags(w.graph, w.common);

  w.cells = app.add_subcommand(
      "cells",
      "Write every Voronoi cell clipped to a domain, with volume, centroid and facet areas/normals/neighbours");
  w.cells->add_option("INPUT", w.input, "Point file")->required();
  w.cells
      ->add_option("-o,--output", w.output,
                   ".npz (NumPy arrays, any d), .vtu (ParaView polygons/polyhedra, 2-d/3-d) or .svg (a 2-d picture)")
      ->required();
  add_domain_flags(w.cells, w.domain, "default: the points' bounding box");
  w.cells->add_option("--threads", w.common.threads, threads_help)->capture_default_str()->check(CLI::Range(1u, 1024u));
  w.cells->add_flag("-q,--quiet", w.common.quiet, "No progress or summary on stderr");
  w.cells
      ->add_option("--cache-mb", w.cells_cache_mb,
                   "Memory cap (MiB) for sharing wraps between the seeds' stars; 0 = none (same cells, slower)")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t{0}, std::size_t{1} << 24));
  w.cells
      ->add_option("--random-seed", w.common.random_seed,
                   "Seed for the random spoke directions (the result does not depend on it)")
      ->capture_default_str();
  add_weight_flags(w.cells, w.common);
  add_periodic_flag(w.cells, w.common);
}

Result<std::pair<std::uint32_t, std::uint32_t>> parse_seed_range(const std::string& seeds, std::uint64_t n) {
  const auto colon = seeds.find(':');
  std::uint64_t begin = 0, end = n;
  try {
    if (colon == std::string::npos) throw std::invalid_argument("no colon");
    if (colon != 0) begin = std::stoull(seeds.substr(0, colon));
    if (colon + 1 != seeds.size()) end = std::stoull(seeds.substr(colon + 1));
  } catch (const std::exception&) {
    return invalid_argument("--seeds: expected A:B (seeds A..B-1), got '" + seeds + "'");
  }
  if (begin > end || end > n)
    return invalid_argument("--seeds " + seeds + ": need 0 <= A <= B <= " + std::to_string(n));
  return std::pair{static_cast<std::uint32_t>(begin), static_cast<std::uint32_t>(end)};
}

Progress::Progress(bool quiet, std::uint64_t total, const char* what)
    : quiet_(quiet), total_(total), tty_(::isatty(2) != 0), what_(what) {}

void Progress::update(std::uint64_t done, std::uint64_t simplices) {
  if (quiet_) return;
  const double elapsed = seconds();
  if (elapsed < 2.0) return;
  const double interval = tty_ ? 0.2 : 5.0;
  if (elapsed - last_ < interval) return;
  last_ = elapsed;
  char line[160];
  const double percent = total_ != 0 ? 100.0 * static_cast<double>(done) / static_cast<double>(total_) : 100.0;
  if (simplices != 0) {
    std::snprintf(line, sizeof line, "%s: %llu/%llu seeds (%.0f%%), %llu simplices, %.1f s", what_,
                  static_cast<unsigned long long>(done), static_cast<unsigned long long>(total_), percent,
                  static_cast<unsigned long long>(simplices), elapsed);
  } else {  // the graph and cells commands count seeds only
    std::snprintf(line, sizeof line, "%s: %llu/%llu seeds (%.0f%%), %.1f s", what_,
                  static_cast<unsigned long long>(done), static_cast<unsigned long long>(total_), percent, elapsed);
  }
  if (tty_)
    std::fprintf(stderr, "\r%s\033[K", line);
  else
    std::fprintf(stderr, "%s\n", line);
  drawn_ = tty_;
}

void Progress::finish() {
  if (drawn_) std::fprintf(stderr, "\r\033[K");
  drawn_ = false;
}

double Progress::seconds() const {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
}

void print_mesh_summary(std::uint64_t points, std::uint64_t simplices, double t, const MeshStats& stats,
                        const std::string& output) {
  // The run's own memory at its peak: what the stars shared (the sweep's front), or
  // the local triangulations held (docs/algorithm.md).
  const bool triangulated = stats.triangulation.regions != 0 || stats.triangulation.whole_set;
  const double mb =
      static_cast<double>(triangulated ? stats.triangulation.peak_bytes : stats.facet_cache_bytes) / (1 << 20);
  std::fprintf(stderr, "spokemesh: %llu points, %llu simplices, %.2f s, %.0f simplices/s, %.1f MB %s -> %s\n",
               static_cast<unsigned long long>(points), static_cast<unsigned long long>(simplices), t,
               t > 0 ? static_cast<double>(simplices) / t : 0.0, mb, triangulated ? "in triangulations" : "shared",
               output.c_str());
  if (triangulated) {
    const TriangulationStats& s = stats.triangulation;
    std::fprintf(
        stderr,
        "spokemesh: %llu regions, %.2f insertions per point, %llu margins grown, %llu balls asked of the tree%s\n",
        static_cast<unsigned long long>(s.regions),
        points != 0 ? static_cast<double>(s.inserted) / static_cast<double>(points) : 0.0,
        static_cast<unsigned long long>(s.margin_rounds), static_cast<unsigned long long>(s.ball_queries),
        s.whole_set ? ", one triangulation of every point (balls across the set)" : "");
  }
}

Result<MeshEngine> parse_engine(const std::string& text) {
  if (text == "auto") return MeshEngine::kAuto;
  if (text == "stars") return MeshEngine::kStars;
  if (text == "triangulations") return MeshEngine::kTriangulations;
  return invalid_argument("--engine " + text + ": use auto, stars or triangulations");
}

void print_graph_summary(std::uint64_t points, std::uint64_t edges, bool approximate, double t,
                         const std::string& output) {
  std::fprintf(stderr, "spokemesh: %llu points, %llu %s edges, mean degree %.2f, %.2f s -> %s\n",
               static_cast<unsigned long long>(points), static_cast<unsigned long long>(edges),
               approximate ? "certified (approximate)" : "exact",
               points != 0 ? 2.0 * static_cast<double>(edges) / static_cast<double>(points) : 0.0, t, output.c_str());
}

void print_cells_summary(std::uint64_t points, const std::string& domain, std::uint64_t facets, double volume, double t,
                         const std::string& output) {
  std::fprintf(stderr, "spokemesh: %llu cells in %s, %llu facets, total volume %.17g, %.2f s -> %s\n",
               static_cast<unsigned long long>(points), domain.c_str(), static_cast<unsigned long long>(facets), volume,
               t, output.c_str());
}

}  // namespace spokemesh::cli
