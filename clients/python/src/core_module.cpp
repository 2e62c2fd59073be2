// spokemesh._core: the core library in-process, for spokemesh.Delaunay and friends
// (clients/python/spokemesh/delaunay.py holds the scipy-compatible surface).
//
// Arrays come in as C-contiguous float64 (numpy converts others once) and go out as
// numpy arrays that own the C++ buffers (no copy). Every long call releases the GIL.
// Errors become ValueError (bad input: the core's message names the index) or
// RuntimeError.
//
// Thread safety: a Triangulation is immutable after construction; its methods may be
// called from several Python threads at once.
#include <gmpxx.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "geojson_domain.hpp"
#include "spokemesh/approx.hpp"
#include "spokemesh/cells.hpp"
#include "spokemesh/convex_hull.hpp"
#include "spokemesh/domain.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/locate.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/natural_neighbors.hpp"
#include "spokemesh/periodic.hpp"
#include "spokemesh/periodic_cells.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/voronoi.hpp"
#include "spokemesh/voronoi_diagram.hpp"

namespace py = pybind11;
using namespace spokemesh;

namespace {

using Points = py::array_t<double, py::array::c_style | py::array::forcecast>;

// _core.DuplicatePointsError (a ValueError): equal points, which spokemesh.Delaunay
// merges and reports as scipy's `coplanar` points.
PyObject* duplicate_points_error = nullptr;

[[noreturn]] void raise(const Status& s) {
  if (s.reason() == "DUPLICATE_POINTS" && duplicate_points_error != nullptr) {
    PyErr_SetString(duplicate_points_error, s.message().c_str());
    throw py::error_already_set();
  }
  if (s.code() == Code::kInvalidArgument || s.code() == Code::kOutOfRange) throw py::value_error(s.message());
  throw std::runtime_error(s.message());
}

// A numpy array owning `data` (moved to the heap), shaped `shape`.
template <class T>
py::array_t<T> owned(std::vector<T>&& data, std::vector<py::ssize_t> shape) {
  auto* heap = new std::vector<T>(std::move(data));
  py::capsule free(heap, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array_t<T>(shape, heap->data(), free);
}

PointSet points_from(const Points& array, bool exact_span = true) {
  if (array.ndim() != 2) throw py::value_error("points: expected a 2-d array of shape (n, d)");
  const auto n = static_cast<std::size_t>(array.shape(0));
  const int d = static_cast<int>(array.shape(1));
  // scipy's index arrays are int32: a set in-process stays below 2^31 points.
  if (n >= (std::size_t{1} << 31))
    throw py::value_error("points: " + std::to_string(n) + " points; at most 2^31 - 1 in-process");
  std::vector<double> coords(array.data(), array.data() + n * static_cast<std::size_t>(d));
  PointSet ps(d, std::move(coords));
  const Status s = exact_span ? ps.validate("points") : ps.validate("points", kMaxApproxDimension, d <= kMaxDimension);
  if (!s.is_ok()) raise(s);
  return ps;
}

unsigned thread_count(std::optional<unsigned> threads) {
  if (threads && *threads > 0) return *threads;
  return std::max(1u, std::thread::hardware_concurrency());
}

std::optional<Domain> domain_from(int d, const std::optional<std::vector<double>>& box,
                                  const std::optional<Points>& halfspaces) {
  if (box && halfspaces) throw py::value_error("give box or halfspaces, not both");
  if (box) {
    if (box->size() != 2 * static_cast<std::size_t>(d)) {
      throw py::value_error("box: expected " + std::to_string(2 * d) + " values (lo_1..lo_d, hi_1..hi_d), got " +
                            std::to_string(box->size()));
    }
    auto b = Domain::box({box->begin(), box->begin() + d}, {box->begin() + d, box->end()});
    if (!b.is_ok()) raise(b.status());
    return std::move(b).value();
  }
  if (halfspaces) {
    const Points& h = *halfspaces;
    if (h.ndim() != 2 || h.shape(1) != d + 1) {
      throw py::value_error("halfspaces: expected shape (m, " + std::to_string(d + 1) +
                            "): rows a_1..a_d b for a.x <= b");
    }
    std::vector<double> normals, offsets;
    for (py::ssize_t k = 0; k < h.shape(0); ++k) {
      normals.insert(normals.end(), h.data(k, 0), h.data(k, 0) + d);
      offsets.push_back(*h.data(k, d));
    }
    auto domain = Domain::halfspaces(d, std::move(normals), std::move(offsets));
    if (!domain.is_ok()) raise(domain.status());
    return std::move(domain).value();
  }
  return std::nullopt;
}

py::dict cell_dict(const VoronoiCell& c) {
  const int d = c.dimension;
  py::dict out;
  out["seed"] = c.seed;
  out["vertices"] = owned(std::vector<double>(c.vertices), {static_cast<py::ssize_t>(c.vertex_count()), d});
  out["bounded"] = c.bounded;
  out["clipped"] = c.clipped;
  out["hidden"] = c.hidden;
  out["volume"] = c.volume;
  out["centroid"] =
      c.centroid.empty() ? py::object(py::none()) : py::object(owned(std::vector<double>(c.centroid), {d}));
  py::list facets;
  for (const VoronoiFacet& f : c.facets) {
    py::dict facet;
    facet["neighbor"] = f.is_wall() ? py::object(py::none()) : py::object(py::int_(f.neighbor));
    facet["wall"] = f.is_wall() ? py::object(py::int_(f.wall())) : py::object(py::none());
    facet["vertices"] = owned(std::vector<std::uint32_t>(f.vertices), {static_cast<py::ssize_t>(f.vertices.size())});
    facet["area"] = f.area;
    facet["normal"] = owned(std::vector<double>(f.normal), {d});
    facets.append(facet);
  }
  out["facets"] = facets;
  return out;
}

// Power weights from an optional (n,) array, checked as the file readers check them
// (ValueError naming the index); empty when none.
std::vector<double> weights_from(const std::optional<Points>& weights, std::size_t n) {
  if (!weights) return {};
  const Points& w = *weights;
  if (w.ndim() != 1) throw py::value_error("weights: expected shape (n,), one weight a point");
  auto checked = weights_from_values(std::span<const double>(w.data(), static_cast<std::size_t>(w.shape(0))), "weights",
                                     n, WeightKind::kPowerWeight);
  if (!checked.is_ok()) raise(checked.status());
  return std::move(checked).value();
}

// IndexError unless seed < n.
void check_seed(std::uint32_t seed, std::size_t n) {
  if (seed >= n)
    throw py::index_error("seed " + std::to_string(seed) + " is out of range (" + std::to_string(n) + " points)");
}

// Every cell's measures as the .npz of `spokemesh cells` holds them, gathered cell by
// cell (with facet_offset on a torus).
struct CellColumns {
  CellColumns(int dimension, bool on_torus) : d(dimension), periodic(on_torus) {}
  int d;
  bool periodic;
  std::vector<double> volume, centroid, area, normal;
  std::vector<std::int64_t> ptr{0}, neighbor;
  std::vector<std::uint8_t> bounded;
  std::vector<std::int32_t> offset;

  void add(const VoronoiCell& c) {
    volume.push_back(c.volume);
    bounded.push_back(c.bounded ? 1 : 0);
    if (c.centroid.empty())
      centroid.insert(centroid.end(), static_cast<std::size_t>(d), std::nan(""));
    else
      centroid.insert(centroid.end(), c.centroid.begin(), c.centroid.end());
    for (const VoronoiFacet& f : c.facets) {
      neighbor.push_back(f.neighbor);
      area.push_back(f.area);
      normal.insert(normal.end(), f.normal.begin(), f.normal.end());
    }
    offset.insert(offset.end(), c.facet_offsets.begin(), c.facet_offsets.end());
    ptr.push_back(static_cast<std::int64_t>(neighbor.size()));
  }
  void clear() { *this = CellColumns(d, periodic); }
  py::dict to_dict() {
    const auto n = static_cast<py::ssize_t>(volume.size());
    const auto m = static_cast<py::ssize_t>(neighbor.size());
    py::dict out;
    out["volume"] = owned(std::move(volume), {n});
    out["centroid"] = owned(std::move(centroid), {n, d});
    out["bounded"] = owned(std::move(bounded), {n}).attr("astype")("bool");
    out["facet_ptr"] = owned(std::move(ptr), {n + 1});
    out["facet_neighbor"] = owned(std::move(neighbor), {m});
    out["facet_area"] = owned(std::move(area), {m});
    out["facet_normal"] = owned(std::move(normal), {m, d});
    if (periodic) out["facet_offset"] = owned(std::move(offset), {m, d});
    return out;
  }
};

// A Delaunay triangulation of the flat torus (periodic.hpp): the points inside a box
// [lo, hi) whose opposite sides are identified.
class PeriodicTriangulation {
 public:
  PeriodicTriangulation(const Points& array, const std::vector<double>& lo, const std::vector<double>& hi,
                        std::optional<unsigned> threads, const std::optional<Points>& weights)
      : points_(points_from(array)), d_(points_.dimension()), threads_(thread_count(threads)) {
    weights_ = weights_from(weights, points_.size());
    auto box = PeriodicBox::of(lo, hi, "periodic");
    if (!box.is_ok()) raise(box.status());
    box_ = std::make_unique<PeriodicBox>(std::move(box).value());
    if (box_->dimension() != d_) {
      throw py::value_error("periodic: a " + std::to_string(box_->dimension()) + "-d box for " + std::to_string(d_) +
                            "-d points");
    }
    if (Status s = box_->check_contains(points_, "points"); !s.is_ok()) raise(s);
    Status status;
    {
      py::gil_scoped_release release;
      MeshOptions options;
      options.threads = threads_;
      options.star.weights = weights_;
      auto run = mesh_periodic(
          points_, *box_, options,
          [&](std::span<const std::uint32_t> s, std::span<const std::int32_t> o, std::uint64_t) {
            simplices_.insert(simplices_.end(), s.begin(), s.end());
            offsets_.insert(offsets_.end(), o.begin(), o.end());
            return Status::ok();
          },
          [&] {
            simplices_.clear();
            offsets_.clear();
            return Status::ok();
          },
          "points");
      status = run.status();
    }
    if (!status.is_ok()) raise(status);
  }

  py::array_t<std::int32_t> simplices() const {
    std::vector<std::int32_t> out(simplices_.begin(), simplices_.end());
    return owned(std::move(out), {static_cast<py::ssize_t>(simplices_.size() / (d_ + 1)), d_ + 1});
  }
  py::array_t<std::int32_t> offsets() const {
    return owned(std::vector<std::int32_t>(offsets_),
                 {static_cast<py::ssize_t>(simplices_.size() / (d_ + 1)), d_ + 1, d_});
  }

  // One seed's simplices (indices, offsets) and, with `cell`, its cell.
  py::tuple star(std::uint32_t seed) const {
    auto result = star_of(seed, nullptr);
    const auto m = static_cast<py::ssize_t>(result.simplices.size() / (d_ + 1));
    std::vector<std::int32_t> s(result.simplices.begin(), result.simplices.end());
    return py::make_tuple(owned(std::move(s), {m, d_ + 1}), owned(std::move(result.offsets), {m, d_ + 1, d_}));
  }
  py::dict cell(std::uint32_t seed) const {
    VoronoiCell c;
    star_of(seed, &c);
    py::dict out = cell_dict(c);
    py::list facets = out["facets"];
    for (std::size_t k = 0; k < c.facets.size(); ++k) {
      py::dict f = facets[k];
      f["offset"] =
          owned(std::vector<std::int32_t>(c.facet_offsets.begin() + static_cast<std::ptrdiff_t>(k * d_),
                                          c.facet_offsets.begin() + static_cast<std::ptrdiff_t>((k + 1) * d_)),
                {d_});
    }
    return out;
  }

  // Every cell's measures, as `spokemesh cells --periodic` writes them.
  py::dict cells() const {
    CellColumns columns(d_, true);
    Status status;
    {
      py::gil_scoped_release release;
      CellsOptions options;
      options.threads = threads_;
      options.measures_only = true;
      options.star.weights = weights_;
      auto run = compute_periodic_cells(
          points_, *box_, options,
          [&](std::span<const VoronoiCell> cells, std::uint64_t) {
            for (const VoronoiCell& c : cells) columns.add(c);
            return Status::ok();
          },
          [&] {
            columns.clear();
            return Status::ok();
          },
          "points");
      status = run.status();
    }
    if (!status.is_ok()) raise(status);
    return columns.to_dict();
  }

 private:
  PeriodicStar star_of(std::uint32_t seed, VoronoiCell* cell) const {
    check_seed(seed, points_.size());
    std::optional<Result<PeriodicStar>> result;
    {
      py::gil_scoped_release release;
      StarOptions options;
      options.weights = weights_;
      result.emplace(periodic_star(points_, *box_, seed, options, "points", cell));
    }
    if (!result->is_ok()) raise(result->status());
    return std::move(*result).value();
  }

  PointSet points_;
  int d_;
  unsigned threads_;
  std::unique_ptr<PeriodicBox> box_;
  std::vector<double> weights_;
  std::vector<std::uint32_t> simplices_;
  std::vector<std::int32_t> offsets_;
};

class Triangulation {
 public:
  // weights: power weights, one per point (the regular triangulation), or none.
  Triangulation(const Points& array, std::optional<unsigned> threads, const std::optional<Points>& weights)
      : points_(points_from(array)), d_(points_.dimension()), threads_(thread_count(threads)) {
    weights_ = weights_from(weights, points_.size());
    py::gil_scoped_release release;
    // The sweep's split first (its records are freed before the tree copies the
    // points); it is dropped after the run.
    auto split = std::make_unique<SpaceSplit>(points_, SpaceSplit::default_block_points(d_, points_.size()));
    tree_ = std::make_unique<KdTree>(points_);
    MeshOptions options;
    options.split = split.get();
    options.threads = threads_;
    options.star.weights = weights_;
    auto stats = mesh_seeds(*tree_, options, [&](std::span<const std::uint32_t> block, std::uint64_t) {
      simplices_.insert(simplices_.end(), block.begin(), block.end());
      return Status::ok();
    });
    if (!stats.is_ok()) {
      py::gil_scoped_acquire acquire;
      raise(stats.status());
    }
  }

  // The triangulation of parent's points followed by `more`, from parent's mesh: only
  // the stars that change are computed (insert_points), and the simplices are those,
  // in the same order, that the whole set's triangulation has.
  Triangulation(const Triangulation& parent, const Points& more) : d_(parent.d_), threads_(parent.threads_) {
    parent.unweighted_only("add_points");
    if (more.ndim() != 2 || more.shape(1) != parent.d_) {
      throw py::value_error("points: expected shape (k, " + std::to_string(parent.d_) + ")");
    }
    const auto k = static_cast<std::size_t>(more.shape(0));
    if (parent.points_.size() + k >= (std::size_t{1} << 31)) {
      throw py::value_error("points: " + std::to_string(parent.points_.size() + k) +
                            " points; at most 2^31 - 1 in-process");
    }
    std::vector<double> coords(parent.points_.coordinates().begin(), parent.points_.coordinates().end());
    coords.insert(coords.end(), more.data(), more.data() + k * static_cast<std::size_t>(d_));
    points_ = PointSet(d_, std::move(coords));
    if (const Status s = points_.validate_appended(parent.points_, "points"); !s.is_ok()) raise(s);
    if (k == 0) {
      tree_ = std::make_unique<KdTree>(points_);
      simplices_ = parent.simplices_;
      return;
    }
    py::gil_scoped_release release;
    const auto n_old = static_cast<std::uint32_t>(parent.points_.size());
    // The split is built beside the tree and the new points' stars (they need only the
    // tree), and waited for when the rows are put in sweep order.
    std::unique_ptr<SpaceSplit> split;
    std::thread sweep(
        [&] { split = std::make_unique<SpaceSplit>(points_, SpaceSplit::default_block_points(d_, points_.size())); });
    // The parent's tree extended by the new points' (rebuilt whole after a few).
    tree_ = KdTree::extended(*parent.tree_, points_);
    MeshOptions options;
    options.threads = threads_;
    auto split_when_needed = [&]() -> const SpaceSplit& {
      if (sweep.joinable()) sweep.join();
      return *split;
    };
    auto stats = insert_points(*tree_, split_when_needed, n_old, parent.simplices_, options, simplices_);
    if (sweep.joinable()) sweep.join();
    if (!stats.is_ok()) {
      py::gil_scoped_acquire acquire;
      raise(stats.status());
    }
    stars_computed_ = stats.value().stars;
  }

  // scipy's Voronoi arrays (voronoi_diagram.hpp): vertices, vertex_of_simplex,
  // ridge_points, ridge_ptr, ridge_vertices, region_ptr, regions.
  py::dict voronoi() const {
    unweighted_only("voronoi");
    std::call_once(adjacency_once_, [&] { build_adjacency(); });
    VoronoiDiagram v;
    {
      py::gil_scoped_release release;
      v = voronoi_diagram(points_, simplices_, adjacency_, threads_);
    }
    py::dict out;
    const auto k = static_cast<py::ssize_t>(v.vertices.size() / static_cast<std::size_t>(d_));
    const auto r = static_cast<py::ssize_t>(v.ridge_points.size() / 2);
    const auto rv = static_cast<py::ssize_t>(v.ridge_vertices.size());
    const auto rg = static_cast<py::ssize_t>(v.regions.size());
    const auto m = static_cast<py::ssize_t>(v.vertex_of_simplex.size());
    out["vertices"] = owned(std::move(v.vertices), {k, d_});
    out["vertex_of_simplex"] = owned(std::move(v.vertex_of_simplex), {m});
    out["ridge_points"] = owned(std::move(v.ridge_points), {r, 2});
    out["ridge_ptr"] = owned(std::move(v.ridge_ptr), {r + 1});
    out["ridge_vertices"] = owned(std::move(v.ridge_vertices), {rv});
    out["region_ptr"] = owned(std::move(v.region_ptr), {static_cast<py::ssize_t>(points_.size()) + 1});
    out["regions"] = owned(std::move(v.regions), {rg});
    return out;
  }

  // The furthest-site triangulation of the same points (furthest_site_simplices), as a
  // Triangulation of its own: neighbours, Voronoi diagram and point location work on
  // it alike. Stars and cells stay nearest-site notions (spokemesh.Delaunay refuses them).
  std::unique_ptr<Triangulation> furthest_site() const {
    unweighted_only("furthest_site");
    std::call_once(adjacency_once_, [&] { build_adjacency(); });
    std::optional<Result<std::vector<std::uint32_t>>> rows;
    {
      py::gil_scoped_release release;
      rows.emplace(furthest_site_simplices(points_, simplices_, adjacency_));
    }
    if (!rows->is_ok()) raise(rows->status());
    return std::unique_ptr<Triangulation>(new Triangulation(*this, std::move(*rows).value()));
  }

  int dimension() const { return d_; }
  bool weighted() const { return !weights_.empty(); }
  // What the weighted triangulation does not offer yet: a clear ValueError.
  void unweighted_only(const char* what) const {
    if (!weights_.empty()) {
      throw py::value_error(std::string(what) + ": not available for a weighted (regular) triangulation yet");
    }
  }
  std::size_t npoints() const { return points_.size(); }
  std::uint64_t stars_computed() const { return stars_computed_; }
  std::size_t nsimplices() const { return simplices_.size() / (d_ + 1); }

  // A copy (numpy may write to it; the rows here stay the parent of insertions), made
  // in parallel: at a million points it is 100 MB.
  py::array_t<std::int32_t> simplices() const {
    // numpy's own buffer, not zero-filled: its pages are first touched by the copiers.
    py::array_t<std::int32_t> out({static_cast<py::ssize_t>(nsimplices()), static_cast<py::ssize_t>(d_ + 1)});
    std::int32_t* to = out.mutable_data();
    {
      py::gil_scoped_release release;
      const std::size_t size = simplices_.size();
      const std::size_t chunk = 1 << 12;  // (parallel_for shares out more than 1024 items)
      parallel_for((size + chunk - 1) / chunk, [&](std::size_t c) {
        const std::size_t from = c * chunk, end = std::min(size, from + chunk);
        std::copy(simplices_.begin() + static_cast<std::ptrdiff_t>(from),
                  simplices_.begin() + static_cast<std::ptrdiff_t>(end), to + from);
      });
    }
    return out;
  }

  // scipy's `neighbors`: row i, column k is the simplex across the facet opposite
  // vertex k of simplex i, -1 on the hull. Facets are matched by sorting their keys.
  py::array_t<std::int32_t> neighbors() const {
    std::call_once(adjacency_once_, [&] { build_adjacency(); });
    std::vector<std::int32_t> out(adjacency_);
    return owned(std::move(out), {static_cast<py::ssize_t>(nsimplices()), d_ + 1});
  }

  // Exact point location: the simplex containing each query (one of them on a shared
  // face), -1 outside the hull. A visibility walk from the simplex of the query's
  // nearest input point; every side test is an exact orientation sign.
  py::array_t<std::int32_t> find_simplex(const Points& queries) const {
    if (queries.ndim() != 2 || queries.shape(1) != d_) {
      throw py::value_error("xi: expected shape (q, " + std::to_string(d_) + ")");
    }
    std::call_once(adjacency_once_, [&] { build_adjacency(); });
    const auto q = static_cast<std::size_t>(queries.shape(0));
    std::vector<std::int32_t> out(q, -1);
    const double* data = queries.data();
    {
      py::gil_scoped_release release;
      // In Morton order, each walked from the one before (locate.hpp).
      locator_->locate_many(data, q, threads_, [&](std::size_t, std::size_t i, std::int32_t s) { out[i] = s; });
    }
    return owned(std::move(out), {static_cast<py::ssize_t>(q)});
  }

  // Each query's natural neighbours and Sibson coordinates (natural_neighbors.hpp),
  // as (ptr, neighbors, weights, where): query i's are [ptr[i], ptr[i + 1]); where[i]
  // is 0 inside, 1 on the hull's boundary, 2 outside.
  // The checks natural_neighbors() and natural_interpolate() share (the queries' shape
  // and values, the set's dimension and weights), and the adjacency they walk; returns
  // the number of queries.
  std::size_t natural_queries(const Points& queries) const {
    if (queries.ndim() != 2 || queries.shape(1) != d_) {
      throw py::value_error("xi: expected shape (q, " + std::to_string(d_) + ")");
    }
    if (d_ != 2 && d_ != 3) {
      throw py::value_error("natural neighbours: dimension " + std::to_string(d_) +
                            " is not supported (Sibson's coordinates are computed in 2-d and 3-d)");
    }
    if (!weights_.empty()) throw py::value_error("natural neighbours: not available for weighted points");
    std::call_once(adjacency_once_, [&] { build_adjacency(); });
    const auto q = static_cast<std::size_t>(queries.shape(0));
    for (std::size_t i = 0; i < q * static_cast<std::size_t>(d_); ++i) {
      if (!std::isfinite(queries.data()[i]))
        throw py::value_error("xi[" + std::to_string(i / d_) + "][" + std::to_string(i % d_) +
                              "]: not a finite number");
    }
    return q;
  }

  // Sibson interpolation of `values` ((n, k) float64, one row per point) at each query:
  // (q, k) values, `fill` outside the hull. The same coordinates as natural_neighbors(),
  // applied as they are found, with no per-query arrays.
  py::array_t<double> natural_interpolate(const Points& queries, const Points& values, double fill) const {
    if (values.ndim() != 2 || static_cast<std::size_t>(values.shape(0)) != points_.size()) {
      throw py::value_error("values: expected shape (" + std::to_string(points_.size()) + ", k)");
    }
    const std::size_t q = natural_queries(queries);
    const auto k = static_cast<std::size_t>(values.shape(1));
    py::array_t<double> out({static_cast<py::ssize_t>(q), static_cast<py::ssize_t>(k)});
    double* o = out.mutable_data();
    const double* data = queries.data();
    const double* v = values.data();
    const DelaunayArrays arrays{&points_, simplices_, adjacency_};
    std::vector<NaturalCoordinates> scratch((q + 255) / 256);
    std::vector<std::string> errors(scratch.size());
    {
      py::gil_scoped_release release;
      locator_->locate_many(data, q, threads_, [&](std::size_t r, std::size_t i, std::int32_t s) {
        double* row = o + i * k;
        std::fill(row, row + k, fill);
        NaturalCoordinates& nn = scratch[r];
        const Status st = spokemesh::natural_neighbors(arrays, s, data + i * d_, nn);
        if (!st.is_ok()) {
          if (errors[r].empty()) errors[r] = "xi[" + std::to_string(i) + "]: " + st.message();
          return;
        }
        if (nn.where == NaturalCoordinates::Where::kOutside) return;
        std::fill(row, row + k, 0.0);
        for (std::size_t j = 0; j < nn.neighbors.size(); ++j) {
          const double* vj = v + static_cast<std::size_t>(nn.neighbors[j]) * k;
          for (std::size_t c = 0; c < k; ++c) row[c] += nn.weights[j] * vj[c];
        }
      });
    }
    for (const std::string& e : errors) {
      if (!e.empty()) throw std::runtime_error(e);
    }
    return out;
  }

  py::tuple natural_neighbors(const Points& queries) const {
    const std::size_t q = natural_queries(queries);
    // The queries in Morton order, each located from the one before (locate.hpp); each
    // run of them writes its own flat buffers, joined in the queries' order below.
    const double* data = queries.data();
    const std::size_t runs = (q + 255) / 256;
    struct RunOut {
      std::vector<std::int32_t> ids;
      std::vector<double> weights;
      std::vector<std::pair<std::size_t, std::int64_t>> start;  // (query, into ids)
      NaturalCoordinates nn;
      std::string error;
    };
    std::vector<RunOut> outs(runs);
    std::vector<std::int64_t> ptr(q + 1, 0);
    std::vector<std::int8_t> where(q);
    const DelaunayArrays arrays{&points_, simplices_, adjacency_};
    {
      py::gil_scoped_release release;
      locator_->locate_many(data, q, threads_, [&](std::size_t r, std::size_t i, std::int32_t s) {
        RunOut& o = outs[r];
        o.start.emplace_back(i, static_cast<std::int64_t>(o.ids.size()));
        const Status st = spokemesh::natural_neighbors(arrays, s, data + i * d_, o.nn);
        if (!st.is_ok()) {
          if (o.error.empty()) o.error = "xi[" + std::to_string(i) + "]: " + st.message();
          return;
        }
        o.ids.insert(o.ids.end(), o.nn.neighbors.begin(), o.nn.neighbors.end());
        o.weights.insert(o.weights.end(), o.nn.weights.begin(), o.nn.weights.end());
        ptr[i + 1] = static_cast<std::int64_t>(o.nn.neighbors.size());
        where[i] = static_cast<std::int8_t>(o.nn.where);
      });
    }
    for (const RunOut& o : outs) {
      if (!o.error.empty()) throw std::runtime_error(o.error);
    }
    for (std::size_t i = 0; i < q; ++i) ptr[i + 1] += ptr[i];
    // The answers in the queries' order, into numpy's own (uninitialized) arrays.
    const auto total = static_cast<py::ssize_t>(ptr[q]);
    py::array_t<std::int32_t> ids(total);
    py::array_t<double> weights(total);
    std::int32_t* ids_out = ids.mutable_data();
    double* weights_out = weights.mutable_data();
    {
      py::gil_scoped_release release;
      for (std::size_t r = 0; r < runs; ++r) {
        RunOut& o = outs[r];
        for (const auto& [i, start] : o.start) {
          const auto from = static_cast<std::size_t>(start);
          const auto count = static_cast<std::size_t>(ptr[i + 1] - ptr[i]);
          std::copy_n(o.ids.begin() + from, count, ids_out + ptr[i]);
          std::copy_n(o.weights.begin() + from, count, weights_out + ptr[i]);
        }
        std::vector<std::int32_t>().swap(o.ids);
        std::vector<double>().swap(o.weights);
      }
    }
    return py::make_tuple(owned(std::move(ptr), {static_cast<py::ssize_t>(q + 1)}), ids, weights,
                          owned(std::move(where), {static_cast<py::ssize_t>(q)}));
  }

  py::array_t<std::uint32_t> star(std::uint32_t seed) const {
    Star star = star_of(seed);
    return owned(std::move(star.simplices), {static_cast<py::ssize_t>(star.size()), d_ + 1});
  }

  py::array_t<std::uint32_t> neighbors_of(std::uint32_t seed) const {
    std::vector<std::uint32_t> n = star_neighbors(star_of(seed));
    const auto size = static_cast<py::ssize_t>(n.size());
    return owned(std::move(n), {size});
  }

  // A domain of any shape from a file's bytes and its format (off, obj, stl, rings,
  // geojson); the last one is kept, so that cell() over many seeds parses it once.
  std::shared_ptr<const ShapeDomain> shape_from(const std::optional<std::string>& format,
                                                const std::optional<py::bytes>& data) const {
    if (!format) return nullptr;
    if (!weights_.empty())
      raise(invalid_argument("domain: cells of weighted points in a domain of any shape are not supported yet"));
    std::string bytes = data ? std::string(*data) : std::string();
    std::lock_guard<std::mutex> lock(shape_mutex_);
    if (shape_ && shape_format_ == *format && shape_bytes_ == bytes) return shape_;
    Result<ShapeDomain> parsed = invalid_argument("");
    {
      py::gil_scoped_release release;
      parsed = parse_domain_bytes(bytes, "domain." + *format);
    }
    if (!parsed.is_ok()) raise(parsed.status());
    if (parsed->dimension() != d_) {
      raise(invalid_argument("domain: a " + std::to_string(parsed->dimension()) + "-d domain (" + parsed->describe() +
                             "); the points are " + std::to_string(d_) + "-d"));
    }
    shape_ = std::make_shared<const ShapeDomain>(std::move(parsed).value());
    shape_box_ = ShapeClipper::box(points_, *shape_).value();  // once, not per cell: it scans every point
    shape_format_ = *format;
    shape_bytes_ = std::move(bytes);
    return shape_;
  }

  // The box of the domain shape_from() returned last (ShapeClipper::box).
  Domain shape_box() const {
    std::lock_guard<std::mutex> lock(shape_mutex_);
    return shape_box_;
  }

  py::dict cell(std::uint32_t seed, const std::optional<std::vector<double>>& box,
                const std::optional<Points>& halfspaces, const std::optional<std::string>& domain_format,
                const std::optional<py::bytes>& domain_data) const {
    if (domain_format) {
      if (box || halfspaces) raise(invalid_argument("give one of box, halfspaces and domain"));
      check_seed(seed, points_.size());
      const std::shared_ptr<const ShapeDomain> shape = shape_from(domain_format, domain_data);
      const Domain box = shape_box();
      VoronoiCell c;
      Status st;
      {
        py::gil_scoped_release release;
        st = shape_cell(*tree_, *shape, box, seed, c);
      }
      if (!st.is_ok()) raise(st);
      return cell_dict(c);
    }
    const std::optional<Domain> domain = domain_from(d_, box, halfspaces);
    if (!domain) return cell_dict(voronoi_cell(points_, star_of(seed), weights_));
    check_seed(seed, points_.size());
    // The builder cells() uses, so that both give the same cell.
    std::optional<Result<VoronoiCell>> c;
    {
      py::gil_scoped_release release;
      StarOptions options;
      options.weights = weights_;
      ClippedCellBuilder builder(*tree_, *domain, options);
      c.emplace(builder.cell(seed));
    }
    if (!c->is_ok()) raise(c->status());
    return cell_dict(c->value());
  }

  // All cells' measures as the .npz of `spokemesh cells` holds them.
  py::dict cells(const std::optional<std::vector<double>>& box, const std::optional<Points>& halfspaces,
                 bool bounding_box, const std::optional<std::string>& domain_format,
                 const std::optional<py::bytes>& domain_data) const {
    if (domain_format && (box || halfspaces)) raise(invalid_argument("give one of box, halfspaces and domain"));
    const std::shared_ptr<const ShapeDomain> shape = shape_from(domain_format, domain_data);
    std::optional<Domain> domain = domain_from(d_, box, halfspaces);
    if (shape) domain = shape_box();
    if (!domain && bounding_box) domain = Domain::bounding_box(points_);
    CellColumns columns(d_, false);
    Status status;
    {
      py::gil_scoped_release release;
      CellsOptions options;
      options.threads = threads_;
      options.measures_only = true;
      options.star.weights = weights_;
      options.shape = shape.get();
      status = compute_cells(*tree_, domain ? &*domain : nullptr, options,
                             [&](std::span<const VoronoiCell> cells, std::uint64_t) {
                               for (const VoronoiCell& c : cells) columns.add(c);
                               return Status::ok();
                             });
    }
    if (!status.is_ok()) raise(status);
    return columns.to_dict();
  }

 private:
  // Another triangulation of `base`'s points (its tree rebuilt over the copy).
  Triangulation(const Triangulation& base, std::vector<std::uint32_t> rows)
      : points_(base.points_),
        d_(base.d_),
        threads_(base.threads_),
        weights_(base.weights_),
        simplices_(rows.begin(), rows.end()) {
    tree_ = std::make_unique<KdTree>(points_);
  }

  template <class Fn>
  void parallel_for(std::size_t count, Fn&& fn) const {
    std::atomic<std::size_t> next{0};
    auto work = [&] {
      for (std::size_t i; (i = next.fetch_add(256)) < count;) {
        for (std::size_t j = i; j < std::min(count, i + 256); ++j) fn(j);
      }
    };
    std::vector<std::thread> pool;
    const unsigned extra = count > 1024 ? threads_ - 1 : 0;
    for (unsigned t = 0; t < extra; ++t) pool.emplace_back(work);
    work();
    for (auto& t : pool) t.join();
  }

  Star star_of(std::uint32_t seed) const {
    check_seed(seed, points_.size());
    StarOptions options;
    options.weights = weights_;
    StarWalker walker(*tree_, options);
    Star star;
    Status s;
    {
      py::gil_scoped_release release;
      s = walker.compute(seed, star);
    }
    if (!s.is_ok()) raise(s);
    return star;
  }

  void build_adjacency() const {
    adjacency_ = simplex_adjacency(simplices_, d_, threads_);
    locator_ = std::make_unique<SimplexLocator>(points_, simplices_, adjacency_, *tree_);
  }

  PointSet points_;
  int d_;
  unsigned threads_;
  std::vector<double> weights_;  // power weights (empty: the Delaunay triangulation)
  // The last domain of any shape cell()/cells() parsed (shape_from), and its box.
  mutable std::mutex shape_mutex_;
  mutable std::shared_ptr<const ShapeDomain> shape_;
  mutable Domain shape_box_;
  mutable std::string shape_format_, shape_bytes_;
  std::unique_ptr<KdTree> tree_;
  Rows simplices_;
  std::uint64_t stars_computed_ = 0;  // by the insertion that made it (0 when built at once)
  mutable std::once_flag adjacency_once_;
  mutable std::vector<std::int32_t> adjacency_;
  mutable std::unique_ptr<SimplexLocator> locator_;  // built with adjacency_
};

// Certified approximate Delaunay graph, any dimension: CSR (indptr, indices) and each
// seed's walk_exhausted (its list is complete).
py::tuple approximate_graph(const Points& array, std::uint32_t misses, std::uint32_t max_vertices,
                            std::uint64_t random_seed, const std::string& mode, std::optional<unsigned> threads) {
  PointSet ps = points_from(array, false);
  auto walk = parse_neighbor_mode(mode, "mode");
  if (!walk.is_ok()) throw py::value_error(walk.status().message());
  if (walk.value() == NeighborMode::kExact) throw py::value_error("mode: an approximate walk is 'rsd' or 'spokes'");
  const std::size_t n = ps.size();
  std::vector<std::vector<std::uint32_t>> lists(n);
  std::vector<std::uint8_t> exhausted(n, 0);
  std::atomic<bool> failed{false};
  Status first_error;
  std::mutex mu;
  {
    py::gil_scoped_release release;
    const KdTree tree(ps);
    ApproxOptions o;
    o.mode = approx_walk(walk.value());
    o.max_misses = misses;
    o.max_vertices = max_vertices;
    o.random_seed = random_seed;
    std::atomic<std::size_t> next{0};
    auto work = [&] {
      ApproxWalker walker(tree, o);
      ApproxNeighbors a;
      for (std::size_t i; !failed && (i = next.fetch_add(1)) < n;) {
        if (Status s = walker.compute(static_cast<std::uint32_t>(i), a); !s.is_ok()) {
          std::lock_guard lock(mu);
          failed = true;
          first_error = s;
          return;
        }
        lists[i] = a.neighbors;
        exhausted[i] = a.exhausted ? 1 : 0;
      }
    };
    std::vector<std::thread> pool;
    const unsigned t = thread_count(threads);
    for (unsigned k = 1; k < t; ++k) pool.emplace_back(work);
    work();
    for (auto& th : pool) th.join();
  }
  if (failed) raise(first_error);
  // Symmetric: an edge certified from either end is an edge.
  std::vector<std::pair<std::uint32_t, std::uint32_t>> edges;
  for (std::size_t i = 0; i < n; ++i) {
    for (std::uint32_t j : lists[i]) {
      edges.emplace_back(static_cast<std::uint32_t>(i), j);
      edges.emplace_back(j, static_cast<std::uint32_t>(i));
    }
  }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  std::vector<std::int64_t> indptr(n + 1, 0);
  std::vector<std::int32_t> indices;
  indices.reserve(edges.size());
  for (const auto& [a, b] : edges) {
    ++indptr[a + 1];
    indices.push_back(static_cast<std::int32_t>(b));
  }
  for (std::size_t i = 0; i < n; ++i) indptr[i + 1] += indptr[i];
  const auto m = static_cast<py::ssize_t>(indices.size());
  return py::make_tuple(owned(std::move(indptr), {static_cast<py::ssize_t>(n + 1)}), owned(std::move(indices), {m}),
                        owned(std::move(exhausted), {static_cast<py::ssize_t>(n)}).attr("astype")("bool"));
}

// Python lists of ints, list i holding flat[ptr[i] .. ptr[i + 1]) (scipy's
// ridge_vertices and regions), made with the C API and the cyclic garbage collector
// paused (a collection every 700 new lists, each scanning every list made so far,
// would take most of the time; these lists hold only ints, so they make no cycles).
py::list split_lists(const py::array_t<std::int32_t, py::array::c_style | py::array::forcecast>& flat,
                     const py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>& ptr) {
  const std::int32_t* v = flat.data();
  const std::int64_t* p = ptr.data();
  const auto count = static_cast<std::size_t>(std::max<py::ssize_t>(0, ptr.size() - 1));
  if (count > 0 && (p[0] < 0 || p[count] > flat.size())) throw py::value_error("split_lists: ptr out of range");
  py::list out(count);
  struct GcPause {
    int was_enabled = PyGC_Disable();
    ~GcPause() {
      if (was_enabled) PyGC_Enable();
    }
  } pause;
  for (std::size_t i = 0; i < count; ++i) {
    const std::int64_t a = p[i], b = p[i + 1];
    if (b < a) throw py::value_error("split_lists: ptr must not decrease");
    PyObject* list = PyList_New(static_cast<Py_ssize_t>(b - a));
    if (list == nullptr) throw py::error_already_set();
    for (std::int64_t j = a; j < b; ++j) {
      PyObject* item = PyLong_FromLong(v[j]);
      if (item == nullptr) {
        Py_DECREF(list);
        throw py::error_already_set();
      }
      PyList_SET_ITEM(list, static_cast<Py_ssize_t>(j - a), item);
    }
    PyList_SET_ITEM(out.ptr(), static_cast<Py_ssize_t>(i), list);
  }
  return out;
}

// The exact convex hull (spokemesh.ConvexHull's engine): built from an (n, d) array,
// extended with the same array plus rows after it. Arrays are read during each call
// only (the Python object keeps the points).
class Hull {
 public:
  Hull(const Points& points, std::int64_t exclude, std::optional<unsigned> threads) {
    const auto [c, d] = rows_of(points);
    HullOptions options;
    options.exclude = exclude;
    options.threads = threads.value_or(0);
    threads_ = options.threads;
    Result<ConvexHull> built = invalid_argument("");
    {
      py::gil_scoped_release release;
      built = ConvexHull::build(c, d, options);
    }
    if (!built.is_ok()) raise(built.status());
    hull_ = std::move(built).value();
    exclude_ = exclude;
  }
  void extend(const Points& points) {
    const auto [c, d] = rows_of(points);
    if (d != hull_.dimension()) throw py::value_error("points: dimension " + std::to_string(d) + " is not the hull's");
    HullOptions options;
    options.exclude = exclude_;
    options.threads = threads_;
    Status s;
    {
      py::gil_scoped_release release;
      s = hull_.extend(c, options);
    }
    if (!s.is_ok()) raise(s);
  }
  py::array_t<std::int32_t> simplices() const {
    const std::vector<std::uint32_t> v = hull_.facet_vertices();
    return owned(std::vector<std::int32_t>(v.begin(), v.end()), shape(hull_.dimension()));
  }
  py::array_t<std::int32_t> neighbors() const { return owned(hull_.facet_neighbors(), shape(hull_.dimension())); }
  py::array_t<double> equations(const Points& points) const {
    const auto [c, d] = rows_of(points);
    return owned(hull_.facet_equations(c), shape(d + 1));
  }
  py::array_t<std::int32_t> coplanar(const Points& points) const {
    const auto [c, d] = rows_of(points);
    std::vector<std::array<std::uint32_t, 3>> rows;
    {
      py::gil_scoped_release release;
      rows = hull_.coplanar(c, exclude_);
    }
    std::vector<std::int32_t> flat;
    for (const auto& r : rows) flat.insert(flat.end(), r.begin(), r.end());
    return owned(std::move(flat), {static_cast<py::ssize_t>(rows.size()), 3});
  }
  // Each point's facets (SphericalVoronoi's regions: a facet is a Voronoi vertex), as
  // (flat, ptr): point i's are flat[ptr[i] .. ptr[i + 1]), ascending; with `sorted`
  // (d = 3), in cyclic order instead, counter-clockwise seen from outside, from the
  // smallest: around vertex v of facet (a, b, c) (counter-clockwise from outside), the
  // next facet is the one across the edge from v to the vertex before it.
  py::tuple regions(std::int64_t npoints, bool sorted) const {
    const int d = hull_.dimension();
    const std::vector<std::uint32_t> rows = hull_.facet_vertices();
    const std::vector<std::int32_t> nb = hull_.facet_neighbors();
    const std::size_t m = hull_.facet_count();
    std::vector<std::int64_t> ptr(static_cast<std::size_t>(npoints) + 1, 0);
    std::vector<std::int32_t> flat(rows.size());
    {
      py::gil_scoped_release release;
      for (const std::uint32_t v : rows) ++ptr[v + 1];
      for (std::size_t i = 0; i < static_cast<std::size_t>(npoints); ++i) ptr[i + 1] += ptr[i];
      std::vector<std::int64_t> next(ptr.begin(), ptr.end() - 1);
      for (std::size_t f = 0; f < m; ++f) {
        for (int k = 0; k < d; ++k)
          flat[static_cast<std::size_t>(next[rows[f * d + k]]++)] = static_cast<std::int32_t>(f);
      }
      if (sorted && d == 3) {
        for (std::size_t v = 0; v < static_cast<std::size_t>(npoints); ++v) {
          const std::int64_t a = ptr[v], b = ptr[v + 1];
          if (b - a < 3) continue;
          std::int32_t f = flat[static_cast<std::size_t>(a)];
          for (std::int64_t j = a; j < b; ++j) {
            flat[static_cast<std::size_t>(j)] = f;
            int at = 0;
            while (at < 3 && rows[static_cast<std::size_t>(f) * 3 + at] != v) ++at;
            f = nb[static_cast<std::size_t>(f) * 3 + (at + 1) % 3];
          }
        }
      }
    }
    return py::make_tuple(owned(std::move(flat), {static_cast<py::ssize_t>(rows.size())}),
                          owned(std::move(ptr), {static_cast<py::ssize_t>(npoints + 1)}));
  }
  // Each facet's group (ConvexHull::facet_groups): the polytope's facets.
  py::array_t<std::int32_t> groups(const Points& points) const {
    const auto [c, d] = rows_of(points);
    std::vector<std::uint32_t> g;
    {
      py::gil_scoped_release release;
      g = hull_.facet_groups(c);
    }
    return owned(std::vector<std::int32_t>(g.begin(), g.end()), {static_cast<py::ssize_t>(g.size())});
  }
  // The points' box (scipy's min_bound, max_bound), in one pass.
  static py::tuple bounds(const Points& points) {
    const auto [c, d] = rows_of(points);
    std::vector<double> lo(static_cast<std::size_t>(d), std::numeric_limits<double>::infinity());
    std::vector<double> hi(static_cast<std::size_t>(d), -std::numeric_limits<double>::infinity());
    {
      py::gil_scoped_release release;
      for (std::size_t i = 0; i < c.size(); i += static_cast<std::size_t>(d)) {
        for (int k = 0; k < d; ++k) {
          lo[static_cast<std::size_t>(k)] = std::min(lo[static_cast<std::size_t>(k)], c[i + k]);
          hi[static_cast<std::size_t>(k)] = std::max(hi[static_cast<std::size_t>(k)], c[i + k]);
        }
      }
    }
    return py::make_tuple(owned(std::move(lo), {d}), owned(std::move(hi), {d}));
  }
  py::array_t<std::int32_t> vertices() const {
    const std::vector<std::uint32_t> v = hull_.vertices();
    return owned(std::vector<std::int32_t>(v.begin(), v.end()), {static_cast<py::ssize_t>(v.size())});
  }
  // Each facet's exact side of point x: +1 visible (x strictly beyond), 0 on its
  // hyperplane, -1 beneath.
  py::array_t<std::int8_t> sides(const Points& points, std::int64_t x) const {
    const auto [c, d] = rows_of(points);
    if (x < 0 || static_cast<std::size_t>(x) * static_cast<std::size_t>(d) >= c.size())
      throw py::value_error("point " + std::to_string(x) + " is out of range");
    std::vector<std::int8_t> out(hull_.facet_count());
    for (std::size_t f = 0; f < out.size(); ++f)
      out[f] = static_cast<std::int8_t>(hull_.side(c, f, static_cast<std::size_t>(x)));
    return owned(std::move(out), {static_cast<py::ssize_t>(hull_.facet_count())});
  }

 private:
  static std::pair<std::span<const double>, int> rows_of(const Points& points) {
    if (points.ndim() != 2) throw py::value_error("points: expected a 2-d array of shape (n, d)");
    const auto n = static_cast<std::size_t>(points.shape(0));
    if (n >= (std::size_t{1} << 31))
      throw py::value_error("points: " + std::to_string(n) + " points; at most 2^31 - 1 in-process");
    const int d = static_cast<int>(points.shape(1));
    return {std::span<const double>(points.data(), n * static_cast<std::size_t>(d)), d};
  }
  std::vector<py::ssize_t> shape(int cols) const {
    return {static_cast<py::ssize_t>(hull_.facet_count()), static_cast<py::ssize_t>(cols)};
  }
  ConvexHull hull_;
  std::int64_t exclude_ = -1;
  unsigned threads_ = 0;
};

// The areas of spherical polygons on the unit sphere: polygon i has the vertices
// vertices[flat[ptr[i] .. ptr[i + 1])] in cyclic order around centres[i], summed as a fan
// of triangles (centre, a, b) whose solid angles come from Van Oosterom and Strackee's
// tan(omega / 2) = |c . (a x b)| / (1 + c . a + a . b + b . c).
py::array_t<double> fan_solid_angles(const Points& centres, const Points& vertices,
                                     const py::array_t<std::int32_t, py::array::c_style | py::array::forcecast>& flat,
                                     const py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>& ptr) {
  if (centres.ndim() != 2 || centres.shape(1) != 3 || vertices.ndim() != 2 || vertices.shape(1) != 3)
    throw py::value_error("fan_solid_angles: 3-d points and vertices");
  const auto n = static_cast<std::size_t>(ptr.size() - 1);
  if (n != static_cast<std::size_t>(centres.shape(0))) throw py::value_error("fan_solid_angles: one range per centre");
  const double* c = centres.data();
  const double* v = vertices.data();
  const std::int32_t* f = flat.data();
  const std::int64_t* p = ptr.data();
  const auto nv = static_cast<std::int64_t>(vertices.shape(0));
  for (py::ssize_t i = 0; i < flat.size(); ++i) {
    if (f[i] < 0 || f[i] >= nv) throw py::value_error("fan_solid_angles: vertex index out of range");
  }
  std::vector<double> out(n, 0.0);
  {
    py::gil_scoped_release release;
    for (std::size_t i = 0; i < n; ++i) {
      const double* g = c + 3 * i;
      double sum = 0;
      for (std::int64_t j = p[i]; j < p[i + 1]; ++j) {
        const double* a = v + 3 * static_cast<std::size_t>(f[j]);
        const double* b = v + 3 * static_cast<std::size_t>(f[j + 1 < p[i + 1] ? j + 1 : p[i]]);
        const double cross[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
        const double triple = g[0] * cross[0] + g[1] * cross[1] + g[2] * cross[2];
        const double dot_ga = g[0] * a[0] + g[1] * a[1] + g[2] * a[2];
        const double dot_ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        const double dot_bg = b[0] * g[0] + b[1] * g[1] + b[2] * g[2];
        sum += std::fabs(2 * std::atan2(triple, 1 + dot_ga + dot_ab + dot_bg));
      }
      out[i] = sum;
    }
  }
  return owned(std::move(out), {static_cast<py::ssize_t>(n)});
}

// Nearest neighbours for spokemesh.interpolate: a k-d tree of `points` (kept, with
// a copy of them) answering the nearest point of each query (floating-point
// distances; of two equally near points, either).
class NearestTree {
 public:
  explicit NearestTree(const Points& points) {
    if (points.ndim() != 2 || points.shape(0) < 1 || points.shape(1) < 1)
      throw py::value_error("points: expected a non-empty (n, d) array");
    const auto n = static_cast<std::size_t>(points.shape(0));
    d_ = static_cast<int>(points.shape(1));
    std::vector<double> coords(points.data(), points.data() + n * static_cast<std::size_t>(d_));
    for (std::size_t i = 0; i < coords.size(); ++i) {
      if (!std::isfinite(coords[i]))
        throw py::value_error("points[" + std::to_string(i / d_) + "][" + std::to_string(i % d_) +
                              "]: not a finite number");
    }
    py::gil_scoped_release release;
    points_ = PointSet(d_, std::move(coords));
    tree_ = std::make_unique<KdTree>(points_);
  }
  py::array_t<std::int64_t> query(const Points& queries) const {
    if (queries.ndim() != 2 || queries.shape(1) != d_)
      throw py::value_error("xi: expected shape (m, " + std::to_string(d_) + ")");
    const auto m = static_cast<std::size_t>(queries.shape(0));
    std::vector<std::int64_t> out(m, -1);
    const double* q = queries.data();
    {
      py::gil_scoped_release release;
      for (std::size_t i = 0; i < m; ++i) {
        std::uint32_t id;
        double dist2;
        if (tree_->knn(q + i * static_cast<std::size_t>(d_), 1, &id, &dist2) == 1) out[i] = id;
      }
    }
    return owned(std::move(out), {static_cast<py::ssize_t>(m)});
  }

 private:
  int d_ = 0;
  PointSet points_;
  std::unique_ptr<KdTree> tree_;
};

// Writes flat[ptr[i] .. ptr[i + 1]) into the existing list i of `lists` (same
// lengths): SphericalVoronoi sorts its regions in place, as scipy's does, so that
// references to them see the order.
void refill_lists(py::list lists, const py::array_t<std::int32_t, py::array::c_style | py::array::forcecast>& flat,
                  const py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>& ptr) {
  const std::int32_t* v = flat.data();
  const std::int64_t* p = ptr.data();
  const auto count = static_cast<std::size_t>(std::max<py::ssize_t>(0, ptr.size() - 1));
  if (count != lists.size()) throw py::value_error("refill_lists: one range per list");
  for (std::size_t i = 0; i < count; ++i) {
    PyObject* list = PyList_GET_ITEM(lists.ptr(), static_cast<Py_ssize_t>(i));
    if (!PyList_Check(list) || PyList_GET_SIZE(list) != p[i + 1] - p[i])
      throw py::value_error("refill_lists: list " + std::to_string(i) + " changed length");
    for (std::int64_t j = p[i]; j < p[i + 1]; ++j) {
      PyObject* item = PyLong_FromLong(v[j]);
      if (item == nullptr) throw py::error_already_set();
      PyList_SetItem(list, static_cast<Py_ssize_t>(j - p[i]), item);  // steals item, drops the old one
    }
  }
}

}  // namespace

PYBIND11_MODULE(_core, m) {
  m.doc() = "spokemesh's exact Delaunay/Voronoi core, in-process (see spokemesh.Delaunay)";
  static py::exception<std::runtime_error> duplicates(m, "DuplicatePointsError", PyExc_ValueError);
  duplicate_points_error = duplicates.ptr();
  // The approximate walk's default budget (core's, as every route uses).
  m.attr("DEFAULT_MAX_MISSES") = kDefaultMaxMisses;
  m.attr("DEFAULT_MAX_VERTICES") = kDefaultMaxVertices;
  // Each point's first occurrence (an index into points): points equal to an earlier
  // one map to it, the others to themselves.
  m.def(
      "first_occurrences",
      [](const Points& array) {
        if (array.ndim() != 2) throw py::value_error("points: expected a 2-d array of shape (n, d)");
        const auto n = static_cast<std::size_t>(array.shape(0));
        const int d = static_cast<int>(array.shape(1));
        std::vector<std::int64_t> first(n);
        {
          py::gil_scoped_release release;
          PointSet ps(d, std::vector<double>(array.data(), array.data() + n * static_cast<std::size_t>(d)));
          const std::vector<std::uint32_t> to_reduced = ps.merge_duplicates();
          std::vector<std::int64_t> original(ps.size(), -1);
          for (std::size_t i = 0; i < n; ++i) {
            std::int64_t& o = original[to_reduced[i]];
            if (o < 0) o = static_cast<std::int64_t>(i);
            first[i] = o;
          }
        }
        return owned(std::move(first), {static_cast<py::ssize_t>(n)});
      },
      py::arg("points"));
  m.def("split_lists", &split_lists, py::arg("flat"), py::arg("ptr"));
  m.def("refill_lists", &refill_lists, py::arg("lists"), py::arg("flat"), py::arg("ptr"));
  py::class_<NearestTree>(m, "NearestTree")
      .def(py::init<const Points&>(), py::arg("points"))
      .def("query", &NearestTree::query, py::arg("xi"));
  m.def("fan_solid_angles", &fan_solid_angles, py::arg("centres"), py::arg("vertices"), py::arg("flat"),
        py::arg("ptr"));
  py::class_<Triangulation>(m, "Triangulation")
      .def(py::init<const Points&, std::optional<unsigned>, const std::optional<Points>&>(), py::arg("points"),
           py::arg("threads") = py::none(), py::arg("weights") = py::none())
      .def_property_readonly("weighted", &Triangulation::weighted)
      .def(
          "inserted",
          [](const Triangulation& self, const Points& more) { return std::make_unique<Triangulation>(self, more); },
          py::arg("points"), "The triangulation with `points` appended (only the stars that change are computed)")
      .def_property_readonly("stars_computed", &Triangulation::stars_computed)
      .def_property_readonly("dimension", &Triangulation::dimension)
      .def_property_readonly("npoints", &Triangulation::npoints)
      .def_property_readonly("nsimplices", &Triangulation::nsimplices)
      .def("simplices", &Triangulation::simplices)
      .def("neighbors", &Triangulation::neighbors)
      .def("voronoi", &Triangulation::voronoi)
      .def("furthest_site", &Triangulation::furthest_site)
      .def("find_simplex", &Triangulation::find_simplex, py::arg("xi"))
      .def("natural_neighbors", &Triangulation::natural_neighbors, py::arg("xi"))
      .def("natural_interpolate", &Triangulation::natural_interpolate, py::arg("xi"), py::arg("values"),
           py::arg("fill"))
      .def("star", &Triangulation::star, py::arg("seed"))
      .def("neighbors_of", &Triangulation::neighbors_of, py::arg("seed"))
      .def("cell", &Triangulation::cell, py::arg("seed"), py::arg("box") = py::none(),
           py::arg("halfspaces") = py::none(), py::arg("domain_format") = py::none(),
           py::arg("domain_data") = py::none())
      .def("cells", &Triangulation::cells, py::arg("box") = py::none(), py::arg("halfspaces") = py::none(),
           py::arg("bounding_box") = true, py::arg("domain_format") = py::none(), py::arg("domain_data") = py::none());
  py::class_<Hull>(m, "Hull")
      .def(py::init<const Points&, std::int64_t, std::optional<unsigned>>(), py::arg("points"), py::arg("exclude") = -1,
           py::arg("threads") = py::none())
      .def("extend", &Hull::extend, py::arg("points"))
      .def("simplices", &Hull::simplices)
      .def("neighbors", &Hull::neighbors)
      .def("equations", &Hull::equations, py::arg("points"))
      .def("vertices", &Hull::vertices)
      .def_static("bounds", &Hull::bounds, py::arg("points"))
      .def("regions", &Hull::regions, py::arg("npoints"), py::arg("sorted"))
      .def("groups", &Hull::groups, py::arg("points"))
      .def("coplanar", &Hull::coplanar, py::arg("points"))
      .def("sides", &Hull::sides, py::arg("points"), py::arg("x"));
  py::class_<PeriodicTriangulation>(m, "PeriodicTriangulation")
      .def(py::init<const Points&, const std::vector<double>&, const std::vector<double>&, std::optional<unsigned>,
                    const std::optional<Points>&>(),
           py::arg("points"), py::arg("lo"), py::arg("hi"), py::arg("threads") = py::none(),
           py::arg("weights") = py::none())
      .def("simplices", &PeriodicTriangulation::simplices)
      .def("offsets", &PeriodicTriangulation::offsets)
      .def("star", &PeriodicTriangulation::star, py::arg("seed"))
      .def("cell", &PeriodicTriangulation::cell, py::arg("seed"))
      .def("cells", &PeriodicTriangulation::cells);
  m.def("approximate_graph", &approximate_graph, py::arg("points"), py::arg("misses") = kDefaultMaxMisses,
        py::arg("max_vertices") = kDefaultMaxVertices, py::arg("random_seed") = 0x5eed, py::arg("mode") = "rsd",
        py::arg("threads") = py::none());
}
