#include "cells/box_cell_3d.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "base/invariant.hpp"
#include "cells/cell_polytope.hpp"  // kWallLabel0
#include "predicates/cramer.hpp"
#include "spokemesh/periodic_box.hpp"

namespace spokemesh::detail {

namespace {
constexpr std::uint32_t kNone = 0xFFFFFFFFu;

double norm3(const std::array<double, 3>& a) { return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); }

// Sign of det[a; b; c] for rows that are each fl(p - s) or an exact unit vector, when
// certified; 0 otherwise. Shewchuk's orient3d filter: the rounded determinant is within
// (7 + 56u) u times its permanent of the determinant of the exact differences (exact
// rows only shrink the error). Taken as 8u: the margin also covers products that
// underflow (absolute error 2^-1074 each) once the permanent is at least 2^-900.
int certified_orientation(const std::array<double, 3>& a, const std::array<double, 3>& b,
                          const std::array<double, 3>& c) {
  const double m0 = b[1] * c[2] - b[2] * c[1], m1 = b[2] * c[0] - b[0] * c[2], m2 = b[0] * c[1] - b[1] * c[0];
  const double det = a[0] * m0 + a[1] * m1 + a[2] * m2;
  const double permanent = (std::abs(b[1] * c[2]) + std::abs(b[2] * c[1])) * std::abs(a[0]) +
                           (std::abs(b[2] * c[0]) + std::abs(b[0] * c[2])) * std::abs(a[1]) +
                           (std::abs(b[0] * c[1]) + std::abs(b[1] * c[0])) * std::abs(a[2]);
  const double bound = 8 * filter::kUnitRoundoff * permanent;
  if (!(permanent < 0x1p1000) || permanent < 0x1p-900) return 0;  // overflow or underflow: not certified
  return det > bound ? 1 : det < -bound ? -1 : 0;
}
}  // namespace

BoxCell3d::BoxCell3d(const PointSet& points, const Domain& box, std::span<const double> weights,
                     const PeriodicCover* cover)
    : points_(points),
      box_(box),
      cover_(cover),
      weights_(weights.empty() ? nullptr : weights.data()),
      max_weight_(weights.empty() ? 0 : *std::max_element(weights.begin(), weights.end())),
      predicates_(points, weights, cover != nullptr ? &cover->box() : nullptr,
                  cover != nullptr ? cover->images() : ImageMap{}) {
  v_.reserve(256);
  planes_.reserve(128);
}

void BoxCell3d::reset(std::uint32_t seed) {
  seed_ = seed;
  s_ = points_.point(seed);
  // max w - w_s, rounded up (both are doubles: one rounding of a non-negative difference).
  weight_reach_ = weights_ == nullptr ? 0 : (max_weight_ - weights_[seed]) * (1 + 4 * filter::kUnitRoundoff);
  planes_.clear();
  // Walls 0..2 are the lower ones (normal -e_c, offset -lo_c), 3..5 the upper ones.
  for (std::uint32_t w = 0; w < 6; ++w) {
    Plane pl;
    pl.axis = static_cast<int>(w % 3);
    pl.a[pl.axis] = w < 3 ? -1.0 : 1.0;
    pl.c = box_.offset(w) - pl.a[pl.axis] * s_[pl.axis];  // the seed's distance to the wall
    pl.a_norm = 1;
    pl.label = kWallLabel0 + w;
    planes_.push_back(pl);
  }
  v_.resize(8);
  rmax_ = 0;
  for (std::uint32_t v = 0; v < 8; ++v) {
    Vertex& x = v_[v];
    for (int c = 0; c < 3; ++c) {
      const bool upper = (v >> c) & 1;
      const Plane& wall = planes_[upper ? 3 + c : c];
      x.y[c] = upper ? wall.c : -wall.c;
      x.plane[c] = upper ? 3 + c : c;
      x.next[c] = v ^ (1u << c);
    }
    // Each coordinate is one rounding from the exact wall minus seed.
    x.error = 2 * filter::kUnitRoundoff * norm3(x.y);
    x.radius = norm3(x.y) * (1 + 1e-12) + x.error;
    rmax_ = std::max(rmax_, x.radius);
  }
  changed_ = false;
}

