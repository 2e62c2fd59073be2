// Clipped Voronoi cells and their measures: invariants
// checked on every cell of whole point sets, in every dimension from 2 to 6 (7 and 8
// with SPOKEMESH_HIGH_D=1), as CGAL's tests validate after every step.
//   * the clipped cells tile the domain: volumes sum to its volume (relative 1e-12),
//     and the volume-weighted centroids to its centroid;
//   * facet i -> j exists iff j -> i does, with equal areas and opposite normals;
//   * the divergence theorem per cell: sum of area x normal = 0;
//   * the walls' pieces sum to each wall's area (boxes);
//   * in 3-d every facet's loop is counter-clockwise from outside: its Newell vector
//     is area x normal.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <map>
#include <random>

#include "inputs.hpp"  // bench/: the shape families
#include "spokemesh/cells.hpp"
#include "spokemesh/domain.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/voronoi.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

using namespace testing;

// Every cell from the star (voronoi_cell), the route every domain can take.
std::vector<VoronoiCell> star_cells(const PointSet& ps, const Domain& domain) {
  const KdTree tree(ps);
  StarWalker walker(tree);
  Star star;
  std::vector<VoronoiCell> cells;
  for (std::uint32_t s = 0; s < ps.size(); ++s) {
    EXPECT_TRUE(walker.compute(s, star).is_ok());
    auto cell = voronoi_cell(ps, star, domain);
    EXPECT_TRUE(cell.is_ok()) << cell.status().message();
    cells.push_back(std::move(cell.value()));
  }
  return cells;
}

// Every cell from ClippedCellBuilder (boxes: clipped directly by bisectors, falling
// back to the star at ties), as `spokemesh cells` and the service compute them.
// (Forced to the direct route in every dimension, to test it everywhere.)
// `fallbacks`: seeds built from the star; `generic`: 3-d seeds the specialised cell
// left to the generic polytope.
std::vector<VoronoiCell> builder_cells(const PointSet& ps, const Domain& domain, std::uint64_t* fallbacks = nullptr,
                                       std::uint64_t* generic = nullptr) {
  const KdTree tree(ps);
  ClippedCellBuilder builder(tree, domain, {}, CellRoute::kDirect);
  std::vector<VoronoiCell> cells;
  for (std::uint32_t s = 0; s < ps.size(); ++s) {
    auto cell = builder.cell(s);
    EXPECT_TRUE(cell.is_ok()) << cell.status().message();
    if (cell.is_ok()) cells.push_back(std::move(cell.value()));
  }
  if (fallbacks) *fallbacks = builder.star_fallbacks();
  if (generic) *generic = builder.generic_fallbacks();
  return cells;
}

// Both routes, with the invariants below checked on each (check_tiling).
template <class Check>
void for_both_routes(const PointSet& ps, const Domain& domain, Check check) {
  {
    SCOPED_TRACE("from stars");
    check(star_cells(ps, domain));
  }
  if (ps.dimension() <= 6) {  // (above, a box's 2^d corners make the direct route slow; never used there)
    SCOPED_TRACE("ClippedCellBuilder");
    check(builder_cells(ps, domain));
  }
}

