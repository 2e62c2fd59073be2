// The whole mesh's kernel alone: Triangulation<D> (core/src/mesh/triangulation.hpp)
// inserting every point of a file in the order the whole-set triangulation uses
// (insertion_order: BRIO rounds over the split's order), one thread, against CGAL's
// Delaunay_triangulation_2/3 (Epick) inserting the same points in the same order, each
// with the previous insertion's vertex as its hint. Reading and ordering are not
// timed. Prints, per insertion: microseconds, the walk's steps, cells destroyed, exact
// evaluations.
//
// With --append F: the service's append instead. The triangulation of every point of
// the file's first (1 - F) of the points (triangulate_whole), then the whole file's from
// it (extend_whole: copied, the rest inserted) against building the whole file's again;
// both timed, with the cells compared (the triangulation is unique).
//
//   build/bin/spokemesh_triangulate FILE [--no-cgal | --append F]
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "base/dimension.hpp"
#include "mesh/insertion_order.hpp"
#include "mesh/triangulation.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/space_split.hpp"

namespace {

using Clock = std::chrono::steady_clock;
using K = CGAL::Exact_predicates_inexact_constructions_kernel;

double seconds_since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

template <int D>
void run(const spokemesh::PointSet& ps, const std::vector<std::uint32_t>& order, bool cgal) {
  const double n = static_cast<double>(order.size());
  {
    const spokemesh::Predicates pred(ps);
    spokemesh::detail::Triangulation<D> t(ps, pred);
    t.reserve(ps.size());
    const auto start = Clock::now();
    for (std::size_t k = 0; k < order.size(); ++k) t.insert_next(order, k);
    const double s = seconds_since(start);
    const auto& st = t.stats();
    std::printf("spokemesh  %.3f s  %.3f us/insertion  %.1f walk steps  %.1f cells destroyed  %.3f exact  %zu cells\n",
                s, 1e6 * s / n, static_cast<double>(st.walk_steps) / n, static_cast<double>(st.cavity_cells) / n,
                static_cast<double>(st.exact_calls) / n, t.cell_count());
  }
  if (!cgal) return;
  if constexpr (D == 2) {
    std::vector<K::Point_2> p;
    for (const std::uint32_t id : order) p.emplace_back(ps.point(id)[0], ps.point(id)[1]);
    CGAL::Delaunay_triangulation_2<K> t;
    const auto start = Clock::now();
    CGAL::Delaunay_triangulation_2<K>::Vertex_handle hint;
    for (const auto& q : p)
      hint = t.insert(q, hint == nullptr ? CGAL::Delaunay_triangulation_2<K>::Face_handle() : hint->face());
    const double s = seconds_since(start);
    std::printf("CGAL       %.3f s  %.3f us/insertion  %zu faces\n", s, 1e6 * s / n, t.number_of_faces());
  } else {
    std::vector<K::Point_3> p;
    for (const std::uint32_t id : order) p.emplace_back(ps.point(id)[0], ps.point(id)[1], ps.point(id)[2]);
    CGAL::Delaunay_triangulation_3<K> t;
    const auto start = Clock::now();
    CGAL::Delaunay_triangulation_3<K>::Vertex_handle hint;
    for (const auto& q : p)
      hint = t.insert(q, hint == nullptr ? CGAL::Delaunay_triangulation_3<K>::Cell_handle() : hint->cell());
    const double s = seconds_since(start);
    std::printf("CGAL       %.3f s  %.3f us/insertion  %zu cells\n", s, 1e6 * s / n, t.number_of_cells());
  }
}

// --append F (above).
int run_append(const spokemesh::PointSet& ps, double fraction) {
  const int d = ps.dimension();
  const auto n0 = static_cast<std::size_t>((1.0 - fraction) * static_cast<double>(ps.size()));
  spokemesh::PointSet first(d, std::vector<double>(ps.point(0), ps.point(0) + n0 * static_cast<std::size_t>(d)));
  if (const auto valid = first.validate("the first points"); !valid.is_ok()) {
    std::fprintf(stderr, "%s\n", valid.message().c_str());
    return 1;
  }
  const auto base = spokemesh::triangulate_whole(first);
  if (!base.is_ok()) {
    std::fprintf(stderr, "%s\n", base.status().message().c_str());
    return 1;
  }
  // Both with the sweep's split of every point given (the service holds the set's).
  const spokemesh::SpaceSplit split(ps, spokemesh::SpaceSplit::default_block_points(d, ps.size()));
  spokemesh::WholeOptions options;
  options.split = &split;
  auto start = Clock::now();
  const auto extended = spokemesh::extend_whole(*base.value(), ps, options);
  const double extend_s = seconds_since(start);
  start = Clock::now();
  const auto again = spokemesh::triangulate_whole(ps, options);
  const double again_s = seconds_since(start);
  if (!extended.is_ok() || !again.is_ok()) {
    std::fprintf(stderr, "failed\n");
    return 1;
  }
  spokemesh::WholeStarReader a(*extended.value()), b(*again.value());
  spokemesh::Star x, y;
  for (std::uint32_t s = 0; s < ps.size(); s += 97) {
    if (!a.star(s, x).is_ok() || !b.star(s, y).is_ok() || x.simplices != y.simplices) {
      std::fprintf(stderr, "seed %u: the stars differ\n", s);
      return 1;
    }
  }
  std::printf("append %zu points to %zu: extend_whole %.3f s, triangulate_whole again %.3f s (%.3fx), %.0f MB\n",
              ps.size() - n0, n0, extend_s, again_s, extend_s / again_s,
              static_cast<double>(extended.value()->bytes()) / 1e6);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const bool append = argc == 4 && std::strcmp(argv[2], "--append") == 0;
  if (argc < 2 || (argc == 3 && std::strcmp(argv[2], "--no-cgal") != 0) || (argc > 3 && !append)) {
    std::fprintf(stderr, "usage: spokemesh_triangulate FILE [--no-cgal | --append FRACTION]\n");
    return 2;
  }
  auto read = spokemesh::read_points(argv[1]);
  if (!read.is_ok()) {
    std::fprintf(stderr, "%s\n", read.status().message().c_str());
    return 1;
  }
  spokemesh::PointSet& ps = read.value();
  if (const auto valid = ps.validate(argv[1]); !valid.is_ok()) {  // the predicates' ranks and scale
    std::fprintf(stderr, "%s\n", valid.message().c_str());
    return 1;
  }
  const int d = ps.dimension();
  if (d != 2 && d != 3) {
    std::fprintf(stderr, "2-d and 3-d sets only\n");
    return 2;
  }
  if (append) return run_append(ps, std::atof(argv[3]));
  const spokemesh::SpaceSplit split(ps, spokemesh::SpaceSplit::default_block_points(d, ps.size()));
  std::vector<std::uint32_t> order(ps.size()), scratch;
  for (std::uint32_t r = 0; r < order.size(); ++r) order[r] = split.point_at(r);
  if (d == 2)
    spokemesh::detail::insertion_order<2>(order, scratch);
  else
    spokemesh::detail::insertion_order<3>(order, scratch);
  const bool cgal = argc == 2;
  if (d == 2)
    run<2>(ps, order, cgal);
  else
    run<3>(ps, order, cgal);
  return 0;
}
