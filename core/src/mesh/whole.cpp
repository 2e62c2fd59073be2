// triangulate_whole and WholeStarReader (mesh.hpp): the triangulation of every point
// built on its own, and stars read out of it (mesh/whole.hpp has the shared parts).
#include <cstring>
#include <optional>

#include "base/dimension.hpp"
#include "mesh/insertion_order.hpp"
#include "mesh/whole.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/space_split.hpp"

namespace spokemesh {

namespace {

// Memory is asked for in steps of at least this (as the sweep's runs do).
constexpr std::size_t kReserveStep = std::size_t{16} << 20;
constexpr std::uint32_t kCheckEvery = 4096;

Status memory_refused() { return resource_exhausted("the triangulation of every point: its memory was refused"); }

// The points' sweep: options.split when it is over them, else one built into `own`.
const SpaceSplit& sweep_of(const PointSet& points, const WholeOptions& options, std::optional<SpaceSplit>& own) {
  if (options.split != nullptr && options.split->size() == points.size()) return *options.split;
  own.emplace(points, SpaceSplit::default_block_points(points.dimension(), points.size()));
  return *own;
}

// Inserts `order` (ids not yet in w's triangulation) into it, its memory asked for as
// it grows (counting what w holds beyond `reserved`, granted already), then indexes
// the cells by owner. Without `near`: in biased randomized rounds over that (spatial)
// order. With it (a point id inserted before, for each of `order`, or kNoOwner): in
// that order, each point's location walked from its `near` point's cells.
template <int D>
Result<std::shared_ptr<const WholeTriangulation>> insert_rest(std::shared_ptr<detail::Whole<D>> w,
                                                              std::vector<std::uint32_t> order,
                                                              const std::vector<std::uint32_t>& near,
                                                              const WholeOptions& options, std::size_t reserved) {
  if (near.empty()) {
    std::vector<std::uint32_t> scratch;
    detail::insertion_order<D>(order, scratch);
  }
  w->tri->reserve(w->points->size());
  auto granted = [&] {
    const std::size_t now = w->bytes();
    if (now <= reserved) return true;
    if (!options.reserve_bytes) {
      reserved = now;
      return true;
    }
    const std::size_t ask = std::max(now - reserved, kReserveStep);
    if (!options.reserve_bytes(ask)) return false;
    reserved += ask;
    return true;
  };
  auto stop = [&] { return options.cancel != nullptr && options.cancel->load(std::memory_order_relaxed); };
  auto inserted = detail::insert_into<D>(*w, order, kCheckEvery, granted, stop, near);
  if (!inserted.is_ok()) return inserted.status();
  if (!inserted.value()) return memory_refused();
  if (!w->tri->full()) return invalid_argument("the points lie in a hyperplane: no triangulation");
  if (options.owner_index) {
    detail::index_owners(*w);
    if (!granted()) return memory_refused();
  }
  return std::shared_ptr<const WholeTriangulation>(std::move(w));
}

template <int D>
Result<std::shared_ptr<const WholeTriangulation>> build(const PointSet& points, const SpaceSplit& split,
                                                        const WholeOptions& options) {
  auto w = std::make_shared<detail::Whole<D>>();
  w->pred = std::make_shared<const Predicates>(points);
  w->points = &points;
  w->tri = std::make_unique<detail::Triangulation<D>>(points, *w->pred);
  w->local.assign(points.size(), 0);
  return insert_rest<D>(std::move(w), std::vector<std::uint32_t>(split.order().begin(), split.order().end()), {},
                        options, 0);
}

// base's triangulation copied over `points` (its set's points first), the others
// inserted in the sweep's order.
template <int D>
Result<std::shared_ptr<const WholeTriangulation>> extend(const detail::Whole<D>& base, const PointSet& points,
                                                         const SpaceSplit& split, const WholeOptions& options) {
  const auto n0 = static_cast<std::uint32_t>(base.points->size());
  // The copy is asked for before it is made.
  const std::size_t copied = base.bytes();
  if (options.reserve_bytes && !options.reserve_bytes(copied)) return memory_refused();
  auto w = std::make_shared<detail::Whole<D>>();
  w->pred = std::make_shared<const Predicates>(points);
  w->points = &points;
  w->tri = std::make_unique<detail::Triangulation<D>>(*base.tri, points, *w->pred);
  w->local = base.local;
  w->local.resize(points.size(), 0);
  // The new points in the sweep's order, each walked to from the old point before it
  // there (its neighbour in space): random rounds would walk across the whole set for
  // each (a torus's surface: 290 us a point, not 20).
  std::vector<std::uint32_t> order, near;
  order.reserve(points.size() - n0);
  near.reserve(points.size() - n0);
  std::uint32_t last_old = detail::kNoOwner;
  for (const std::uint32_t id : split.order()) {
    if (id < n0) {
      last_old = id;
    } else {
      order.push_back(id);
      near.push_back(last_old);
    }
  }
  return insert_rest<D>(std::move(w), std::move(order), near, options, copied);
}

}  // namespace

Result<std::shared_ptr<const WholeTriangulation>> triangulate_whole(const PointSet& points,
                                                                    const WholeOptions& options) {
  const int d = points.dimension();
  if (d != 2 && d != 3) return invalid_argument("a triangulation of every point is built in 2-d and 3-d only");
  std::optional<SpaceSplit> own;
  const SpaceSplit& split = sweep_of(points, options, own);
  return detail::dispatch_2d_3d(d, Result<std::shared_ptr<const WholeTriangulation>>(invalid_argument("")),
                                [&](auto dim) { return build<decltype(dim)::value>(points, split, options); });
}

Result<std::shared_ptr<const WholeTriangulation>> extend_whole(const WholeTriangulation& base, const PointSet& points,
                                                               const WholeOptions& options) {
  const PointSet& had = base.point_set();
  const int d = points.dimension();
  if (d != base.dimension() || points.size() < had.size()) {
    return invalid_argument("extend_whole: the set (" + std::to_string(points.size()) + " " + std::to_string(d) +
                            "-d points) does not extend the triangulation's (" + std::to_string(had.size()) + " " +
                            std::to_string(base.dimension()) + "-d points)");
  }
  // Its first points must be base's: a copy's cells name them by id.
  const std::size_t prefix = had.size() * static_cast<std::size_t>(d);
  if (prefix > 0 && std::memcmp(points.point(0), had.point(0), prefix * sizeof(double)) != 0) {
    return invalid_argument("extend_whole: the set's first " + std::to_string(had.size()) +
                            " points are not the triangulation's");
  }
  std::optional<SpaceSplit> own;
  const SpaceSplit& split = sweep_of(points, options, own);
  return detail::dispatch_2d_3d(d, Result<std::shared_ptr<const WholeTriangulation>>(invalid_argument("")),
                                [&](auto dim) {
                                  constexpr int D = decltype(dim)::value;
                                  return extend<D>(static_cast<const detail::Whole<D>&>(base), points, split, options);
                                });
}

struct WholeStarReader::Impl {
  const WholeTriangulation& whole;
  detail::StarScratch<2> scratch2;
  detail::StarScratch<3> scratch3;
  std::vector<std::uint32_t> cells, seen;
};

WholeStarReader::WholeStarReader(const WholeTriangulation& whole) : impl_(new Impl{whole, {}, {}, {}, {}}) {}
WholeStarReader::~WholeStarReader() = default;

Status WholeStarReader::star(std::uint32_t seed, Star& out, StarPart part) {
  Impl& m = *impl_;
  if (seed >= m.whole.point_set().size()) {
    return out_of_range("seed " + std::to_string(seed) + " is not below " + std::to_string(m.whole.point_set().size()));
  }
  if (m.whole.dimension() == 2) {
    detail::whole_star<2>(static_cast<const detail::Whole<2>&>(m.whole), seed, part, out, m.scratch2, m.cells, m.seen);
  } else {
    detail::whole_star<3>(static_cast<const detail::Whole<3>&>(m.whole), seed, part, out, m.scratch3, m.cells, m.seen);
  }
  return Status::ok();
}

}  // namespace spokemesh
