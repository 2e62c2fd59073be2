// HttpApi: the REST mirror of the gRPC API, as a pure function from a parsed
// request to a response. No sockets here: HttpServer owns the connections, and
// tests call handle_request() directly.
//
// Routes (JSON; errors are {"error": {"code": <http>, "status": "<gRPC code>", "message": ...}}):
//   POST   /v1/pointsets                       upload: JSON {"dimension", "coordinates"} or
//                                              {"points": [[...], ...]}, optional "display_name";
//                                              or application/octet-stream raw float64 LE with
//                                              ?dimension=d[&display_name=...]. 201 new, 200 existing.
//   GET    /v1/pointsets[?page_size=&page_token=]
//   GET    /v1/pointsets/{id}
//   DELETE /v1/pointsets/{id}
//   GET    /v1/pointsets/{id}/seeds/{seed}/star | neighbors | cell
//                                              (on a sharded replica, relayed to the seed's shard)
//   GET    /v1/pointsets/{id}/simplices?shard=k&shards=n[&batch_size=b]
//                                              NDJSON, one simplex per line, chunked
//   GET    /v1/pointsets/{id}/shards          the shard map (JSON); .../shards/seeds: each
//                                              seed's shard as a .npy uint16 array
//   GET    /v1/pointsets/{id}/points[?dtype=float64|float32]
//                                              the coordinates as a .npy file (n, d), chunked
//   GET    /healthz  /readyz  /metrics
//   GET    /  /docs  /ui/{file}                the browser page (ui.hpp; absent with --no-ui)
// A request may carry `X-Timeout-Ms: <ms>` to shorten its deadline (default
// --default-deadline). With an auth token configured, every route but /healthz and
// /readyz needs `Authorization: Bearer <token>`.
//
// Thread safety: handle_request() may be called concurrently.
#pragma once

#include <boost/beast/http.hpp>
#include <nlohmann/json.hpp>

#include <array>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "auth.hpp"
#include "engine.hpp"
#include "router.hpp"
#include "shard_peers.hpp"
#include "telemetry.hpp"
#include "ui.hpp"

namespace spokemesh::service {

namespace http = boost::beast::http;

struct PendingRelay;

struct HttpResponse {
  unsigned status = 200;
  std::string content_type = "application/json";
  std::string body;
  // Further header fields (the page's Content-Security-Policy, a download's name).
  std::vector<std::pair<std::string, std::string>> headers;
  // Streaming responses: called after handle_request() returns, with a function that
  // sends one chunk (false once the client is gone). If it fails before the first
  // chunk, `status`/`body` are replaced by the error it returns.
  std::function<Status(const std::function<bool(std::string_view)>& write_chunk)> stream;
  // Not an answer yet: the request goes to another shard's replica (answer_at_once only).
  std::shared_ptr<PendingRelay> relay;
};

// A seed's request for another shard's replica, relayed by the server without a thread
// (answer_at_once): it sends `request` with ShardPeers::forward_http_async and answers
// what `finish` makes of the result (which also records the request). If the relay
// cannot be made without a thread (the shard's addresses need a lookup), the server
// calls handle_request() instead, which relays it from a thread.
struct PendingRelay {
  ShardPeers* peers = nullptr;
  std::uint32_t shard = 0;
  ShardPeers::HttpRequest request;
  Clock::time_point deadline;
  std::function<HttpResponse(Result<ShardPeers::HttpResponse>)> finish;
};

// {"error": {"code", "status", "message"[, "reason"]}}; code is the HTTP status sent
// (http_code, or the one http_status(s) maps to when 0).
std::string error_json(const Status& s, int http_code = 0);

class HttpApi {
 public:
  // ready(): false while starting or shutting down (/readyz answers 503). ui: the
  // browser page's files; null (--no-ui) serves no page at all.
  // peers: on a sharded replica, the way to the other shards (a seed's request for
  // another shard's piece is relayed there); null otherwise.
  HttpApi(Engine& engine, Telemetry& telemetry, std::shared_ptr<const Authenticator> auth, std::function<bool()> ready,
          std::shared_ptr<const UiAssets> ui = nullptr, ShardPeers* peers = nullptr);

