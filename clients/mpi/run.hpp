// One distributed run of spokemesh-mpi, in the steps docs/distributed.md describes:
//
//   check_usage     flags and output, alike on every rank, before anything is read
//   read_input      each rank's slice; the set checked as one process checks it
//   split           the whole set's box; the top of the SpaceSplit dealt out; the first halo
//   rounds          hold the points fetched so far; compute the pending seeds (the job's
//                   part: round 1 sweeps, later rounds walk the refused seeds); certify;
//                   grow_requests for the refused; fetch; until no rank has any left
//   write           the file, the CLI's bytes (the job's part)
//   report_stats    --stats JSON and rank 0's summary
//
// What differs between mesh, graph and cells is the Job (job.hpp).
//
// Thread safety: collective; the main thread drives it.
#pragma once

#include <string>

#include "comm.hpp"
#include "commands.hpp"
#include "job.hpp"

namespace spokemesh::mpi {

struct RunOptions {
  JobKind kind = JobKind::kMesh;
  std::string stats_path;   // --stats: per-rank JSON, or empty
  double first_halo = 2.5;  // --first-halo: mean spacings
  StoreSettings store;      // `store`'s --data-dir and --piece-points
};

// Runs the job on every rank (collective); returns the exit code (the CLI's: 0, 1, 2),
// the same on every rank. Only rank 0 prints.
int run_distributed(Comm& comm, const cli::WholeCommands& commands, const RunOptions& options);

}  // namespace spokemesh::mpi
