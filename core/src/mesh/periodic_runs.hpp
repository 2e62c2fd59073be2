// Internal: what every periodic run shares (meshes here, stars and cells in
// cells/periodic_stars.cpp and cells/periodic_cells.cpp): which simplex of the cover
// is a torus simplex's representative, the margin a run's spheres need, and the loop
// that repeats a run on a wider cover until its margin suffices.
//
// Thread safety: MarginPlan::sphere/power_sphere/unbounded may be called concurrently
// during a run; the rest by the run's owner.
#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/circumcentre.hpp"
#include "spokemesh/periodic_cover.hpp"
#include "spokemesh/predicates.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::periodic_runs {

// The first margin, in mean spacings (V / n)^(1/d). The circumspheres of well-spread
// points reach about twice the spacing; a margin that proves too thin is measured and
// the run repeated (mesh_periodic).
inline constexpr double kFirstMarginSpacings = 3.5;
// A margin beyond this many box lengths means too few points for the torus.
inline constexpr double kMostMarginBoxes = 3;

// Whether a simplex of the cover (ids, owner first at offset 0) is the representative
// its owner writes: no vertex stands for a smaller point, and the owner's other images
// in it have offsets lexicographically above zero.
inline bool is_representative(const PeriodicCover& cover, const std::uint32_t* s, int d) {
  const std::uint32_t owner = s[0];
  for (int v = 1; v <= d; ++v) {
    const std::uint32_t p = cover.point_of(s[v]);
    if (p < owner) return false;
    if (p == owner) {
      const std::int32_t* k = cover.offset_of(s[v]);
      for (int c = 0; c < d; ++c) {
        if (k[c] != 0) {
          if (k[c] < 0) return false;
          break;
        }
      }
    }
  }
  return true;
}

// Raises `slot` to at least v (atomically; rarely contended: only a larger need writes).
inline void raise_to(std::atomic<double>& slot, double v) {
  double seen = slot.load(std::memory_order_relaxed);
  while (v > seen && !slot.compare_exchange_weak(seen, v, std::memory_order_relaxed)) {}
}

// The margins of a periodic run and how they grow: per axis, the first from the mean
// spacing, then from what a thin run's spheres needed.
class MarginPlan {
 public:
  // start: the first run's margin (empty: kFirstMarginSpacings mean spacings).
  MarginPlan(const PointSet& points, const PeriodicBox& box, std::span<const double> start = {})
      : box_(box), d_(static_cast<std::size_t>(box.dimension())) {
    double volume = 1;
    for (std::size_t c = 0; c < d_; ++c) volume *= box.hi()[c] - box.lo()[c];
    spacing_ = std::pow(volume / static_cast<double>(points.size()), 1.0 / static_cast<double>(d_));
    margin_.resize(d_);
    for (std::size_t c = 0; c < d_; ++c) {
      margin_[c] = start.empty() ? std::min(kFirstMarginSpacings * spacing_, most(c)) : start[c];
    }
    needed_ = std::vector<std::atomic<double>>(d_);
  }
  const std::vector<double>& margin() const { return margin_; }

  // Starts a run: nothing needed yet.
  void begin() {
    for (auto& v : needed_) v.store(0);
    unbounded_.store(false);
  }
  // A sphere of the run (centre, radius, both from the cover's coordinates, within
  // `pad` of the exact ones): records how far it reaches past the box. Thread-safe.
  void sphere(const double* centre, double radius, double pad) {
    double size = 0;
    for (std::size_t c = 0; c < d_; ++c) size = std::max(size, std::fabs(centre[c]));
    const double r = radius * (1 + 1e-9) + 4 * pad + 8 * filter::kUnitRoundoff * size;
    for (std::size_t c = 0; c < d_; ++c) {
      const double reach = std::max(box_.lo()[c] - (centre[c] - r), (centre[c] + r) - box_.hi()[c]);
      if (reach > 0) raise_to(needed_[c], (reach + 2 * pad) * (1 + 1e-9));
    }
  }
  // A power sphere of the run (centre c, squared radius r2 = |c - x|^2 - w_x): only
  // points within sqrt(r2 + max w) of c can enter it.
  void power_sphere(const double* centre, double r2, double max_weight, double pad) {
    const double reach2 = r2 + max_weight;
    sphere(centre,
           std::sqrt(std::max(0.0, reach2) + 1e-12 * std::fabs(r2) +
                     8 * filter::kUnitRoundoff * (std::fabs(r2) + std::fabs(max_weight))),
           pad);
  }
  // A cell of the run was unbounded: the cover is too thin somewhere.
  void unbounded() { unbounded_.store(true, std::memory_order_relaxed); }

