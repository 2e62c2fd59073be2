#include "run.hpp"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <numeric>
#include <optional>
#include <set>

#include "halo.hpp"
#include "input.hpp"
#include "split.hpp"
#include "spokemesh/certify.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/space_split.hpp"

namespace spokemesh::mpi {
namespace {

using Clock = std::chrono::steady_clock;
constexpr const char* kProgram = "spokemesh-mpi";

// Debugging aid (SPOKEMESH_MPI_DEBUG): the peak so far at a named point.
void note_peak(const Comm& comm, const char* where) {
  if (std::getenv("SPOKEMESH_MPI_DEBUG") == nullptr) return;
  rusage u{};
  ::getrusage(RUSAGE_SELF, &u);
  static const auto t0 = Clock::now();
  std::fprintf(stderr, "rank %d peak %ld MB at %s, %.2f s\n", comm.rank, u.ru_maxrss / 1024, where,
               std::chrono::duration<double>(Clock::now() - t0).count());
}

std::uint64_t peak_rss_bytes() {
  rusage u{};
  ::getrusage(RUSAGE_SELF, &u);
  return static_cast<std::uint64_t>(u.ru_maxrss) * 1024;
}

// A hull facet as global indices (d of them).
using FacetKey = std::vector<std::uint64_t>;

// What the rounds have fetched for the rank's refused seeds, and so what their
// certificates may count on.
struct Reach {
  // Owned k -> the box around its uncertified balls (doubling each round it is
  // refused again), and the balls fetched for it (d + 1 doubles each).
  std::map<std::uint32_t, std::vector<double>> boxes;
  std::map<std::uint32_t, std::vector<double>> balls;
  // Hull facets whose outer side has been fetched whole: if such a facet is still on
  // the hull of the held points, it is on the whole set's.
  std::set<FacetKey> known_hull;
  // The region of each asked hull facet's outer side fetched so far: it grows round by
  // round; once it holds the whole set's box, the facet is known (a true hull facet's
  // outer side is empty, so the answers stay empty and cheap).
  std::map<FacetKey, std::vector<double>> hull_region;
  // A seed's balls reached across the whole set (MeshOptions::defer): every point of
  // it was fetched, as one process takes the whole set.
  bool everything = false;
};

// This round's requests of the others: boxes, hull facets with their regions, balls;
// and the facets that will be known once they are answered.
struct Requests {
  std::vector<double> boxes, facets, balls;
  std::vector<FacetKey> asked;
};

// Whether a box holds the whole set's box.
bool covers(const std::vector<double>& box, const std::vector<double>& global_box) {
  const std::size_t d = global_box.size() / 2;
  for (std::size_t c = 0; c < d; ++c) {
    if (box[c] > global_box[c] || box[d + c] < global_box[d + c]) return false;
  }
  return true;
}

// RoundCertifier over the held points: a seed's certificate may count on its piece's
// held box and on the boxes and balls fetched for it (every point inside them is
// held), and must clear the boxes that may hold points it does not have (none once
// its reach covers the whole set, or once this rank holds every point).
class HeldCertifier final : public RoundCertifier {
 public:
  HeldCertifier(const LocalSet& local, const std::vector<std::uint32_t>& own_of_local, const Halo& halo,
                std::size_t pieces, const Reach& reach, const RunFacts& facts)
      : local_(local),
        own_of_local_(own_of_local),
        halo_(halo),
        reach_(reach),
        facts_(facts),
        certifier_(local.points, facts.global_box),
        holds_all_(local.points.size() == facts.n) {
    // The boxes each piece's seeds do not see, once for the round.
    unheld_.resize(pieces);
    for (std::size_t p = 0; p < pieces; ++p) unheld_[p] = halo.unheld(p);
  }