// Checks every invariant above; `volume` and `centroid` are the domain's.
void check_tiling(const PointSet& ps, const std::vector<VoronoiCell>& cells, double volume,
                  const std::vector<double>& centroid, const std::vector<double>* wall_areas) {
  const int d = ps.dimension();
  double total = 0, scale = std::pow(volume, 1.0 / d);
  std::vector<double> moment(d, 0.0), wall_sum(wall_areas ? wall_areas->size() : 0, 0.0);
  std::map<std::pair<std::int64_t, std::int64_t>, const VoronoiFacet*> facets;
  for (const VoronoiCell& cell : cells) {
    SCOPED_TRACE("seed " + std::to_string(cell.seed));
    ASSERT_TRUE(cell.bounded);
    ASSERT_TRUE(std::isfinite(cell.volume));
    EXPECT_GE(cell.volume, 0);
    total += cell.volume;
    for (int c = 0; c < d; ++c) moment[c] += cell.volume * cell.centroid[c];
    std::vector<double> flux(d, 0.0);
    double area_sum = 0;
    for (const VoronoiFacet& f : cell.facets) {
      ASSERT_TRUE(std::isfinite(f.area));
      EXPECT_GE(f.area, 0);
      area_sum += f.area;
      double n2 = 0;
      for (int c = 0; c < d; ++c) {
        flux[c] += f.area * f.normal[c];
        n2 += f.normal[c] * f.normal[c];
      }
      EXPECT_NEAR(n2, 1.0, 1e-14);
      if (f.is_wall()) {
        if (wall_areas) wall_sum[f.wall()] += f.area;
      } else {
        facets[{cell.seed, f.neighbor}] = &f;
      }
      if (d == 3 && f.vertices.size() >= 3) {
        double newell[3] = {0, 0, 0};
        for (std::size_t i = 0; i < f.vertices.size(); ++i) {
          const double* a = &cell.vertices[3 * f.vertices[i]];
          const double* b = &cell.vertices[3 * f.vertices[(i + 1) % f.vertices.size()]];
          for (int c = 0; c < 3; ++c) {
            const int c1 = (c + 1) % 3, c2 = (c + 2) % 3;
            newell[c] += 0.5 * (a[c1] - b[c1]) * (a[c2] + b[c2]);
          }
        }
        for (int c = 0; c < 3; ++c) {
          EXPECT_NEAR(newell[c], f.area * f.normal[c], 1e-9 * scale * scale) << "facet " << f.neighbor;
        }
      }
    }
    for (int c = 0; c < d; ++c) EXPECT_NEAR(flux[c], 0.0, 1e-11 * std::max(area_sum, 1e-300)) << "coordinate " << c;
  }
  EXPECT_NEAR(total, volume, 1e-12 * volume);
  for (int c = 0; c < d; ++c) EXPECT_NEAR(moment[c] / total, centroid[c], 1e-11 * scale);
  for (const auto& [key, f] : facets) {
    const auto other = facets.find({key.second, key.first});
    ASSERT_NE(other, facets.end()) << "facet " << key.first << " -> " << key.second << " has no partner";
    const VoronoiFacet& g = *other->second;
    EXPECT_NEAR(f->area, g.area, 1e-11 * std::pow(scale, d - 1)) << key.first << " <-> " << key.second;
    for (int c = 0; c < d; ++c) EXPECT_NEAR(f->normal[c], -g.normal[c], 1e-14);
  }
  if (wall_areas) {
    for (std::size_t k = 0; k < wall_sum.size(); ++k) {
      EXPECT_NEAR(wall_sum[k], (*wall_areas)[k], 1e-12 * (*wall_areas)[k]) << "wall " << k;
    }
  }
}

// The box's volume, centroid and wall areas.
void check_box_tiling(const PointSet& ps, const Domain& box) {
  const int d = ps.dimension();
  const std::vector<double> lo = box.lower(), hi = box.upper();
  double volume = 1;
  std::vector<double> centroid(d), walls(2 * d);
  for (int c = 0; c < d; ++c) {
    volume *= hi[c] - lo[c];
    centroid[c] = 0.5 * (lo[c] + hi[c]);
  }
  for (int c = 0; c < d; ++c) walls[c] = walls[d + c] = volume / (hi[c] - lo[c]);
  for_both_routes(ps, box,
                  [&](const std::vector<VoronoiCell>& cells) { check_tiling(ps, cells, volume, centroid, &walls); });
}

int max_dimension() { return std::getenv("SPOKEMESH_HIGH_D") ? 8 : 6; }

std::size_t points_for(int d) {
  switch (d) {
    case 2:
      return 400;
    case 3:
      return 200;
    case 4:
      return 80;
    case 5:
      return 40;
    case 6:
      return 25;
    default:
      return 18;
  }
}

TEST(ClippedCells, UniformPointsTileTheUnitBox) {
  for (int d = 2; d <= max_dimension(); ++d) {
    SCOPED_TRACE("d " + std::to_string(d) + ", seed " + std::to_string(100 + d));
    const PointSet ps = make_points(d, uniform_points(d, points_for(d), 100 + d));
    check_box_tiling(ps, Domain::box(std::vector<double>(d, 0.0), std::vector<double>(d, 1.0)).value());
  }
}

TEST(ClippedCells, BoundingBoxHasSeedsOnItsWalls) {
  // The default domain passes through the extreme points: seeds on walls.
  for (int d = 2; d <= std::min(5, max_dimension()); ++d) {
    SCOPED_TRACE("d " + std::to_string(d));
    const PointSet ps = make_points(d, uniform_points(d, points_for(d), 200 + d));
    check_box_tiling(ps, Domain::bounding_box(ps));
  }
}

