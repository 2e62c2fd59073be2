// spokemesh: exact Delaunay meshes and Voronoi cells of point files.
//
// Exit codes: 0 success, 1 failure (including an invalid mesh for `check`),
// 2 bad usage or bad input.
#include <malloc.h>
#include <sys/stat.h>
#include <unistd.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "cell_print.hpp"
#include "commands.hpp"
#include "interpolate.hpp"
#include "spokemesh/approx.hpp"
#include "spokemesh/cell_io.hpp"
#include "spokemesh/cells.hpp"
#include "spokemesh/graph.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/periodic.hpp"
#include "spokemesh/periodic_cells.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/units.hpp"
#include "spokemesh/validate.hpp"
#include "spokemesh/voronoi.hpp"
#ifdef SPOKEMESH_REMOTE
#include "remote.hpp"
#endif

namespace {

using namespace spokemesh;
using Clock = std::chrono::steady_clock;
using namespace spokemesh::cli;

// A validated point set with its tree; `original` maps indices back when
// duplicates were merged.
struct Loaded {
  PointSet points;
  std::size_t input_count = 0;          // points in the file, before merging duplicates
  std::vector<std::uint32_t> original;  // empty: identity
  std::unique_ptr<SpaceSplit> split;    // a whole mesh's sweep order (commands that sweep)
  std::unique_ptr<KdTree> tree;

  std::vector<double> weights;  // --weights/--radii: one power weight per point; empty: unweighted