  StarCertificate star(const Star& star) const override {
    const Regions r = regions_of(own_of_local_[star.seed], star.seed);
    return certifier_.certify(star, r.held, r.balls, r.unheld, [&](std::span<const std::uint32_t> facet) {
      FacetKey key(facet.size());
      for (std::size_t i = 0; i < facet.size(); ++i) key[i] = local_.global[facet[i]];
      return reach_.known_hull.count(key) != 0;
    });
  }

  // A cell is the whole set's when the points within the distance that decided it are
  // all held (then the whole set's builder takes the same points in the same order)
  // and, built from a star, the star is the whole set's.
  StarCertificate cell(std::uint32_t k, std::uint32_t seed, const ClippedCellBuilder& builder) const override {
    StarCertificate c;
    c.certified = true;
    const int d = facts_.d;
    if (const double r2 = builder.last_reach2(); r2 > 0) {
      const Regions r = regions_of(k, seed);
      // (nanoflann's distances are within kDistanceMargin of the exact ones.)
      const double want = r2 * (1 + 4 * kDistanceMargin);
      if (!certifier_.ball_is_held(seed, want, r.held, r.balls, r.unheld)) {
        c.certified = false;
        const double* x = local_.points.point(seed);
        if (std::isfinite(want)) {
          c.balls.assign(x, x + d);
          c.balls.push_back(std::sqrt(want) * (1 + 1e-12));
        } else {
          c.reach = facts_.global_box;  // it rested on there being no other points: all of them
        }
      }
    }
    if (const Star* s = builder.last_star()) {
      StarCertificate from_star = star(*s);
      c.certified = c.certified && from_star.certified;
      c.balls.insert(c.balls.end(), from_star.balls.begin(), from_star.balls.end());
      if (c.reach.empty()) c.reach = std::move(from_star.reach);
      c.hull_facets = std::move(from_star.hull_facets);
    }
    return c;
  }

 private:
  struct Regions {
    std::vector<double> held;
    std::span<const double> balls, unheld;
  };
  Regions regions_of(std::uint32_t k, std::uint32_t seed) const {
    Regions r;
    const auto piece = static_cast<std::size_t>(local_.piece_of[seed]);
    r.held.assign(halo_.held_box(piece).begin(), halo_.held_box(piece).end());
    bool everything = holds_all_;
    if (const auto it = reach_.boxes.find(k); it != reach_.boxes.end()) {
      r.held.insert(r.held.end(), it->second.begin(), it->second.end());
      everything = covers(it->second, facts_.global_box);
    }
    if (const auto it = reach_.balls.find(k); it != reach_.balls.end()) r.balls = it->second;
    if (!everything) r.unheld = unheld_[piece];
    return r;
  }

  const LocalSet& local_;
  const std::vector<std::uint32_t>& own_of_local_;
  const Halo& halo_;
  const Reach& reach_;
  const RunFacts& facts_;
  const StarCertifier certifier_;
  const bool holds_all_;
  std::vector<std::vector<double>> unheld_;
};

struct RankStats {
  std::uint64_t owned = 0, ghosts = 0, rounds = 0, bytes_sent = 0, bytes_received = 0, peak_rss = 0;
  std::uint64_t balls_asked = 0;  // balls asked of the other ranks
  double seconds = 0;
};

class DistributedRun {
 public:
  DistributedRun(Comm& comm, const cli::WholeCommands& commands, const RunOptions& options)
      : comm_(comm), w_(commands), options_(options), job_(Job::make(options.kind, commands, options.store)) {}

  int run() {
    if (Status s = check_usage(); !s.is_ok()) return fail(s);
    note_peak(comm_, "start");
    if (Status s = read_input(); !s.is_ok()) return fail(s);
    note_peak(comm_, "read");
    if (Status s = split(); !s.is_ok()) return fail(s);
    if (Status s = rounds(); !s.is_ok()) return fail(s);
    note_peak(comm_, "rounds done");
    // What the job needs held beyond the stars' points (store: every piece's held box).
    const std::vector<double> boxes = job_->final_boxes(*split_);
    if (comm_.allreduce<std::uint64_t>(boxes.size(), MPI_SUM) != 0) {
      halo_->fetch(boxes, {}, {});
      held_tree_.reset();
      held_ = std::make_unique<LocalSet>(gather_local(*split_, halo_->ghosts()));
    }
    if (Status s = job_->write(comm_, held_tree_, held_, slice_coords_); !s.is_ok()) return fail(s);
    note_peak(comm_, "written");
    if (Status s = report_stats(); !s.is_ok()) return fail(s);
    return cli::kExitOk;
  }