TEST(ClippedCells, GridsInTheirBoundingBoxAreUnitCellsAndFractions) {
  // Cospherical everywhere, walls through seeds and along Voronoi facets, rays
  // parallel to walls: every tie the clipping has.
  for (int d = 2; d <= 4; ++d) {
    SCOPED_TRACE("d " + std::to_string(d));
    const int side = d == 2 ? 6 : d == 3 ? 4 : 3;
    const PointSet ps = make_points(d, grid_points(d, side));
    const Domain box = Domain::bounding_box(ps);
    for_both_routes(ps, box, [&](const std::vector<VoronoiCell>& cells) {
      for (const VoronoiCell& cell : cells) {
        // A grid point's cell is the product of [x - 1/2, x + 1/2] cut to [0, side - 1].
        double expected = 1;
        for (int c = 0; c < d; ++c) {
          const double x = ps.point(cell.seed)[c];
          expected *= (x == 0 || x == side - 1) ? 0.5 : 1.0;
        }
        EXPECT_NEAR(cell.volume, expected, 1e-14) << "seed " << cell.seed;
      }
      std::vector<double> centroid(d, 0.5 * (side - 1)), walls(2 * d, std::pow(side - 1.0, d - 1));
      check_tiling(ps, cells, std::pow(side - 1.0, d), centroid, &walls);
    });
  }
}

// The two routes give the same cell: the same facets (neighbours and walls, decided
// exactly), and measures that agree to rounding. Random points take the direct route
// throughout; grids tie everywhere and go to the star, so there they are identical.
// `relative`: the measures' tolerance relative to the cell's size (coordinates far
// from the origin keep fewer digits of a small cell, in both routes).
void expect_same_cells(const std::vector<VoronoiCell>& a, const std::vector<VoronoiCell>& b, double relative = 1e-11) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    SCOPED_TRACE("seed " + std::to_string(a[i].seed));
    ASSERT_EQ(a[i].facets.size(), b[i].facets.size());
    const double scale = std::pow(std::max(a[i].volume, 1e-300), 1.0 / a[i].dimension);
    EXPECT_NEAR(a[i].volume, b[i].volume, relative * a[i].volume);
    for (int c = 0; c < a[i].dimension; ++c) {
      EXPECT_NEAR(a[i].centroid[c], b[i].centroid[c], relative * scale + 4 * std::abs(a[i].centroid[c]) * 1.2e-16);
    }
    for (std::size_t k = 0; k < a[i].facets.size(); ++k) {
      const VoronoiFacet& f = a[i].facets[k];
      const VoronoiFacet& g = b[i].facets[k];
      ASSERT_EQ(f.neighbor, g.neighbor) << "facet " << k;
      EXPECT_EQ(f.vertices.size(), g.vertices.size()) << "facet " << k;
      EXPECT_NEAR(f.area, g.area, 10 * relative * std::pow(scale, a[i].dimension - 1)) << "facet " << k;
    }
  }
}

TEST(ClippedCellBuilder, DirectRouteEqualsTheStarsRoute) {
  for (int d = 2; d <= 5; ++d) {
    for (const bool bounding : {false, true}) {
      const std::uint64_t seed = 300 + d + (bounding ? 50 : 0);
      SCOPED_TRACE("d " + std::to_string(d) + ", seed " + std::to_string(seed) + (bounding ? ", bounding box" : ""));
      const PointSet ps = make_points(d, uniform_points(d, points_for(d) * 2, seed));
      const Domain box = bounding ? Domain::bounding_box(ps)
                                  : Domain::box(std::vector<double>(d, -0.25), std::vector<double>(d, 1.5)).value();
      std::uint64_t fallbacks = 0, generic = 0;
      const std::vector<VoronoiCell> direct = builder_cells(ps, box, &fallbacks, &generic);
      if (bounding) {
        EXPECT_EQ(fallbacks, 0u) << "random points in general position never tie";
      } else {
        // In a box far larger than the set, the cells of seeds near the hull reach deep
        // into the empty margin; past 256 candidates they go to the star (cells.cpp).
        EXPECT_LT(fallbacks, ps.size() / 4);
      }
      EXPECT_EQ(generic, 0u) << "the specialised 3-d cell certifies every decision on random points";
      expect_same_cells(direct, star_cells(ps, box));
    }
  }
}