std::uint32_t BoxCell3d::step_around(std::uint32_t face, std::uint32_t prev, std::uint32_t cur) const {
  // cur lies on `face`; of its three edges, the two that leave its other planes stay
  // on the face.
  const Vertex& x = v_[cur];
  std::uint32_t ways[2] = {cur, cur};
  int found = 0;
  for (int k = 0; k < 3; ++k) {
    if (x.plane[k] != face && found < 2) ways[found++] = x.next[k];
  }
  return ways[0] == prev ? ways[1] : ways[0];
}

bool BoxCell3d::solve(Vertex& v) const {
  // Rows a_i . y = c_i, by Cramer's rule with its forward error bound (cramer.hpp; for
  // three bisectors, the circumcentre of the seed's tetrahedron). A wall's unit row is
  // scaled by a power of two to the bisectors' size, exactly, so that it does not
  // inflate the bound.
  double a[3][3], c[3], y[3];
  double scale = 0;
  for (int i = 0; i < 3; ++i) {
    const Plane& pl = planes_[v.plane[i]];
    if (pl.axis < 0) scale = std::max(scale, pl.a_norm);
  }
  const int e = scale > 0 ? std::ilogb(scale) : 0;
  for (int i = 0; i < 3; ++i) {
    const Plane& pl = planes_[v.plane[i]];
    const double f = pl.axis < 0 ? 1.0 : std::ldexp(1.0, e);
    for (int k = 0; k < 3; ++k) a[i][k] = pl.a[k] * f;
    c[i] = pl.c * f;
  }
  double forward = 0;
  if (!cramer_solve(a, c, y, forward)) return false;  // nearly flat: the generic route decides
  for (int k = 0; k < 3; ++k) v.y[k] = y[k];
  v.error = std::sqrt(3.0) * forward;
  v.radius = norm3(v.y) * (1 + 1e-12) + v.error;
  return true;
}

int BoxCell3d::exact_side(const Vertex& v, const Plane& bisector) const {
  // In y' = 2 (x - s) the bisector of s and p is q . y' = |q|^2, and with the star's
  // perturbed heights |q|^2 + delta_p - delta_s it is the power bisector of the
  // perturbed weights (docs/algorithm.md); a wall is e . y' = 2 c, c its exact distance
  // from the seed, unperturbed. The vertex's three planes and p's bisector are the rows
  // of a lifted matrix M (points as (q, |q|^2), walls as (e, 2 c)), and by the Schur
  // complement det M = -det(A) f, with A the vertex's three normals and f = q . y' -
  // |q|^2 the amount by which the vertex lies beyond p's bisector. Both signs come from
  // the star's own predicates (walls through the seed are direction rows; a wall that
  // misses it takes GMP for det M, and the perturbation's coefficients, which see only
  // the spatial parts, from the same rows with the wall's height set to 0), so the
  // cell's facets are those of the star's cell, the perturbation's zero-area facets
  // included.
  std::array<Row, 4> rows;
  bool walls_off_seed = false;
  for (int k = 0; k < 3; ++k) {
    const Plane& plane = planes_[v.plane[k]];
    if (plane.axis < 0) {
      rows[k] = Row::of_point(plane.label);
    } else {
      rows[k] = Row::of_direction(plane.a.data());
      walls_off_seed |= plane.c != 0;  // exact: the wall's offset minus the seed's coordinate
    }
  }
  rows[3] = Row::of_point(bisector.label);
  int a = certified_orientation(planes_[v.plane[0]].a, planes_[v.plane[1]].a, planes_[v.plane[2]].a);
  if (a == 0) a = predicates_.spatial_sign_exact(seed_, std::span<const Row>(rows.data(), 3));
  if (a == 0) return 0;
  int m = 0;
  // Power cells leave exact ties to the star's cell: where the perturbation would
  // decide, the zero-area facets it makes on the domain's walls follow the star's
  // clipping, which this polytope does not reproduce (weighted grids showed it).
  if (!walls_off_seed && weights_ != nullptr) {
    m = predicates_.lifted_sign_exact(seed_, std::span<const Row>(rows.data(), 4), /*perturb=*/false);
    if (m == 0) return 0;
  } else if (!walls_off_seed) {
    m = predicates_.lifted_sign_exact(seed_, std::span<const Row>(rows.data(), 4), /*perturb=*/true);
  } else {
    std::vector<mpq_class> matrix(16);
    for (int k = 0; k < 4; ++k) {
      const Plane& plane = k < 3 ? planes_[v.plane[k]] : bisector;
      if (plane.axis < 0) {
        mpq_class norm2 = 0;
        for (int c = 0; c < 3; ++c) {
          matrix[k * 4 + c] = exact_difference(plane.label, c);
          norm2 += matrix[k * 4 + c] * matrix[k * 4 + c];
        }
        if (weights_ != nullptr)
          norm2 -= mpq_class(weights_[plane.label]) - mpq_class(weights_[seed_]);  // power height
        matrix[k * 4 + 3] = norm2;
      } else {
        const auto wall = static_cast<std::size_t>(plane.label - kWallLabel0);
        for (int c = 0; c < 3; ++c) matrix[k * 4 + c] = plane.a[c];
        matrix[k * 4 + 3] = 2 * (mpq_class(box_.offset(wall)) - plane.a[plane.axis] * mpq_class(s_[plane.axis]));
      }
    }
    m = sgn(exact_determinant(std::move(matrix), 4));
    if (m == 0 && weights_ != nullptr) return 0;  // a tie: the star's way (above)
    if (m == 0) m = predicates_.perturbation_sign(seed_, std::span<const Row>(rows.data(), 4));
  }
  if (m == 0) return 0;
  return m == a ? -1 : 1;
}