  // After a run: OK when its margin sufficed (every sphere strictly inside the region
  // the cover holds every image of); otherwise grows the margin and says so, or fails
  // when it cannot grow.
  Result<bool> thin(const std::string& source) {
    // A sphere measured in a cover too thin may be larger than the torus's (its far
    // side is missing), so a need far beyond the margin grows it at most eightfold.
    bool thin = unbounded_.load(), can_grow = false;
    std::vector<double> next(margin_);
    for (std::size_t c = 0; c < d_; ++c) {
      const double need = needed_[c].load();
      if (need >= margin_[c] || unbounded_.load()) {
        thin = true;
        next[c] = std::min({most(c), 8 * margin_[c], std::max(need * 1.25 + 0.5 * spacing_, 2 * margin_[c])});
        can_grow = can_grow || next[c] > margin_[c];
      }
    }
    if (!thin) return false;
    if (!can_grow) {
      return invalid_argument(source +
                              ": too few points for a periodic Delaunay triangulation of this box: the "
                              "circumspheres reach more than " +
                              std::to_string(static_cast<int>(kMostMarginBoxes)) +
                              " box lengths beyond it (add points)");
    }
    margin_ = next;
    return true;
  }

 private:
  double most(std::size_t c) const { return kMostMarginBoxes * (box_.hi()[c] - box_.lo()[c]); }
  const PeriodicBox& box_;
  std::size_t d_;
  double spacing_ = 0;
  std::vector<double> margin_;
  std::vector<std::atomic<double>> needed_;
  std::atomic<bool> unbounded_{false};
};

// Records the (power) sphere of a simplex of the cover (d + 1 ids, the first a point):
// its centre within 1e-12 of its size plus an ulp (circumcentre()), from the cover's
// coordinates, within pad of the images'.
inline void power_sphere_of(const PeriodicCover& cover, const std::uint32_t* s, int d, MarginPlan& plan) {
  const double* weights = cover.weights().empty() ? nullptr : cover.weights().data();
  const std::vector<double> centre = circumcentre(cover.points(), s, d + 1, weights);
  const double* x = cover.points().point(s[0]);
  double r2 = 0;
  for (int c = 0; c < d; ++c)
    r2 += (centre[static_cast<std::size_t>(c)] - x[c]) * (centre[static_cast<std::size_t>(c)] - x[c]);
  if (weights != nullptr) r2 -= weights[s[0]];
  plan.power_sphere(centre.data(), r2, cover.max_weight(), cover.pad());
}

// Runs attempt(cover, plan) on covers of growing margins until a run's spheres all lie
// inside its margin, calling `restart` between runs; returns the number of runs (the
// last attempt's results stand). kept: when not null, the first run's cover (and on
// return, the last run's).
template <class Attempt>
Result<int> with_growing_margins(const PointSet& points, const PeriodicBox& box, std::span<const double> weights,
                                 const std::string& source, const std::function<Status()>& restart, Attempt&& attempt,
                                 std::shared_ptr<const PeriodicCover>* kept = nullptr) {
  std::shared_ptr<const PeriodicCover> cover = kept != nullptr ? *kept : nullptr;
  MarginPlan plan(points, box, cover != nullptr ? std::span<const double>(cover->margin()) : std::span<const double>());
  for (int runs = 1;; ++runs) {
    if (cover == nullptr) {
      auto built = PeriodicCover::build(points, box, plan.margin(), source, weights);
      if (!built.is_ok()) return built.status();
      cover = std::move(built).value();
    }
    plan.begin();
    if (Status s = attempt(*cover, plan); !s.is_ok()) return s;
    auto thin = plan.thin(source);
    if (!thin.is_ok()) return thin.status();
    if (!thin.value()) {
      if (kept != nullptr) *kept = std::move(cover);
      return runs;
    }
    cover = nullptr;
    if (restart) {
      if (Status s = restart(); !s.is_ok()) return s;
    }
  }
}

}  // namespace spokemesh::periodic_runs