 private:
  // A status every rank has agreed on: rank 0 reports it.
  int fail(const Status& s) const {
    if (comm_.rank == 0) return cli::report(s, kProgram);
    return cli::exit_code(s);
  }

  // Flags and output, alike on every rank; the output is probed for writing first, as
  // the CLI opens its output before meshing.
  Status check_usage() {
    Status usage;
    if (w_.common.merge_duplicates) {
      usage = invalid_argument(
          "--merge-duplicates: spokemesh-mpi does not merge duplicates; remove them, or mesh on one process with "
          "spokemesh");
    }
    if (usage.is_ok()) usage = job_->check_usage();
    auto engine = cli::parse_engine(w_.engine);
    if (usage.is_ok() && !engine.is_ok()) usage = engine.status();
    if (usage.is_ok()) facts_.engine = engine.value();
    if (usage.is_ok() && comm_.rank == 0) usage = cli::check_not_input(w_.input, w_.output);
    if (usage.is_ok() && comm_.rank == 0) {
      const std::string probe = w_.output + ".spokemesh-mpi-probe-" + std::to_string(::getpid());
      if (std::FILE* f = std::fopen(probe.c_str(), "wb"); f != nullptr) {
        std::fclose(f);
        std::remove(probe.c_str());
      } else {
        usage = invalid_argument(w_.output + ": cannot open for writing (" + std::strerror(errno) + ")");
      }
    }
    return comm_.agree(usage);
  }

  // Each rank's slice, the set's checks, the whole set's box, and the job's settings.
  Status read_input() {
    auto slice = read_slice(comm_, w_.input);
    if (!slice.is_ok()) return slice.status();
    slice_ = std::move(slice).value();
    if (Status s = check_set(comm_, slice_, w_.input); !s.is_ok()) return s;
    facts_.d = slice_.points.d;
    facts_.n = slice_.n;
    const auto d = static_cast<std::size_t>(facts_.d);
    // The whole set's box (the halos stop at it).
    std::vector<double>& box = facts_.global_box;
    box.assign(2 * d, std::numeric_limits<double>::infinity());
    for (std::size_t k = 0; k < slice_.points.size(); ++k) {
      for (std::size_t c = 0; c < d; ++c) {
        box[c] = std::min(box[c], slice_.points.point(k)[c]);
        box[d + c] = std::min(box[d + c], -slice_.points.point(k)[c]);
      }
    }
    comm_.allreduce(box, MPI_MIN);
    for (std::size_t c = 0; c < d; ++c) box[d + c] = -box[d + c];
    if (Status s = job_->prepare(comm_, facts_); !s.is_ok()) return s;
    if (job_->lists_points()) slice_coords_ = slice_.points.coords;
    return Status::ok();
  }

  // The top of the split dealt out (Job::split_target), and the first halo fetched.
  Status split() {
    const std::uint64_t n = facts_.n;
    const auto ranks = static_cast<std::uint64_t>(comm_.size);
    const std::uint64_t target = job_->split_target(n, static_cast<int>(ranks));
    auto split = split_across_ranks(comm_, std::move(slice_.points), n, target, w_.input);
    if (!split.is_ok()) return split.status();
    split_.emplace(std::move(split).value());
    split_->sweep_ends = sweep_piece_ends(*split_, comm_.rank);
    note_peak(comm_, "split across ranks");
    note_peak(comm_, "split");
    owned_ = split_->owned.size();
    if (Status s = job_->check_seeds(comm_, *split_); !s.is_ok()) return s;
    halo_ = std::make_unique<Halo>(comm_, *split_, facts_.global_box, options_.first_halo);
    std::vector<std::size_t> all_pieces(split_->owned_nodes.size());
    std::iota(all_pieces.begin(), all_pieces.end(), std::size_t{0});
    note_peak(comm_, "halo made");
    halo_->fetch(halo_->requests_of(all_pieces), {}, {});
    progress_ = std::make_unique<cli::Progress>(w_.common.quiet || comm_.rank != 0, owned_, job_->progress_label());
    return Status::ok();
  }

