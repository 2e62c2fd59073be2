#include "http_api.hpp"

#include <array>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstring>
#include <future>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>

#include "grpc_service.hpp"
#include "json_text.hpp"
#include "openapi_json.hpp"
#include "status_map.hpp"
#include "upload_json.hpp"

namespace spokemesh::service {
namespace {

using json = nlohmann::json;

std::string dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

std::string percent_decode(std::string_view s) {
  std::string out;
  out.reserve(s.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '+') {
      out += ' ';
    } else if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(static_cast<unsigned char>(s[i + 1])) &&
               std::isxdigit(static_cast<unsigned char>(s[i + 2]))) {
      out += static_cast<char>(std::stoi(std::string(s.substr(i + 1, 2)), nullptr, 16));
      i += 2;
    } else {
      out += s[i];
    }
  }
  return out;
}

std::vector<std::string> split_path(std::string_view path) {
  std::vector<std::string> parts;
  std::size_t at = 0;
  while (at < path.size()) {
    const std::size_t next = path.find('/', at);
    const std::string_view part = path.substr(at, next == std::string_view::npos ? std::string_view::npos : next - at);
    if (!part.empty()) parts.push_back(percent_decode(part));
    if (next == std::string_view::npos) break;
    at = next + 1;
  }
  return parts;
}

// A non-negative integer parameter; `what` names it in the error.
Result<std::uint64_t> parse_uint(const std::string& text, const std::string& what) {
  std::uint64_t v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (text.empty() || ec != std::errc() || end != text.data() + text.size()) {
    return invalid_argument(what + ": \"" + text.substr(0, 40) + "\" is not a non-negative integer");
  }
  return v;
}

// `already_existed` belongs to an upload's answer only (get and list leave it out).
json point_set_json(const PointSetInfo& info, bool upload = false) {
  json out = {{"id", info.id},
              {"dimension", info.dimension},
              {"count", info.count},
              {"display_name", info.display_name},
              {"weighted", info.weighted},
              {"expected_simplices", expected_simplices(info.dimension, info.count)}};
  if (!info.periodic_box.empty()) out["periodic_box"] = info.periodic_box;
  if (upload) out["already_existed"] = info.already_existed;
  return out;
}

