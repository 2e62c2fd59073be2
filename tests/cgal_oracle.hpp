// CGAL's Delaunay triangulations as test oracles: the finite simplices of a point set
// as sorted index tuples (test-only; CGAL is never linked into shipped binaries).
#pragma once

#include <CGAL/Delaunay_triangulation.h>
#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Epick_d.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>

#include <algorithm>
#include <cstdint>
#include <set>
#include <vector>

#include "spokemesh/point_set.hpp"

namespace spokemesh::testing {

using Tuples = std::set<std::vector<std::uint32_t>>;

inline Tuples cgal_dd(const PointSet& ps) {
  using K = CGAL::Epick_d<CGAL::Dynamic_dimension_tag>;
  using Vb = CGAL::Triangulation_vertex<K, std::uint32_t>;
  using Cb = CGAL::Triangulation_full_cell<K>;
  using Tds = CGAL::Triangulation_data_structure<CGAL::Dynamic_dimension_tag, Vb, Cb>;
  using DT = CGAL::Delaunay_triangulation<K, Tds>;
  const int d = ps.dimension();
  DT dt(d);
  for (std::uint32_t i = 0; i < ps.size(); ++i) {
    auto v = dt.insert(K::Point_d(d, ps.point(i), ps.point(i) + d));
    v->data() = i;
  }
  Tuples out;
  for (auto c = dt.finite_full_cells_begin(); c != dt.finite_full_cells_end(); ++c) {
    std::vector<std::uint32_t> t;
    for (int k = 0; k <= d; ++k) t.push_back(c->vertex(k)->data());
    std::sort(t.begin(), t.end());
    out.insert(t);
  }
  return out;
}

using Epick = CGAL::Exact_predicates_inexact_constructions_kernel;

inline Tuples cgal_2(const PointSet& ps) {
  using Vb = CGAL::Triangulation_vertex_base_with_info_2<std::uint32_t, Epick>;
  using Tds = CGAL::Triangulation_data_structure_2<Vb>;
  CGAL::Delaunay_triangulation_2<Epick, Tds> dt;
  for (std::uint32_t i = 0; i < ps.size(); ++i) dt.insert(Epick::Point_2(ps.point(i)[0], ps.point(i)[1]))->info() = i;
  Tuples out;
  for (auto f = dt.finite_faces_begin(); f != dt.finite_faces_end(); ++f) {
    std::vector<std::uint32_t> t = {f->vertex(0)->info(), f->vertex(1)->info(), f->vertex(2)->info()};
    std::sort(t.begin(), t.end());
    out.insert(t);
  }
  return out;
}

inline Tuples cgal_3(const PointSet& ps) {
  using Vb = CGAL::Triangulation_vertex_base_with_info_3<std::uint32_t, Epick>;
  using Tds = CGAL::Triangulation_data_structure_3<Vb>;
  CGAL::Delaunay_triangulation_3<Epick, Tds> dt;
  for (std::uint32_t i = 0; i < ps.size(); ++i) {
    dt.insert(Epick::Point_3(ps.point(i)[0], ps.point(i)[1], ps.point(i)[2]))->info() = i;
  }
  Tuples out;
  for (auto c = dt.finite_cells_begin(); c != dt.finite_cells_end(); ++c) {
    std::vector<std::uint32_t> t = {c->vertex(0)->info(), c->vertex(1)->info(), c->vertex(2)->info(),
                                    c->vertex(3)->info()};
    std::sort(t.begin(), t.end());
    out.insert(t);
  }
  return out;
}

}  // namespace spokemesh::testing