  std::uint32_t to_original(std::uint32_t i) const { return original.empty() ? i : original[i]; }
};

// Reads --weights or --radii for the loaded points (one per point; every bad value
// named by file and line or index).
// The weights --weights or --radii names (radii squared), n of them.
Result<std::vector<double>> read_weight_flags(const Common& common, std::size_t n) {
  const bool radii = !common.radii.empty();
  return read_weights(radii ? common.radii : common.weights, n, radii ? WeightKind::kRadius : WeightKind::kPowerWeight);
}

Status load_weights(const Common& common, Loaded& loaded) {
  if (!common.weighted()) return Status::ok();
  if (!loaded.original.empty()) {
    return invalid_argument(
        "--merge-duplicates cannot be combined with --weights or --radii (which weight would a "
        "merged point keep?): remove the duplicates from both files");
  }
  auto weights = read_weight_flags(common, loaded.points.size());
  if (!weights.is_ok()) return weights.status();
  loaded.weights = std::move(weights).value();
  return Status::ok();
}

// approximate: accepts any dimension up to kMaxApproxDimension (the exact affine-span
// check runs only where exact meshing is defined, d <= kMaxDimension). sweep: also the
// sweep's SpaceSplit, built first (its records are freed before the tree's build
// copies the points). (A tree laid out in the split's order was tried: no faster on
// uniform points, 10% slower on a 2-d grid, whose ties nanoflann splits worse in it.)
// sweep: the SpaceSplit of a whole mesh too; tree: the k-d tree (a whole mesh by local
// triangulations does without it).
Result<std::unique_ptr<Loaded>> load(const std::string& path, bool merge_duplicates, bool approximate = false,
                                     bool sweep = false, bool tree = true) {
  auto points = read_points(path);
  if (!points.is_ok()) return points.status();
  auto loaded = std::make_unique<Loaded>();
  loaded->points = std::move(points).value();
  loaded->input_count = loaded->points.size();
  if (merge_duplicates) {
    const std::vector<std::uint32_t> map = loaded->points.merge_duplicates();
    loaded->original.assign(loaded->points.size(), 0);
    for (std::size_t i = map.size(); i-- > 0;) loaded->original[map[i]] = static_cast<std::uint32_t>(i);
  }
  const int d = loaded->points.dimension();
  if (!approximate && d > kMaxDimension) {
    return invalid_argument(path + ": dimension " + std::to_string(d) + " is above the exact limit " +
                            std::to_string(kMaxDimension) +
                            "; use --approx for a certified approximate Delaunay graph");
  }
  Status valid = approximate ? loaded->points.validate(path, kMaxApproxDimension, d <= kMaxDimension)
                             : loaded->points.validate(path);
  if (!valid.is_ok() && valid.reason() == "DUPLICATE_POINTS") {
    return invalid_argument(valid.message() + " (use --merge-duplicates to map duplicates to their first occurrence)");
  }
  if (!valid.is_ok()) return valid;
  if (sweep) {
    loaded->split =
        std::make_unique<SpaceSplit>(loaded->points, SpaceSplit::default_block_points(d, loaded->points.size()));
  }
  if (tree) loaded->tree = std::make_unique<KdTree>(loaded->points);
  return loaded;
}

// Maps a user's seed (an input index) to the internal index.
Result<std::uint32_t> internal_seed(const Loaded& loaded, std::int64_t seed) {
  if (seed < 0 || static_cast<std::size_t>(seed) >= loaded.input_count) {
    return out_of_range("seed " + std::to_string(seed) + " is out of range (the input has " +
                        std::to_string(loaded.input_count) + " points)");
  }
  if (loaded.original.empty()) return static_cast<std::uint32_t>(seed);
  // With merged duplicates, a seed maps to its first occurrence.
  for (std::size_t i = 0; i < loaded.original.size(); ++i) {
    if (loaded.original[i] == static_cast<std::uint32_t>(seed)) return static_cast<std::uint32_t>(i);
  }
  return invalid_argument("seed " + std::to_string(seed) + " duplicates an earlier point; use the first occurrence");
}

// The points and box of a --periodic run, checked: the box parsed, the points read,
// inside it and valid.
struct PeriodicInput {
  PointSet points;
  std::unique_ptr<PeriodicBox> box;
  std::vector<double> weights;  // with --weights or --radii
};
Result<PeriodicInput> load_periodic(const Common& common, const std::string& input) {
  if (common.merge_duplicates) return invalid_argument("--merge-duplicates cannot be combined with --periodic");
  auto box = PeriodicBox::parse(common.periodic, "--periodic");
  if (!box.is_ok()) return box.status();
  auto points = read_points(input);
  if (!points.is_ok()) return points.status();
  PeriodicInput in{std::move(points).value(), std::make_unique<PeriodicBox>(std::move(box).value()), {}};
  const int d = in.points.dimension();
  if (d != in.box->dimension()) {
    return invalid_argument("--periodic: " + std::to_string(2 * in.box->dimension()) + " values describe a " +
                            std::to_string(in.box->dimension()) + "-d box; " + input + " holds " + std::to_string(d) +
                            "-d points (give LO1,...,LOd,HI1,...,HId)");
  }
  if (d > kMaxDimension) {
    return invalid_argument(input + ": dimension " + std::to_string(d) + " is above the exact limit " +
                            std::to_string(kMaxDimension));
  }
  if (Status s = in.box->check_contains(in.points, input); !s.is_ok()) return s;
  if (Status s = in.points.validate(input); !s.is_ok()) return s;
  if (common.weighted()) {
    auto weights = read_weight_flags(common, in.points.size());
    if (!weights.is_ok()) return weights.status();
    in.weights = std::move(weights).value();
  }
  return in;
}

void say_margin_too_thin(const Common& common) {
  if (!common.quiet) std::fprintf(stderr, "\nspokemesh: the images' margin was too thin; again with a wider one\n");
}

// mesh --periodic: the torus's simplices with their offsets (periodic.hpp).
int run_periodic_mesh(const Common& common, const std::string& input, const std::string& output,
                      const std::string& seeds) {
  if (Status s = check_not_input(input, output); !s.is_ok()) return report(s);
  auto in = load_periodic(common, input);
  if (!in.is_ok()) return report(in.status());
  const PointSet& ps = in->points;
  auto writer_or = PeriodicMeshWriter::open(output, ps.dimension(), &ps, &*in->box);
  if (!writer_or.is_ok()) return report(writer_or.status());
  PeriodicMeshWriter& writer = *writer_or.value();

  MeshOptions options;
  if (!seeds.empty()) {
    // The simplices these points own (as for plain meshes): ranges together are the torus.
    auto range = parse_seed_range(seeds, ps.size());
    if (!range.is_ok()) return report(range.status());
    std::tie(options.seed_begin, options.seed_end) = range.value();
  }
  options.threads = common.threads;
  options.star.random_seed = common.random_seed;
  options.star.weights = in->weights;
  options.facet_cache_bytes = common.cache_mb << 20;
  Progress progress(common.quiet, std::min<std::uint64_t>(options.seed_end, ps.size()) - options.seed_begin);
  std::uint64_t written = 0;
  auto result = mesh_periodic(
      ps, *in->box, options,
      [&](std::span<const std::uint32_t> simplices, std::span<const std::int32_t> offsets, std::uint64_t done) {
        written += simplices.size() / static_cast<std::size_t>(ps.dimension() + 1);
        progress.update(done, written);
        return writer.write(simplices, offsets);
      },
      [&] {
        written = 0;
        say_margin_too_thin(common);
        return writer.restart();
      },
      input);
  progress.finish();
  if (!result.is_ok()) return report(result.status());
  if (Status s = writer.commit(); !s.is_ok()) return report(s);
  if (!common.quiet) {
    print_mesh_summary(ps.size(), result->mesh.simplices, progress.seconds(), result->mesh, output);
    std::fprintf(stderr, "spokemesh: periodic: %zu images within %.3g of the box, %d run%s\n",
                 static_cast<std::size_t>(result->images), result->margin.empty() ? 0.0 : result->margin[0],
                 result->runs, result->runs == 1 ? "" : "s");
  }
  return kExitOk;
}

int run_mesh(const Common& common, const std::string& input, const std::string& output, const std::string& seeds,
             const std::string& engine_text) {
  auto engine = parse_engine(engine_text);
  if (!engine.is_ok()) return report(engine.status());
  if (engine.value() == MeshEngine::kTriangulations && (!common.periodic.empty() || common.weighted())) {
    return report(
        invalid_argument("--engine triangulations meshes unweighted, non-periodic sets: use --engine stars "
                         "(or auto) with --weights, --radii or --periodic"));
  }
  if (!common.periodic.empty()) return run_periodic_mesh(common, input, output, seeds);
  if (Status s = check_not_input(input, output); !s.is_ok()) return report(s);
  // Local triangulations (unweighted 2-d and 3-d sets) query the split, not a k-d tree.
  const bool tree = engine.value() == MeshEngine::kStars || common.weighted();
  auto loaded_or = load(input, common.merge_duplicates, false, /*sweep=*/true, tree);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  if (Status s = load_weights(common, *loaded_or.value()); !s.is_ok()) return report(s);
  const Loaded& loaded = *loaded_or.value();
  const std::size_t n = loaded.points.size();

  MeshOptions options;
  options.star.weights = loaded.weights;
  options.split = loaded.split.get();
  options.threads = common.threads;
  options.star.random_seed = common.random_seed;
  options.facet_cache_bytes = common.cache_mb << 20;
  options.engine = engine.value();
  if (!seeds.empty()) {
    auto range = parse_seed_range(seeds, n);
    if (!range.is_ok()) return report(range.status());
    std::tie(options.seed_begin, options.seed_end) = range.value();
    if (!loaded.original.empty()) return report(invalid_argument("--seeds cannot be combined with --merge-duplicates"));
  }
  auto writer_or = MeshWriter::open(output, loaded.points);
  if (!writer_or.is_ok()) return report(writer_or.status());
  MeshWriter& writer = *writer_or.value();

  Progress progress(common.quiet, std::min<std::uint64_t>(options.seed_end, n) - options.seed_begin);
  std::uint64_t written = 0;
  std::vector<std::uint32_t> mapped;
  auto sink = [&](std::span<const std::uint32_t> block, std::uint64_t done) {
    written += block.size() / (loaded.points.dimension() + 1);
    progress.update(done, written);
    if (loaded.original.empty()) return writer.write(block);
    mapped.assign(block.begin(), block.end());
    for (auto& v : mapped) v = loaded.to_original(v);
    return writer.write(mapped);
  };
  auto result = loaded.tree ? mesh_seeds(*loaded.tree, options, sink) : mesh_seeds(loaded.points, options, sink);
  progress.finish();
  if (!result.is_ok()) return report(result.status());
  if (Status s = writer.commit(); !s.is_ok()) return report(s);
  if (!common.quiet) {
    print_mesh_summary(n, result.value().simplices, progress.seconds(), result.value(), output);
    if (!loaded.weights.empty()) {
      std::fprintf(stderr, "spokemesh: %llu of %zu points hidden (empty power cells: in no simplex)\n",
                   static_cast<unsigned long long>(result.value().star.hidden), n);
    }
  }
  return kExitOk;
}

// Loads, computes the star of one seed, and hands it to `use`.
template <class Use>
int with_star(const Common& common, const std::string& input, std::int64_t seed, Use&& use) {
  auto loaded_or = load(input, common.merge_duplicates);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  if (Status s = load_weights(common, *loaded_or.value()); !s.is_ok()) return report(s);
  const Loaded& loaded = *loaded_or.value();
  auto internal = internal_seed(loaded, seed);
  if (!internal.is_ok()) return report(internal.status());
  StarOptions options;
  options.random_seed = common.random_seed;
  options.weights = loaded.weights;
  StarWalker walker(*loaded.tree, options);
  Star star;
  if (Status s = walker.compute(internal.value(), star); !s.is_ok()) return report(s);
  if (star.hidden && !common.quiet) {
    std::fprintf(stderr, "spokemesh: seed %lld is hidden: its power cell is empty, so it is in no simplex\n",
                 static_cast<long long>(seed));
  }
  return use(loaded, star);  // internal indices; printers map them with to_original()
}

// The --domain file for these points: read, validated, and of their dimension.
Result<ShapeDomain> shape_for(const std::string& path, const Loaded& loaded) {
  if (!loaded.weights.empty()) {
    return invalid_argument("--domain: cells of weighted points in a domain of any shape are not supported yet");
  }
  auto shape = read_domain(path);
  if (!shape.is_ok()) return shape.status();
  if (shape->dimension() != loaded.points.dimension()) {
    return invalid_argument("--domain " + path + " is " + std::to_string(shape->dimension()) + "-d; the points are " +
                            std::to_string(loaded.points.dimension()) + "-d");
  }
  return shape;
}

int run_cell(const Common& common, const std::string& input, std::int64_t seed, bool json, const DomainFlags& flags) {
  return with_star(common, input, seed, [&](const Loaded& loaded, Star& star) {
    auto domain = domain_for(flags, loaded.points.dimension(), std::nullopt);
    if (!domain.is_ok()) return report(domain.status());
    VoronoiCell cell;
    if (!flags.shape.empty()) {
      // A domain of any shape: the convex cell in its box, then intersected with it.
      auto shape = shape_for(flags.shape, loaded);
      if (!shape.is_ok()) return report(shape.status());
      auto box = ShapeClipper::box(loaded.points, shape.value());
      if (!box.is_ok()) return report(box.status());
      StarOptions options;
      options.random_seed = common.random_seed;
      if (Status s = shape_cell(*loaded.tree, shape.value(), box.value(), star.seed, cell, options); !s.is_ok())
        return report(s);
    } else if (domain.value().has_value()) {
      // The builder `cells` uses, so that both print the same cell.
      StarOptions options;
      options.random_seed = common.random_seed;
      options.weights = loaded.weights;
      ClippedCellBuilder builder(*loaded.tree, *domain.value(), options);
      auto clipped = builder.cell(star.seed);
      if (!clipped.is_ok()) return report(clipped.status());
      cell = std::move(clipped).value();
    } else {
      cell = voronoi_cell(loaded.points, star, loaded.weights);
    }
    // Original indices (duplicates merged away map to first occurrences).
    cli::print_cell(cell, static_cast<std::uint64_t>(seed), json,
                    [&](std::uint32_t i) { return loaded.to_original(i); });
    return kExitOk;
  });
}

// star, neighbors and cell --periodic: one seed on the torus (periodic.hpp). star prints
// each simplex's indices then its vertices' offsets; neighbors each neighbour image,
// "index offsets..." (a neighbour may appear at several offsets); cell the unclipped
// cell with each facet's offset.
int run_periodic_seed(const Common& common, const std::string& input, std::int64_t seed, const char* what, bool json,
                      const DomainFlags& flags) {
  if (!flags.box.empty() || !flags.halfspaces.empty() || !flags.shape.empty()) {
    return report(invalid_argument("--periodic cells fill the torus: --box, --halfspaces and --domain do not apply"));
  }
  auto in = load_periodic(common, input);
  if (!in.is_ok()) return report(in.status());
  const int d = in->points.dimension();
  if (seed < 0 || static_cast<std::size_t>(seed) >= in->points.size()) {
    return report(out_of_range("seed " + std::to_string(seed) + " is out of range (the input has " +
                               std::to_string(in->points.size()) + " points)"));
  }
  StarOptions options;
  options.random_seed = common.random_seed;
  options.weights = in->weights;
  VoronoiCell cell;
  const bool want_cell = std::string(what) == "cell";
  auto star = periodic_star(in->points, *in->box, static_cast<std::uint32_t>(seed), options, input,
                            want_cell ? &cell : nullptr);
  if (!star.is_ok()) return report(star.status());
  const auto w = static_cast<std::size_t>(d + 1), du = static_cast<std::size_t>(d);
  std::string out;
  if (want_cell) {
    cli::print_cell(cell, static_cast<std::uint64_t>(seed), json, [](std::uint32_t i) { return i; });
    return kExitOk;
  }
  if (std::string(what) == "star") {
    for (std::size_t s = 0; s < star->size(d); ++s) {
      for (std::size_t v = 0; v < w; ++v) out.append(v ? " " : "").append(std::to_string(star->simplices[s * w + v]));
      for (std::size_t k = 0; k < w * du; ++k) out.append(" ").append(std::to_string(star->offsets[s * w * du + k]));
      out += "\n";
    }
  } else {
    // Neighbour images, sorted by index then offset, each once.
    std::vector<std::uint32_t> points;
    std::vector<std::int32_t> offsets;
    periodic_neighbors(star.value(), d, points, offsets);
    for (std::size_t i = 0; i < points.size(); ++i) {
      out.append(std::to_string(points[i]));
      for (std::size_t c = 0; c < du; ++c) out.append(" ").append(std::to_string(offsets[i * du + c]));
      out += "\n";
    }
  }
  std::fwrite(out.data(), 1, out.size(), stdout);
  return kExitOk;
}

// Hands a block of cells to the writer, counting their facets and volume for the
// summary and reporting progress (the cells commands' sink).
Status write_tallied(std::span<const VoronoiCell> cells, std::uint64_t done, CellWriter& writer, Progress& progress,
                     std::uint64_t& facets, double& volume) {
  for (const VoronoiCell& c : cells) {
    facets += c.facets.size();
    volume += c.volume;
  }
  progress.update(done, 0);
  return writer.write(cells);
}

// cells --periodic: the torus's cells, facet offsets in .npz (periodic.hpp).
int run_periodic_cells(const Common& common, const std::string& input, const std::string& output,
                       const DomainFlags& flags) {
  if (!flags.box.empty() || !flags.halfspaces.empty() || !flags.shape.empty()) {
    return report(invalid_argument("--periodic cells fill the torus: --box, --halfspaces and --domain do not apply"));
  }
  auto in = load_periodic(common, input);
  if (!in.is_ok()) return report(in.status());
  const PointSet& ps = in->points;
  const int d = ps.dimension();
  auto writer = CellWriter::open(output, d, /*periodic=*/true);
  if (!writer.is_ok()) return report(writer.status());
  CellsOptions options;
  options.threads = common.threads;
  options.star.random_seed = common.random_seed;
  options.star.weights = in->weights;
  options.measures_only = !writer.value()->needs_vertices();
  options.facet_cache_bytes = common.cache_mb << 20;
  Progress progress(common.quiet, ps.size(), "cells");
  std::uint64_t facets = 0;
  double volume = 0;
  auto result = compute_periodic_cells(
      ps, *in->box, options,
      [&](std::span<const VoronoiCell> cells, std::uint64_t done) {
        return write_tallied(cells, done, *writer.value(), progress, facets, volume);
      },
      [&] {
        facets = 0;
        volume = 0;
        say_margin_too_thin(common);
        auto fresh = CellWriter::open(output, d, true);
        if (!fresh.is_ok()) return fresh.status();
        writer = std::move(fresh);
        return Status::ok();
      },
      input);
  progress.finish();
  Status status = result.status();
  if (status.is_ok()) status = writer.value()->commit();
  if (!status.is_ok()) return report(status);
  if (!common.quiet) {
    std::string torus = "the torus [";
    for (int c = 0; c < d; ++c) {
      char side[64];
      std::snprintf(side, sizeof side, "%s%g, %g)", c == 0 ? "" : " x [", in->box->lo()[c], in->box->hi()[c]);
      torus += side;
    }
    print_cells_summary(ps.size(), torus, facets, volume, progress.seconds(), output);
  }
  return kExitOk;
}

int run_cells(const Common& common, const std::string& input, const std::string& output, const DomainFlags& flags) {
  if (Status s = check_not_input(input, output); !s.is_ok()) return report(s);
  if (!common.periodic.empty()) return run_periodic_cells(common, input, output, flags);
  auto loaded_or = load(input, false);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  if (Status s = load_weights(common, *loaded_or.value()); !s.is_ok()) return report(s);
  const Loaded& loaded = *loaded_or.value();
  auto domain = domain_for(flags, loaded.points.dimension(), Domain::bounding_box(loaded.points));
  if (!domain.is_ok()) return report(domain.status());
  std::optional<ShapeDomain> shape;
  if (!flags.shape.empty()) {
    auto read = shape_for(flags.shape, loaded);
    if (!read.is_ok()) return report(read.status());
    shape.emplace(std::move(read).value());
    auto box = ShapeClipper::box(loaded.points, *shape);
    if (!box.is_ok()) return report(box.status());
    domain.value() = std::move(box).value();
  }
  auto writer = CellWriter::open(output, loaded.points.dimension());
  if (!writer.is_ok()) return report(writer.status());
  if (shape && writer.value()->needs_vertices()) {
    return report(
        invalid_argument("-o " + output + ": cells in a domain of any shape are written as measures: use .npz"));
  }
  CellsOptions options;
  options.threads = common.threads;
  options.star.random_seed = common.random_seed;
  options.star.weights = loaded.weights;
  options.measures_only = !writer.value()->needs_vertices();
  options.facet_cache_bytes = common.cache_mb << 20;
  if (shape) options.shape = &*shape;
  Progress progress(common.quiet, loaded.points.size(), "cells");
  std::uint64_t facets = 0;
  double volume = 0;
  Status status = compute_cells(*loaded.tree, &*domain.value(), options,
                                [&](std::span<const VoronoiCell> cells, std::uint64_t done) {
                                  return write_tallied(cells, done, *writer.value(), progress, facets, volume);
                                });
  progress.finish();
  if (status.is_ok()) status = writer.value()->commit();
  if (!status.is_ok()) return report(status);
  if (!common.quiet) {
    print_cells_summary(loaded.points.size(), shape ? shape->describe() : domain.value()->describe(), facets, volume,
                        progress.seconds(), output);
  }
  return kExitOk;
}

int run_check(const std::string& input, const std::string& mesh_path) {
  auto loaded_or = load(input, false);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  const Loaded& loaded = *loaded_or.value();
  auto simplices = read_simplices(mesh_path, loaded.points.dimension() + 1);
  if (!simplices.is_ok()) return report(simplices.status());
  const MeshCheck check = check_mesh(*loaded.tree, simplices.value());
  if (check.valid) {
    std::printf("valid: %zu simplices, %zu interior facets, %zu hull facets\n", check.simplices, check.interior_facets,
                check.hull_facets);
    return kExitOk;
  }
  std::printf("INVALID: %zu simplices\n", check.simplices);
  for (const auto& v : check.violations) std::printf("  %s\n", v.c_str());
  return kExitFailure;
}

int run_approx_neighbors(const Common& common, const ApproxFlags& flags, const std::string& input, std::int64_t seed) {
  auto loaded_or = load(input, common.merge_duplicates, true);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  const Loaded& loaded = *loaded_or.value();
  auto internal = internal_seed(loaded, seed);
  if (!internal.is_ok()) return report(internal.status());
  ApproxWalker walker(*loaded.tree, flags.options(common.random_seed));
  ApproxNeighbors result;
  const auto start = Clock::now();
  if (Status s = walker.compute(internal.value(), result); !s.is_ok()) return report(s);
  const double ms = std::chrono::duration<double, std::milli>(Clock::now() - start).count();
  for (std::uint32_t v : result.neighbors) std::printf("%u\n", loaded.to_original(v));
  std::fprintf(stderr,
               "spokemesh: %zu certified neighbours (approximate, %s): %llu %s visited, %llu consecutive misses at "
               "the end%s, %.1f ms\n",
               result.neighbors.size(), flags.mode.c_str(), static_cast<unsigned long long>(result.vertices),
               flags.mode == "spokes" ? "rays" : "Voronoi vertices", static_cast<unsigned long long>(result.misses),
               result.exhausted ? " (complete: every point found or refuted)" : "", ms);
  return kExitOk;
}

int run_graph(const Common& common, const ApproxFlags& flags, const std::string& input, const std::string& output) {
  if (Status s = check_not_input(input, output); !s.is_ok()) return report(s);
  if (flags.enabled && common.weighted()) {
    return report(invalid_argument("--weights and --radii need the exact engine: drop --approx"));
  }
  auto loaded_or = load(input, common.merge_duplicates, flags.enabled);
  if (!loaded_or.is_ok()) return report(loaded_or.status());
  if (Status s = load_weights(common, *loaded_or.value()); !s.is_ok()) return report(s);
  const Loaded& loaded = *loaded_or.value();
  const PointSet edge_shape(1, {});  // width 2
  auto writer = MeshWriter::open_tuples(output, edge_shape);
  if (!writer.is_ok()) return report(writer.status());
  GraphOptions options;
  options.approximate = flags.enabled;
  options.approx = flags.options(common.random_seed);
  options.star.random_seed = common.random_seed;
  options.star.weights = loaded.weights;
  options.threads = common.threads;
  Progress progress(common.quiet, loaded.points.size(), "graph");
  options.progress = [&](std::uint64_t done) { progress.update(done, 0); };
  GraphStats stats;
  auto edges = delaunay_graph(*loaded.tree, options, &stats);
  progress.finish();
  if (!edges.is_ok()) return report(edges.status());
  std::vector<std::uint32_t> flat;
  flat.reserve(edges->size() * 2);
  for (auto [i, j] : edges.value()) {
    std::uint32_t a = loaded.to_original(i), b = loaded.to_original(j);
    flat.push_back(std::min(a, b));
    flat.push_back(std::max(a, b));
  }
  if (Status s = writer.value()->write(flat); !s.is_ok()) return report(s);
  if (Status s = writer.value()->commit(); !s.is_ok()) return report(s);
  if (!common.quiet) {
    print_graph_summary(loaded.points.size(), edges->size(), flags.enabled, progress.seconds(), output);
  }
  return kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  // A fixed mmap threshold: glibc's default raises it to 32 MB after the first large
  // free (the sweep's split records, freed before the tree's build), after which the
  // tree's and the front's large buffers come from a heap that never shrinks (a higher
  // peak: bench/README.md, "Tuning history"). 4 MiB keeps the blocks' buffers in the heap.
  ::mallopt(M_MMAP_THRESHOLD, 4 << 20);
  CLI::App app{
      "spokemesh: exact Delaunay meshes and Voronoi cells by Recursive Spoke Darts.\n"
      "Points are text (one point per line) or .npy (shape (n, d), C order, little-endian float64, float32,\n"
      "int64, int32 or int16); indices are 0-based."};
  app.require_subcommand(1);
  app.fallthrough();  // global options (--server, --deadline, ...) may follow the command
  app.set_version_flag("--version", "spokemesh 0.1.0");
  // mesh, graph and cells: defined with spokemesh-mpi's (commands.hpp).
  WholeCommands whole;
  define_whole_commands(app, whole, /*one_process=*/true);
  Common& common = whole.common;
  std::string &input = whole.input, &output = whole.output;
  ApproxFlags& approx_flags = whole.approx;
  DomainFlags& domain_flags = whole.domain;
  CLI::App *mesh = whole.mesh, *graph = whole.graph, *cells = whole.cells;

  std::string mesh_path;
  std::int64_t seed = -1;
  bool json = false;

  // Remote mode: --server HOST:PORT sends the commands to a spokemesh-server, and
  // INPUT becomes a point-set id (from `upload`).
  std::string server, deadline_text = "60s", token_file, tls_ca, tls_cert, tls_key, display_name;
  app.add_option("--server", server, "Run against a spokemesh-server at HOST:PORT (gRPC); INPUT is then a point-set id")
      ->group("Remote mode");
  app.add_option("--deadline", deadline_text, "Deadline of each remote call (e.g. 500ms, 30s, 5m)")
      ->capture_default_str()
      ->group("Remote mode");
  app.add_option("--token-file", token_file, "File with the server's bearer token (or set SPOKEMESH_TOKEN)")
      ->group("Remote mode");
  app.add_option("--tls-ca", tls_ca, "Use TLS, trusting this PEM CA bundle")->group("Remote mode");
  app.add_option("--tls-cert", tls_cert, "Client certificate (PEM) for mutual TLS")->group("Remote mode");
  app.add_option("--tls-key", tls_key, "Client private key (PEM) for mutual TLS")->group("Remote mode");

  auto* star = app.add_subcommand("star", "Print the Delaunay simplices incident to one seed, one per line");
  star->add_option("INPUT", input, "Point file")->required();
  star->add_option("--seed", seed, "Seed index (0-based)")->required();
  add_common_flags(star, common);
  add_weight_flags(star, common);
  add_periodic_flag(star, common);

  auto* neighbors = app.add_subcommand("neighbors", "Print the Delaunay neighbours of one seed, one per line");
  neighbors->add_option("INPUT", input, "Point file")->required();
  neighbors->add_option("--seed", seed, "Seed index (0-based)")->required();
  add_approx_flags(neighbors, approx_flags);
  add_common_flags(neighbors, common);
  add_weight_flags(neighbors, common);
  add_periodic_flag(neighbors, common);

  auto* cell = app.add_subcommand("cell", "Print the Voronoi cell of one seed: vertices, facets, boundedness, volume");
  cell->add_option("INPUT", input, "Point file")->required();
  cell->add_option("--seed", seed, "Seed index (0-based)")->required();
  cell->add_flag("--json", json, "Print JSON instead of text");
  add_domain_flags(cell, domain_flags, "default: unclipped");
  add_common_flags(cell, common);
  add_weight_flags(cell, common);
  add_periodic_flag(cell, common);

  auto* check = app.add_subcommand(
      "check", "Validate a mesh of a point file independently (exit 0 only if it is the Delaunay mesh)");
  check->add_option("INPUT", input, "Point file")->required();
  check->add_option("MESH", mesh_path, "Mesh file (.simplices/.txt or .npy)")->required();

  auto* upload = app.add_subcommand("upload", "Remote mode: upload a point file; prints its id");
  upload->add_option("INPUT", input, "Point file (.txt/.csv/.xyz text or .npy)")->required();
  upload->add_option("--name", display_name, "Display name stored with the point set");
  upload->add_flag("-q,--quiet", common.quiet, "Print only the id");
  add_weight_flags(upload, common);
  add_periodic_flag(upload, common);
  std::string append_id;
  auto* append = app.add_subcommand(
      "append", "Remote mode: store a new point set, a stored set's points followed by a file's; prints its id");
  append->add_option("ID", append_id, "Id of the stored set appended to (it stays as it is)")->required();
  append->add_option("POINTS", input, "Point file of the new points (.txt/.csv/.xyz text or .npy)")->required();
  append->add_option("--name", display_name, "Display name stored with the new point set");
  append->add_flag("-q,--quiet", common.quiet, "Print only the id");
  append->footer(
      "The new set's id is the hash of all its points, as if uploaded whole; only the new points are sent.\n"
      "Its points are the stored set's (indices 0..n-1) and then the file's (n, n+1, ...).");
  auto* batch = app.add_subcommand(
      "batch", "Remote mode: stars, neighbours or cells of many seeds in one call; one JSON object per line");
  std::string batch_kind, seeds_text, seeds_file;
  batch->add_option("ID", input, "Point-set id")->required();
  batch->add_option("KIND", batch_kind, "stars, neighbors or cells")
      ->required()
      ->check(CLI::IsMember({"stars", "neighbors", "cells"}));
  batch->add_option("--seeds", seeds_text, "Comma-separated seed indices, e.g. 0,5,17");
  batch->add_option("--seeds-file", seeds_file, "File of seed indices (whitespace or commas)");
  add_domain_flags(batch, domain_flags, "cells only; default: unclipped");
  add_approx_flags(batch, approx_flags);
  bool batch_no_route = false;
  batch->add_flag("--no-route", batch_no_route,
                  "Ask --server for every seed, even on a sharded deployment (by default a batch large enough "
                  "to be worth the shard map, 2 bytes a point, goes to each seed's shard directly)");
  InterpolateFlags interp_flags;
  auto* interp = app.add_subcommand(
      "interpolate", "Values at any point from a value per point: natural neighbours (Sibson), linear or nearest");
  interp->add_option("POINTS", interp_flags.points, "Point file (2-d or 3-d for natural; up to 8-d for linear)")
      ->required();
  interp->add_option("VALUES", interp_flags.values, "One value per point, in the points' order (text or .npy)")
      ->required();
  interp->add_option("QUERIES", interp_flags.queries, "Point file of the query points (or --grid)");
  interp
      ->add_option("-o,--output", interp_flags.output,
                   "Values file: .npy (float64; with --grid shape (NY, NX)) or text (one value a line)")
      ->required();
  interp
      ->add_option("--method", interp_flags.method,
                   "natural (Sibson's natural-neighbour coordinates, 2-d and 3-d), linear (barycentric in the "
                   "Delaunay simplex holding the point) or nearest")
      ->capture_default_str()
      ->check(CLI::IsMember({"natural", "linear", "nearest"}));
  interp->add_option("--grid", interp_flags.grid,
                     "A raster of 2-d query points instead of QUERIES: X0,Y0,X1,Y1,NX,NY (corners included; row j "
                     "at Y0 + j (Y1 - Y0) / (NY - 1))");
  interp->add_option("--fill", interp_flags.fill, "The value outside the points' hull (natural, linear; default NaN)");
  interp->add_option("--threads", interp_flags.threads, "Worker threads (default: all cores)")
      ->check(CLI::Range(1u, 1024u));
  interp->add_flag("-q,--quiet", interp_flags.quiet, "No progress or summary on stderr");
  interp->footer(
      "Which simplex holds a query, and which points are its natural neighbours, are decided by exact predicates;\n"
      "the values are computed in double. Points are validated as for `mesh` (distinct, full dimension).");
  auto* health = app.add_subcommand("health", "Remote mode: ask the server's gRPC health service (exit 0 if SERVING)");
  auto* list = app.add_subcommand("list", "Remote mode: list the stored point sets");
  auto* del = app.add_subcommand("delete", "Remote mode: delete a stored point set");
  del->add_option("ID", input, "Point-set id")->required();

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return kExitUsage;
  }