  // Round after round until no rank has a seed left: certified answers are kept by
  // the job; the refused ask for more points, which the next round holds.
  Status rounds() {
    for (int round = 1;; ++round) {
      stats_.rounds = static_cast<std::uint64_t>(round);
      hold_points(round);
      std::vector<std::pair<std::uint32_t, StarCertificate>> refused;
      Status failure = compute(round, refused);
      stats_.ghosts = halo_->ghosts().size();
      if (Status s = comm_.agree(failure); !s.is_ok()) return s;
      Requests requests;
      const std::uint64_t left = grow_requests(round, refused, requests);
      if (left == 0) break;
      stats_.balls_asked += requests.balls.size() / (static_cast<std::size_t>(facts_.d) + 1);
      halo_->fetch(requests.boxes, requests.facets, requests.balls, held_tree_.get(), &own_of_local_);
      // Every point beyond or on an asked facet's plane is held now: if the facet is
      // still on the hull of the held points, it is on the whole set's.
      for (FacetKey& key : requests.asked) reach_.known_hull.insert(std::move(key));
    }
    progress_->finish();
    return Status::ok();
  }

  // The held points and their tree, kept from round to round until new points arrive
  // (the rounds of hull facets mostly fetch none); the tree also answers the other
  // ranks' requests.
  void hold_points(int round) {
    if (held_ && halo_->ghosts().size() == ghosts_held_) return;
    held_tree_.reset();
    held_.reset();
    held_ = std::make_unique<LocalSet>(gather_local(*split_, halo_->ghosts()));
    ghosts_held_ = halo_->ghosts().size();
    PointSet& fresh = held_->points;
    spans_ = fresh.size() > static_cast<std::size_t>(facts_.d) && fresh.validate(w_.input, 3, false).is_ok() &&
             fresh.check_affine_span(w_.input).is_ok();
    own_of_local_.assign(fresh.size(), Halo::kNone);
    for (std::size_t k = 0; k < owned_; ++k) own_of_local_[held_->local_of_own[k]] = static_cast<std::uint32_t>(k);
    if ((round > 1 || job_->tree_in_first_round()) && spans_) held_tree_ = std::make_unique<KdTree>(fresh);
  }

  // The job's part of the round on the pending seeds (round 1: all of them).
  Status compute(int round, std::vector<std::pair<std::uint32_t, StarCertificate>>& refused) {
    if (owned_ == 0) return Status::ok();
    const HeldCertifier certifier(*held_, own_of_local_, *halo_, split_->owned_nodes.size(), reach_, facts_);
    const HeldRegion held = held_region();
    Round r{round, *held_, own_of_local_, *split_, certifier, held, held_tree_, pending_, refused, *progress_};
    if (spans_) return job_->compute(r);
    // Too few held points to span the space: every seed waits for more, asking for
    // the points around it.
    if (round == 1) {
      job_->defer_first_round(r);
      for (std::size_t k = 0; k < owned_; ++k) pending_.push_back(static_cast<std::uint32_t>(k));
    }
    const int d = facts_.d;
    for (const std::uint32_t k : pending_) {
      StarCertificate c;
      const double* x = split_->owned.point(k);
      c.reach.assign(x, x + d);
      c.reach.insert(c.reach.end(), x, x + d);
      refused.emplace_back(k, std::move(c));
    }
    return Status::ok();
  }

