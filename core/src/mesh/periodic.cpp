#include "spokemesh/periodic.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>
#include <optional>

#include "spokemesh/voronoi.hpp"

namespace spokemesh {

namespace {

constexpr double kUnit = 0x1p-53;
// The first margin, in mean spacings (V / n)^(1/d). The circumspheres of well-spread
// points reach about twice the spacing; a margin that proves too thin is measured and
// the run repeated (mesh_periodic).
constexpr double kFirstMarginSpacings = 3.5;
// A margin beyond this many box lengths means too few points for the torus.
constexpr double kMostMarginBoxes = 3;

}  // namespace

const std::int32_t* PeriodicCover::offset_of(std::uint32_t id) const {
  if (id < n_) return zeros_.data();
  return image_offset_.data() + static_cast<std::size_t>(id - n_) * static_cast<std::size_t>(base_.dimension());
}

Result<std::unique_ptr<PeriodicCover>> PeriodicCover::build(const PointSet& points, const PeriodicBox& box,
                                                            std::span<const double> margin, const std::string& source,
                                                            std::span<const double> weights) {
  const int d = points.dimension();
  const auto du = static_cast<std::size_t>(d);
  std::unique_ptr<PeriodicCover> cover(new PeriodicCover(points, box));
  cover->n_ = static_cast<std::uint32_t>(points.size());
  cover->margin_.assign(margin.begin(), margin.end());
  cover->zeros_.assign(du, 0);
  const auto& lo = box.lo();
  const auto& hi = box.hi();
  // Per axis, the offsets an image may have: |k| <= ceil(margin / side).
  std::vector<int> reach(du);
  double magnitude = 0;
  for (std::size_t c = 0; c < du; ++c) {
    const double side = hi[c] - lo[c];
    reach[c] = static_cast<int>(std::min(64.0, std::ceil(margin[c] / side)));
    magnitude = std::max({magnitude, std::fabs(lo[c] - margin[c]), std::fabs(hi[c] + margin[c])});
  }
  // An image's stored coordinate is its exact one rounded once: within u |coordinate|.
  // Twice that, plus the rounding of the tree's widened boxes, is the pad.
  cover->pad_ = 4 * kUnit * magnitude;

  std::vector<double> coords(points.coordinates().begin(), points.coordinates().end());
  std::vector<std::int32_t> k(du);
  std::vector<double> at(du);
  for (std::uint32_t i = 0; i < cover->n_; ++i) {
    const double* p = points.point(i);
    // Odometer over k in [-reach, reach]^d, skipping k = 0 and coordinates outside the region.
    for (std::size_t c = 0; c < du; ++c) k[c] = -reach[c];
    for (;;) {
      bool inside = false;
      bool zero = true;
      for (std::size_t c = 0; c < du; ++c) zero = zero && k[c] == 0;
      if (!zero) {
        inside = true;
        for (std::size_t c = 0; c < du && inside; ++c) {
          at[c] = image_difference(p[c], k[c], lo[c], hi[c], 0.0);
          inside = at[c] >= lo[c] - margin[c] && at[c] <= hi[c] + margin[c];
        }
      }
      if (inside) {
        coords.insert(coords.end(), at.begin(), at.end());
        cover->image_point_.push_back(i);
        cover->image_offset_.insert(cover->image_offset_.end(), k.begin(), k.end());
      }
      std::size_t c = 0;
      while (c < du && k[c] == reach[c]) {
        k[c] = -reach[c];
        ++c;
      }
      if (c == du) break;
      ++k[c];
    }
  }
  if (coords.size() / du > std::numeric_limits<std::uint32_t>::max() - 1) {
    return invalid_argument(source + ": the periodic images of " + std::to_string(points.size()) +
                            " points are too many for 32-bit indices");
  }
  cover->cover_ = PointSet(d, std::move(coords));
  if (Status s = cover->cover_.validate(source); !s.is_ok()) {
    // The points are valid, so two images (or an image and a point) fell on the same
    // double: points closer than the box's coordinates can resolve.
    return invalid_argument(source + ": the periodic images of the points cannot be told apart in double precision "
                            "(points closer together than the rounding of the box's coordinates, about " +
                            std::to_string(cover->pad_) + "): " + s.message());
  }
  if (!weights.empty()) {
    cover->weights_.assign(weights.begin(), weights.end());
    for (const std::uint32_t p : cover->image_point_) cover->weights_.push_back(weights[p]);
    cover->max_weight_ = *std::max_element(weights.begin(), weights.end());
  }
  cover->tree_ = std::make_unique<KdTree>(cover->cover_, cover->n_, cover->pad_);
  return cover;
}

namespace {

// Whether a simplex of the cover (ids, owner first at offset 0) is the representative
// its owner writes: no vertex stands for a smaller point, and the owner's other images
// in it have offsets lexicographically above zero.
bool is_representative(const PeriodicCover& cover, const std::uint32_t* s, int d) {
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
void raise_to(std::atomic<double>& slot, double v) {
  double seen = slot.load(std::memory_order_relaxed);
  while (v > seen && !slot.compare_exchange_weak(seen, v, std::memory_order_relaxed)) {
  }
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
    const double r = radius * (1 + 1e-9) + 4 * pad + 8 * kUnit * size;
    for (std::size_t c = 0; c < d_; ++c) {
      const double reach = std::max(box_.lo()[c] - (centre[c] - r), (centre[c] + r) - box_.hi()[c]);
      if (reach > 0) raise_to(needed_[c], (reach + 2 * pad) * (1 + 1e-9));
    }
  }
  // A power sphere of the run (centre c, squared radius r2 = |c - x|^2 - w_x): only
  // points within sqrt(r2 + max w) of c can enter it.
  void power_sphere(const double* centre, double r2, double max_weight, double pad) {
    const double reach2 = r2 + max_weight;
    sphere(centre, std::sqrt(std::max(0.0, reach2) + 1e-12 * std::fabs(r2) + 8 * kUnit * (std::fabs(r2) + std::fabs(max_weight))),
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
      return invalid_argument(source + ": too few points for a periodic Delaunay triangulation of this box: the "
                              "circumspheres reach more than " + std::to_string(static_cast<int>(kMostMarginBoxes)) +
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
void power_sphere_of(const PeriodicCover& cover, const std::uint32_t* s, int d, MarginPlan& plan) {
  const double* weights = cover.weights().empty() ? nullptr : cover.weights().data();
  const std::vector<double> centre = circumcentre(cover.points(), s, d + 1, weights);
  const double* x = cover.points().point(s[0]);
  double r2 = 0;
  for (int c = 0; c < d; ++c) r2 += (centre[static_cast<std::size_t>(c)] - x[c]) * (centre[static_cast<std::size_t>(c)] - x[c]);
  if (weights != nullptr) r2 -= weights[s[0]];
  plan.power_sphere(centre.data(), r2, cover.max_weight(), cover.pad());
}

// Runs attempt(cover, plan) on covers of growing margins until a run's spheres all lie
// inside its margin, calling `restart` between runs; returns the number of runs (the
// last attempt's results stand). kept: when not null, the first run's cover (and on
// return, the last run's).
template <class Attempt>
Result<int> with_growing_margins(const PointSet& points, const PeriodicBox& box, std::span<const double> weights,
                                 const std::string& source, const std::function<Status()>& restart,
                                 Attempt&& attempt, std::shared_ptr<const PeriodicCover>* kept = nullptr) {
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

// One seed's star on a cover, mapped to points and offsets (canonical form), with its
// cell and centres when asked; every sphere recorded in `plan`.
Status star_on_cover(const PeriodicCover& cover, MarginPlan& plan, std::uint32_t seed, const StarOptions& options,
                     VoronoiCell* cell, bool centres, PeriodicStar& out) {
  const int d = cover.points().dimension();
  StarOptions run = options;
  run.cover = &cover;
  run.weights = cover.weights();
  StarWalker walker(cover.tree(), run);
  Star star;
  if (Status s = walker.compute(seed, star); !s.is_ok()) return s;
  if (!star.bounded_cell()) plan.unbounded();
  for (std::size_t i = 0; i < star.size(); ++i) power_sphere_of(cover, star.simplex(i), d, plan);
  out = PeriodicStar{};
  out.seed = seed;
  out.hidden = star.hidden;
  for (const std::uint32_t id : star.simplices) {
    out.simplices.push_back(cover.point_of(id));
    const std::int32_t* k = cover.offset_of(id);
    out.offsets.insert(out.offsets.end(), k, k + d);
  }
  canonicalize_periodic_rows(d, out.simplices, out.offsets, true);
  if (centres) {
    // From the images' coordinates relative to the seed (each rounded once), so every
    // copy of a vertex has the same centre up to its translate.
    const auto du = static_cast<std::size_t>(d);
    const double* x = cover.points().point(seed);
    const double* w = cover.weights().empty() ? nullptr : cover.weights().data();
    std::vector<double> local((du + 1) * du);
    std::vector<double> local_w(du + 1);
    std::vector<std::uint32_t> ids(du + 1);
    for (std::size_t r = 0; r < out.size(d); ++r) {
      for (std::size_t v = 0; v <= du; ++v) {
        const std::uint32_t p = out.simplices[r * (du + 1) + v];
        const std::int32_t* k = out.offsets.data() + (r * (du + 1) + v) * du;
        for (std::size_t c = 0; c < du; ++c) {
          local[v * du + c] = image_difference(cover.points().point(p)[c], k[c], cover.box().lo()[c],
                                               cover.box().hi()[c], x[c]);
        }
        local_w[v] = w != nullptr ? w[p] : 0;
        ids[v] = static_cast<std::uint32_t>(v);
      }
      const PointSet simplex(d, std::vector<double>(local));
      std::vector<double> c = circumcentre(simplex, ids.data(), d + 1, w != nullptr ? local_w.data() : nullptr);
      for (std::size_t k = 0; k < du; ++k) out.centres.push_back(c[k] + x[k]);
    }
  }
  if (cell != nullptr) {
    *cell = voronoi_cell(cover.points(), star, cover.weights());
    cell->vertex_simplices.clear();  // the cover's ids: the star's rows say it with offsets
    cell->facet_offsets.clear();
    for (VoronoiFacet& f : cell->facets) {
      const auto id = static_cast<std::uint32_t>(f.neighbor);
      const std::int32_t* k = cover.offset_of(id);
      cell->facet_offsets.insert(cell->facet_offsets.end(), k, k + d);
      f.neighbor = cover.point_of(id);
    }
  }
  return Status::ok();
}

}  // namespace

Result<PeriodicMeshStats> mesh_periodic(const PointSet& points, const PeriodicBox& box, const MeshOptions& options,
                                        const PeriodicSink& sink, const std::function<Status()>& restart,
                                        const std::string& source) {
  const int d = points.dimension();
  const auto du = static_cast<std::size_t>(d);
  PeriodicMeshStats stats;
  auto runs = with_growing_margins(points, box, options.star.weights, source, restart,
                                   [&](const PeriodicCover& cover, MarginPlan& plan) -> Status {
    MeshOptions run = options;
    run.star.weights = cover.weights();
    // The points' seed range (the images are never seeds); the sweep is the cover's.
    run.seed_begin = std::min(options.seed_begin, cover.point_count());
    run.seed_end = std::min(options.seed_end, cover.point_count());
    run.sweep_begin = 0;
    run.sweep_end = 0xFFFFFFFFu;
    run.split = nullptr;
    run.star.cover = &cover;
    run.accept = [&](const Star& star) {
      if (!star.bounded_cell()) {
        plan.unbounded();
        return true;
      }
      const auto owned = owned_simplices(star);
      for (std::size_t at = 0; at < owned.size(); at += du + 1) {
        const std::uint32_t* s = owned.data() + at;
        if (is_representative(cover, s, d)) power_sphere_of(cover, s, d, plan);
      }
      return true;
    };
    std::vector<std::uint32_t> kept;
    std::vector<std::int32_t> offsets;
    std::uint64_t written = 0;
    auto result = mesh_seeds(cover.tree(), run, [&](std::span<const std::uint32_t> rows, std::uint64_t done) {
      kept.clear();
      offsets.clear();
      for (std::size_t at = 0; at < rows.size(); at += du + 1) {
        const std::uint32_t* s = rows.data() + at;
        if (!is_representative(cover, s, d)) continue;
        for (std::size_t v = 0; v <= du; ++v) {
          kept.push_back(cover.point_of(s[v]));
          const std::int32_t* k = cover.offset_of(s[v]);
          offsets.insert(offsets.end(), k, k + d);
        }
      }
      canonicalize_periodic_rows(d, kept, offsets, false);
      written += kept.size() / (du + 1);
      return sink(kept, offsets, done);
    });
    if (!result.is_ok()) return result.status();
    stats.mesh = result.value();
    stats.mesh.simplices = written;  // the torus's (the run's rows less the translates)
    stats.images = cover.image_count();
    stats.margin = cover.margin();
    return Status::ok();
  });
  if (!runs.is_ok()) return runs.status();
  stats.runs = runs.value();
  return stats;
}

Result<PeriodicStar> periodic_star(const PointSet& points, const PeriodicBox& box, std::uint32_t seed,
                                   const StarOptions& options, const std::string& source, VoronoiCell* cell) {
  if (seed >= points.size()) {
    return out_of_range("seed " + std::to_string(seed) + " is out of range (the input has " +
                        std::to_string(points.size()) + " points)");
  }
  PeriodicStar out;
  auto runs = with_growing_margins(points, box, options.weights, source, nullptr,
                                   [&](const PeriodicCover& cover, MarginPlan& plan) -> Status {
    return star_on_cover(cover, plan, seed, options, cell, false, out);
  });
  if (!runs.is_ok()) return runs.status();
  return out;
}

void periodic_neighbors(const PeriodicStar& star, int d, std::vector<std::uint32_t>& points,
                        std::vector<std::int32_t>& offsets) {
  const auto du = static_cast<std::size_t>(d);
  std::vector<std::vector<std::int64_t>> images;
  for (std::size_t v = 0; v < star.simplices.size(); ++v) {
    std::vector<std::int64_t> image{star.simplices[v]};
    bool self = star.simplices[v] == star.seed;
    for (std::size_t c = 0; c < du; ++c) {
      image.push_back(star.offsets[v * du + c]);
      self = self && star.offsets[v * du + c] == 0;
    }
    if (!self) images.push_back(std::move(image));
  }
  std::sort(images.begin(), images.end());
  images.erase(std::unique(images.begin(), images.end()), images.end());
  points.clear();
  offsets.clear();
  for (const auto& image : images) {
    points.push_back(static_cast<std::uint32_t>(image[0]));
    for (std::size_t c = 0; c < du; ++c) offsets.push_back(static_cast<std::int32_t>(image[c + 1]));
  }
}

void canonicalize_periodic_rows(int d, std::vector<std::uint32_t>& simplices, std::vector<std::int32_t>& offsets,
                                bool sort_rows) {
  const auto du = static_cast<std::size_t>(d);
  const std::size_t width = du + 1, rows = simplices.size() / width;
  // Vertex a of a row before vertex b: by point, then offset lexicographically.
  auto before = [&](std::size_t a, std::size_t b) {
    if (simplices[a] != simplices[b]) return simplices[a] < simplices[b];
    return std::lexicographical_compare(offsets.begin() + static_cast<std::ptrdiff_t>(a * du),
                                        offsets.begin() + static_cast<std::ptrdiff_t>((a + 1) * du),
                                        offsets.begin() + static_cast<std::ptrdiff_t>(b * du),
                                        offsets.begin() + static_cast<std::ptrdiff_t>((b + 1) * du));
  };
  auto swap_vertices = [&](std::size_t a, std::size_t b) {
    std::swap(simplices[a], simplices[b]);
    std::swap_ranges(offsets.begin() + static_cast<std::ptrdiff_t>(a * du),
                     offsets.begin() + static_cast<std::ptrdiff_t>((a + 1) * du),
                     offsets.begin() + static_cast<std::ptrdiff_t>(b * du));
  };
  for (std::size_t r = 0; r < rows; ++r) {
    const std::size_t first = r * width;
    // Insertion sort (d + 1 <= 9 vertices), counting transpositions: the parity says
    // whether the sorted order has the row's orientation.
    bool odd = false;
    for (std::size_t i = 1; i < width; ++i) {
      for (std::size_t j = i; j > 0 && before(first + j, first + j - 1); --j) {
        swap_vertices(first + j, first + j - 1);
        odd = !odd;
      }
    }
    if (odd) swap_vertices(first + width - 2, first + width - 1);
  }
  if (!sort_rows || rows < 2) return;
  std::vector<std::size_t> order(rows);
  for (std::size_t r = 0; r < rows; ++r) order[r] = r;
  auto row_before = [&](std::size_t a, std::size_t b) {
    for (std::size_t v = 0; v < width; ++v) {
      if (before(a * width + v, b * width + v)) return true;
      if (before(b * width + v, a * width + v)) return false;
    }
    return false;
  };
  std::sort(order.begin(), order.end(), row_before);
  std::vector<std::uint32_t> s2;
  std::vector<std::int32_t> o2;
  s2.reserve(simplices.size());
  o2.reserve(offsets.size());
  for (const std::size_t r : order) {
    s2.insert(s2.end(), simplices.begin() + static_cast<std::ptrdiff_t>(r * width),
              simplices.begin() + static_cast<std::ptrdiff_t>((r + 1) * width));
    o2.insert(o2.end(), offsets.begin() + static_cast<std::ptrdiff_t>(r * width * du),
              offsets.begin() + static_cast<std::ptrdiff_t>((r + 1) * width * du));
  }
  simplices = std::move(s2);
  offsets = std::move(o2);
}

Result<std::unique_ptr<PeriodicStars>> PeriodicStars::build(const PointSet& points, const PeriodicBox& box,
                                                            std::span<const double> weights, std::string source) {
  auto stars = std::unique_ptr<PeriodicStars>(new PeriodicStars(points, box, weights, std::move(source)));
  const MarginPlan plan(points, box);
  auto cover = PeriodicCover::build(points, box, plan.margin(), stars->source_, weights);
  if (!cover.is_ok()) return cover.status();
  stars->cover_ = std::move(cover).value();
  return stars;
}

std::uint64_t PeriodicStars::estimated_bytes(std::uint64_t n, int d) {
  // The first margin is 3.5 spacings on each side of n^(1/d) spacings per axis (at
  // most 3 box lengths): (1 + 7 / n^(1/d))^d times the points, each as a tree holds
  // it (coordinates twice, boxes, ranks: about 20 d + 40 bytes) plus an image's
  // point and offset (4 + 4 d).
  const double per_axis = std::pow(static_cast<double>(std::max<std::uint64_t>(n, 1)), 1.0 / d);
  const double factor = std::pow(std::min(7.0, 1 + 7 / per_axis), d);
  return static_cast<std::uint64_t>(factor * static_cast<double>(n) * (24.0 * d + 44));
}

Result<PeriodicStar> PeriodicStars::star(std::uint32_t seed, const StarOptions& options, VoronoiCell* cell,
                                         bool centres) const {
  if (seed >= points_.size()) {
    return out_of_range("seed " + std::to_string(seed) + " is out of range (the input has " +
                        std::to_string(points_.size()) + " points)");
  }
  // Always from the kept (first) cover: a seed's answer does not depend on which seeds
  // were asked before, on this server or another.
  std::shared_ptr<const PeriodicCover> cover = cover_;
  PeriodicStar out;
  auto runs = with_growing_margins(points_, box_, weights_, source_, nullptr,
                                   [&](const PeriodicCover& c, MarginPlan& plan) -> Status {
    return star_on_cover(c, plan, seed, options, cell, centres, out);
  }, &cover);
  if (!runs.is_ok()) return runs.status();
  return out;
}

Result<PeriodicCellsStats> compute_periodic_cells(const PointSet& points, const PeriodicBox& box,
                                                  const CellsOptions& options, const CellSink& sink,
                                                  const std::function<Status()>& restart, const std::string& source) {
  const int d = points.dimension();
  const auto du = static_cast<std::size_t>(d);
  PeriodicCellsStats stats;
  std::vector<VoronoiCell> mapped;
  auto runs = with_growing_margins(points, box, options.star.weights, source, restart,
                                   [&](const PeriodicCover& cover, MarginPlan& plan) -> Status {
    CellsOptions run = options;
    run.star.weights = cover.weights();
    run.seed_begin = 0;
    run.seed_end = cover.point_count();
    run.measures_only = false;  // the vertices certify the cells (then are dropped if asked)
    // Rounds of 2048 cells a thread: their vertices are held until certified (rounds of
    // 8192 held 40 MB more at 3-d 1M, for no speed).
    if (run.block_size == 0) run.block_size = 2048;
    run.star.cover = &cover;
    stats.images = cover.image_count();
    stats.margin = cover.margin();
    // In 3-d, cells are built directly (cells.hpp): the cover's region, a box, clipped by
    // the bisectors of points and images. A cell that keeps a facet on the region's
    // walls reaches past the margin: the run is then thin, as for an unbounded cell.
    std::optional<Domain> region;
    if (d == 3) {
      std::vector<double> lo(du), hi(du);
      for (std::size_t c = 0; c < du; ++c) {
        lo[c] = box.lo()[c] - cover.margin()[c];
        hi[c] = box.hi()[c] + cover.margin()[c];
      }
      auto made = Domain::box(lo, hi);
      if (made.is_ok()) region = std::move(made).value();
    }
    return compute_cells(cover.tree(), region ? &*region : nullptr, run,
                         [&](std::span<const VoronoiCell> cells, std::uint64_t done) {
      // Copied into records kept across rounds (their buffers reused), and without the
      // vertices when the caller wants measures only: the vertices certify the cell first.
      mapped.resize(cells.size());
      for (std::size_t i = 0; i < cells.size(); ++i) {
        const VoronoiCell& from = cells[i];
        VoronoiCell& cell = mapped[i];
        const bool on_wall = std::any_of(from.facets.begin(), from.facets.end(),
                                         [](const VoronoiFacet& f) { return f.is_wall(); });
        if (!from.bounded || on_wall) {
          plan.unbounded();
          continue;
        }
        // Every vertex is the centre of a (power) sphere through the seed.
        const double* x = cover.points().point(from.seed);
        const double w = cover.weights().empty() ? 0 : cover.weights()[from.seed];
        for (std::size_t v = 0; v < from.vertex_count(); ++v) {
          const double* c = from.vertices.data() + v * du;
          double r2 = 0;
          for (std::size_t k = 0; k < du; ++k) r2 += (c[k] - x[k]) * (c[k] - x[k]);
          plan.power_sphere(c, r2 - w, cover.max_weight(), cover.pad());
        }
        if (options.measures_only) {
          cell.seed = from.seed;
          cell.dimension = from.dimension;
          cell.vertices.clear();
          cell.vertex_simplices.clear();
          cell.bounded = from.bounded;
          cell.volume = from.volume;
          cell.centroid = from.centroid;
          cell.hidden = from.hidden;
          cell.facets.resize(from.facets.size());
          for (std::size_t f = 0; f < from.facets.size(); ++f) {
            cell.facets[f].neighbor = from.facets[f].neighbor;
            cell.facets[f].vertices.clear();
            cell.facets[f].area = from.facets[f].area;
            cell.facets[f].normal = from.facets[f].normal;
          }
        } else {
          cell = from;
        }
        cell.clipped = false;  // the region's walls cut nothing
        cell.facet_offsets.clear();
        for (VoronoiFacet& f : cell.facets) {
          const auto id = static_cast<std::uint32_t>(f.neighbor);
          const std::int32_t* k = cover.offset_of(id);
          cell.facet_offsets.insert(cell.facet_offsets.end(), k, k + d);
          f.neighbor = cover.point_of(id);
        }
      }
      return sink(mapped, done);
    });
  });
  if (!runs.is_ok()) return runs.status();
  stats.runs = runs.value();
  return stats;
}

}  // namespace spokemesh
