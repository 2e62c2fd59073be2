// spokemesh-mpi: one point set meshed by many processes, the same bytes as
// `spokemesh` writes (docs/distributed.md).
//
//   mpirun -np P spokemesh-mpi {mesh|graph|cells} IN -o OUT [flags]
//   mpirun -np P spokemesh-mpi store IN --data-dir DIR [flags]   (pieces for sharded serving)
//
// Every rank reads a slice of IN (MPI-IO for .npy; rank 0 reads text and scatters);
// the ranks cut the set together into the nodes of SpaceSplit's recursion and deal
// them out in order; each rank fetches the others' points in a halo around its own,
// meshes its points' stars (RSD, the single-process sweep) and keeps the stars it can
// certify (certify.hpp); the others fetch a halo twice as deep, in rounds, until a
// reduction says none is left. Rows go to their place in the file by MPI-IO at computed
// offsets, written under a temporary name that rank 0 renames into OUT only after
// every rank succeeded. The run's steps are run.hpp's; what differs between the
// three commands is job.hpp's.
//
// Exit codes (the CLI's): 0 success, 1 failure, 2 bad usage or bad input.
#include <malloc.h>

#include <csignal>
#include <string>

#include "comm.hpp"
#include "commands.hpp"
#include "run.hpp"
#include "spokemesh/pieces.hpp"

using namespace spokemesh;
using namespace spokemesh::cli;
using spokemesh::mpi::Comm;

namespace {
constexpr const char* kProgram = "spokemesh-mpi";
}  // namespace

int main(int argc, char** argv) {
  ::mallopt(M_MMAP_THRESHOLD, 4 << 20);  // as the CLI (main.cpp there says why)
  // A file-size limit (ulimit -f) makes writes fail with EFBIG, reported as a full
  // disk is, instead of killing the process.
  std::signal(SIGXFSZ, SIG_IGN);
  int provided = 0;
  MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided);
  Comm comm = Comm::world();
  CLI::App app{
      "spokemesh-mpi: the Delaunay mesh, graph or clipped Voronoi cells of one point set by many processes "
      "(Open MPI), the same bytes as spokemesh writes.\nRun as: mpirun -np P spokemesh-mpi {mesh|graph|cells} "
      "INPUT -o OUTPUT [flags]"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "spokemesh-mpi 0.1.0");
  WholeCommands w;
  w.common.threads = 1;  // one worker per process unless asked: mpirun places processes on cores
  define_whole_commands(app, w, /*one_process=*/false);
  mpi::StoreSettings store_settings;
  store_settings.piece_points = kDefaultPiecePoints;
  CLI::App* store = app.add_subcommand(
      "store",
      "Keep a point set as pieces in spokemesh-server's data directory for sharded serving (docs/service.md, "
      "\"Sharded serving\"): the set's file as an upload stores it, each piece of its split with its halo, a "
      "manifest and an owner map; the same bytes on any number of processes");
  store->add_option("INPUT", w.input, "Point file (.txt/.csv/.xyz text or .npy), 2-d or 3-d")->required();
  store->add_option("--data-dir", store_settings.data_dir, "The servers' shared data directory")->required();
  store->add_option("--piece-points", store_settings.piece_points, "Most points in a piece")
      ->capture_default_str()
      ->check(CLI::Range(std::uint32_t{64}, std::uint32_t{1} << 30));
  store->add_option("--threads", w.common.threads, "Worker threads per process")
      ->capture_default_str()
      ->check(CLI::Range(1u, 1024u));
  store
      ->add_option("--random-seed", w.common.random_seed,
                   "Seed for the random spoke directions (the result does not depend on it)")
      ->capture_default_str();
  store->add_flag("-q,--quiet", w.common.quiet, "No progress or summary on stderr");
  std::string stats_path;
  double first_halo = 2.5;
  for (CLI::App* cmd : {w.mesh, w.graph, w.cells, store}) {
    cmd->add_option("--stats", stats_path,
                    "Write JSON {\"ranks\": [{rank, owned, ghosts, rounds, bytes_sent, bytes_received, "
                    "peak_rss_bytes, seconds}]}");
    cmd->add_option("--first-halo", first_halo,
                    "Depth of the first halo in mean point spacings (deeper halos are fetched in rounds where stars "
                    "need them; 0 starts from none)")
        ->capture_default_str()
        ->check(CLI::Range(0.0, 1000.0));
  }
  int code = kExitOk;
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (comm.rank == 0) {
      code = app.exit(e);
    } else {
      code = e.get_exit_code();
    }
    if (code != 0) code = kExitUsage;
    MPI_Finalize();
    return code;
  }
  if (!w.common.periodic.empty()) {
    if (comm.rank == 0) {
      report(invalid_argument("--periodic is not supported by spokemesh-mpi yet: use spokemesh"), kProgram);
    }
    MPI_Finalize();
    return kExitUsage;
  }
  if (w.common.weighted()) {
    // The halos certify stars with circumspheres, not power spheres.
    if (comm.rank == 0) {
      report(invalid_argument("--weights and --radii are not supported by spokemesh-mpi yet: use spokemesh"), kProgram);
    }
    MPI_Finalize();
    return kExitUsage;
  }
  mpi::RunOptions options;
  options.kind = *w.mesh    ? mpi::JobKind::kMesh
                 : *w.graph ? mpi::JobKind::kGraph
                 : *store   ? mpi::JobKind::kStore
                            : mpi::JobKind::kCells;
  options.store = store_settings;
  options.stats_path = stats_path;
  options.first_halo = first_halo;
  code = mpi::run_distributed(comm, w, options);
  MPI_Finalize();
  return code;
}