  // What the rank lacks of the whole set, as the core's runs read it: the other ranks'
  // nodes are unheld, less the pieces' held boxes and what the rounds fetched (boxes,
  // balls; the whole set once a seed asked for it); hull facets whose outer side was
  // fetched whole are known.
  HeldRegion held_region() const {
    HeldRegion h(facts_.d, facts_.global_box, facts_.n);
    if (held_->points.size() == facts_.n || reach_.everything) {
      h.add_held_box(facts_.global_box);
    } else {
      for (const TopNode& node : split_->nodes) {
        if (node.owner != comm_.rank) h.add_unheld_box(node.box, node.count);
      }
      for (std::size_t p = 0; p < split_->owned_nodes.size(); ++p) h.add_held_box(halo_->held_box(p));
      std::set<std::vector<double>> boxes;  // (a region's seeds share theirs)
      for (const auto& [k, box] : reach_.boxes) boxes.insert(box);
      for (const std::vector<double>& box : boxes) h.add_held_box(box);
      const auto d = static_cast<std::size_t>(facts_.d);
      for (const auto& [k, balls] : reach_.balls) {
        for (std::size_t b = 0; b + d + 1 <= balls.size(); b += d + 1)
          h.add_held_ball(std::span<const double>(balls).subspan(b, d + 1));
      }
      h.set_known_hull([this](std::span<const std::uint32_t> facet) {
        FacetKey key(facet.size());
        for (std::size_t i = 0; i < facet.size(); ++i) key[i] = held_->global[facet[i]];
        return reach_.known_hull.count(key) != 0;
      });
    }
    h.freeze();
    return h;
  }