// What spokemesh-mpi relies on: a builder over a subset of the points that holds every
// point within last_reach2 of the seed builds the whole set's cell bit for bit (3-d
// direct route; the star route is certified by StarCertifier). Uniform points and an
// integer grid (equal distances everywhere, whose order must not depend on the tree).
TEST(ClippedCellBuilder, TheReachNamesEverythingThatDecidedTheCell) {
  for (const bool grid : {false, true}) {
    SCOPED_TRACE(grid ? "3-d integer grid 14^3" : "3-d uniform 6000, seed 77");
    const PointSet all = make_points(3, grid ? grid_points(3, 14) : uniform_points(3, 6000, 77));
    const Domain box = Domain::bounding_box(all);
    const KdTree all_tree(all);
    ClippedCellBuilder whole(all_tree, box);
    std::mt19937_64 rng(78);
    std::size_t direct = 0;
    for (int trial = 0; trial < 60; ++trial) {
      const auto seed = static_cast<std::uint32_t>(rng() % all.size());
      VoronoiCell truth;
      ASSERT_TRUE(whole.cell(seed, truth).is_ok());
      if (whole.last_star() != nullptr) continue;
      ++direct;
      const double reach2 = whole.last_reach2();
      ASSERT_GT(reach2, 0);
      // The points within reach (with a margin over nanoflann's rounding), and every
      // fifth other point, in index order.
      std::vector<double> sub;
      std::vector<std::uint32_t> global;
      std::uint32_t mine = 0;
      for (std::uint32_t i = 0; i < all.size(); ++i) {
        double d2 = 0;
        for (int c = 0; c < 3; ++c)
          d2 += (all.point(i)[c] - all.point(seed)[c]) * (all.point(i)[c] - all.point(seed)[c]);
        if (d2 > reach2 * (1 + 1e-8) && i % 5 != 0) continue;
        if (i == seed) mine = static_cast<std::uint32_t>(global.size());
        sub.insert(sub.end(), all.point(i), all.point(i) + 3);
        global.push_back(i);
      }
      const PointSet part = make_points(3, sub);
      const KdTree part_tree(part);
      ClippedCellBuilder builder(part_tree, box);
      VoronoiCell cell;
      ASSERT_TRUE(builder.cell(mine, cell).is_ok());
      EXPECT_EQ(builder.last_star(), nullptr) << "seed " << seed;
      EXPECT_EQ(std::memcmp(&cell.volume, &truth.volume, sizeof(double)), 0) << "seed " << seed;
      ASSERT_EQ(cell.centroid.size(), truth.centroid.size());
      EXPECT_EQ(std::memcmp(cell.centroid.data(), truth.centroid.data(), 3 * sizeof(double)), 0) << "seed " << seed;
      ASSERT_EQ(cell.facets.size(), truth.facets.size()) << "seed " << seed;
      for (std::size_t f = 0; f < cell.facets.size(); ++f) {
        const VoronoiFacet& a = cell.facets[f];
        const VoronoiFacet& b = truth.facets[f];
        EXPECT_EQ(a.is_wall() ? a.neighbor : static_cast<std::int64_t>(global[static_cast<std::size_t>(a.neighbor)]),
                  b.neighbor);
        EXPECT_EQ(std::memcmp(&a.area, &b.area, sizeof(double)), 0) << "seed " << seed << " facet " << f;
        EXPECT_EQ(std::memcmp(a.normal.data(), b.normal.data(), 3 * sizeof(double)), 0) << "seed " << seed;
      }
    }
    if (!grid) {
      EXPECT_EQ(direct, 60u) << "uniform points are built directly";
    }
  }
}

TEST(ClippedCellBuilder, TiesFollowThePerturbationAndNearTiesStayExact) {
  // A grid ties at every Voronoi vertex; the same grid jittered by 1e-9 ties nowhere,
  // but every decision there is within rounding of a tie: the filters must defer to
  // exact arithmetic, and the cells must still be the stars' cells. In 3-d the direct
  // route decides ties itself by the star's perturbation (walls through the seed
  // included), so the grid's cells, zero-area facets and all, are the star's without
  // a fallback. In other dimensions ties go to the star.
  for (int d = 2; d <= 4; ++d) {
    SCOPED_TRACE("d " + std::to_string(d));
    const int side = d == 2 ? 7 : d == 3 ? 5 : 3;
    std::vector<double> grid = grid_points(d, side);
    const PointSet exact_grid = make_points(d, grid);
    const Domain box = Domain::bounding_box(exact_grid);
    std::uint64_t fallbacks = 0;
    const std::vector<VoronoiCell> tied = builder_cells(exact_grid, box, &fallbacks);
    if (d == 3) {
      EXPECT_EQ(fallbacks, 0u);
      // Walls through Voronoi vertices (halfway between grid planes) and walls beyond
      // the grid, which the grid's axis-parallel Voronoi edges meet at tied vertices.
      for (const double lo : {-0.5, -0.75}) {
        SCOPED_TRACE("box from " + std::to_string(lo));
        const Domain walls = Domain::box(std::vector<double>(d, lo), std::vector<double>(d, side - 1 - lo)).value();
        std::uint64_t wall_fallbacks = 0;
        expect_same_cells(builder_cells(exact_grid, walls, &wall_fallbacks), star_cells(exact_grid, walls));
        EXPECT_EQ(wall_fallbacks, 0u);
      }
    } else {
      EXPECT_GT(fallbacks, 0u);
    }
    expect_same_cells(tied, star_cells(exact_grid, box));
    std::mt19937_64 rng(4242 + d);
    std::uniform_real_distribution<double> jitter(-1e-9, 1e-9);
    for (double& v : grid) v += jitter(rng);
    const PointSet jittered = make_points(d, grid);
    const Domain big = Domain::box(std::vector<double>(d, -1.0), std::vector<double>(d, side + 0.0)).value();
    expect_same_cells(builder_cells(jittered, big), star_cells(jittered, big));
    if (d == 3) {
      // Jittered by a few ulps: the specialised 3-d cell's bounds cannot certify these
      // decisions; it decides them exactly itself (4-d's jittered grid above is where
      // the generic polytope's exact arithmetic decides near-ties).
      std::vector<double> close = grid_points(d, side);
      std::uniform_real_distribution<double> ulps(-2e-15, 2e-15);
      for (double& v : close) v += ulps(rng);
      const PointSet nearly = make_points(d, close);
      std::uint64_t generic = 0;
      const std::vector<VoronoiCell> cells = builder_cells(nearly, big, nullptr, &generic);
      EXPECT_EQ(generic, 0u);
      expect_same_cells(cells, star_cells(nearly, big));
    }
  }
}

