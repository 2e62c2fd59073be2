// GeoJSON polygons as domains of any shape (shape_domain.hpp), for the clients and
// the service (the core holds no JSON).
//
// Accepted: a Polygon, a MultiPolygon, a Feature or a FeatureCollection (or a
// GeometryCollection) of them; every ring of every polygon becomes a ring of the
// domain (its first ring need not be the outer one: rings are oriented by nesting).
// Positions are [x, y] (further values, such as an altitude, are ignored). Errors name
// the member: "part.geojson: features[0].geometry.coordinates[1][3]: expected a position [x, y]".
//
// Thread safety: reentrant.
#pragma once

#include <string>

#include "spokemesh/shape_domain.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh {

Result<ShapeDomain> parse_geojson_domain(const std::string& text, const std::string& name);
// A domain file's bytes by its name's extension: GeoJSON here, else parse_shape_domain.
Result<ShapeDomain> parse_domain_bytes(const std::string& bytes, const std::string& name);

}  // namespace spokemesh