  // The refused seeds are next round's pending ones; their certificates say what to
  // fetch: a box around the balls that failed (grown when refused again), the balls,
  // and the outer sides of hull facets in growing regions. Returns the seeds left on
  // every rank (collective).
  std::uint64_t grow_requests(int round, std::vector<std::pair<std::uint32_t, StarCertificate>>& refused,
                              Requests& out) {
    const auto dd = static_cast<std::size_t>(facts_.d);
    const int d = facts_.d;
    const PointSet& points = held_->points;
    pending_.clear();
    bool everything = false;  // one request for the whole set serves every seed that needs it
    std::set<std::vector<double>> asked_boxes;
    for (auto& [k, c] : refused) {
      pending_.push_back(k);
      const double* x = split_->owned.point(k);
      if (!c.reach.empty() && covers(c.reach, facts_.global_box)) {
        if (!everything && !reach_.everything) {
          out.boxes.insert(out.boxes.end(), facts_.global_box.begin(), facts_.global_box.end());
        }
        everything = true;
        continue;
      }
      if (!c.balls.empty()) {
        std::vector<double>& mine = reach_.balls[k];
        mine.insert(mine.end(), c.balls.begin(), c.balls.end());
        out.balls.insert(out.balls.end(), c.balls.begin(), c.balls.end());
      }
      if (!c.reach.empty()) {
        // A box to hold (a region's E, or the points around a seed whose held points do
        // not span the space yet): a little beyond it the first time, so that a ball
        // grown by a new point of it is often still inside; asked again, the union
        // with the last box, and when that asks for nothing more, twice the last box
        // around the seed: the boxes grow until every ball fits (or the whole set is
        // held). A region's seeds ask for one box: each box once a round.
        std::vector<double>& box = reach_.boxes[k];
        if (!box.empty()) {
          bool grows = false;
          for (std::size_t c2 = 0; c2 < dd; ++c2) {
            grows = grows || c.reach[c2] < box[c2] || c.reach[dd + c2] > box[dd + c2];
            c.reach[c2] = std::min(c.reach[c2], box[c2]);
            c.reach[dd + c2] = std::max(c.reach[dd + c2], box[dd + c2]);
          }
          for (std::size_t c2 = 0; c2 < dd && !grows; ++c2) {
            const double half = std::max(x[c2] - box[c2], box[dd + c2] - x[c2]);
            c.reach[c2] = std::min(c.reach[c2], x[c2] - 2 * half);
            c.reach[dd + c2] = std::max(c.reach[dd + c2], x[c2] + 2 * half);
          }
        } else {
          for (std::size_t c2 = 0; c2 < dd; ++c2) {
            const double pad = (c.reach[dd + c2] - c.reach[c2]) * 0.25;
            c.reach[c2] -= pad;
            c.reach[dd + c2] += pad;
          }
        }
        box = c.reach;
        if (asked_boxes.insert(box).second) out.boxes.insert(out.boxes.end(), box.begin(), box.end());
      }
      for (std::size_t f = 0; f + dd + 1 <= c.hull_facets.size(); f += dd + 1) {
        FacetKey key(dd);
        for (std::size_t v = 0; v < dd; ++v) {
          const std::uint32_t local_v = c.hull_facets[f + v];
          key[v] = held_->global[local_v];
          out.facets.insert(out.facets.end(), points.point(local_v), points.point(local_v) + d);
        }
        const std::uint32_t apex = c.hull_facets[f + dd];
        out.facets.insert(out.facets.end(), points.point(apex), points.point(apex) + d);
        std::vector<double>& region = reach_.hull_region[key];
        // A first region of four times the facet's size around the seed (a facet facing
        // other points fetches what lies just beyond it), growing while it is asked
        // again.
        std::vector<double> last = region;
        const bool last_was_asked = !last.empty();
        if (last.empty()) {
          last.assign(x, x + d);
          last.insert(last.end(), x, x + d);
          for (std::size_t v = 0; v <= dd; ++v) {
            const double* p = points.point(c.hull_facets[f + v]);
            for (std::size_t c2 = 0; c2 < dd; ++c2) {
              last[c2] = std::min(last[c2], p[c2]);
              last[dd + c2] = std::max(last[dd + c2], p[c2]);
            }
          }
        }
        region.assign(2 * dd, 0);
        for (std::size_t c2 = 0; c2 < dd; ++c2) {
          const double half = std::max({x[c2] - last[c2], last[dd + c2] - x[c2], 0.0});
          // Asked again, the facet is likely a true hull facet, whose answers stay
          // empty however large the region: 16x.
          const double grow = last_was_asked ? 16 : 4;
          region[c2] = x[c2] - grow * half;
          region[dd + c2] = x[c2] + grow * half;
        }
        out.facets.insert(out.facets.end(), region.begin(), region.end());
        if (covers(region, facts_.global_box)) out.asked.push_back(std::move(key));
      }
    }
    std::sort(pending_.begin(), pending_.end());
    pending_.erase(std::unique(pending_.begin(), pending_.end()), pending_.end());
    // The whole set asked for: nothing else needs fetching.
    if (everything) {
      out.balls.clear();
      out.facets.clear();
      out.asked.clear();
      out.boxes.assign(facts_.global_box.begin(), facts_.global_box.end());
      reach_.everything = true;
    }
    const std::uint64_t left = comm_.allreduce<std::uint64_t>(pending_.size(), MPI_SUM);
    if (std::getenv("SPOKEMESH_MPI_DEBUG") != nullptr) {
      std::fprintf(stderr,
                   "rank %d round %d: %zu owned, %zu held, %zu refused (all ranks: %llu), %zu boxes, %zu balls, %zu "
                   "facets asked, %.2f s\n",
                   comm_.rank, round, owned_, points.size(), pending_.size(), static_cast<unsigned long long>(left),
                   out.boxes.size() / (2 * dd), out.balls.size() / (dd + 1), out.facets.size() / ((dd + 3) * dd),
                   std::chrono::duration<double>(Clock::now() - start_).count());
    }
    return left;
  }

