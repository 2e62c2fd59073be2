// The three jobs of spokemesh-mpi behind one strategy: what a job computes for a seed,
// what it keeps of a certified one, and how it writes the file (the CLI's bytes). The
// rounds, the halos and the certification are the run's, the same for all three
// (run.cpp; docs/distributed.md).
//
//   mesh   the stars' owned simplices, first round by the single-process sweep
//   graph  the Delaunay edges, the same stars
//   cells  clipped Voronoi cells, seed by seed, certified by what decided each
//
// Thread safety: a Job's compute() runs the round's threads itself; every other call
// is made by the main thread, collective where it says so.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "comm.hpp"
#include "commands.hpp"
#include "halo.hpp"
#include "split.hpp"
#include "spokemesh/cells.hpp"
#include "spokemesh/certify.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/star.hpp"

namespace spokemesh::mpi {

enum class JobKind { kMesh, kGraph, kCells, kStore };

// `store`: where the pieces go and how large they are (pieces.hpp).
struct StoreSettings {
  std::string data_dir;
  std::uint32_t piece_points = 0;
};

// What every step knows once the input is read.
struct RunFacts {
  int d = 0;
  std::uint64_t n = 0;             // points in the whole set
  std::vector<double> global_box;  // the whole set's box: d lows, d highs
  MeshEngine engine = MeshEngine::kAuto;
};

// Whether a seed's answer, computed from the held points, is the whole set's (run.cpp
// answers from what has been fetched for the seed). Thread-safe: const calls only.
class RoundCertifier {
 public:
  virtual ~RoundCertifier() = default;
  // A star of a held point (local indices).
  virtual StarCertificate star(const Star& star) const = 0;
  // The cell `builder` just built for owned point k (local index `seed`).
  virtual StarCertificate cell(std::uint32_t k, std::uint32_t seed, const ClippedCellBuilder& builder) const = 0;
};

// One round as a job sees it.
struct Round {
  int number = 1;
  const LocalSet& local;
  const std::vector<std::uint32_t>& own_of_local;  // local index -> owned k (Halo::kNone: a ghost)
  const TopSplit& split;
  const RoundCertifier& certify;
  const HeldRegion& held;               // what the rank lacks of the whole set (MeshOptions::held)
  std::unique_ptr<KdTree>& tree;        // the held points' tree, kept between rounds (a job may build it)
  std::vector<std::uint32_t>& pending;  // owned k to compute (round 1 of cells: the job fills it)
  std::vector<std::pair<std::uint32_t, StarCertificate>>& refused;  // out: owned k, and what it needs
  cli::Progress& progress;
};

class Job {
 public:
  static std::unique_ptr<Job> make(JobKind kind, const cli::WholeCommands& commands, const StoreSettings& store = {});
  virtual ~Job() = default;

  // Before reading (the dimension unknown): the job's flags and the output's extension.
  virtual Status check_usage() const = 0;
  virtual const char* progress_label() const { return "meshing (rank 0's share)"; }
  // Once read: the output's format in dimension d and the job's own settings. Collective.
  virtual Status prepare(Comm& comm, const RunFacts& facts) = 0;
  // Once split: the seeds the job refuses (cells: outside the domain), as the CLI
  // reports them. Collective.
  virtual Status check_seeds(Comm& /*comm*/, const TopSplit& /*split*/) { return Status::ok(); }
  // Whether the file lists the points: the rank then keeps its slice's coordinates.
  virtual bool lists_points() const { return false; }
  // Whether round 1 needs the held points' tree before compute() (the sweep builds its own).
  virtual bool tree_in_first_round() const { return false; }
  // The most points in a node of the split dealt out: nodes of at most n / (32 P)
  // points keep every rank within 1/32 of its share (one process takes the whole set as
  // one node); `store` cuts the set into its pieces, whatever P.
  virtual std::uint64_t split_target(std::uint64_t n, int ranks) const;
  // Boxes (2 d doubles each) every point inside of which the rank must hold before
  // write() (collective fetch after the rounds); none by default.
  virtual std::vector<double> final_boxes(const TopSplit& /*split*/) const { return {}; }

  // One round on the rank's pending seeds (held points spanning the space): computes,
  // certifies, keeps what is certified and lists the rest in round.refused. Returns
  // the first failure.
  virtual Status compute(Round& round) = 0;
  // Round 1 when the held points do not span the space yet (every seed waits).
  virtual void defer_first_round(const Round& /*round*/) {}
  // After the rounds: writes the file (collective). `tree` and `held` are the last
  // round's (a job that no longer needs them releases them first); slice_coords the
  // rank's slice of the points when lists_points().
  virtual Status write(Comm& comm, std::unique_ptr<KdTree>& tree, std::unique_ptr<LocalSet>& held,
                       std::span<const double> slice_coords) = 0;
  // Rank 0's summary line on stderr.
  virtual void print_summary(double seconds, std::uint64_t halo_points, std::uint64_t rounds, int ranks) const = 0;
  // The sphere (ball) queries the rank's stars made of its own k-d trees: the star
  // walks' certifying queries and the local triangulations' ball queries (--stats).
  virtual std::uint64_t sphere_queries() const { return 0; }

 protected:
  explicit Job(const cli::WholeCommands& commands) : w_(commands) {}
  // A walker's options for a seed walked on its own: the run's random seed.
  StarOptions star_options() const {
    StarOptions o;
    o.random_seed = w_.common.random_seed;
    return o;
  }
  const cli::WholeCommands& w_;
  RunFacts facts_;
};

}  // namespace spokemesh::mpi