TEST(ClippedCellBuilder, TinyCellsFarFromTheOriginStayExact) {
  // A 3-d lattice of spacing 1e-3 jittered by 2e-9 (a few ulps of its coordinates), a
  // million units from the origin: coordinates keep about 7 digits of the cell's size,
  // so nearly every decision is within a few ulps of a tie and left to the filters'
  // bounds and the exact fallback. Also points rounded onto a sphere with its centre,
  // in a box that cuts their cells.
  const int d = 3;
  std::vector<double> lattice = grid_points(d, 5);
  std::mt19937_64 rng(977);
  std::uniform_real_distribution<double> jitter(-2e-9, 2e-9);
  for (double& v : lattice) v = 1e6 + v * 1e-3 + jitter(rng);
  const PointSet far = make_points(d, lattice);
  const Domain box = Domain::box({1e6 - 1e-3, 1e6 - 1e-3, 1e6 - 1e-3}, {1e6 + 5e-3, 1e6 + 5e-3, 1e6 + 5e-3}).value();
  std::uint64_t fallbacks = 0;
  const std::vector<VoronoiCell> direct = builder_cells(far, box, &fallbacks);
  EXPECT_LT(fallbacks, far.size() / 2) << "the jitter breaks the lattice's ties";
  // Facets identical (exact); measures to the coordinates' precision: an ulp of 1e6 is
  // 1.2e-7 of the spacing.
  expect_same_cells(direct, star_cells(far, box), 1e-5);

  std::vector<double> sphere = {0, 0, 0};
  std::uniform_real_distribution<double> u(-1, 1);
  while (sphere.size() < 3 * 60) {
    double p[3] = {u(rng), u(rng), u(rng)};
    const double r = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
    if (r < 0.1) continue;
    for (double c : p) sphere.push_back(c / r);  // rounded onto the unit sphere
  }
  const PointSet cospherical = make_points(d, sphere);
  const Domain cut = Domain::box({-1.2, -1.2, -1.2}, {1.2, 1.2, 1.2}).value();
  expect_same_cells(builder_cells(cospherical, cut), star_cells(cospherical, cut));
}

