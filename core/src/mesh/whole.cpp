// triangulate_whole and WholeStarReader (mesh.hpp): the triangulation of every point
// built on its own, and stars read out of it (mesh/whole.hpp has the shared parts).
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

template <int D>
Result<std::shared_ptr<const WholeTriangulation>> build(const PointSet& points, const SpaceSplit& split,
                                                        const WholeOptions& options) {
  const auto n = static_cast<std::uint32_t>(points.size());
  auto w = std::make_shared<detail::Whole<D>>();
  w->pred = std::make_shared<const Predicates>(points);
  w->points = &points;
  w->tri = std::make_unique<detail::Triangulation<D>>(points, *w->pred);
  w->local.assign(n, 0);
  std::vector<std::uint32_t> order(split.order().begin(), split.order().end()), scratch;
  detail::insertion_order<D>(order, scratch);
  w->tri->reserve(n);
  std::size_t reserved = 0;
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
  auto inserted = detail::insert_into<D>(*w, order, kCheckEvery, granted, stop);
  if (!inserted.is_ok()) return inserted.status();
  auto refused = [] { return resource_exhausted("the triangulation of every point: its memory was refused"); };
  if (!inserted.value()) return refused();
  if (!w->tri->full()) return invalid_argument("the points lie in a hyperplane: no triangulation");
  if (options.owner_index) {
    detail::index_owners(*w);
    if (!granted()) return refused();
  }
  return std::shared_ptr<const WholeTriangulation>(std::move(w));
}

}  // namespace

Result<std::shared_ptr<const WholeTriangulation>> triangulate_whole(const PointSet& points,
                                                                    const WholeOptions& options) {
  const int d = points.dimension();
  if (d != 2 && d != 3) return invalid_argument("a triangulation of every point is built in 2-d and 3-d only");
  std::optional<SpaceSplit> own;
  const SpaceSplit* split = options.split;
  if (split == nullptr || split->size() != points.size()) {
    own.emplace(points, SpaceSplit::default_block_points(d, points.size()));
    split = &*own;
  }
  return detail::dispatch_2d_3d(d, Result<std::shared_ptr<const WholeTriangulation>>(invalid_argument("")),
                                [&](auto dim) { return build<decltype(dim)::value>(points, *split, options); });
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