// The media type of a Content-Type value: type/subtype without parameters, lowercased
// (RFC 9110 8.3.1: type, subtype and parameter names are case-insensitive).
std::string media_type_of(std::string_view content_type) {
  std::string_view type = content_type.substr(0, content_type.find(';'));
  while (!type.empty() && (type.back() == ' ' || type.back() == '\t')) type.remove_suffix(1);
  while (!type.empty() && (type.front() == ' ' || type.front() == '\t')) type.remove_prefix(1);
  std::string out(type);
  std::transform(out.begin(), out.end(), out.begin(),
                 [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
  return out;
}

// The answers' JSON, written straight into text (json_text.hpp), keys in the order
// they have always had.
// {"circumcenters", "dimension", "hidden", "hull_facets"[, "offsets"], "point_set_id",
//  "seed", "simplices"}
std::string star_text(const StarAnswer& answer, const std::string& id, std::uint64_t seed) {
  const Star& star = answer.star;
  const auto d = static_cast<std::size_t>(star.dimension);
  std::string out;
  out.reserve(64 + 48 * answer.circumcentres.size() + 12 * star.simplices.size());
  JsonText j(out);
  j.open_object();
  j.key("circumcenters").rows(answer.circumcentres, d);
  j.key("dimension").integer(star.dimension);
  j.key("hidden").boolean(star.hidden);
  j.key("hull_facets").integer(star.hull_facets);
  if (!answer.offsets.empty()) {
    // Per simplex, its vertices' offsets: [[o_1..o_d] x (d + 1)].
    const std::size_t per = (d + 1) * d;
    const std::span<const std::int32_t> offsets(answer.offsets);
    j.key("offsets").raw("[");
    for (std::size_t i = 0; i + per <= offsets.size(); i += per) {
      if (i != 0) j.raw(",");
      j.rows(offsets.subspan(i, per), d);
    }
    j.raw("]");
  }
  j.key("point_set_id").string(id);
  j.key("seed").integer(seed);
  j.key("simplices").rows(star.simplices, d + 1);
  j.close_object();
  return out;
}

std::string neighbors_text(const NeighborAnswer& answer, const std::string& id, std::uint64_t seed,
                           const std::string& mode) {
  std::string out;
  JsonText j(out);
  j.open_object();
  if (!answer.exact) j.key("consecutive_misses").integer(answer.walk.misses);
  j.key("exact").boolean(answer.exact);
  j.key("mode").string(mode);
  j.key("neighbors").array(answer.neighbors);
  if (!answer.offsets.empty()) j.key("offsets").rows(answer.offsets, answer.offsets.size() / answer.neighbors.size());
  j.key("point_set_id").string(id);
  if (!answer.exact) j.key("rays").integer(answer.walk.rays);
  j.key("seed").integer(seed);
  if (!answer.exact) {
    j.key("vertices_visited").integer(answer.walk.vertices);
    j.key("walk_exhausted").boolean(answer.walk.exhausted);
  }
  j.close_object();
  return out;
}

Result<NeighborQuery> neighbor_query_of(const std::string& mode, std::uint64_t misses, std::uint64_t max_vertices) {
  NeighborQuery query;
  auto parsed = parse_neighbor_mode(mode, "mode");
  if (!parsed.is_ok()) return parsed.status();
  query.mode = parsed.value();
  if (misses > 100000000)
    return invalid_argument("max_consecutive_misses: " + std::to_string(misses) + " is too large");
  if (max_vertices > 100000000)
    return invalid_argument("max_vertices: " + std::to_string(max_vertices) + " is too large");
  query.max_consecutive_misses = static_cast<std::uint32_t>(misses);
  query.max_vertices = static_cast<std::uint32_t>(max_vertices);
  return query;
}

// The cell as REST answers it: unbounded volumes, centroids and areas are null beside
// "bounded": false (docs/service.md, "Unbounded cells"); walls are {"wall": k}; with `id`,
// "point_set_id" too.
std::string cell_text(const VoronoiCell& cell, const std::string* id = nullptr) {
  const auto d = static_cast<std::size_t>(cell.dimension);
  std::string out;
  out.reserve(256 + 40 * cell.vertices.size() + 96 * cell.facets.size());
  JsonText j(out);
  j.open_object();
  j.key("bounded").boolean(cell.bounded);
  j.key("centroid");
  if (cell.bounded) {
    j.array(cell.centroid);
  } else {
    j.raw("null");
  }
  j.key("clipped").boolean(cell.clipped);
  j.key("dimension").integer(cell.dimension);
  j.key("facets").raw("[");
  for (std::size_t k = 0; k < cell.facets.size(); ++k) {
    const VoronoiFacet& f = cell.facets[k];
    if (k != 0) j.raw(",");
    j.open_object();
    j.key("area").number(f.area);  // null when unbounded
    if (!f.is_wall()) j.key("neighbor").integer(f.neighbor);
    j.key("normal").array(f.normal);
    if (!cell.facet_offsets.empty()) {
      j.key("offset").array(std::span<const std::int32_t>(cell.facet_offsets).subspan(k * d, d));
    }
    j.key("vertices").array(f.vertices);
    if (f.is_wall()) j.key("wall").integer(f.wall());
    j.close_object();
  }
  j.raw("]");
  if (cell.hidden) j.key("hidden").boolean(true);
  if (id != nullptr) j.key("point_set_id").string(*id);
  j.key("seed").integer(cell.seed);
  if (!cell.vertex_simplices.empty()) j.key("vertex_simplices").rows(cell.vertex_simplices, d + 1);
  j.key("vertices").rows(cell.vertices, d);
  j.key("volume");
  if (cell.bounded) {
    j.number(cell.volume);
  } else {
    j.raw("null");
  }
  j.close_object();
  return out;
}

}  // namespace

std::string error_json(const Status& s, int http_code) {
  json error = {
      {"code", http_code != 0 ? http_code : http_status(s)}, {"status", code_name(s.code())}, {"message", s.message()}};
  if (!s.reason().empty()) error["reason"] = s.reason();
  return dump({{"error", std::move(error)}});
}

struct HttpApi::Context {
  const http::request<http::string_body>& request;
  std::map<std::string, std::string> query;
  std::function<bool()> client_gone;
  Clock::time_point deadline;
  Telemetry::Request record;
  RequestTimer timer;
  Principal principal;  // set once authenticated
  // Answering on the connection's I/O thread (answer_at_once): only what cannot block;
  // anything else returns later() and is asked again on a thread of its own.
  bool at_once = false;
  static HttpResponse later() {
    HttpResponse r;
    r.status = 0;
    return r;
  }

  HttpResponse fail(const Status& s) { return failure(record, s); }
  static HttpResponse failure(Telemetry::Request& record, const Status& s) {
    record.code = s.code();
    record.message = s.message();
    HttpResponse r;
    r.status = static_cast<unsigned>(http_status(s));
    r.body = error_json(s);
    return r;
  }
  HttpResponse ok(const json& body, unsigned status = 200) {
    HttpResponse r;
    r.status = status;
    r.body = dump(body);
    return r;
  }
  HttpResponse ok_text(std::string body) {
    HttpResponse r;
    r.body = std::move(body);
    return r;
  }
  std::optional<std::string> param(const std::string& key) const {
    const auto it = query.find(key);
    if (it == query.end()) return std::nullopt;
    return it->second;
  }
};

namespace {

// The compact form of batches (docs/service.md, "Compact batches"): the gRPC
// BatchSeedsResponse messages, each preceded by its length as a base-128 varint
// (protobuf's delimited framing). An item is one answer as its message's field entry
// (tag, length, bytes), so a part's message is its items' concatenation.
constexpr const char* kCompactType = "application/x-protobuf";

void append_varint(std::string& out, std::uint64_t v) {
  while (v >= 0x80) {
    out += static_cast<char>((v & 0x7f) | 0x80);
    v >>= 7;
  }
  out += static_cast<char>(v);
}

bool read_varint(std::string_view& in, std::uint64_t& v) {
  v = 0;
  for (int shift = 0; shift < 64 && !in.empty(); shift += 7) {
    const auto byte = static_cast<unsigned char>(in.front());
    in.remove_prefix(1);
    v |= static_cast<std::uint64_t>(byte & 0x7f) << shift;
    if ((byte & 0x80) == 0) return true;
  }
  return false;
}

// One answer's field entry: field 1 (stars), 2 (neighbors) or 3 (cells), length-delimited.
std::string compact_entry(BatchKind kind, const google::protobuf::MessageLite& answer) {
  std::string out;
  out += static_cast<char>(((kind == BatchKind::kStars ? 1 : kind == BatchKind::kNeighbors ? 2 : 3) << 3) | 2);
  const std::string bytes = answer.SerializeAsString();
  append_varint(out, bytes.size());
  out += bytes;
  return out;
}

std::string compact_item(const BatchAnswer& a, BatchKind kind, pb::NeighborMode mode) {
  pb::BatchSeedsResponse one;
  return compact_entry(kind, add_batch_answer(a, kind, mode, one));
}

// A part's answers as one framed message: the entries, then `done` (field 4).
std::string compact_frame(const std::vector<std::string>& items, std::size_t from, std::size_t to, std::uint64_t done) {
  std::string message;
  for (std::size_t i = from; i < to; ++i) message += items[i];
  message += static_cast<char>((4 << 3) | 0);
  append_varint(message, done);
  std::string frame;
  append_varint(frame, message.size());
  return frame + message;
}

// Another shard's compact answer, back into items (nullopt: malformed).
std::optional<std::vector<std::string>> compact_items(std::string_view body, BatchKind kind) {
  std::vector<std::string> items;
  while (!body.empty()) {
    std::uint64_t size = 0;
    if (!read_varint(body, size) || size > body.size()) return std::nullopt;
    pb::BatchSeedsResponse message;
    if (!message.ParseFromArray(body.data(), static_cast<int>(size))) return std::nullopt;
    body.remove_prefix(size);
    for (const auto& star : message.stars()) items.push_back(compact_entry(kind, star));
    for (const auto& neighbors : message.neighbors()) items.push_back(compact_entry(kind, neighbors));
    for (const auto& cell : message.cells()) items.push_back(compact_entry(kind, cell));
  }
  return items;
}

// A batch's encoder (Engine::AnswerEncoder): the answer's text kept, its data dropped.
Engine::AnswerEncoder encode_with(std::function<std::string(const BatchAnswer&)> item_of) {
  return [item_of = std::move(item_of)](BatchAnswer& a) {
    a.encoded = item_of(a);
    a.star = {};
    a.neighbors = {};
    a.cell = {};
  };
}

// Whether the request came from another shard's replica (Router: relayed once).
bool forwarded(const http::request<http::string_body>& request) {
  return request.find(kForwardedHeader) != request.end();
}

// The status an error body ({"error": {"status", "message"[, "reason"]}}) names.
Status status_of_error_body(const std::string& body) {
  const json error = json::parse(body, nullptr, false);
  Status s{Code::kInternal, "a shard answered: " + body.substr(0, 200)};
  if (error.is_object() && error.contains("error") && error["error"].is_object()) {
    const std::string name = error["error"].value("status", "");
    for (Code k : {Code::kCancelled, Code::kInvalidArgument, Code::kDeadlineExceeded, Code::kNotFound,
                   Code::kAlreadyExists, Code::kResourceExhausted, Code::kFailedPrecondition, Code::kOutOfRange,
                   Code::kUnimplemented, Code::kInternal, Code::kUnavailable, Code::kUnauthenticated}) {
      if (name == code_name(k)) s = Status{k, error["error"].value("message", "")};
    }
    // The reason too (OVER_BUDGET, STORAGE_FULL, SHARD_UNAVAILABLE): it picks the HTTP
    // status (status_map.hpp) and is part of the answer.
    if (const std::string reason = error["error"].value("reason", ""); !reason.empty() && !s.is_ok()) {
      s = std::move(s).with_reason(reason);
    }
  }
  return s;
}

}  // namespace

HttpApi::HttpApi(Engine& engine, Telemetry& telemetry, std::shared_ptr<const Authenticator> auth,
                 std::function<bool()> ready, std::shared_ptr<const UiAssets> ui, ShardPeers* peers)
    : engine_(engine),
      telemetry_(telemetry),
      auth_(std::move(auth)),
      ready_(std::move(ready)),
      ui_(std::move(ui)),
      peers_(peers),
      router_(engine, peers) {}

HttpResponse HttpApi::handle_request(const http::request<http::string_body>& request,
                                     std::function<bool()> client_gone) {
  return respond(request, std::move(client_gone), false);
}

std::optional<HttpResponse> HttpApi::answer_at_once(const http::request<http::string_body>& request) {
  HttpResponse r = respond(request, {}, true);
  if (r.status == 0) return std::nullopt;
  return r;
}

HttpResponse HttpApi::respond(const http::request<http::string_body>& request, std::function<bool()> client_gone,
                              bool at_once) {
  Context c{request, {}, std::move(client_gone), Clock::now() + engine_.limits().default_deadline, {}, {}, {}};
  c.at_once = at_once;
  c.record.transport = "http";
  const std::string_view target(request.target().data(), request.target().size());
  const std::size_t q = target.find('?');
  c.record.method = "Unrouted";  // each route names itself; never a raw path (metric label cardinality)
  if (q != std::string_view::npos) {
    std::string_view rest = target.substr(q + 1);
    while (!rest.empty()) {
      const std::size_t amp = rest.find('&');
      const std::string_view pair = rest.substr(0, amp);
      const std::size_t eq = pair.find('=');
      if (!pair.empty()) {
        c.query[percent_decode(pair.substr(0, eq))] =
            eq == std::string_view::npos ? "" : percent_decode(pair.substr(eq + 1));
      }
      if (amp == std::string_view::npos) break;
      rest = rest.substr(amp + 1);
    }
  }
  if (const auto it = request.find("X-Timeout-Ms"); it != request.end()) {
    auto ms = parse_uint(std::string(it->value()), "X-Timeout-Ms");
    if (!ms.is_ok()) return c.fail(ms.status());
    c.deadline = Clock::now() + std::chrono::milliseconds(std::min<std::uint64_t>(ms.value(), 1ull << 40));
  }
  HttpResponse response = route(c);
  if (response.status == 0) return response;  // not at once: nothing happened yet
  if (response.relay) return response;        // recorded once the peer answered
  if (!response.stream) {
    c.record.seconds = c.timer.seconds();
    telemetry_.record(c.record);
  }
  return response;
}

HttpResponse HttpApi::route(Context& c) {
  const auto& req = c.request;
  const std::string_view target(req.target().data(), req.target().size());
  const std::vector<std::string> p = split_path(target.substr(0, target.find('?')));
  const auto method = req.method();
  // Un-authenticated probes first.
  if (p.size() == 1 && p[0] == "healthz" && method == http::verb::get) {
    c.record.method = "Healthz";
    return c.ok({{"status", "SERVING"}});
  }
  if (p.size() == 1 && p[0] == "openapi.json" && method == http::verb::get) {
    c.record.method = "OpenApi";
    HttpResponse r;
    r.body = kOpenApiJson;
    return r;
  }
  // The browser page: static files holding no data, so no token is asked for them (the
  // page asks for one and sends it with each API call).
  if (ui_ != nullptr && method == http::verb::get && (p.empty() || p[0] == "docs" || p[0] == "ui")) {
    if (const UiAsset* asset = ui_->find(target.substr(0, target.find('?')))) {
      c.record.method = "Page";
      HttpResponse r;
      r.content_type = asset->content_type;
      r.body = std::string(asset->body);
      r.headers = UiAssets::security_headers();
      return r;
    }
    // /ui/ holds only the page's files: an unknown one is absent, token or not.
    if (!p.empty() && p[0] == "ui")
      return c.fail({Code::kNotFound, "no route for " + std::string(target.substr(0, 200))});
  }
  if (p.size() == 1 && p[0] == "readyz" && method == http::verb::get) {
    c.record.method = "Readyz";
    if (ready_ && !ready_()) return c.fail({Code::kUnavailable, "not ready: the server is starting or shutting down"});
    return c.ok({{"status", "READY"}});
  }
  {
    const auto it = req.find(http::field::authorization);
    const std::string_view presented =
        it == req.end() ? std::string_view{} : std::string_view(it->value().data(), it->value().size());
    auto principal = auth_->authenticate(presented, "Authorization header");
    if (!principal.is_ok()) return c.fail(principal.status());
    c.principal = std::move(principal).value();
  }
  // At once: a seed's GET only (below); the rest may read files or take long.
  if (c.at_once && !(p.size() == 6 && p[3] == "seeds" && method == http::verb::get)) return Context::later();
  if (p.size() == 1 && p[0] == "metrics" && method == http::verb::get) {
    c.record.method = "Metrics";
    auto& store = engine_.store();
    telemetry_.set_memory(store.memory_in_use(), store.loaded_count(), store.budget().used(), store.budget().limit());
    const auto [pieces, piece_bytes] = store.pieces_in_memory();
    telemetry_.set_pieces(pieces, piece_bytes, engine_.point_queries_from_whole());
    HttpResponse r;
    r.content_type = "text/plain; version=0.0.4";
    r.body = telemetry_.render_metrics();
    return r;
  }
  if (p.size() == 2 && p[0] == "v1" && p[1] == "domains:check") {
    if (method != http::verb::post) {
      return c.fail(
          {Code::kUnimplemented, std::string(req.method_string()) + " is not supported on /v1/domains:check"});
    }
    c.record.method = "CheckDomain";
    return check_domain(c);
  }
  if (p.size() < 2 || p[0] != "v1" || p[1] != "pointsets") {
    return c.fail({Code::kNotFound, "no route for " + std::string(target.substr(0, 200))});
  }
  auto wrong_method = [&] {
    return c.fail({Code::kUnimplemented, std::string(req.method_string()) + " is not supported on " +
                                             std::string(target.substr(0, target.find('?')))});
  };
  if (p.size() == 2) {
    if (method == http::verb::post) {
      c.record.method = "UploadPointSet";
      return upload(c);
    }
    if (method != http::verb::get) return wrong_method();
    c.record.method = "ListPointSets";
    std::uint32_t page_size = 0;
    if (auto s = c.param("page_size")) {
      auto v = parse_uint(*s, "page_size");
      if (!v.is_ok()) return c.fail(v.status());
      page_size = static_cast<std::uint32_t>(std::min<std::uint64_t>(v.value(), 1u << 30));
    }
    std::string next;
    auto page = engine_.list_point_sets(page_size, c.param("page_token").value_or(""), &next, c.principal);
    if (!page.is_ok()) return c.fail(page.status());
    json sets = json::array();
    for (const PointSetInfo& info : page.value()) sets.push_back(point_set_json(info));
    return c.ok({{"point_sets", sets}, {"next_page_token", next}});
  }
  if (p.size() == 3 && p[2].size() > 7 && p[2].compare(p[2].size() - 7, 7, ":append") == 0) {
    if (method != http::verb::post) return wrong_method();
    c.record.method = "AppendPoints";
    const std::string parent = p[2].substr(0, p[2].size() - 7);
    c.record.point_set = parent.substr(0, 64);
    return upload(c, &parent);
  }
  for (const auto& [suffix, interpolate] :
       {std::pair<std::string_view, bool>{":locate", false}, {":interpolate", true}}) {
    if (p.size() != 3 || p[2].size() <= suffix.size() ||
        p[2].compare(p[2].size() - suffix.size(), suffix.size(), suffix) != 0) {
      continue;
    }
    if (method != http::verb::post) return wrong_method();
    c.record.method = interpolate ? "Interpolate" : "Locate";
    const std::string set = p[2].substr(0, p[2].size() - suffix.size());
    c.record.point_set = set.substr(0, 64);
    if (Status s = engine_.authorize(set, c.principal); !s.is_ok()) return c.fail(s);
    return point_queries(c, set, interpolate);
  }
  const std::string& id = p[2];
  if (p.size() <= 6) c.record.point_set = id.substr(0, 64);
  // Other tenants' sets are answered as absent, on every route below.
  if (Status s = engine_.authorize(id, c.principal); !s.is_ok()) return c.fail(s);
  if (p.size() == 3) {
    if (method == http::verb::get) {
      c.record.method = "GetPointSet";
      auto info = engine_.get_point_set(id, c.principal);
      if (!info.is_ok()) return c.fail(info.status());
      return c.ok(point_set_json(info.value()));
    }
    if (method == http::verb::delete_) {
      c.record.method = "DeletePointSet";
      if (Status s = engine_.delete_point_set(id, c.principal); !s.is_ok()) return c.fail(s);
      return c.ok(json::object());
    }
    return wrong_method();
  }
  if (p.size() == 4 && (p[3] == "stars:batch" || p[3] == "neighbors:batch" || p[3] == "cells:batch")) {
    if (method != http::verb::post) return wrong_method();
    c.record.method = "BatchSeeds";
    return batch(c, id, p[3].substr(0, p[3].find(':')));
  }
  if (p.size() == 4 && p[3] == "cells") {
    // POST: the body is a domain of any shape (?domain=FORMAT); GET otherwise.
    if (method != http::verb::get && method != http::verb::post) return wrong_method();
    c.record.method = "StreamCells";
    return cells(c, id);
  }
  if (p.size() == 4 && p[3] == "values") {
    if (method != http::verb::post) return wrong_method();
    c.record.method = "PutValues";
    return put_values(c, id);
  }
  if (p.size() == 4 && p[3] == "points") {
    if (method != http::verb::get) return wrong_method();
    c.record.method = "DownloadPointSet";
    return points(c, id);
  }
  if ((p.size() == 4 && p[3] == "shards") || (p.size() == 5 && p[3] == "shards" && p[4] == "seeds")) {
    if (method != http::verb::get) return wrong_method();
    c.record.method = "GetShardMap";
    return shard_map(c, id, p.size() == 5);
  }
  if (p.size() == 4 && p[3] == "simplices") {
    if (method != http::verb::get) return wrong_method();
    c.record.method = "StreamSimplices";
    return simplices(c, id);
  }
  if (p.size() == 6 && p[3] == "seeds" && (p[5] == "star" || p[5] == "neighbors" || p[5] == "cell")) {
    if (method != http::verb::get && !(method == http::verb::post && p[5] == "cell")) return wrong_method();
    return seed_route(c, id, p[4], p[5]);
  }
  return c.fail({Code::kNotFound, "no route for " + std::string(target.substr(0, 200))});
}

HttpResponse HttpApi::upload(Context& c, const std::string* parent) {
  const std::string& body = c.request.body();
  const auto ctype = c.request.find(http::field::content_type);
  const std::string content_type = ctype == c.request.end() ? "" : std::string(ctype->value());
  const std::string media_type = media_type_of(content_type);
  UploadHeader header;
  std::vector<double> coords;
  if (media_type == "application/octet-stream") {
    std::optional<std::string> d = c.param("dimension");
    if (!d && parent != nullptr) {
      // Appending: the parent's dimension unless the client names one.
      auto info = engine_.get_point_set(*parent, c.principal);
      if (!info.is_ok()) return c.fail(info.status());
      d = std::to_string(info->dimension);
    }
    if (!d) return c.fail(invalid_argument("dimension: the query parameter is required for raw float64 uploads"));
    auto dim = parse_uint(*d, "dimension");
    if (!dim.is_ok()) return c.fail(dim.status());
    if (dim.value() < 2 || dim.value() > static_cast<std::uint64_t>(kMaxApproxDimension)) {
      return c.fail(invalid_argument("dimension: " + *d + " is not supported; it must be between 2 and " +
                                     std::to_string(kMaxApproxDimension)));
    }
    // weighted=true: the n points' coordinates, then their n weights (float64 each).
    const std::string weighted = c.param("weighted").value_or("false");
    if (weighted != "true" && weighted != "false") {
      return c.fail(invalid_argument("weighted: \"" + weighted.substr(0, 40) + "\" is not true or false"));
    }
    header.weighted = weighted == "true";
    if (auto box = c.param("periodic_box")) {
      auto v = parse_number_list(*box, "periodic_box", 2 * static_cast<std::size_t>(kMaxApproxDimension));
      if (!v.is_ok()) return c.fail(v.status());
      header.periodic_box = std::move(v).value();
    }
    const std::size_t row = 8 * dim.value() + (header.weighted ? 8 : 0);
    if (body.size() % row != 0) {
      return c.fail(invalid_argument("body: " + std::to_string(body.size()) + " bytes are not a whole number of " + *d +
                                     "-dimensional float64 points (" + std::to_string(row) + " bytes each" +
                                     (header.weighted ? ", with its weight" : "") + ")"));
    }
    header.dimension = static_cast<std::int64_t>(dim.value());
    header.count = static_cast<std::int64_t>(body.size() / row);
    header.display_name = c.param("display_name").value_or("");
    const std::size_t coordinate_bytes = static_cast<std::size_t>(header.count) * 8 * dim.value();
    return store_upload(c, header, std::span<const char>(body.data(), coordinate_bytes), parent,
                        std::span<const char>(body.data() + coordinate_bytes, body.size() - coordinate_bytes));
  }
  // JSON also under curl -d's default type, so `curl -d '{...}'` just works.
  if (!media_type.empty() && media_type != "application/json" && media_type != "application/x-www-form-urlencoded") {
    return c.fail(invalid_argument("Content-Type: \"" + content_type.substr(0, 80) +
                                   "\" is not supported; send application/json or application/octet-stream"));
  }
  MemoryBudget& budget = engine_.store().budget();
  MemoryBudget::Charge charge = budget.empty_charge();
  std::vector<double> weights;
  if (Status s = read_upload_json(body, engine_.limits(), header, coords, weights, &charge, &budget); !s.is_ok()) {
    return c.fail(s);
  }
  return store_upload(c, header, std::make_pair(std::move(coords), std::move(charge)), parent,
                      std::span<const char>(reinterpret_cast<const char*>(weights.data()), weights.size() * 8));
}

HttpResponse HttpApi::store_upload(Context& c, const UploadHeader& header, UploadData data, const std::string* parent,
                                   std::span<const char> weights) {
  auto session = parent == nullptr ? engine_.begin_upload(header) : engine_.begin_append(*parent, header, c.principal);
  if (!session.is_ok()) return c.fail(session.status());
  Status appended;
  if (data.index() == 0) {
    appended = session.value()->append(std::get<0>(data).data(), std::get<0>(data).size());
  } else if (parent == nullptr) {
    // Parsed doubles, the whole set: taken without a second copy.
    appended = session.value()->adopt(std::move(std::get<1>(data).first), std::move(std::get<1>(data).second));
  } else {
    // The new points follow the parent's, already in the session.
    const std::vector<double>& more = std::get<1>(data).first;
    appended = session.value()->append(more.data(), more.size() * sizeof(double));
  }
  if (appended.is_ok()) appended = session.value()->append_weights(weights.data(), weights.size());
  if (!appended.is_ok()) return c.fail(appended);
  auto info = engine_.finish_upload(*session.value(), c.principal);
  if (!info.is_ok()) return c.fail(info.status());
  if (!info->already_existed) telemetry_.add_points_uploaded(info->count);
  c.record.point_set = info->id;
  json body = point_set_json(info.value(), true);
  if (parent != nullptr) body["parent_id"] = *parent;
  return c.ok(body, info->already_existed ? 200 : 201);
}

HttpResponse HttpApi::seed_route(Context& c, const std::string& id, const std::string& seed_text,
                                 const std::string& what) {
  c.record.method = what == "star" ? "GetStar" : what == "neighbors" ? "GetNeighbors" : "GetVoronoiCell";
  auto seed = parse_uint(seed_text, "seed");
  if (!seed.is_ok()) return c.fail(seed.status());
  c.record.seed = seed.value();
  // A neighbours request's query is checked before anything is held (a bad mode must
  // not load a whole set).
  const std::string mode = c.param("mode").value_or("exact");
  NeighborQuery query;
  if (what == "neighbors") {
    std::uint64_t limits[2] = {0, 0};
    const char* names[2] = {"max_consecutive_misses", "max_vertices"};
    for (int i = 0; i < 2; ++i) {
      if (auto text = c.param(names[i])) {
        auto v = parse_uint(*text, names[i]);
        if (!v.is_ok()) return c.fail(v.status());
        limits[i] = v.value();
      }
    }
    auto parsed = neighbor_query_of(mode, limits[0], limits[1]);
    if (!parsed.is_ok()) return c.fail(parsed.status());
    query = parsed.value();
  }
  const bool approximate = what == "neighbors" && query.mode != NeighborQuery::Mode::kExact;
  // A cell's domain, likewise.
  DomainSpec spec;
  if (what == "cell") {
    auto parsed = domain_from_query(c);
    if (!parsed.is_ok()) return c.fail(parsed.status());
    spec = std::move(parsed).value();
  }
  std::optional<Holding> held;
  if (c.at_once) {
    // Another shard's seed: relayed by the server without a thread (relay_at_once).
    if (peers_ != nullptr) {
      const SeedRoute route = router_.route(id, seed.value(), forwarded(c.request));
      if (!route.here) return relay_at_once(c, route.shard);
    }
    // From a kept triangulation in memory; an approximate walk, a domain of a piece
    // (whose cell may need other pieces' points) and every error take a thread.
    if (approximate) return Context::later();
    held = engine_.hold_at_hand(id, seed.value());
    if (!held) return Context::later();
    if (what == "cell" && held->set->piece && !spec.empty()) return Context::later();
  } else {
    // A seed of another shard's piece is answered there (Router: relayed once).
    const SeedRoute route = router_.route(id, seed.value(), forwarded(c.request));
    if (!route.here) return forward(c, route.shard);
    auto holding = engine_.hold(id, seed.value(), !approximate);
    if (!holding.is_ok()) return c.fail(holding.status());
    held = std::move(holding).value();
  }
  CallControl control(c.deadline, c.client_gone);
  if (what == "star") {
    auto answer = engine_.star(*held, control);
    if (!answer.is_ok()) return c.fail(answer.status());
    telemetry_.add_simplices_served(answer->star.size());
    return c.ok_text(star_text(answer.value(), id, seed.value()));
  }
  if (what == "neighbors") {
    auto answer = engine_.neighbors(*held, query, control);
    if (!answer.is_ok()) return c.fail(answer.status());
    return c.ok_text(neighbors_text(answer.value(), id, seed.value(), mode));
  }
  auto cell = engine_.cell(*held, spec, control);
  if (!cell.is_ok()) return c.fail(cell.status());
  return c.ok_text(cell_text(cell.value(), &id));
}

ShardPeers::HttpRequest HttpApi::relayed_request(const Context& c) {
  ShardPeers::HttpRequest request = c.request;
  // The peer's deadline is what is left of this one.
  const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(c.deadline - Clock::now());
  request.set("X-Timeout-Ms", std::to_string(std::max<std::int64_t>(1, left.count())));
  return request;
}

HttpResponse HttpApi::forward(Context& c, std::uint32_t shard) {
  return relayed_response(c.record, shard, peers_->forward_http(shard, relayed_request(c), c.deadline));
}

HttpResponse HttpApi::relay_at_once(Context& c, std::uint32_t shard) {
  HttpResponse r;
  r.relay = std::make_shared<PendingRelay>();
  r.relay->peers = peers_;
  r.relay->shard = shard;
  r.relay->request = relayed_request(c);
  r.relay->deadline = c.deadline;
  r.relay->finish = [this, shard, record = c.record,
                     timer = c.timer](Result<ShardPeers::HttpResponse> relayed) mutable -> HttpResponse {
    HttpResponse response = relayed_response(record, shard, std::move(relayed));
    record.seconds = timer.seconds();
    telemetry_.record(record);
    return response;
  };
  return r;
}

HttpResponse HttpApi::relayed_response(Telemetry::Request& record, std::uint32_t shard,
                                       Result<ShardPeers::HttpResponse> relayed) {
  telemetry_.add_forwarded(shard, relayed.status().code());
  if (!relayed.is_ok()) return Context::failure(record, relayed.status());
  ShardPeers::HttpResponse& peer = relayed.value();
  HttpResponse r;
  r.status = peer.result_int();
  if (r.status >= 400) {
    // Recorded here as the peer answered it (the gRPC code its error names).
    const Status error = status_of_error_body(peer.body());
    record.code = error.code();
    record.message = error.message();
  }
  r.content_type = std::string(peer[http::field::content_type]);
  r.body = std::move(peer.body());
  for (const auto& field : peer) {
    const auto name = field.name();
    if (name == http::field::content_type || name == http::field::content_length || name == http::field::connection ||
        name == http::field::keep_alive || name == http::field::transfer_encoding || name == http::field::server ||
        name == http::field::date) {
      continue;
    }
    r.headers.emplace_back(std::string(field.name_string()), std::string(field.value()));
  }
  r.headers.emplace_back("X-Spokemesh-Shard", std::to_string(shard));
  return r;
}

// A stream records its own outcome once it ends (after the headers went out).
Status HttpApi::finish_stream(Telemetry::Request& record, const RequestTimer& timer, Status s) {
  record.code = s.code();
  record.message = s.message();
  record.seconds = timer.seconds();
  telemetry_.record(record);
  return s;
}

Result<DomainSpec> HttpApi::domain_from_query(Context& c) {
  DomainSpec spec;
  if (auto box = c.param("box")) {
    auto v = parse_number_list(*box, "box", (kMaxDomainWalls + 1) * (kMaxDimension + 1));
    if (!v.is_ok()) return v.status();
    spec.box = std::move(v).value();
  }
  if (auto h = c.param("halfspaces")) {
    auto v = parse_number_list(*h, "halfspaces", (kMaxDomainWalls + 1) * (kMaxDimension + 1));
    if (!v.is_ok()) return v.status();
    spec.halfspaces = std::move(v).value();
  }
  auto bounding_box = bool_param(c, "bounding_box");
  if (!bounding_box.is_ok()) return bounding_box.status();
  spec.bounding_box = bounding_box.value();
  // A domain of any shape: POST with the file as the body and ?domain=FORMAT.
  const bool post = c.request.method() == http::verb::post;
  if (auto format = c.param("domain")) {
    if (!post) return invalid_argument("domain=" + format->substr(0, 40) + ": send the domain file as a POST body");
    spec.shape_format = *format;
    spec.shape_data = c.request.body();
  } else if (post) {
    return invalid_argument("POST: give ?domain=FORMAT (off, obj, stl, rings, geojson) for the domain in the body");
  }
  return spec;
}

Result<bool> HttpApi::bool_param(Context& c, const char* name) {
  const auto text = c.param(name);
  if (!text) return false;
  if (*text != "true" && *text != "false") {
    return invalid_argument(std::string(name) + ": '" + text->substr(0, 40) + "' is not true or false");
  }
  return *text == "true";
}

Result<std::array<std::uint64_t, 3>> HttpApi::shard_params(Context& c) {
  std::array<std::uint64_t, 3> values = {0, 1, 0};
  const char* names[3] = {"shard", "shards", "batch_size"};
  for (int i = 0; i < 3; ++i) {
    if (auto s = c.param(names[i])) {
      auto v = parse_uint(*s, names[i]);
      if (!v.is_ok()) return v.status();
      if (v.value() > 0xFFFFFFFFull) return invalid_argument(std::string(names[i]) + ": " + *s + " is too large");
      values[i] = v.value();
    }
  }
  return values;
}

// POST /v1/domains:check?domain=FORMAT with a domain file as the body: the domain as
// validated (its fault named, 400) and oriented, for a client to draw its walls.
HttpResponse HttpApi::check_domain(Context& c) {
  const auto format = c.param("domain");
  if (!format) return c.fail(invalid_argument("give ?domain=FORMAT (off, obj, stl, rings, geojson)"));
  auto shape = engine_.parse_shape(*format, c.request.body());
  if (!shape.is_ok()) return c.fail(shape.status());
  const ShapeDomain& s = *shape.value();
  const int d = s.dimension();
  json vertices = json::array(), faces = json::array();
  for (std::size_t v = 0; v < s.vertex_count(); ++v) {
    vertices.push_back(json(std::vector<double>(s.vertices().begin() + static_cast<std::ptrdiff_t>(v * d),
                                                s.vertices().begin() + static_cast<std::ptrdiff_t>((v + 1) * d))));
  }
  for (std::size_t f = 0; f < s.face_count(); ++f) {
    faces.push_back(json(std::vector<std::uint32_t>(s.faces().begin() + static_cast<std::ptrdiff_t>(f * d),
                                                    s.faces().begin() + static_cast<std::ptrdiff_t>((f + 1) * d))));
  }
  return c.ok({{"dimension", d},
               {"description", s.describe()},
               {"components", s.component_count()},
               {"volume", s.volume()},
               {"boundary_measure", s.boundary_measure()},
               {"vertices", std::move(vertices)},
               {"faces", std::move(faces)}});
}

HttpResponse HttpApi::cells(Context& c, const std::string& id) {
  auto shard = shard_params(c);
  if (!shard.is_ok()) return c.fail(shard.status());
  const std::array<std::uint64_t, 3> values = shard.value();
  auto measures_only_or = bool_param(c, "measures_only");
  if (!measures_only_or.is_ok()) return c.fail(measures_only_or.status());
  const bool measures_only = measures_only_or.value();
  auto spec = domain_from_query(c);
  if (!spec.is_ok()) return c.fail(spec.status());
  HttpResponse r;
  r.content_type = "application/x-ndjson";
  // One JSON object per line and cell, in seed order.
  r.stream = [this, id, values, measures_only, spec = std::move(spec).value(), deadline = c.deadline,
              gone = c.client_gone, record = c.record,
              timer = c.timer](const std::function<bool(std::string_view)>& write_chunk) mutable -> Status {
    CallControl control(deadline, gone);
    std::string text;
    auto emit = [&](std::span<const VoronoiCell> batch, std::uint64_t) -> Status {
      text.clear();
      for (const VoronoiCell& cell : batch) {
        text += cell_text(cell);
        text += '\n';
      }
      if (!write_chunk(text)) return cancelled("streaming stopped: the client went away");
      return Status::ok();
    };
    Status s = engine_.stream_cells(id, static_cast<std::uint32_t>(values[0]), static_cast<std::uint32_t>(values[1]),
                                    static_cast<std::uint32_t>(values[2]), spec, measures_only, control, emit);
    return finish_stream(record, timer, std::move(s));
  };
  return r;
}

HttpResponse HttpApi::simplices(Context& c, const std::string& id) {
  auto shard = shard_params(c);
  if (!shard.is_ok()) return c.fail(shard.status());
  const std::array<std::uint64_t, 3> values = shard.value();
  HttpResponse r;
  r.content_type = "application/x-ndjson";
  // The stream runs after the headers are decided; it records its own outcome.
  r.stream = [this, id, values, deadline = c.deadline, gone = c.client_gone, record = c.record,
              timer = c.timer](const std::function<bool(std::string_view)>& write_chunk) mutable -> Status {
    CallControl control(deadline, gone);
    std::string text;
    int dimension = 0;
    auto emit = [&](std::span<const std::uint32_t> batch, std::span<const std::int32_t> offsets,
                    std::uint64_t) -> Status {
      const std::size_t width = static_cast<std::size_t>(dimension) + 1;
      const std::size_t d = width - 1;
      text.clear();
      for (std::size_t i = 0; i < batch.size(); i += width) {
        // A plain line is [i,j,k]; a periodic one {"simplex":[i,j,k],"offsets":[[..],[..],[..]]}.
        text += offsets.empty() ? "[" : "{\"simplex\":[";
        for (std::size_t k = 0; k < width; ++k) {
          if (k > 0) text += ',';
          text += std::to_string(batch[i + k]);
        }
        if (!offsets.empty()) {
          text += "],\"offsets\":[";
          for (std::size_t v = 0; v < width; ++v) {
            text += v > 0 ? ",[" : "[";
            for (std::size_t k = 0; k < d; ++k) {
              if (k > 0) text += ',';
              text += std::to_string(offsets[(i + v) * d + k]);
            }
            text += ']';
          }
          text += ']';
        }
        text += offsets.empty() ? "]\n" : "}\n";
      }
      if (!write_chunk(text)) return cancelled("streaming stopped: the client went away");
      telemetry_.add_simplices_served(batch.size() / width);
      return Status::ok();
    };
    Status s =
        engine_.stream_simplices(id, static_cast<std::uint32_t>(values[0]), static_cast<std::uint32_t>(values[1]),
                                 static_cast<std::uint32_t>(values[2]), control, emit, nullptr, &dimension);
    return finish_stream(record, timer, std::move(s));
  };
  return r;
}

// GET .../points: the coordinates as a NumPy .npy file (format 1.0: a header naming
// dtype and shape, then the values in C order), streamed in chunks from the stored set
// so that no copy of it is held. float32 halves the bytes for a viewer.
HttpResponse HttpApi::points(Context& c, const std::string& id) {
  const std::string dtype = c.param("dtype").value_or("float64");
  if (dtype != "float64" && dtype != "float32") {
    return c.fail(invalid_argument("dtype: \"" + dtype.substr(0, 40) + "\" is not float64 or float32"));
  }
  auto set = engine_.point_set(id);
  if (!set.is_ok()) return c.fail(set.status());
  HttpResponse r;
  r.content_type = "application/octet-stream";
  r.headers = {{"Content-Disposition", "attachment; filename=\"" + id.substr(0, 64) + ".npy\""}};
  r.stream = [this, set = std::move(set).value(), wide = dtype == "float64", deadline = c.deadline,
              gone = c.client_gone, record = c.record,
              timer = c.timer](const std::function<bool(std::string_view)>& write_chunk) mutable -> Status {
    CallControl control(deadline, gone);
    const auto coords = set->points.coordinates();
    const std::size_t n = set->points.size(), d = static_cast<std::size_t>(set->points.dimension());
    std::string header = std::string("{'descr': '") + (wide ? "<f8" : "<f4") + "', 'fortran_order': False, 'shape': (" +
                         std::to_string(n) + ", " + std::to_string(d) + "), }";
    // Magic, version 1.0, a little-endian u16 length, then the dict padded with spaces
    // and ended by a newline so that the data starts on a 64-byte boundary.
    const std::size_t unpadded = 10 + header.size() + 1;
    header.append((64 - unpadded % 64) % 64, ' ');
    header += '\n';
    std::string chunk("\x93NUMPY\x01\x00", 8);
    chunk += static_cast<char>(header.size() & 0xff);
    chunk += static_cast<char>(header.size() >> 8);
    chunk += header;
    Status s = Status::ok();
    if (!write_chunk(chunk)) s = cancelled("download stopped: the client went away");
    constexpr std::size_t kValues = defaults::kDownloadChunkBytes / sizeof(double);
    std::vector<float> narrow;
    for (std::size_t at = 0; s.is_ok() && at < coords.size(); at += kValues) {
      if (control.stopped()) {
        s = control.stopped_status("download");
        break;
      }
      const std::size_t count = std::min(kValues, coords.size() - at);
      std::string_view bytes;
      if (wide) {
        // float64 is stored little-endian already (x86-64 and aarch64 hosts).
        bytes = {reinterpret_cast<const char*>(coords.data() + at), count * sizeof(double)};
      } else {
        narrow.assign(coords.begin() + static_cast<std::ptrdiff_t>(at),
                      coords.begin() + static_cast<std::ptrdiff_t>(at + count));
        bytes = {reinterpret_cast<const char*>(narrow.data()), count * sizeof(float)};
      }
      if (!write_chunk(bytes)) s = cancelled("download stopped: the client went away");
    }
    return finish_stream(record, timer, std::move(s));
  };
  return r;
}

// GET .../shards: the shard map's description (JSON); .../shards/seeds: the shard of
// every seed as a .npy uint16 array (n,). Every answer carries its version.
HttpResponse HttpApi::shard_map(Context& c, const std::string& id, bool seeds) {
  auto map = router_.shard_map(id);
  if (!map.is_ok()) return c.fail(map.status());
  const ShardMap& m = map->map;
  HttpResponse r;
  if (!seeds) {
    r = c.ok({{"point_set_id", id},
              {"sharded", m.sharded},
              {"version", m.version},
              {"shard_count", m.shard_count},
              {"count", m.count},
              {"grpc_addresses", map->grpc_addresses},
              {"http_addresses", map->http_addresses}});
  } else {
    if (!m.sharded) {
      return c.fail(failed_precondition("point set " + id +
                                        " is answered by every replica (not kept as pieces on a sharded deployment): "
                                        "it has no per-seed shards"));
    }
    std::string header = "{'descr': '<u2', 'fortran_order': False, 'shape': (" + std::to_string(m.count) + ",), }";
    const std::size_t unpadded = 10 + header.size() + 1;
    header.append((64 - unpadded % 64) % 64, ' ');
    header += '\n';
    r.content_type = "application/octet-stream";
    r.body = std::string("\x93NUMPY\x01\x00", 8);
    r.body += static_cast<char>(header.size() & 0xff);
    r.body += static_cast<char>(header.size() >> 8);
    r.body += header;
    r.body.append(reinterpret_cast<const char*>(m.seed_shards.data()), m.seed_shards.size() * 2);
  }
  r.headers.emplace_back("X-Spokemesh-Shard-Map", m.version);
  return r;
}

namespace {

// A request's JSON body, or INVALID_ARGUMENT saying why it is not JSON.
Result<json> json_body(const std::string& text) {
  try {
    return json::parse(text);
  } catch (const json::exception& e) {
    return invalid_argument(std::string("body: not JSON (") + e.what() + ")");
  }
}

}  // namespace

// POST .../{stars,neighbors,cells}:batch with {"seeds": [...], ...}: NDJSON, one line
// per seed in request order, each the single route's body.
HttpResponse HttpApi::batch(Context& c, const std::string& id, const std::string& what) {
  auto parsed = json_body(c.request.body());
  if (!parsed.is_ok()) return c.fail(parsed.status());
  json body = std::move(parsed).value();
  if (!body.is_object() || !body.contains("seeds") || !body["seeds"].is_array()) {
    return c.fail(invalid_argument("seeds: the body needs {\"seeds\": [i, j, ...]}"));
  }
  const json& list = body["seeds"];
  if (list.size() > defaults::kMaxBatchSeeds) {
    return c.fail(invalid_argument("seeds: " + std::to_string(list.size()) + " exceed the limit of " +
                                   std::to_string(defaults::kMaxBatchSeeds) + " per call"));
  }
  std::vector<std::uint64_t> seeds;
  seeds.reserve(list.size());
  for (std::size_t i = 0; i < list.size(); ++i) {
    if (!list[i].is_number_unsigned()) {
      return c.fail(invalid_argument("seeds[" + std::to_string(i) + "]: " + list[i].dump().substr(0, 40) +
                                     " is not a non-negative integer"));
    }
    seeds.push_back(list[i].get<std::uint64_t>());
  }
  auto number = [&](const char* key) -> Result<std::uint64_t> {
    if (!body.contains(key)) return std::uint64_t{0};
    if (!body[key].is_number_unsigned()) return invalid_argument(std::string(key) + ": not a non-negative integer");
    return body[key].get<std::uint64_t>();
  };
  const std::string mode =
      body.contains("mode") && body["mode"].is_string() ? body["mode"].get<std::string>() : "exact";
  auto misses = number("max_consecutive_misses");
  if (!misses.is_ok()) return c.fail(misses.status());
  auto max_vertices = number("max_vertices");
  if (!max_vertices.is_ok()) return c.fail(max_vertices.status());
  auto query = neighbor_query_of(mode, misses.value(), max_vertices.value());
  if (!query.is_ok()) return c.fail(query.status());
  DomainSpec spec;
  for (const char* key : {"box", "halfspaces"}) {
    if (!body.contains(key)) continue;
    if (!body[key].is_array()) return c.fail(invalid_argument(std::string(key) + ": expected an array of numbers"));
    std::vector<double>& out = std::string(key) == "box" ? spec.box : spec.halfspaces;
    for (const json& v : body[key]) {
      if (!v.is_number()) return c.fail(invalid_argument(std::string(key) + ": expected an array of numbers"));
      out.push_back(v.get<double>());
    }
  }
  spec.bounding_box =
      body.contains("bounding_box") && body["bounding_box"].is_boolean() && body["bounding_box"].get<bool>();
  if (body.contains("domain")) {
    const json& shape = body["domain"];
    if (!shape.is_object() || !shape.contains("format") || !shape["format"].is_string() || !shape.contains("data") ||
        !shape["data"].is_string()) {
      return c.fail(invalid_argument(
          "domain: expected {\"format\": \"off|obj|stl|rings|geojson\", \"data\": \"the file's text\"}"));
    }
    spec.shape_format = shape["format"].get<std::string>();
    spec.shape_data = shape["data"].get<std::string>();
    if (spec.shape_format.empty()) spec.shape_format = "(none)";
  }
  const BatchKind kind = what == "stars"       ? BatchKind::kStars
                         : what == "neighbors" ? BatchKind::kNeighbors
                                               : BatchKind::kCells;
  // On a sharded replica, the seeds of other shards' pieces go to those shards.
  auto routed = router_.batch_routes(id, seeds, forwarded(c.request));
  if (!routed.is_ok()) return c.fail(routed.status());
  std::vector<std::uint32_t> routes = std::move(routed).value();
  const bool relays = !routes.empty();
  // The compact form when the client asks for it (Accept: application/x-protobuf).
  const auto accept = c.request.find(http::field::accept);
  const bool compact =
      accept != c.request.end() &&
      std::string_view(accept->value().data(), accept->value().size()).find(kCompactType) != std::string_view::npos;
  const pb::NeighborMode pb_mode = neighbor_mode_proto(query->mode);
  HttpResponse r;
  r.content_type = compact ? std::string(kCompactType) + "; delimited=true" : "application/x-ndjson";
  r.stream = [this, id, seeds = std::move(seeds), routes = std::move(routes), body = std::move(body),
              request = relays ? c.request : http::request<http::string_body>(), kind, mode, query = query.value(),
              spec, deadline = c.deadline, gone = c.client_gone, record = c.record, timer = c.timer, compact,
              pb_mode](const std::function<bool(std::string_view)>& write_chunk) mutable -> Status {
    CallControl control(deadline, gone);
    // One answer as written: a JSON line's text, or the compact form's field entry.
    auto item_of = [&](const BatchAnswer& a) {
      if (compact) return compact_item(a, kind, pb_mode);
      if (kind == BatchKind::kStars) return star_text(a.star, id, a.seed);
      if (kind == BatchKind::kNeighbors) return neighbors_text(a.neighbors, id, a.seed, mode);
      return cell_text(a.cell, &id);
    };
    // Consecutive items as written: lines, or framed messages of about 2 MiB at most.
    // One buffer for every chunk (each write is waited for): large blocks are fresh
    // pages from the system each time (--max-memory's mmap threshold), which cost more
    // to fault in than to fill.
    std::string text;
    auto write_items = [&](const std::vector<std::string>& items, std::uint64_t done) -> Status {
      text.clear();
      if (!compact) {
        for (const std::string& item : items) {
          text += item;
          text += '\n';
        }
      } else {
        std::size_t from = 0, bytes = 0;
        for (std::size_t i = 0; i < items.size(); ++i) {
          bytes += items[i].size();
          if (bytes > defaults::kMessagePayloadBytes || i + 1 == items.size()) {
            text += compact_frame(items, from, i + 1, done - (items.size() - 1 - i));
            from = i + 1;
            bytes = 0;
          }
        }
      }
      if (!write_chunk(text)) return cancelled("streaming stopped: the client went away");
      return Status::ok();
    };
    if (!routes.empty()) {
      Status s =
          relay_batch(request, body, id, seeds, routes, kind, query, spec, control, item_of, write_items, compact);
      return finish_stream(record, timer, std::move(s));
    }
    std::vector<std::string> items;
    auto emit = [&](std::span<const BatchAnswer> answers, std::uint64_t done) -> Status {
      items.clear();
      for (const BatchAnswer& a : answers) items.push_back(a.encoded);
      return write_items(items, done);
    };
    // Encoded by the workers that computed the answers (the encoding is most of a
    // JSON batch's time: it runs in parallel, beside the next round's answers).
    Status s = engine_.batch(id, seeds, kind, query, spec, control, emit, encode_with(item_of));
    return finish_stream(record, timer, std::move(s));
  };
  return r;
}

namespace {

// One query's line of :locate: where it lies and, asked, its natural neighbours.
std::string locate_text(const PointResult& r, bool natural) {
  std::string out;
  JsonText j(out);
  j.open_object();
  const auto w = static_cast<std::size_t>(r.answer.vertex_count);
  j.key("barycentric");
  if (w == 0) {
    j.raw("null");
  } else {
    j.array(std::span<const double>(r.answer.barycentric.data(), w));
  }
  j.key("index").integer(r.index);
  if (natural) {
    j.key("natural_neighbors").array(std::span<const std::uint32_t>(r.answer.natural.neighbors));
  }
  j.key("simplex");
  if (w == 0) {
    j.raw("null");
  } else {
    j.array(std::span<const std::uint32_t>(r.answer.simplex.data(), w));
  }
  if (natural) j.key("weights").array(std::span<const double>(r.answer.natural.weights));
  j.close_object();
  return out;
}

// One query's line of :interpolate: its values (null outside the hull without a fill).
std::string values_text(const PointResult& r) {
  std::string out;
  JsonText j(out);
  j.open_object();
  j.key("index").integer(r.index);
  if (r.nearest >= 0) j.key("nearest").integer(r.nearest);
  j.key("values");
  if (r.has_values) {
    j.array(std::span<const double>(r.values));
  } else {
    j.raw("null");
  }
  j.close_object();
  return out;
}

// Numbers of `field` in a JSON body: a flat array, or an array of rows of equal length
// (*width set to it). Names the first bad entry.
Status json_numbers(const json& body, const char* field, std::vector<double>& out, std::size_t* width) {
  if (!body.contains(field)) return invalid_argument(std::string(field) + ": required");
  const json& list = body[field];
  if (!list.is_array()) return invalid_argument(std::string(field) + ": expected an array of numbers or of rows");
  out.reserve(list.size());
  for (std::size_t i = 0; i < list.size(); ++i) {
    const json& item = list[i];
    if (item.is_number() && *width == 0) {
      out.push_back(item.get<double>());
      continue;
    }
    if (!item.is_number() && !item.is_array()) {
      return invalid_argument(std::string(field) + "[" + std::to_string(i) + "]: " + item.dump().substr(0, 40) +
                              " is not a number or a row of numbers");
    }
    if (i > 0 && item.is_array() != (*width > 0)) {
      return invalid_argument(std::string(field) + "[" + std::to_string(i) +
                              "]: numbers and rows mixed (give every entry as a number, or every one as a row)");
    }
    if (i == 0) *width = item.size();
    if (item.empty()) return invalid_argument(std::string(field) + "[" + std::to_string(i) + "]: an empty row");
    if (item.size() != *width) {
      return invalid_argument(std::string(field) + "[" + std::to_string(i) + "]: " + std::to_string(item.size()) +
                              " numbers, expected " + std::to_string(*width) + " (the rows before)");
    }
    for (std::size_t k = 0; k < item.size(); ++k) {
      if (!item[k].is_number()) {
        return invalid_argument(std::string(field) + "[" + std::to_string(i) + "][" + std::to_string(k) +
                                "]: " + item[k].dump().substr(0, 40) + " is not a number");
      }
      out.push_back(item[k].get<double>());
    }
  }
  return Status::ok();
}

// A body's "values": one number or one row per point; `width` the rows' length, or for
// a flat array the body's "width" (a positive integer, default 1).
Status json_values(const json& body, std::vector<double>& out, std::size_t* width) {
  if (Status s = json_numbers(body, "values", out, width); !s.is_ok()) return s;
  if (*width != 0) return Status::ok();
  *width = 1;
  if (body.contains("width")) {
    if (!body["width"].is_number_unsigned() || body["width"].get<std::uint64_t>() == 0) {
      return invalid_argument("width: not a positive integer");
    }
    *width = body["width"].get<std::size_t>();
  }
  return Status::ok();
}

}  // namespace

HttpResponse HttpApi::point_queries(Context& c, const std::string& id, bool interpolate) {
  auto parsed = json_body(c.request.body());
  if (!parsed.is_ok()) return c.fail(parsed.status());
  json body = std::move(parsed).value();
  if (!body.is_object()) return c.fail(invalid_argument("body: expected a JSON object with \"queries\""));
  auto info = engine_.get_point_set(id, c.principal);
  if (!info.is_ok()) return c.fail(info.status());
  const int d = info->dimension;
  std::vector<double> queries;
  std::size_t query_width = 0;
  if (Status s = json_numbers(body, "queries", queries, &query_width); !s.is_ok()) return c.fail(s);
  if (query_width != 0 && query_width != static_cast<std::size_t>(d)) {
    return c.fail(invalid_argument("queries[0]: " + std::to_string(query_width) + " coordinates, but point set " + id +
                                   " is " + std::to_string(d) + "-d"));
  }
  PointQuery query;
  std::vector<double> values;
  std::shared_ptr<const KeptValues> kept;  // values_id's
  if (interpolate) {
    const std::string method = body.contains("method") && body["method"].is_string()
                                   ? body["method"].get<std::string>()
                                   : (d == 2 || d == 3 ? "natural" : "linear");
    if (method == "natural") {
      query.method = PointMethod::kNatural;
    } else if (method == "linear") {
      query.method = PointMethod::kLinear;
    } else if (method == "nearest") {
      query.method = PointMethod::kNearest;
    } else {
      return c.fail(invalid_argument("method: \"" + method.substr(0, 40) + "\" is not natural, linear or nearest"));
    }
    if (body.contains("values_id")) {
      if (!body["values_id"].is_string()) return c.fail(invalid_argument("values_id: not a string"));
      if (body.contains("values")) return c.fail(invalid_argument("values: give values or values_id, not both"));
      auto got = engine_.kept_values(id, body["values_id"].get<std::string>());
      if (!got.is_ok()) return c.fail(got.status());
      kept = std::move(got).value();
      query.width = kept->width;
    } else if (Status s = json_values(body, values, &query.width); !s.is_ok()) {
      return c.fail(s);
    }
    query.values = values;
    if (body.contains("fill_value")) {
      if (!body["fill_value"].is_number()) return c.fail(invalid_argument("fill_value: not a number"));
      query.fill = body["fill_value"].get<double>();
    }
  } else if (body.contains("natural")) {
    if (!body["natural"].is_boolean()) return c.fail(invalid_argument("natural: not true or false"));
    query.natural = body["natural"].get<bool>();
  }
  const bool natural = !interpolate && query.natural && (d == 2 || d == 3);
  HttpResponse r;
  r.content_type = "application/x-ndjson";
  r.stream = [this, id, queries = std::move(queries), values = std::move(values), kept, query, interpolate, natural,
              deadline = c.deadline, gone = c.client_gone, record = c.record,
              timer = c.timer](const std::function<bool(std::string_view)>& write_chunk) mutable -> Status {
    CallControl control(deadline, gone);
    query.values = kept ? std::span<const double>(kept->values) : std::span<const double>(values);
    std::string text;
    auto emit = [&](std::span<const PointResult> answers, std::uint64_t) -> Status {
      text.clear();
      for (const PointResult& a : answers) {
        text += a.encoded;
        text += '\n';
      }
      if (!write_chunk(text)) return cancelled("streaming stopped: the client went away");
      return Status::ok();
    };
    auto encode = [interpolate, natural](PointResult& a) {
      a.encoded = interpolate ? values_text(a) : locate_text(a, natural);
      a.answer.natural.neighbors = {};
      a.answer.natural.weights = {};
      a.values = {};
    };
    Status s = engine_.points(id, queries, query, control, emit, encode);
    return finish_stream(record, timer, std::move(s));
  };
  return r;
}

// POST .../{id}/values: JSON {"values": [...] or [[...], ...], "width": k}, or raw
// little-endian float64 (Content-Type application/octet-stream, ?width=k).
HttpResponse HttpApi::put_values(Context& c, const std::string& id) {
  const auto ctype = c.request.find(http::field::content_type);
  const std::string media_type = media_type_of(ctype == c.request.end() ? "" : std::string(ctype->value()));
  std::vector<double> values;
  std::size_t width = 0;
  if (media_type == "application/octet-stream") {
    const std::string& body = c.request.body();
    if (body.size() % sizeof(double) != 0) {
      return c.fail(invalid_argument("body: " + std::to_string(body.size()) + " bytes are not whole float64 values"));
    }
    values.resize(body.size() / sizeof(double));
    std::memcpy(values.data(), body.data(), body.size());
    width = 1;
    if (auto w = c.param("width")) {
      auto v = parse_uint(*w, "width");
      if (!v.is_ok()) return c.fail(v.status());
      width = v.value();
    }
  } else {
    auto parsed = json_body(c.request.body());
    if (!parsed.is_ok()) return c.fail(parsed.status());
    const json body = std::move(parsed).value();
    if (!body.is_object()) return c.fail(invalid_argument("body: expected a JSON object with \"values\""));
    if (Status s = json_values(body, values, &width); !s.is_ok()) return c.fail(s);
  }
  if (width == 0 || width > 1u << 20) return c.fail(invalid_argument("width: not between 1 and 1048576"));
  auto put = engine_.put_values(id, values, static_cast<std::uint32_t>(width));
  if (!put.is_ok()) return c.fail(put.status());
  return c.ok({{"values_id", put->values_id},
               {"point_set_id", put->point_set_id},
               {"width", put->width},
               {"count", put->count},
               {"already_existed", put->already_existed}},
              put->already_existed ? 200 : 201);
}

Status HttpApi::relay_batch(const http::request<http::string_body>& request, const json& body, const std::string& id,
                            const std::vector<std::uint64_t>& seeds, const std::vector<std::uint32_t>& routes,
                            BatchKind kind, const NeighborQuery& query, const DomainSpec& spec,
                            const CallControl& control, const std::function<std::string(const BatchAnswer&)>& item_of,
                            const std::function<Status(const std::vector<std::string>&, std::uint64_t)>& write_items,
                            bool compact) {
  json base = body;  // the request without its seeds, copied once
  base.erase("seeds");
  // Another shard's items for its seeds: the request relayed with only them (in the
  // same form: the client's Accept goes along).
  auto ask = [&](std::uint32_t shard, const std::vector<std::uint64_t>& part) -> Result<std::vector<std::string>> {
    json asked = base;
    asked["seeds"] = part;
    ShardPeers::HttpRequest relayed = request;
    relayed.body() = dump(asked);
    relayed.prepare_payload();
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(control.deadline() - Clock::now());
    relayed.set("X-Timeout-Ms", std::to_string(std::max<std::int64_t>(1, left.count())));
    auto answer = peers_->forward_http(shard, std::move(relayed), control.deadline());
    telemetry_.add_forwarded(shard, answer.status().code());
    if (!answer.is_ok()) return answer.status();
    if (answer->result_int() != 200) return status_of_error_body(answer->body());
    if (compact) {
      auto items = compact_items(answer->body(), kind);
      if (!items) return Status{Code::kUnavailable, "shard " + std::to_string(shard) + " answered a malformed batch"};
      return std::move(*items);
    }
    std::vector<std::string> lines;
    std::string_view text = answer->body();
    while (!text.empty()) {
      const std::size_t newline = text.find('\n');
      lines.emplace_back(text.substr(0, newline));
      text = newline == std::string_view::npos ? std::string_view() : text.substr(newline + 1);
    }
    return lines;
  };
  auto local = [&](const std::vector<std::uint64_t>& part) -> Result<std::vector<std::string>> {
    std::vector<std::string> items;
    items.reserve(part.size());
    Status s = engine_.batch(
        id, part, kind, query, spec, control,
        [&](std::span<const BatchAnswer> answers, std::uint64_t) -> Status {
          for (const BatchAnswer& a : answers) items.push_back(a.encoded);
          return Status::ok();
        },
        encode_with(item_of));
    if (!s.is_ok()) return s;
    return items;
  };
  auto emit = [&](std::vector<std::string>& items, std::uint64_t done) { return write_items(items, done); };
  return router_.scatter_gather<std::string>(seeds, routes, control, ask, local, emit);
}

}  // namespace spokemesh::service