TEST(ClippedCells, HalfspaceDomainsTileTheirPolytope) {
  // A cube rotated about (1, 1, 1) / sqrt 3 and a 2-d hexagon: general walls.
  {
    const int d = 2;
    std::vector<double> normals, offsets;
    for (int k = 0; k < 6; ++k) {
      const double t = k * M_PI / 3 + 0.1;
      normals.insert(normals.end(), {std::cos(t), std::sin(t)});
      offsets.push_back(normals[2 * k] * 0.5 + normals[2 * k + 1] * 0.5 + 0.45);
    }
    const Domain hexagon = Domain::halfspaces(d, normals, offsets).value();
    // Points inside the hexagon (apothem 0.45 around (0.5, 0.5)).
    std::vector<double> inside;
    for (std::size_t i = 0; inside.size() < 2 * 300; ++i) {
      const std::vector<double> p = uniform_points(2, 1, 300 + i);
      if (!hexagon.violated_wall(p.data())) inside.insert(inside.end(), p.begin(), p.end());
    }
    const PointSet ps = make_points(d, inside);
    const double volume = 6 * 0.45 * 0.45 * std::tan(M_PI / 6);
    check_tiling(ps, builder_cells(ps, hexagon), volume, {0.5, 0.5}, nullptr);
  }
  {
    const int d = 3;
    const double a = 0.3, c = std::cos(a), s = std::sin(a), t = 1 - c;
    const double u[3] = {1 / std::sqrt(3.0), 1 / std::sqrt(3.0), 1 / std::sqrt(3.0)};
    double r[3][3];  // rotation by a about u (Rodrigues)
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) r[i][j] = t * u[i] * u[j] + (i == j ? c : 0);
    r[0][1] -= s * u[2], r[0][2] += s * u[1], r[1][0] += s * u[2];
    r[1][2] -= s * u[0], r[2][0] -= s * u[1], r[2][1] += s * u[0];
    std::vector<double> normals, offsets;
    for (int k = 0; k < 3; ++k) {
      for (const double sign : {1.0, -1.0}) {
        for (int i = 0; i < 3; ++i) normals.push_back(sign * r[i][k]);
        offsets.push_back(0.4 + sign * (r[0][k] + r[1][k] + r[2][k]) * 0.5);  // centred at (.5,.5,.5), half side .4
      }
    }
    const Domain cube = Domain::halfspaces(d, normals, offsets).value();
    std::vector<double> inside;
    for (std::size_t i = 0; inside.size() < 3 * 150; ++i) {
      const std::vector<double> p = uniform_points(3, 1, 500 + i);
      if (!cube.violated_wall(p.data())) inside.insert(inside.end(), p.begin(), p.end());
    }
    const PointSet ps = make_points(d, inside);
    check_tiling(ps, builder_cells(ps, cube), 0.8 * 0.8 * 0.8, {0.5, 0.5, 0.5}, nullptr);
  }
}

TEST(ClippedCells, SeedsOutsideTheDomainAreNamed) {
  const PointSet ps = make_points(2, uniform_points(2, 50, 7));
  const KdTree tree(ps);
  StarWalker walker(tree);
  Star star;
  const Domain small = Domain::box({0.0, 0.0}, {0.5, 0.5}).value();
  int outside = 0;
  for (std::uint32_t s = 0; s < ps.size(); ++s) {
    ASSERT_TRUE(walker.compute(s, star).is_ok());
    const auto cell = voronoi_cell(ps, star, small);
    if (ps.point(s)[0] <= 0.5 && ps.point(s)[1] <= 0.5) {
      EXPECT_TRUE(cell.is_ok());
      continue;
    }
    ++outside;
    ASSERT_FALSE(cell.is_ok());
    EXPECT_EQ(cell.status().code(), Code::kInvalidArgument);
    EXPECT_NE(cell.status().message().find("seed " + std::to_string(s) + " lies outside the domain"), std::string::npos)
        << cell.status().message();
  }
  EXPECT_GT(outside, 20);
  EXPECT_FALSE(Domain::box({0.0, 1.0}, {1.0, 0.0}).is_ok());
  EXPECT_FALSE(Domain::parse_box("0,0,1").is_ok());
  EXPECT_FALSE(Domain::parse_box("0,x,1,1").is_ok());
  EXPECT_TRUE(Domain::parse_box("0,0,1,1").is_ok());
  EXPECT_FALSE(Domain::halfspaces(2, {0.0, 0.0}, {1.0}).is_ok());
}

