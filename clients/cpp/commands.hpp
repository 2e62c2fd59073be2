// The commands that write a whole result (mesh, graph, cells), their flags and what
// they share (exit codes, errors, progress, domains): defined once, for `spokemesh`
// and for `spokemesh-mpi`, so that both take the same command lines and say the same
// things (docs/distributed.md).
//
// Thread safety: none needed (the command line is parsed once, on the main thread);
// Progress is used by one thread.
#pragma once

#include <CLI/CLI.hpp>

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

#include "spokemesh/approx.hpp"
#include "spokemesh/domain.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/shape_domain.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::cli {

constexpr int kExitOk = 0, kExitFailure = 1, kExitUsage = 2;

// Prints "PROGRAM: message" on stderr; returns the exit code for the status (2 for bad
// usage or input, 1 otherwise).
int report(const Status& status, const char* program = "spokemesh");
int exit_code(const Status& status);

// --approx and its budget (graph, neighbors, batch).
struct ApproxFlags {
  bool enabled = false;
  std::uint32_t misses = kDefaultMaxMisses;
  std::uint32_t max_vertices = kDefaultMaxVertices;
  std::string mode = "rsd";  // checked by parse_neighbor_mode (approx.hpp) when parsed

  // The mode asked for: kExact without --approx.
  NeighborMode neighbor_mode() const;
  ApproxOptions options(std::uint64_t random_seed) const;
};
void add_approx_flags(CLI::App* cmd, ApproxFlags& flags);

// Flags most commands take.
struct Common {
  unsigned threads = 0;  // 0 until parsed: the machine's threads (set by define_whole_commands)
  bool quiet = false;
  bool merge_duplicates = false;
  std::uint64_t random_seed = 0x5eed;
  std::size_t cache_mb = 1024;  // the front's cap for whole meshes
  // Power weights (--weights) or radii (--radii, squared into weights) of the points:
  // the regular triangulation instead of the Delaunay one. At most one is set.
  std::string weights, radii;
  bool weighted() const { return !weights.empty() || !radii.empty(); }
  // --periodic LO1,...,LOd,HI1,...,HId: mesh on the flat torus of that box.
  std::string periodic;
};
void add_common_flags(CLI::App* cmd, Common& common);
// --weights FILE and --radii FILE (the commands of the exact engine that support them).
void add_weight_flags(CLI::App* cmd, Common& common);
// --periodic BOX.
void add_periodic_flag(CLI::App* cmd, Common& common);

// The domain of `cell` and `cells`: --box, --halfspaces, or (for `cells`, when
// `default_box`) the points' bounding box; none for an unclipped `cell`.
struct DomainFlags {
  std::string box, halfspaces;
  std::string shape;  // --domain FILE: a domain of any shape (shape_domain.hpp)
};
void add_domain_flags(CLI::App* cmd, DomainFlags& flags, const char* when_absent);
// The domain for `points` (the box of every point: give the global box when the
// points are a part of the set).
Result<std::optional<Domain>> domain_for(const DomainFlags& flags, int dimension,
                                         const std::optional<Domain>& bounding_box);

// A domain of any shape from a file: GeoJSON (.geojson, .json: a Polygon, a
// MultiPolygon, a Feature or a FeatureCollection of them; every ring of every polygon),
// else by extension as read_shape_domain. Errors name the file and, in GeoJSON, the
// member (features[0].geometry.coordinates[1][3]).
Result<ShapeDomain> read_domain(const std::string& path);

// An output that is the input file itself (same path, a link, another spelling) would
// destroy the input when the result is renamed into place: refused up front.
Status check_not_input(const std::string& input, const std::string& output);

// mesh, graph and cells with their flags. `one_process` adds what only the
// single-process CLI has (the remote mode's --shards).
struct WholeCommands {
  Common common;
  ApproxFlags approx;
  DomainFlags domain;
  std::string input, output;
  std::string seeds;                 // mesh --seeds A:B
  std::string engine = "auto";       // mesh --engine
  std::size_t cells_cache_mb = 256;  // cells --cache-mb
  unsigned shards = 4;               // mesh --shards (remote mode)
  CLI::App* mesh = nullptr;
  CLI::App* graph = nullptr;
  CLI::App* cells = nullptr;
};
void define_whole_commands(CLI::App& app, WholeCommands& commands, bool one_process);

// Parses mesh --engine.
Result<MeshEngine> parse_engine(const std::string& text);

// Parses --seeds A:B for n points: [begin, end).
Result<std::pair<std::uint32_t, std::uint32_t>> parse_seed_range(const std::string& text, std::uint64_t n);

// Progress of a long run on stderr: after 2 s, a line redrawn every 0.2 s on a
// terminal, every 5 s otherwise.
class Progress {
 public:
  Progress(bool quiet, std::uint64_t total, const char* what = "meshing");
  void update(std::uint64_t done, std::uint64_t simplices);
  void finish();
  double seconds() const;

 private:
  bool quiet_;
  std::uint64_t total_;
  bool tty_;
  const char* what_;
  bool drawn_ = false;
  double last_ = 0;
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

// The one-line summaries the commands print when done (unless --quiet).
void print_mesh_summary(std::uint64_t points, std::uint64_t simplices, double seconds, const MeshStats& stats,
                        const std::string& output);
void print_graph_summary(std::uint64_t points, std::uint64_t edges, bool approximate, double seconds,
                         const std::string& output);
void print_cells_summary(std::uint64_t points, const std::string& domain, std::uint64_t facets, double volume,
                         double seconds, const std::string& output);

}  // namespace spokemesh::cli
