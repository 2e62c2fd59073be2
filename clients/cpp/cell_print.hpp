// Printing one Voronoi cell (the `cell` command), shared by local and remote mode so
// both print the same text or JSON.
#pragma once

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <iostream>

#include "spokemesh/voronoi.hpp"

namespace spokemesh::cli {

// The cell as JSON (the `cell --json` layout); `original` maps a neighbour or vertex
// index to the user's numbering.
inline nlohmann::json cell_json(const VoronoiCell& cell, std::uint64_t seed,
                                const std::function<std::uint32_t(std::uint32_t)>& original) {
  const int d = cell.dimension;
  const bool simplices = !cell.vertex_simplices.empty();
  nlohmann::json j;
  j["seed"] = seed;
  j["dimension"] = d;
  j["bounded"] = cell.bounded;
  j["clipped"] = cell.clipped;
  if (cell.hidden) j["hidden"] = true;  // weighted: an empty power cell (volume 0, no facets)
  j["volume"] = cell.bounded ? nlohmann::json(cell.volume) : nlohmann::json(nullptr);
  j["centroid"] = cell.bounded && !cell.centroid.empty() ? nlohmann::json(cell.centroid) : nlohmann::json(nullptr);
  j["vertices"] = nlohmann::json::array();
  for (std::size_t v = 0; v < cell.vertex_count(); ++v) {
    nlohmann::json vertex = {{"position", std::vector<double>(&cell.vertices[v * d], &cell.vertices[v * d] + d)}};
    if (simplices) {
      std::vector<std::uint32_t> s(&cell.vertex_simplices[v * (d + 1)], &cell.vertex_simplices[(v + 1) * (d + 1)]);
      for (auto& i : s) i = original(i);
      vertex["simplex"] = s;
    }
    j["vertices"].push_back(std::move(vertex));
  }
  j["facets"] = nlohmann::json::array();
  for (std::size_t k = 0; k < cell.facets.size(); ++k) {
    const VoronoiFacet& f = cell.facets[k];
    nlohmann::json facet;
    if (f.is_wall())
      facet["wall"] = f.wall();
    else
      facet["neighbor"] = original(static_cast<std::uint32_t>(f.neighbor));
    if (!cell.facet_offsets.empty()) {  // on a torus: the neighbour's image
      facet["offset"] =
          std::vector<std::int32_t>(cell.facet_offsets.begin() + static_cast<std::ptrdiff_t>(k * d),
                                    cell.facet_offsets.begin() + static_cast<std::ptrdiff_t>((k + 1) * d));
    }
    facet["vertices"] = f.vertices;
    facet["area"] = std::isfinite(f.area) ? nlohmann::json(f.area) : nlohmann::json(nullptr);
    facet["normal"] = f.normal;
    j["facets"].push_back(std::move(facet));
  }
  return j;
}

inline void print_cell(const VoronoiCell& cell, std::uint64_t seed, bool json,
                       const std::function<std::uint32_t(std::uint32_t)>& original) {
  const int d = cell.dimension;
  const bool simplices = !cell.vertex_simplices.empty();
  if (json) {
    std::cout << cell_json(cell, seed, original).dump(2) << "\n";
    return;
  }
  std::printf("seed %llu\ndimension %d\nbounded %s\n", static_cast<unsigned long long>(seed), d,
              cell.bounded ? "yes" : "no");
  if (cell.clipped) std::printf("clipped yes\n");
  if (cell.hidden) std::printf("hidden yes (an empty power cell)\n");
  if (cell.bounded) {
    std::printf("volume %.17g\ncentroid", cell.volume);
    for (double c : cell.centroid) std::printf(" %.17g", c);
    std::printf("\n");
  } else {
    std::printf("volume inf\n");
  }
  std::printf("vertices %zu\n", cell.vertex_count());
  for (std::size_t v = 0; v < cell.vertex_count(); ++v) {
    std::printf("v %zu", v);
    for (int c = 0; c < d; ++c) std::printf(" %.17g", cell.vertices[v * d + c]);
    if (simplices) {
      std::printf("  simplex");
      for (int c = 0; c <= d; ++c) std::printf(" %u", original(cell.vertex_simplices[v * (d + 1) + c]));
    }
    std::printf("\n");
  }
  std::printf("facets %zu\n", cell.facets.size());
  for (std::size_t k = 0; k < cell.facets.size(); ++k) {
    const VoronoiFacet& f = cell.facets[k];
    if (f.is_wall())
      std::printf("f wall %zu", f.wall());
    else
      std::printf("f neighbor %u", original(static_cast<std::uint32_t>(f.neighbor)));
    if (!cell.facet_offsets.empty()) {  // on a torus: the neighbour's image
      std::printf(" offset");
      for (int c = 0; c < d; ++c)
        std::printf(" %d", cell.facet_offsets[k * static_cast<std::size_t>(d) + static_cast<std::size_t>(c)]);
    }
    std::printf(" area %.17g normal", f.area);
    for (double c : f.normal) std::printf(" %.17g", c);
    std::printf(" vertices");
    for (auto v : f.vertices) std::printf(" %u", v);
    std::printf("\n");
  }
}

}  // namespace spokemesh::cli