  // client_gone: polled during long computations to stop work for a closed connection.
  HttpResponse handle_request(const http::request<http::string_body>& request, std::function<bool()> client_gone = {});
  // The response when it is cheap and cannot block, for the connection's I/O thread to
  // send without handing the request to a thread of its own: health, readiness, the
  // OpenAPI description and the page's files, and a seed's star, neighbours (exact) or
  // cell read from a kept triangulation in memory (Engine::hold_at_hand); on a sharded
  // replica, a seed's request for another shard is a PendingRelay (response.relay).
  // nullopt: nothing was done; handle_request() answers it, errors included.
  std::optional<HttpResponse> answer_at_once(const http::request<http::string_body>& request);

 private:
  struct Context;
  HttpResponse respond(const http::request<http::string_body>& request, std::function<bool()> client_gone,
                       bool at_once);
  HttpResponse route(Context& c);
  // An upload, or with `parent` an append to that set (POST /v1/pointsets/{id}:append).
  HttpResponse upload(Context& c, const std::string* parent = nullptr);
  // Coordinates decoded from any body form -> stored point set (201, or 200 if it existed).
  // Raw float64 bytes (copied), or doubles parsed from JSON with their memory charge
  // (taken).
  using UploadData = std::variant<std::span<const char>, std::pair<std::vector<double>, MemoryBudget::Charge>>;
  // weights: a weighted upload's (header.weighted), as raw float64 bytes or parsed.
  HttpResponse store_upload(Context& c, const UploadHeader& header, UploadData data, const std::string* parent,
                            std::span<const char> weights = {});
  HttpResponse seed_route(Context& c, const std::string& id, const std::string& seed, const std::string& what);
  // A batch whose seeds lie in several shards' pieces (Router::scatter_gather): each
  // shard's seeds answered there over REST (this one's here), the lines written in the
  // request's order.
  Status relay_batch(const http::request<http::string_body>& request, const nlohmann::json& body, const std::string& id,
                     const std::vector<std::uint64_t>& seeds, const std::vector<std::uint32_t>& routes, BatchKind kind,
                     const NeighborQuery& query, const DomainSpec& spec, const CallControl& control,
                     const std::function<std::string(const BatchAnswer&)>& item_of,
                     const std::function<Status(const std::vector<std::string>&, std::uint64_t)>& write_items,
                     bool compact);
  // The request relayed to a replica of `shard`, its response returned as it came.
  HttpResponse forward(Context& c, std::uint32_t shard);
  // The same as a PendingRelay, for the server to send without a thread.
  HttpResponse relay_at_once(Context& c, std::uint32_t shard);
  // The request as relayed to `shard` (what is left of the deadline as X-Timeout-Ms).
  static ShardPeers::HttpRequest relayed_request(const Context& c);
  // A peer's answer (or the failure to get one) as this replica's response, recorded
  // in `record` (the peer's error code for an error it answered).
  HttpResponse relayed_response(Telemetry::Request& record, std::uint32_t shard,
                                Result<ShardPeers::HttpResponse> relayed);
  HttpResponse shard_map(Context& c, const std::string& id, bool seeds);
  HttpResponse simplices(Context& c, const std::string& id);
  HttpResponse points(Context& c, const std::string& id);
  HttpResponse cells(Context& c, const std::string& id);
  HttpResponse check_domain(Context& c);
  HttpResponse batch(Context& c, const std::string& id, const std::string& what);
  // POST .../{id}:locate and :interpolate: NDJSON, one line per query point in order.
  HttpResponse point_queries(Context& c, const std::string& id, bool interpolate);
  // POST .../{id}/values: values kept for Interpolate's values_id (Engine::put_values).
  HttpResponse put_values(Context& c, const std::string& id);
  static Result<DomainSpec> domain_from_query(Context& c);
  static Result<bool> bool_param(Context& c, const char* name);
  static Result<std::array<std::uint64_t, 3>> shard_params(Context& c);  // shard, shards, batch_size
  Status finish_stream(Telemetry::Request& record, const RequestTimer& timer, Status s);

  Engine& engine_;
  Telemetry& telemetry_;
  std::shared_ptr<const Authenticator> auth_;
  std::function<bool()> ready_;
  std::shared_ptr<const UiAssets> ui_;
  ShardPeers* peers_;
  Router router_;
};

}  // namespace spokemesh::service