  // --stats (rank 0 writes every rank's figures) and rank 0's summary line.
  Status report_stats() {
    stats_.owned = owned_;
    stats_.bytes_sent = comm_.bytes_sent;
    stats_.bytes_received = comm_.bytes_received;
    stats_.peak_rss = peak_rss_bytes();
    stats_.seconds = std::chrono::duration<double>(Clock::now() - start_).count();
    std::vector<double> mine{static_cast<double>(stats_.owned),
                             static_cast<double>(stats_.ghosts),
                             static_cast<double>(stats_.rounds),
                             static_cast<double>(stats_.bytes_sent),
                             static_cast<double>(stats_.bytes_received),
                             static_cast<double>(stats_.peak_rss),
                             stats_.seconds,
                             static_cast<double>(job_->sphere_queries() + stats_.balls_asked)};
    std::vector<double> every(comm_.rank == 0 ? mine.size() * static_cast<std::size_t>(comm_.size) : 0);
    MPI_Gather(mine.data(), static_cast<int>(mine.size()), MPI_DOUBLE, every.data(), static_cast<int>(mine.size()),
               MPI_DOUBLE, 0, comm_.comm);
    Status status;
    if (comm_.rank == 0) {
      std::uint64_t ghosts = 0, most_rounds = 0;
      nlohmann::json ranks = nlohmann::json::array();
      for (int r = 0; r < comm_.size; ++r) {
        const double* v = &every[static_cast<std::size_t>(r) * mine.size()];
        ghosts += static_cast<std::uint64_t>(v[1]);
        most_rounds = std::max(most_rounds, static_cast<std::uint64_t>(v[2]));
        ranks.push_back({{"rank", r},
                         {"owned", static_cast<std::uint64_t>(v[0])},
                         {"ghosts", static_cast<std::uint64_t>(v[1])},
                         {"rounds", static_cast<std::uint64_t>(v[2])},
                         {"bytes_sent", static_cast<std::uint64_t>(v[3])},
                         {"bytes_received", static_cast<std::uint64_t>(v[4])},
                         {"peak_rss_bytes", static_cast<std::uint64_t>(v[5])},
                         {"seconds", v[6]},
                         {"sphere_queries", static_cast<std::uint64_t>(v[7])}});
      }
      if (!options_.stats_path.empty()) {
        std::ofstream out(options_.stats_path);
        out << nlohmann::json{{"ranks", ranks},
                              {"joint_levels", split_->joint_levels},
                              {"select_rounds", split_->select_rounds}}
                   .dump(2)
            << "\n";
        if (!out) status = internal_error("--stats: cannot write " + options_.stats_path);
      }
      if (!w_.common.quiet) {
        job_->print_summary(std::chrono::duration<double>(Clock::now() - start_).count(), ghosts, most_rounds,
                            comm_.size);
      }
    }
    return comm_.agree(status);
  }

  Comm& comm_;
  const cli::WholeCommands& w_;
  const RunOptions& options_;
  const std::unique_ptr<Job> job_;
  const Clock::time_point start_ = Clock::now();
  RunFacts facts_;
  Slice slice_;                       // until split: then its points move into the split
  std::vector<double> slice_coords_;  // kept when the file lists the points
  std::optional<TopSplit> split_;
  std::size_t owned_ = 0;
  std::unique_ptr<Halo> halo_;
  std::unique_ptr<cli::Progress> progress_;
  RankStats stats_;
  // The rounds' state.
  std::unique_ptr<LocalSet> held_;
  std::unique_ptr<KdTree> held_tree_;
  std::vector<std::uint32_t> own_of_local_;  // local index -> owned k, or Halo::kNone
  std::size_t ghosts_held_ = 0;
  bool spans_ = false;
  std::vector<std::uint32_t> pending_;  // owned k refused in the last round
  Reach reach_;
};

}  // namespace

int run_distributed(Comm& comm, const cli::WholeCommands& commands, const RunOptions& options) {
  return DistributedRun(comm, commands, options).run();
}

}  // namespace spokemesh::mpi
