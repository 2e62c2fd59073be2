#include "geojson_domain.hpp"

#include <nlohmann/json.hpp>

#include "spokemesh/shape_io.hpp"

namespace spokemesh {

namespace {

using nlohmann::json;

// GeoJSON coordinates -> rings; `at` names the member for messages.
Status geojson_rings(const nlohmann::json& geometry, const std::string& at, std::vector<std::vector<double>>& rings) {
  if (!geometry.is_object() || !geometry.contains("type") || !geometry["type"].is_string()) {
    return invalid_argument(at + ": a GeoJSON object with a \"type\"");
  }
  const std::string type = geometry["type"];
  if (type == "Feature") {
    if (!geometry.contains("geometry")) return invalid_argument(at + ": a Feature without \"geometry\"");
    return geojson_rings(geometry["geometry"], at + ".geometry", rings);
  }
  // A collection: every member's rings.
  const char* members = type == "FeatureCollection"    ? "features"
                        : type == "GeometryCollection" ? "geometries"
                                                       : nullptr;
  if (members != nullptr) {
    if (!geometry.contains(members) || !geometry[members].is_array()) {
      return invalid_argument(at + ": a " + type + " without a \"" + members + "\" array");
    }
    for (std::size_t i = 0; i < geometry[members].size(); ++i) {
      const std::string member = at + "." + members + "[" + std::to_string(i) + "]";
      if (Status s = geojson_rings(geometry[members][i], member, rings); !s.is_ok()) return s;
    }
    return Status::ok();
  }
  if (type != "Polygon" && type != "MultiPolygon") {
    return invalid_argument(at + ": a " + type + "; a domain is a Polygon or MultiPolygon (with holes as inner rings)");
  }
  if (!geometry.contains("coordinates") || !geometry["coordinates"].is_array()) {
    return invalid_argument(at + ": no \"coordinates\" array");
  }
  auto polygon = [&](const nlohmann::json& p, const std::string& where) -> Status {
    if (!p.is_array()) return invalid_argument(where + ": a polygon is an array of rings");
    for (std::size_t r = 0; r < p.size(); ++r) {
      const std::string ring_at = where + "[" + std::to_string(r) + "]";
      if (!p[r].is_array()) return invalid_argument(ring_at + ": a ring is an array of [x, y] positions");
      std::vector<double> ring;
      for (std::size_t v = 0; v < p[r].size(); ++v) {
        const nlohmann::json& pos = p[r][v];
        if (!pos.is_array() || pos.size() < 2 || !pos[0].is_number() || !pos[1].is_number()) {
          return invalid_argument(ring_at + "[" + std::to_string(v) + "]: expected a position [x, y]");
        }
        ring.push_back(pos[0].get<double>());
        ring.push_back(pos[1].get<double>());
      }
      rings.push_back(std::move(ring));
    }
    return Status::ok();
  };
  const nlohmann::json& c = geometry["coordinates"];
  if (type == "Polygon") return polygon(c, at + ".coordinates");
  for (std::size_t i = 0; i < c.size(); ++i) {
    if (Status s = polygon(c[i], at + ".coordinates[" + std::to_string(i) + "]"); !s.is_ok()) return s;
  }
  return Status::ok();
}

}  // namespace

Result<ShapeDomain> parse_geojson_domain(const std::string& text, const std::string& name) {
  nlohmann::json doc;
  std::vector<std::vector<double>> rings;
  try {
    doc = nlohmann::json::parse(text);
    if (Status s = geojson_rings(doc, name, rings); !s.is_ok()) return s;
  } catch (const nlohmann::json::parse_error& e) {
    return invalid_argument(name + ": not JSON (byte " + std::to_string(e.byte) + ")");
  } catch (const nlohmann::json::exception& e) {
    // A number beyond double's range, and the like (found by tests/fuzz/fuzz_domains).
    return invalid_argument(name + ": " + std::string(e.what()).substr(0, 200));
  }
  return ShapeDomain::polygon(std::move(rings), name);
}

Result<ShapeDomain> parse_domain_bytes(const std::string& bytes, const std::string& name) {
  if (is_geojson_path(name)) return parse_geojson_domain(bytes, name);
  return parse_shape_domain(bytes, name);
}

}  // namespace spokemesh