// compute_cells visits each round's seeds in the tree's leaf order, split among the
// threads, and hands them over in seed order: the same bytes whatever the threads and
// block size, and the same error (the lowest seed outside the domain).
TEST(ComputeCells, ThreadsAndBlocksChangeNothing) {
  for (const int d : {2, 3}) {
    SCOPED_TRACE("d " + std::to_string(d));
    const PointSet ps = make_points(d, uniform_points(d, 700, 60 + d));
    const KdTree tree(ps);
    const Domain box = Domain::box(std::vector<double>(d, 0.0), std::vector<double>(d, 1.0)).value();
    auto run = [&](unsigned threads, std::uint32_t block, bool measures_only) {
      CellsOptions options;
      options.threads = threads;
      options.block_size = block;
      options.measures_only = measures_only;
      std::vector<VoronoiCell> all;
      std::uint64_t reported = 0;
      const Status st = compute_cells(tree, &box, options, [&](std::span<const VoronoiCell> cells, std::uint64_t done) {
        for (const VoronoiCell& c : cells) {
          EXPECT_EQ(c.seed, all.size());
          all.push_back(c);
        }
        EXPECT_EQ(done, all.size());
        reported = done;
        return Status::ok();
      });
      EXPECT_TRUE(st.is_ok()) << st.message();
      EXPECT_EQ(reported, ps.size());
      return all;
    };
    const std::vector<VoronoiCell> one = run(1, 5000, false);
    for (const auto& [threads, block] : {std::pair{2u, 7u}, std::pair{3u, 64u}, std::pair{2u, 1u}}) {
      SCOPED_TRACE(std::to_string(threads) + " threads, blocks of " + std::to_string(block));
      const std::vector<VoronoiCell> other = run(threads, block, false);
      ASSERT_EQ(one.size(), other.size());
      for (std::size_t i = 0; i < one.size(); ++i) {
        ASSERT_EQ(one[i].vertices, other[i].vertices) << "seed " << i;
        ASSERT_EQ(one[i].volume, other[i].volume) << "seed " << i;
        ASSERT_EQ(one[i].centroid, other[i].centroid) << "seed " << i;
        ASSERT_EQ(one[i].facets.size(), other[i].facets.size()) << "seed " << i;
        for (std::size_t k = 0; k < one[i].facets.size(); ++k) {
          EXPECT_EQ(one[i].facets[k].neighbor, other[i].facets[k].neighbor);
          EXPECT_EQ(one[i].facets[k].area, other[i].facets[k].area);
          EXPECT_EQ(one[i].facets[k].normal, other[i].facets[k].normal);
          EXPECT_EQ(one[i].facets[k].vertices, other[i].facets[k].vertices);
        }
      }
      const std::vector<VoronoiCell> measures = run(threads, block, true);
      for (std::size_t i = 0; i < one.size(); ++i) {
        EXPECT_TRUE(measures[i].vertices.empty());
        ASSERT_EQ(one[i].volume, measures[i].volume) << "seed " << i;
        ASSERT_EQ(one[i].facets.size(), measures[i].facets.size()) << "seed " << i;
      }
    }
    // Seeds outside a smaller box: the lowest one is named, whatever the threads.
    const Domain half = Domain::box(std::vector<double>(d, 0.0), std::vector<double>(d, 0.6)).value();
    std::uint32_t first_outside = 0;
    while (!half.violated_wall(ps.point(first_outside))) ++first_outside;
    for (const unsigned threads : {1u, 2u, 3u}) {
      CellsOptions options;
      options.threads = threads;
      options.block_size = 256;
      const Status st =
          compute_cells(tree, &half, options, [](std::span<const VoronoiCell>, std::uint64_t) { return Status::ok(); });
      EXPECT_EQ(st.code(), Code::kInvalidArgument);
      EXPECT_NE(st.message().find("seed " + std::to_string(first_outside) + " lies outside"), std::string::npos)
          << st.message();
    }
  }
}

// Every field of two runs' cells equal, bit for bit.
void expect_identical_cells(const std::vector<VoronoiCell>& a, const std::vector<VoronoiCell>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].vertices, b[i].vertices) << "seed " << i;
    ASSERT_EQ(a[i].vertex_simplices, b[i].vertex_simplices) << "seed " << i;
    ASSERT_EQ(a[i].volume, b[i].volume) << "seed " << i;
    ASSERT_EQ(a[i].centroid, b[i].centroid) << "seed " << i;
    ASSERT_EQ(a[i].bounded, b[i].bounded) << "seed " << i;
    ASSERT_EQ(a[i].facets.size(), b[i].facets.size()) << "seed " << i;
    for (std::size_t k = 0; k < a[i].facets.size(); ++k) {
      ASSERT_EQ(a[i].facets[k].neighbor, b[i].facets[k].neighbor) << "seed " << i;
      ASSERT_EQ(a[i].facets[k].area, b[i].facets[k].area) << "seed " << i;
      ASSERT_EQ(a[i].facets[k].normal, b[i].facets[k].normal) << "seed " << i;
      ASSERT_EQ(a[i].facets[k].vertices, b[i].facets[k].vertices) << "seed " << i;
    }
  }
}

