// spokemesh interpolate: values at any point, from a point file and a value per point
// (natural neighbours, linear on the Delaunay triangulation, or the nearest point),
// at the points of a query file or of a 2-d raster (--grid). Exit codes as the other
// commands (0 done, 2 usage, 1 bad input or failure, naming the file and line).
#include "interpolate.hpp"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "spokemesh/io.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/locate.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/natural_neighbors.hpp"
#include "spokemesh/space_split.hpp"
#include "spokemesh/voronoi_diagram.hpp"

namespace spokemesh::cli {
namespace {

struct Grid {
  double x0 = 0, y0 = 0, x1 = 0, y1 = 0;
  std::uint64_t nx = 0, ny = 0;
};

Result<Grid> parse_grid(const std::string& text) {
  Grid g;
  char tail = 0;
  unsigned long long nx = 0, ny = 0;
  if (std::sscanf(text.c_str(), "%lf,%lf,%lf,%lf,%llu,%llu%c", &g.x0, &g.y0, &g.x1, &g.y1, &nx, &ny, &tail) != 6) {
    return invalid_argument("--grid " + text + ": expected X0,Y0,X1,Y1,NX,NY (the raster's corners and its size)");
  }
  g.nx = nx;
  g.ny = ny;
  if (!(std::isfinite(g.x0) && std::isfinite(g.y0) && std::isfinite(g.x1) && std::isfinite(g.y1))) {
    return invalid_argument("--grid " + text + ": corners must be finite");
  }
  if (g.nx < 1 || g.ny < 1 || g.nx * g.ny > (std::uint64_t{1} << 31)) {
    return invalid_argument("--grid " + text + ": NX and NY must be at least 1, NX * NY at most 2^31");
  }
  return g;
}

// The value file's extension decides the output: .npy (float64; a grid's shape (NY, NX),
// row j at y0 + j (y1 - y0) / (NY - 1)) or text (one value a line, 17 digits; NaN
// outside the hull). Written beside the target and renamed into place.
Status write_values(const std::string& path, const std::vector<double>& values, const Grid* grid) {
  const bool npy = path.size() >= 4 && path.compare(path.size() - 4, 4, ".npy") == 0;
  const std::string temp = path + ".partial-" + std::to_string(::getpid());
  std::FILE* f = std::fopen(temp.c_str(), "wb");
  if (f == nullptr) return invalid_argument("-o " + path + ": cannot write here");
  bool ok = true;
  if (npy) {
    const std::string header =
        grid != nullptr ? npy_header_of_shape("<f8", std::to_string(grid->ny) + ", " + std::to_string(grid->nx))
                        : npy_vector_header("<f8", values.size());
    ok = std::fwrite(header.data(), 1, header.size(), f) == header.size() &&
         std::fwrite(values.data(), sizeof(double), values.size(), f) == values.size();
  } else {
    char line[40];
    for (const double v : values) {
      const int len =
          std::isnan(v) ? std::snprintf(line, sizeof line, "nan\n") : std::snprintf(line, sizeof line, "%.17g\n", v);
      if (std::fwrite(line, 1, static_cast<std::size_t>(len), f) != static_cast<std::size_t>(len)) {
        ok = false;
        break;
      }
    }
  }
  ok = std::fflush(f) == 0 && ok;
  ok = std::fclose(f) == 0 && ok;
  if (!ok || std::rename(temp.c_str(), path.c_str()) != 0) {
    std::remove(temp.c_str());
    return internal_error("-o " + path + ": writing failed (disk full?)");
  }
  return Status::ok();
}

}  // namespace

int run_interpolate(const InterpolateFlags& flags) {
  const std::string& method = flags.method;
  auto points_or = read_points(flags.points);
  if (!points_or.is_ok()) return report(points_or.status());
  PointSet points = std::move(points_or).value();
  const int d = points.dimension();
  if (method == "natural" && d != 2 && d != 3) {
    return report(invalid_argument(flags.points + ": dimension " + std::to_string(d) +
                                   " is not supported by --method natural (2-d and 3-d); use --method linear"));
  }
  if (Status s = points.validate(flags.points); !s.is_ok()) return report(s);
  auto values_or = read_weights(flags.values, points.size(), WeightKind::kValue);
  if (!values_or.is_ok()) return report(values_or.status());
  const std::vector<double> values = std::move(values_or).value();

  // The queries: a file's points, or a raster's.
  std::vector<double> queries;
  Grid grid;
  const bool gridded = !flags.grid.empty();
  if (gridded) {
    if (!flags.queries.empty()) return report(invalid_argument("give QUERIES or --grid, not both"));
    if (d != 2)
      return report(
          invalid_argument("--grid: a raster of 2-d points; " + flags.points + " is " + std::to_string(d) + "-d"));
    auto g = parse_grid(flags.grid);
    if (!g.is_ok()) return report(g.status());
    grid = g.value();
    queries.reserve(grid.nx * grid.ny * 2);
    for (std::uint64_t j = 0; j < grid.ny; ++j) {
      for (std::uint64_t i = 0; i < grid.nx; ++i) {
        queries.push_back(grid.nx == 1 ? grid.x0
                                       : grid.x0 + (grid.x1 - grid.x0) * static_cast<double>(i) /
                                                       static_cast<double>(grid.nx - 1));
        queries.push_back(grid.ny == 1 ? grid.y0
                                       : grid.y0 + (grid.y1 - grid.y0) * static_cast<double>(j) /
                                                       static_cast<double>(grid.ny - 1));
      }
    }
  } else {
    if (flags.queries.empty())
      return report(invalid_argument("give QUERIES (a point file) or --grid X0,Y0,X1,Y1,NX,NY"));
    auto q = read_points(flags.queries);
    if (!q.is_ok()) return report(q.status());
    if (q.value().dimension() != d) {
      return report(invalid_argument(flags.queries + ": " + std::to_string(q.value().dimension()) + "-d queries for " +
                                     std::to_string(d) + "-d points"));
    }
    queries.assign(q.value().coordinates().begin(), q.value().coordinates().end());
  }
  const std::size_t m = queries.size() / static_cast<std::size_t>(d);
  std::vector<double> out(m, flags.fill);
  KdTree tree(points);
  Progress progress(flags.quiet, m, "interpolating");
  if (method == "nearest") {
    for (std::size_t i = 0; i < m; ++i) {
      std::uint32_t id;
      double dist2;
      if (tree.knn(&queries[i * d], 1, &id, &dist2) == 1) out[i] = values[id];
      if (i % 65536 == 0) progress.update(i, 0);
    }
  } else {
    // The whole Delaunay mesh, its adjacency, and each query located by the exact walk.
    SpaceSplit split(points, SpaceSplit::default_block_points(d, points.size()));
    MeshOptions options;
    options.split = &split;
    options.threads = flags.threads;
    std::vector<std::uint32_t> simplices;
    auto meshed = mesh_seeds(tree, options, [&](std::span<const std::uint32_t> block, std::uint64_t) {
      simplices.insert(simplices.end(), block.begin(), block.end());
      return Status::ok();
    });
    if (!meshed.is_ok()) return report(meshed.status());
    const std::vector<std::int32_t> adjacency = simplex_adjacency(simplices, d, flags.threads);
    const SimplexLocator locator(points, simplices, adjacency, tree);
    const DelaunayArrays arrays{&points, simplices, adjacency};
    std::vector<NaturalCoordinates> scratch((m + 255) / 256);
    std::vector<std::string> errors(scratch.size());
    std::atomic<std::size_t> done{0};
    locator.locate_many(queries.data(), m, flags.threads, [&](std::size_t run, std::size_t i, std::int32_t s) {
      const double* x = &queries[i * d];
      if (s < 0) return;  // outside the hull: the fill value
      if (method == "natural") {
        NaturalCoordinates& nn = scratch[run];
        if (Status st = natural_neighbors(arrays, s, x, nn); !st.is_ok()) {
          if (errors[run].empty()) errors[run] = "query " + std::to_string(i) + ": " + st.message();
          return;
        }
        double v = 0;
        for (std::size_t k = 0; k < nn.neighbors.size(); ++k) v += nn.weights[k] * values[nn.neighbors[k]];
        out[i] = v;
      } else {
        // Barycentric coordinates in the located simplex (double; exact location).
        const std::uint32_t* v = &simplices[static_cast<std::size_t>(s) * (d + 1)];
        std::array<double, kMaxDimension + 1> lambda;
        barycentric_coordinates(points, v, x, lambda.data());
        double value = 0;
        for (int k = 0; k <= d; ++k) value += lambda[k] * values[v[k]];
        out[i] = value;
      }
      const std::size_t n_done = done.fetch_add(1, std::memory_order_relaxed) + 1;
      if (run == 0 && n_done % 4096 == 0) progress.update(n_done, 0);
    });
    for (const std::string& e : errors) {
      if (!e.empty()) return report(internal_error(e));
    }
  }
  progress.finish();
  if (Status s = write_values(flags.output, out, gridded ? &grid : nullptr); !s.is_ok()) return report(s);
  if (!flags.quiet) {
    std::size_t outside = 0;
    for (const double v : out) outside += std::isnan(v) ? 1 : 0;
    std::fprintf(stderr, "spokemesh: %zu values (%s, %zu points) in %.2f s -> %s%s\n", m, method.c_str(), points.size(),
                 progress.seconds(), flags.output.c_str(),
                 outside > 0 ? (", " + std::to_string(outside) + " outside the hull: fill value").c_str() : "");
  }
  return kExitOk;
}

}  // namespace spokemesh::cli
