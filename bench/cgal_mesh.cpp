// CGAL as a whole process on a point file, the peer of `spokemesh mesh FILE` in
// bench/whole.py: reads the file with spokemesh's reader (text or .npy, the same
// parse for both), builds CGAL's Delaunay triangulation (2-d, 3-d: the specialised
// Delaunay_triangulation_2/_3 with Epick, which sort the input spatially; d >= 4: the
// dD Delaunay_triangulation with Epick_d), and prints the number of finite simplices.
// It writes no mesh file (spokemesh's time includes writing one). With a weights file
// (read by spokemesh's reader too), CGAL's Regular_triangulation_2/_3 instead, the
// peer of `spokemesh mesh FILE --weights WEIGHTS`; it also prints the hidden count.
// With --periodic SIDE (2-d, 3-d), CGAL's Periodic_2/_3_Delaunay_triangulation on the
// square or cube [0, SIDE)^d (their domains must be squares and cubes), inserted as a
// large point set, the peer of `spokemesh mesh FILE --periodic 0,..,SIDE,..`; it prints
// the number of simplices of the torus, and "sheeted" when CGAL had to keep its 9- or
// 27-sheeted covering (too few points, or voids, for one copy).
//
//   build/bin/spokemesh_cgal_mesh FILE [WEIGHTS | --periodic SIDE]
#include <CGAL/Delaunay_triangulation.h>
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Epick_d.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Periodic_2_Delaunay_triangulation_2.h>
#include <CGAL/Periodic_2_Delaunay_triangulation_traits_2.h>
#include <CGAL/Periodic_3_Delaunay_triangulation_3.h>
#include <CGAL/Periodic_3_Delaunay_triangulation_traits_3.h>
#include <CGAL/Regular_triangulation_2.h>
#include <CGAL/Regular_triangulation_3.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "spokemesh/io.hpp"

int main(int argc, char** argv) {
  if (argc != 2 && argc != 3 && !(argc == 4 && std::strcmp(argv[2], "--periodic") == 0)) {
    std::fprintf(stderr, "usage: spokemesh_cgal_mesh FILE [WEIGHTS | --periodic SIDE]\n");
    return 2;
  }
  auto read = spokemesh::read_points(argv[1]);
  if (!read.is_ok()) {
    std::fprintf(stderr, "%s\n", read.status().message().c_str());
    return 1;
  }
  const spokemesh::PointSet& ps = read.value();
  const int d = ps.dimension();
  std::size_t simplices = 0;
  using K = CGAL::Exact_predicates_inexact_constructions_kernel;
  if (argc == 4) {
    const double side = std::atof(argv[3]);
    bool one_cover = false;
    if (d == 2) {
      using Gt = CGAL::Periodic_2_Delaunay_triangulation_traits_2<K>;
      std::vector<K::Point_2> p;
      p.reserve(ps.size());
      for (std::size_t i = 0; i < ps.size(); ++i) p.emplace_back(ps.point(i)[0], ps.point(i)[1]);
      CGAL::Periodic_2_Delaunay_triangulation_2<Gt> t(Gt::Iso_rectangle_2(0, 0, side, side));
      t.insert(p.begin(), p.end(), /*is_large_point_set=*/true);
      one_cover = t.is_1_cover();
      simplices = t.number_of_faces();
    } else if (d == 3) {
      using Gt = CGAL::Periodic_3_Delaunay_triangulation_traits_3<K>;
      std::vector<K::Point_3> p;
      p.reserve(ps.size());
      for (std::size_t i = 0; i < ps.size(); ++i) p.emplace_back(ps.point(i)[0], ps.point(i)[1], ps.point(i)[2]);
      CGAL::Periodic_3_Delaunay_triangulation_3<Gt> t(Gt::Iso_cuboid_3(0, 0, 0, side, side, side));
      t.insert(p.begin(), p.end(), /*is_large_point_set=*/true);
      one_cover = t.is_1_cover();
      simplices = t.number_of_cells();
    } else {
      std::fprintf(stderr, "--periodic: 2-d and 3-d only here\n");
      return 2;
    }
    std::printf("%zu%s\n", simplices, one_cover ? "" : " sheeted");
    return 0;
  }
  if (argc == 3) {
    auto weights = spokemesh::read_weights(argv[2], ps.size(), spokemesh::WeightKind::kPowerWeight);
    if (!weights.is_ok()) {
      std::fprintf(stderr, "%s\n", weights.status().message().c_str());
      return 1;
    }
    const std::vector<double>& w = weights.value();
    std::size_t vertices = 0;
    if (d == 2) {
      std::vector<K::Weighted_point_2> p;
      p.reserve(ps.size());
      for (std::size_t i = 0; i < ps.size(); ++i) p.emplace_back(K::Point_2(ps.point(i)[0], ps.point(i)[1]), w[i]);
      CGAL::Regular_triangulation_2<K> rt(p.begin(), p.end());
      simplices = rt.number_of_faces();
      vertices = rt.number_of_vertices();
    } else if (d == 3) {
      std::vector<K::Weighted_point_3> p;
      p.reserve(ps.size());
      for (std::size_t i = 0; i < ps.size(); ++i) {
        p.emplace_back(K::Point_3(ps.point(i)[0], ps.point(i)[1], ps.point(i)[2]), w[i]);
      }
      CGAL::Regular_triangulation_3<K> rt(p.begin(), p.end());
      simplices = rt.number_of_finite_cells();
      vertices = rt.number_of_vertices();
    } else {
      std::fprintf(stderr, "weights: 2-d and 3-d only here\n");
      return 2;
    }
    std::printf("%zu simplices, %zu hidden\n", simplices, ps.size() - vertices);
    return 0;
  }
  if (d == 2) {
    std::vector<K::Point_2> p;
    p.reserve(ps.size());
    for (std::size_t i = 0; i < ps.size(); ++i) p.emplace_back(ps.point(i)[0], ps.point(i)[1]);
    CGAL::Delaunay_triangulation_2<K> dt(p.begin(), p.end());
    simplices = dt.number_of_faces();
  } else if (d == 3) {
    std::vector<K::Point_3> p;
    p.reserve(ps.size());
    for (std::size_t i = 0; i < ps.size(); ++i) p.emplace_back(ps.point(i)[0], ps.point(i)[1], ps.point(i)[2]);
    CGAL::Delaunay_triangulation_3<K> dt(p.begin(), p.end());
    simplices = dt.number_of_finite_cells();
  } else {
    using KD = CGAL::Epick_d<CGAL::Dynamic_dimension_tag>;
    std::vector<KD::Point_d> p;
    p.reserve(ps.size());
    for (std::size_t i = 0; i < ps.size(); ++i) p.emplace_back(d, ps.point(i), ps.point(i) + d);
    CGAL::Delaunay_triangulation<KD> dt(d);
    dt.insert(p.begin(), p.end());
    simplices = dt.number_of_finite_full_cells();
  }
  std::printf("%zu\n", simplices);
  return 0;
}