mpq_class BoxCell3d::exact_difference(std::uint32_t id, int c) const {
  if (cover_ == nullptr || id < cover_->point_count()) return mpq_class(points_.point(id)[c]) - mpq_class(s_[c]);
  const auto cu = static_cast<std::size_t>(c);
  const PeriodicBox& box = cover_->box();
  return mpq_class(points_.point(cover_->point_of(id))[c]) +
         mpq_class(cover_->offset_of(id)[c]) * (mpq_class(box.hi()[cu]) - mpq_class(box.lo()[cu])) - mpq_class(s_[c]);
}

bool BoxCell3d::clip(std::uint32_t label, const double* p) {
  changed_ = false;
  Plane pl;
  pl.label = label;
  double q2 = 0;
  const bool image = cover_ != nullptr && label >= cover_->point_count();
  for (int k = 0; k < 3; ++k) {
    // An image's difference from its exact position, rounded once (as fl(p - s) is).
    const auto ku = static_cast<std::size_t>(k);
    pl.a[k] = image ? image_difference(points_.point(cover_->point_of(label))[k], cover_->offset_of(label)[k],
                                       cover_->box().lo()[ku], cover_->box().hi()[ku], s_[k])
                    : p[k] - s_[k];
    q2 += pl.a[k] * pl.a[k];
  }
  pl.dw = weights_ == nullptr ? 0.0 : weights_[label] - weights_[seed_];
  pl.c = (q2 - pl.dw) / 2;
  pl.a_norm = std::sqrt(q2);
  // The bisector lies c / |q| from the seed: vertices closer (with their error) are
  // strictly inside, and if all are, it cuts nothing. (A power bisector may pass
  // behind the seed, c <= 0: no shortcut then.) c's rounding: that of |q|^2 / 2 (as
  // below) and of the weights' difference and the subtraction.
  const double c_error =
      weights_ == nullptr ? 0.0 : 28 * filter::kUnitRoundoff * (q2 + std::abs(pl.dw) + std::abs(pl.c));
  const double reach = weights_ == nullptr ? pl.a_norm / 2 * (1 - 1e-12)
                       : pl.c > c_error    ? (pl.c - c_error) / pl.a_norm * (1 - 1e-12)
                                           : -1.0;
  if (reach > rmax_) return true;
  const std::size_t n = v_.size();
  side_.resize(n);
  bool any_out = false;
  for (std::size_t v = 0; v < n; ++v) {
    const Vertex& x = v_[v];
    if (x.radius < reach) {
      side_[v] = -1;
      continue;
    }
    double f = -pl.c, magnitude = std::abs(pl.c);
    for (int k = 0; k < 3; ++k) {
      f += pl.a[k] * x.y[k];
      magnitude += std::abs(pl.a[k] * x.y[k]);
    }
    // The sum's rounding and that of q and |q|^2 / 2 against the exact bisector (as
    // CellPolytope::plane_value), with weights that of w_p - w_s and of the offset
    // (c_error), plus the vertex's own error along the normal.
    const double bound = 28 * filter::kUnitRoundoff * (magnitude + std::abs(pl.c)) + c_error +
                         pl.a_norm * x.error * (1 + 16 * filter::kUnitRoundoff);
    if (f > bound) {
      side_[v] = 1;
      any_out = true;
    } else if (f < -bound) {
      side_[v] = -1;
    } else {
      // Within rounding of the plane: decided exactly, ties by the perturbation.
      const int exact = exact_side(x, pl);
      if (exact == 0) return false;  // undecidable (see exact_side): the generic route
      side_[v] = static_cast<std::int8_t>(exact);
      any_out |= exact > 0;
    }
  }
  if (!any_out) return true;
  const auto pid = static_cast<std::uint32_t>(planes_.size());
  planes_.push_back(pl);
  // A new vertex on every edge from a kept vertex v to a dropped one w; w's pointer
  // back to v is redirected to it, so that walks through the dropped part find it.
  const auto first_new = static_cast<std::uint32_t>(n);
  dropped_end_.clear();
  double rmax = 0;
  for (std::uint32_t v = 0; v < first_new; ++v) {
    if (side_[v] > 0) continue;
    rmax = std::max(rmax, v_[v].radius);
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t w = v_[v].next[k];
      if (w >= first_new || side_[w] < 0) continue;
      Vertex u;
      u.plane = v_[v].plane;
      u.plane[k] = pid;
      u.next = {kNone, kNone, kNone};
      u.next[k] = v;
      if (!solve(u)) return false;
      rmax = std::max(rmax, u.radius);
      const auto id = static_cast<std::uint32_t>(v_.size());
      v_[v].next[k] = id;
      Vertex& x = v_[w];
      x.next[x.next[0] == v ? 0 : x.next[1] == v ? 1 : 2] = id;
      v_.push_back(u);
      dropped_end_.push_back(w);
    }
  }
  // Join the new vertices: the one reached from u by leaving plane m lies on u's face S
  // (its third plane) at the far end of S's dropped part; walk that part from u's
  // dropped end (Voro++'s way: caps are small). Each join is made from both ends.
  for (std::uint32_t u = first_new; u < v_.size(); ++u) {
    const int at = v_[u].plane[0] == pid ? 0 : v_[u].plane[1] == pid ? 1 : 2;
    for (int m = 0; m < 3; ++m) {
      if (m == at || v_[u].next[m] != kNone) continue;
      const std::uint32_t face = v_[u].plane[3 - at - m];
      std::uint32_t prev = u, cur = dropped_end_[u - first_new];
      for (std::size_t steps = 0;; ++steps) {
        SPOKEMESH_INVARIANT(steps <= n, "the dropped part of a face ends at a new vertex");
        const std::uint32_t nxt = step_around(face, prev, cur);
        prev = cur;
        cur = nxt;
        if (cur >= first_new) break;
      }
      Vertex& partner = v_[cur];
      v_[u].next[m] = cur;
      for (int k = 0; k < 3; ++k) {
        if (partner.plane[k] != face && partner.plane[k] != pid) partner.next[k] = u;
      }
    }
  }
  // Fill the dropped vertices' slots with the last live vertices, redirecting the
  // pointers to each moved one.
  std::uint32_t end = static_cast<std::uint32_t>(v_.size());
  for (std::uint32_t h = 0; h < end; ++h) {
    if (h >= first_new || side_[h] < 0) continue;  // live
    while (end - 1 > h && end - 1 < first_new && side_[end - 1] > 0) --end;
    if (end - 1 == h) {  // only dropped vertices from here on
      end = h;
      break;
    }
    const std::uint32_t from = --end;
    v_[h] = v_[from];
    for (int k = 0; k < 3; ++k) {
      Vertex& b = v_[v_[h].next[k]];
      b.next[b.next[0] == from ? 0 : b.next[1] == from ? 1 : 2] = h;
    }
  }
  v_.resize(end);
  rmax_ = rmax;
  changed_ = true;
  return true;
}

