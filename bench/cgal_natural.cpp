// CGAL's natural-neighbour coordinates on a point file, the peer of
// spokemesh.interpolate's in bench/interpolation.py: reads the 2-d points (.npy or
// text, spokemesh's reader), builds CGAL's Delaunay_triangulation_2 (Epick), then
// computes natural_neighbor_coordinates_2 at either a raster's points (row by row,
// each located from the one before: CGAL's best case for gridding) or the queries of a
// second file (put in CGAL's spatial_sort order first, timed with the queries, then
// each located from the one before: without the sort, hints from scattered queries
// make every walk long). One thread. Prints the build and query seconds and a checksum
// (the coordinates applied to x).
//
//   build/bin/spokemesh_cgal_natural POINTS --raster X0,Y0,X1,Y1,NX,NY
//   build/bin/spokemesh_cgal_natural POINTS --queries QUERIES
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/natural_neighbor_coordinates_2.h>
#include <CGAL/spatial_sort.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <vector>

#include "spokemesh/io.hpp"

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Dt = CGAL::Delaunay_triangulation_2<K>;

int main(int argc, char** argv) {
  if (argc != 4 || (std::strcmp(argv[2], "--raster") != 0 && std::strcmp(argv[2], "--queries") != 0)) {
    std::fprintf(stderr, "usage: spokemesh_cgal_natural POINTS (--raster X0,Y0,X1,Y1,NX,NY | --queries FILE)\n");
    return 2;
  }
  auto read = spokemesh::read_points(argv[1]);
  if (!read.is_ok() || read.value().dimension() != 2) {
    std::fprintf(stderr, "%s\n", read.is_ok() ? "2-d points expected" : read.status().message().c_str());
    return 1;
  }
  const spokemesh::PointSet& ps = read.value();
  std::vector<K::Point_2> points;
  points.reserve(ps.size());
  for (std::size_t i = 0; i < ps.size(); ++i) points.emplace_back(ps.point(i)[0], ps.point(i)[1]);
  std::vector<K::Point_2> queries;
  if (std::strcmp(argv[2], "--raster") == 0) {
    double x0, y0, x1, y1;
    long nx, ny;
    if (std::sscanf(argv[3], "%lf,%lf,%lf,%lf,%ld,%ld", &x0, &y0, &x1, &y1, &nx, &ny) != 6 || nx < 2 || ny < 2) {
      std::fprintf(stderr, "--raster X0,Y0,X1,Y1,NX,NY expected\n");
      return 2;
    }
    for (long j = 0; j < ny; ++j) {
      for (long i = 0; i < nx; ++i) queries.emplace_back(x0 + (x1 - x0) * i / (nx - 1), y0 + (y1 - y0) * j / (ny - 1));
    }
  } else {
    auto q = spokemesh::read_points(argv[3]);
    if (!q.is_ok() || q.value().dimension() != 2) {
      std::fprintf(stderr, "%s\n", q.is_ok() ? "2-d queries expected" : q.status().message().c_str());
      return 1;
    }
    for (std::size_t i = 0; i < q.value().size(); ++i)
      queries.emplace_back(q.value().point(i)[0], q.value().point(i)[1]);
  }
  const bool sort = std::strcmp(argv[2], "--queries") == 0;
  const auto t0 = std::chrono::steady_clock::now();
  Dt dt(points.begin(), points.end());
  const auto t1 = std::chrono::steady_clock::now();
  if (sort) CGAL::spatial_sort(queries.begin(), queries.end());
  double checksum = 0;
  std::size_t inside = 0;
  std::vector<std::pair<K::Point_2, K::FT>> coords;
  Dt::Face_handle hint;
  for (const K::Point_2& q : queries) {
    coords.clear();
    hint = dt.locate(q, hint);
    auto r = CGAL::natural_neighbor_coordinates_2(dt, q, std::back_inserter(coords), hint);
    if (!r.third) continue;
    ++inside;
    for (const auto& [p, w] : coords) checksum += w / r.second * p.x();
  }
  const auto t2 = std::chrono::steady_clock::now();
  std::printf("{\"build_s\": %.4f, \"query_s\": %.4f, \"queries\": %zu, \"inside\": %zu, \"checksum\": %.10g}\n",
              std::chrono::duration<double>(t1 - t0).count(), std::chrono::duration<double>(t2 - t1).count(),
              queries.size(), inside, checksum);
}
