// Reading domains of any shape (shape_domain.hpp) from files, by extension:
//   .off, .obj, .stl (ASCII or binary): a closed triangle mesh (3-d). Polygons with
//       more than three corners are cut into fans, numbered in place. Vertices at equal
//       coordinates are one vertex (STL repeats them).
//   anything else (e.g. .txt, .rings): 2-d rings, one ring per block of lines, blocks
//       separated by blank lines; a line is "x y" (blanks or commas); '#' comments.
//       The first ring need not be the outer one: rings are oriented by nesting.
// GeoJSON (.geojson, .json) is read by the clients (this library holds no JSON):
// their rings go to ShapeDomain::polygon.
// Errors name the file and the line (or face, or byte offset), then what is wrong.
//
// Thread safety: reentrant.
#pragma once

#include <string>

#include "spokemesh/shape_domain.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

// The format a domain file's extension names (any case): off, obj, stl, geojson (.geojson
// or .json), else rings. The service's requests name their domain by it.
std::string shape_domain_format(const std::string& path);
// Whether it is GeoJSON (.geojson or .json).
bool is_geojson_path(const std::string& path);

Result<ShapeDomain> read_shape_domain(const std::string& path);
// The same from a file's bytes; `name` is its path or extension (".off", "part.stl").
Result<ShapeDomain> parse_shape_domain(const std::string& bytes, const std::string& name);

}  // namespace spokemesh