// Cells whose stars come from the triangulation of every point (CellsOptions::stars)
// equal the cells of walked stars, every measure and every facet: on the shape
// families (surfaces, scans, contours), on grids (ties everywhere) and uniform points;
// in the bounding box (the direct route, with the seeds it would give up on sent
// straight to their stars), in halfspaces (stars only), and unclipped.
TEST(ComputeCells, StarsFromTheTriangulationGiveTheWalkedCells) {
  struct Case {
    std::string name;
    int d;
    std::vector<double> coords;
  };
  std::vector<Case> all = {{"uniform-2d", 2, uniform_points(2, 800, 71)},
                           {"uniform-3d", 3, uniform_points(3, 800, 72)},
                           {"grid-2d", 2, grid_points(2, 20)},
                           {"grid-3d", 3, grid_points(3, 7)}};
  for (auto& shape : bench::shape_families(700, 73)) all.push_back({shape.name, shape.d, std::move(shape.coords)});
  for (const Case& c : all) {
    SCOPED_TRACE(c.name);
    const PointSet ps = make_points(c.d, c.coords);
    const KdTree tree(ps);
    std::vector<double> lo(ps.point(0), ps.point(0) + c.d), hi = lo;
    for (std::size_t i = 0; i < ps.size(); ++i) {
      for (int k = 0; k < c.d; ++k) {
        lo[static_cast<std::size_t>(k)] = std::min(lo[static_cast<std::size_t>(k)], ps.point(i)[k]);
        hi[static_cast<std::size_t>(k)] = std::max(hi[static_cast<std::size_t>(k)], ps.point(i)[k]);
      }
    }
    const Domain box = Domain::box(lo, hi).value();
    std::vector<double> normals, offsets;  // the same box as halfspaces: the stars' route
    for (int k = 0; k < c.d; ++k) {
      for (const double sign : {-1.0, 1.0}) {
        for (int j = 0; j < c.d; ++j) normals.push_back(j == k ? sign : 0.0);
        offsets.push_back(sign < 0 ? -lo[static_cast<std::size_t>(k)] : hi[static_cast<std::size_t>(k)]);
      }
    }
    const Domain walls = Domain::halfspaces(c.d, normals, offsets).value();
    for (const Domain* domain : {&box, &walls, static_cast<const Domain*>(nullptr)}) {
      SCOPED_TRACE(domain == nullptr ? "unclipped" : domain == &box ? "box" : "halfspaces");
      auto run = [&](MeshEngine stars, bool* built) {
        CellsOptions options;
        options.threads = 2;
        options.stars = stars;
        options.keep_whole = [&](std::shared_ptr<const WholeTriangulation>) { *built = true; };
        std::vector<VoronoiCell> out;
        const Status st = compute_cells(tree, domain, options, [&](std::span<const VoronoiCell> cells, std::uint64_t) {
          out.insert(out.end(), cells.begin(), cells.end());
          return Status::ok();
        });
        EXPECT_TRUE(st.is_ok()) << st.message();
        return out;
      };
      bool walked_built = false, triangulated_built = false;
      const std::vector<VoronoiCell> walked = run(MeshEngine::kStars, &walked_built);
      const std::vector<VoronoiCell> triangulated = run(MeshEngine::kTriangulations, &triangulated_built);
      EXPECT_FALSE(walked_built);
      EXPECT_TRUE(triangulated_built);
      expect_identical_cells(walked, triangulated);
    }
  }
}

TEST(ClippedCells, AnUnboundedHalfspaceDomainLeavesCellsUnbounded) {
  const PointSet ps = make_points(2, uniform_points(2, 60, 8));
  const Domain half = Domain::halfspaces(2, {1.0, 0.0}, {2.0}).value();  // x <= 2
  const std::vector<VoronoiCell> cells = builder_cells(ps, half);
  int unbounded = 0;
  for (const VoronoiCell& cell : cells) {
    if (cell.bounded) continue;
    ++unbounded;
    EXPECT_TRUE(std::isinf(cell.volume));
    EXPECT_TRUE(cell.centroid.empty());
  }
  EXPECT_GT(unbounded, 3);
}

TEST(UnclippedCells, FacetMeasuresObeyTheDivergenceTheorem) {
  for (int d = 2; d <= 5; ++d) {
    const PointSet ps = make_points(d, uniform_points(d, points_for(d), 400 + d));
    const KdTree tree(ps);
    StarWalker walker(tree);
    Star star;
    int bounded = 0;
    for (std::uint32_t s = 0; s < ps.size(); ++s) {
      ASSERT_TRUE(walker.compute(s, star).is_ok());
      const VoronoiCell cell = voronoi_cell(ps, star);
      if (!cell.bounded) {
        EXPECT_TRUE(std::any_of(cell.facets.begin(), cell.facets.end(),
                                [](const VoronoiFacet& f) { return std::isinf(f.area); }));
        continue;
      }
      ++bounded;
      std::vector<double> flux(d, 0.0);
      double area = 0;
      for (const VoronoiFacet& f : cell.facets) {
        area += f.area;
        for (int c = 0; c < d; ++c) flux[c] += f.area * f.normal[c];
      }
      for (int c = 0; c < d; ++c) EXPECT_NEAR(flux[c], 0.0, 1e-11 * area) << "d " << d << ", seed " << s;
    }
    EXPECT_GT(bounded, 0) << "d " << d;
  }
}

}  // namespace
}  // namespace spokemesh