  if (*interp) {
    if (!server.empty()) {
      return report(invalid_argument("interpolate: local only for now (the service's interpolation is not built yet)"));
    }
    if (interp_flags.threads == 0) interp_flags.threads = std::max(1u, std::thread::hardware_concurrency());
    return run_interpolate(interp_flags);
  }
  const bool remote_only = *upload || *append || *health || *list || *del || *batch;
  if (!server.empty() && !*upload && (!common.periodic.empty() || common.weighted())) {
    // A stored set carries its own weights and box (given at upload): its answers use them.
    return report(invalid_argument(std::string(common.weighted() ? "--weights/--radii" : "--periodic") +
                                   " go with `upload` in remote mode: a stored set carries its own, and every "
                                   "answer about it uses them"));
  }
  if (!server.empty()) {
#ifdef SPOKEMESH_REMOTE
    remote::RemoteOptions o;
    o.server = server;
    o.tls_ca = tls_ca;
    o.tls_cert = tls_cert;
    o.tls_key = tls_key;
    o.quiet = common.quiet;
    if (tls_cert.empty() != tls_key.empty()) return report(invalid_argument("--tls-cert and --tls-key go together"));
    if (!tls_cert.empty() && tls_ca.empty()) return report(invalid_argument("--tls-cert needs --tls-ca"));
    {
      auto deadline = parse_duration(deadline_text, "--deadline");
      if (!deadline.is_ok()) return report(deadline.status());
      o.deadline = deadline.value();
    }
    if (!token_file.empty()) {
      std::FILE* f = std::fopen(token_file.c_str(), "rb");
      if (f == nullptr) return report(invalid_argument("--token-file: cannot read " + token_file));
      char buf[4096];
      const std::size_t got = std::fread(buf, 1, sizeof buf, f);
      std::fclose(f);
      o.token.assign(buf, got);
    } else if (const char* env = std::getenv("SPOKEMESH_TOKEN")) {
      o.token = env;
    }
    while (!o.token.empty() && std::isspace(static_cast<unsigned char>(o.token.back()))) o.token.pop_back();
    if (seed < -1) return report(out_of_range("--seed: " + std::to_string(seed) + " is negative"));
    const auto s = static_cast<std::uint64_t>(seed);
    if (*upload) {
      return remote::upload(
          o, input, display_name,
          {common.radii.empty() ? common.weights : common.radii, !common.radii.empty(), common.periodic});
    }
    if (*append) return remote::append(o, append_id, input, display_name);
    if (*batch) {
      std::string text = seeds_text;
      if (!seeds_file.empty()) {
        std::ifstream in(seeds_file);
        if (!in) return report(invalid_argument("--seeds-file: cannot read " + seeds_file));
        text.append(",").append(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
      }
      std::vector<std::uint64_t> seed_list;
      std::string item;
      for (char ch : text + ",") {
        if (ch == ',' || std::isspace(static_cast<unsigned char>(ch))) {
          if (item.empty()) continue;
          char* end = nullptr;
          const unsigned long long v = std::strtoull(item.c_str(), &end, 10);
          if (*end != '\0' || item[0] == '-') {
            return report(invalid_argument("--seeds: '" + item + "' (seed " + std::to_string(seed_list.size()) +
                                           ") is not a seed index"));
          }
          seed_list.push_back(v);
          item.clear();
        } else {
          item += ch;
        }
      }
      if (seed_list.empty()) return report(invalid_argument("batch: give seeds with --seeds or --seeds-file"));
      const std::string mode = neighbor_mode_name(approx_flags.neighbor_mode());
      return remote::batch(o, input, batch_kind, seed_list, mode, approx_flags.enabled ? approx_flags.misses : 0,
                           approx_flags.enabled ? approx_flags.max_vertices : 0, domain_flags.box,
                           domain_flags.halfspaces, domain_flags.shape, !batch_no_route);
    }
    if (*health) return remote::health(o);
    if (*list) return remote::list(o);
    if (*del) return remote::remove(o, input);
    if (*star) return remote::star(o, input, s);
    if (*neighbors) {
      const std::string mode = neighbor_mode_name(approx_flags.neighbor_mode());
      return remote::neighbors(o, input, s, mode, approx_flags.enabled ? approx_flags.misses : 0,
                               approx_flags.enabled ? approx_flags.max_vertices : 0);
    }
    if (*cell) return remote::cell(o, input, s, json, domain_flags.box, domain_flags.halfspaces, domain_flags.shape);
    if (*cells) return remote::cells(o, input, output, domain_flags.box, domain_flags.halfspaces, domain_flags.shape);
    if (*mesh) {
      if (!whole.seeds.empty())
        return report(invalid_argument("--seeds is local only; remote meshes are split with --shards"));
      return remote::mesh(o, input, output, whole.shards);
    }
#else
    return report(invalid_argument("--server: this build has no remote mode (built without SPOKEMESH_BUILD_SERVICE)"));
#endif
  }
  if (remote_only) {
    return report(invalid_argument(std::string(app.get_subcommands().front()->get_name()) +
                                   ": needs --server HOST:PORT (a spokemesh-server)"));
  }
  if (*mesh) return run_mesh(common, input, output, whole.seeds, whole.engine);
  if (!common.periodic.empty() && (*star || *neighbors || *cell)) {
    if (*neighbors && approx_flags.enabled)
      return report(invalid_argument("--periodic needs the exact engine: drop --approx"));
    return run_periodic_seed(common, input, seed,
                             *star        ? "star"
                             : *neighbors ? "neighbors"
                                          : "cell",
                             json, domain_flags);
  }
  if (*star) {
    return with_star(common, input, seed, [](const Loaded& loaded, Star& s) {
      for (auto& v : s.simplices) v = loaded.to_original(v);
      std::string out;
      append_index_lines(out, s.simplices, s.dimension + 1);
      std::fwrite(out.data(), 1, out.size(), stdout);
      return kExitOk;
    });
  }
  if (*graph) return run_graph(common, approx_flags, input, output);
  if (*neighbors && approx_flags.enabled && common.weighted()) {
    return report(invalid_argument("--weights and --radii need the exact engine: drop --approx"));
  }
  if (*neighbors && approx_flags.enabled) return run_approx_neighbors(common, approx_flags, input, seed);
  if (*neighbors) {
    return with_star(common, input, seed, [](const Loaded& loaded, Star& s) {
      for (std::uint32_t v : star_neighbors(s)) std::printf("%u\n", loaded.to_original(v));
      return kExitOk;
    });
  }
  if (*cell) return run_cell(common, input, seed, json, domain_flags);
  if (*cells) {
    common.cache_mb = whole.cells_cache_mb;
    return run_cells(common, input, output, domain_flags);
  }
  if (*check) return run_check(input, mesh_path);
  return kExitUsage;
}