void BoxCell3d::assemble(VoronoiCell& out, bool measures_only) {
  out.seed = seed_;
  out.dimension = 3;
  out.clipped = true;
  out.bounded = true;
  out.hidden = false;  // (the record may have held a hidden seed's cell: buffers are reused)
  out.facet_offsets.clear();
  std::size_t facet_count = 0;  // out.facets is reused, buffers and all
  out.vertices.clear();
  out.vertex_simplices.clear();
  const std::size_t n = v_.size();
  if (!measures_only) {
    out.vertices.resize(n * 3);
    for (std::size_t v = 0; v < n; ++v) {
      const Vertex& x = v_[v];
      double* o = &out.vertices[v * 3];
      for (int k = 0; k < 3; ++k) o[k] = s_[k] + x.y[k];
      bool on_wall = false;
      for (int k = 0; k < 3; ++k) {
        const Plane& pl = planes_[x.plane[k]];
        if (pl.axis >= 0) {  // a box wall fixes its coordinate exactly
          o[pl.axis] = pl.a[pl.axis] * box_.offset(pl.label - kWallLabel0);
          on_wall = true;
        }
      }
      // A Voronoi vertex: within circumcentre()'s bound (1e-12 of its radius plus an
      // ulp), or recomputed by it.
      if (!on_wall && x.error > 1e-12 * norm3(x.y)) {
        std::uint32_t ids[4] = {seed_, planes_[x.plane[0]].label, planes_[x.plane[1]].label, planes_[x.plane[2]].label};
        std::sort(ids, ids + 4);
        const std::vector<double> cc = circumcentre(points_, ids, 4, weights_);
        std::copy(cc.begin(), cc.end(), o);
      }
    }
  }
  // One facet per plane that still has a vertex: its loop, area, centre.
  first_on_plane_.assign(planes_.size(), kNone);
  for (std::uint32_t v = 0; v < n; ++v) {
    for (int k = 0; k < 3; ++k) {
      std::uint32_t& f = first_on_plane_[v_[v].plane[k]];
      if (f == kNone) f = v;
    }
  }
  double volume = 0;
  std::array<double, 3> moment{};
  for (std::uint32_t pid = 0; pid < planes_.size(); ++pid) {
    const std::uint32_t start = first_on_plane_[pid];
    if (start == kNone) continue;
    const Plane& pl = planes_[pid];
    loop_.clear();
    std::uint32_t prev = start, cur = start;
    do {
      loop_.push_back(cur);
      const std::uint32_t nxt = step_around(pid, prev, cur);
      prev = cur;
      cur = nxt;
    } while (cur != start && loop_.size() <= n);
    SPOKEMESH_INVARIANT(cur == start, "a face's boundary is a cycle");
    std::array<double, 3> normal{};
    for (int k = 0; k < 3; ++k) normal[k] = pl.a[k] / pl.a_norm;
    // Fan from the loop's first vertex (relative coordinates: small numbers).
    std::array<double, 3> centre{};
    double area = fan_area(
        loop_, [&](std::uint32_t v) { return v_[v].y.data(); }, normal.data(), centre.data());
    if (area < 0) {  // walked clockwise seen from outside
      std::reverse(loop_.begin() + 1, loop_.end());
      area = -area;
      for (double& x : centre) x = -x;
    }
    if (out.facets.size() == facet_count) out.facets.emplace_back();
    VoronoiFacet& facet = out.facets[facet_count++];
    facet.neighbor =
        pl.axis >= 0 ? -1 - static_cast<std::int64_t>(pl.label - kWallLabel0) : static_cast<std::int64_t>(pl.label);
    facet.area = area;
    facet.normal.assign(normal.begin(), normal.end());
    if (measures_only) {
      facet.vertices.clear();
    } else {
      facet.vertices.assign(loop_.begin(), loop_.end());
    }
    if (area > 0) {
      // The cone from the seed: its height is the plane's distance from the seed
      // (|q| / 2 for a bisector, the wall's distance), its centroid 3/4 of the way to
      // the face's centroid.
      const double h = pl.c / pl.a_norm;
      const double cone = area * h / 3;
      volume += cone;
      for (int k = 0; k < 3; ++k) moment[k] += cone * 0.75 * (centre[k] / area);
    }
  }
  out.facets.resize(facet_count);
  sort_facets(out.facets);
  out.volume = volume;
  out.centroid.resize(3);
  for (int k = 0; k < 3; ++k) out.centroid[k] = s_[k] + (volume > 0 ? moment[k] / volume : 0.0);
}

}  // namespace spokemesh::detail
