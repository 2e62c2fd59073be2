// spokemesh-server's flags and the ServerConfig they make (server.hpp).
#include <unistd.h>

#include <algorithm>
#include <fstream>
#include <sstream>
#include <thread>

#include "server.hpp"
#include "spokemesh/approx.hpp"
#include "spokemesh/units.hpp"

namespace spokemesh::service {

Result<std::string> read_text_file(const std::string& path, const std::string& flag) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return invalid_argument(flag + ": cannot read " + path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

namespace {

// The default memory budget: half of what this process may use, the smaller of the
// cgroup's limit (v2 memory.max, or v1 memory.limit_in_bytes) and physical memory;
// `why` says which.
std::uint64_t default_memory_budget(std::string& why) {
  const auto pages = static_cast<std::uint64_t>(::sysconf(_SC_PHYS_PAGES));
  const auto page = static_cast<std::uint64_t>(::sysconf(_SC_PAGE_SIZE));
  std::uint64_t limit = pages * page;
  why = "physical memory " + std::to_string(limit);
  for (const char* path : {"/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"}) {
    std::ifstream in(path);
    std::string text;
    if (!(in >> text) || text == "max") continue;
    try {
      const std::uint64_t cgroup = std::stoull(text);
      if (cgroup < limit) {
        limit = cgroup;
        why = std::string("the cgroup limit ") + std::to_string(cgroup) + " (" + path + ")";
      }
    } catch (const std::exception&) {}
    break;
  }
  return limit / 2;
}

}  // namespace

void add_server_flags(CLI::App& app, ServerFlags& f) {
  app.add_option("--grpc-listen", f.grpc_listen, "gRPC address HOST:PORT (port 0 picks a free port)")
      ->capture_default_str();
  app.add_option("--http-listen", f.http_listen, "REST address HOST:PORT (port 0 picks a free port)")
      ->capture_default_str();
  app.add_option("--data-dir", f.data_dir, "Directory of stored point sets (may be shared by replicas)")
      ->capture_default_str();
  app.add_option("--threads", f.threads, "Worker threads per streamed shard")
      ->check(CLI::Range(1u, 1024u))
      ->capture_default_str();
  app.add_option("--max-points", f.max_points, "Largest point set accepted")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--max-concurrent-rpcs", f.max_concurrent,
                 "gRPC calls served at once; beyond it gRPC answers RESOURCE_EXHAUSTED (load shedding)")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  app.add_option("--max-dimension", f.max_dimension,
                 "Largest dimension accepted (exact answers need d <= 8; above, approximate neighbours only)")
      ->check(CLI::Range(2, kMaxApproxDimension))
      ->capture_default_str();
  app.add_option("--max-memory", f.max_memory,
                 "The one memory budget: loaded point sets and trees (the least recently used leave memory, "
                 "they stay on disk), stream caches and windows, upload buffers; over it requests get 503 / "
                 "RESOURCE_EXHAUSTED. auto: half the cgroup limit or physical memory")
      ->capture_default_str();
  app.add_option("--stream-cache", f.stream_cache,
                 "Memory per streamed shard for the work its seeds share: local triangulations (2-d, 3-d "
                 "meshes), or facets shared between stars (0 = none: same simplices, slower)")
      ->capture_default_str();
  app.add_option("--keep-triangulations", f.keep_triangulations,
                 "Build each 2-d or 3-d set's triangulation of every point in the background on its first request "
                 "and keep it with the set, within --max-memory: single star, neighbour and cell requests then read "
                 "it (the same bytes as walked stars, which answer until it is built, and when it does not fit)")
      ->capture_default_str();
  app.add_option("--default-deadline", f.default_deadline, "Deadline of requests that carry none (500ms, 30s, 2m)")
      ->capture_default_str();
  app.add_option("--upload-idle-timeout", f.upload_idle,
                 "An upload that sends nothing for this long is ended and its memory returned (gRPC "
                 "upload streams; 1s, 30s, 2m)")
      ->capture_default_str();
  app.add_option("--http-max-connections", f.http_max_connections,
                 "REST connections open at once; beyond it a complete 503 with Retry-After")
      ->check(CLI::Range(std::size_t{1}, std::size_t{1000000}))
      ->capture_default_str();
  app.add_option("--http-max-connections-per-address", f.http_per_address,
                 "REST connections open at once from one client address")
      ->check(CLI::Range(std::size_t{1}, std::size_t{1000000}))
      ->capture_default_str();
  app.add_option("--http-max-in-flight", f.http_in_flight, "REST requests handled at once (one thread each)")
      ->check(CLI::Range(std::size_t{1}, std::size_t{100000}))
      ->capture_default_str();
  app.add_option("--http-header-timeout", f.http_header_timeout, "Time for a REST request's header to arrive")
      ->capture_default_str();
  app.add_option("--http-body-timeout", f.http_body_timeout, "Time for a REST request's body to arrive")
      ->capture_default_str();
  app.add_option("--http-idle-timeout", f.http_idle_timeout, "A keep-alive REST connection with no request is closed")
      ->capture_default_str();
  app.add_option("--http-write-timeout", f.http_write_timeout,
                 "A REST client that reads nothing of a response this long is disconnected")
      ->capture_default_str();
  app.add_option("--tls-handshake-timeout", f.tls_handshake_timeout, "Time for a REST client's TLS handshake")
      ->capture_default_str();
  app.add_option("--drain-delay", f.drain,
                 "On SIGTERM, keep serving this long while health says NOT_SERVING (lets load balancers "
                 "move traffic away), then stop accepting")
      ->capture_default_str();
  app.add_option("--grace-period", f.grace, "On SIGTERM, how long in-flight requests may then finish")
      ->capture_default_str();
  app.add_option("--max-body-bytes", f.max_body, "Largest REST request body")->capture_default_str();
  app.add_option("--tls-cert", f.tls_cert, "PEM certificate chain: serve TLS on both ports");
  app.add_option("--tls-key", f.tls_key, "PEM private key for --tls-cert");
  app.add_option("--tls-client-ca", f.tls_client_ca, "PEM CA bundle: require client certificates signed by it (mTLS)");
  app.add_option("--auth-token-file", f.auth_token_file,
                 "File holding a bearer token that every request must carry (health and readiness exempt); it "
                 "acts as one admin key");
  app.add_flag("--no-ui", f.no_ui, "Serve no browser page: /, /docs and /ui/* answer 404 (the API is unchanged)");
  app.add_option("--ui-three-dir", f.ui_three_dir,
                 "Where the page finds three.js (Debian's libjs-three), read once at startup")
      ->capture_default_str();
  app.add_option("--shard", f.shard,
                 "Serve shard K of N (K/N, 0 <= K < N): of each set kept as pieces, hold only the pieces of shard K "
                 "(contiguous runs in sweep order) and relay other seeds' requests to their shard "
                 "(docs/service.md, \"Sharded serving\")");
  app.add_option("--shard-http", f.shard_http,
                 "REST address of shard {shard}'s replicas (a name resolving to them), or one entry per shard "
                 "separated by ';', each listing its replicas' HOST:PORT separated by ','")
      ->capture_default_str();
  app.add_option("--shard-grpc", f.shard_grpc, "gRPC address of shard {shard}'s replicas (as --shard-http)")
      ->capture_default_str();
  app.add_option("--pieces-above", f.pieces_above,
                 "Uploads of 2-d and 3-d sets of at least this many points are also stored as pieces before they "
                 "are acknowledged (auto: 8000000 with --shard, else never; 0: never)")
      ->capture_default_str();
  app.add_option("--piece-points", f.piece_points, "Most points in a piece (the layout of sets cut from now on)")
      ->check(CLI::Range(std::uint32_t{64}, std::uint32_t{1} << 30))
      ->capture_default_str();
  app.add_option("--keys", f.keys_file,
                 "API keys with tenants, one `key tenant [admin]` per line (re-read on SIGHUP): a tenant sees only "
                 "its own point sets, an admin all");
}

Result<ServerConfig> make_config(const ServerFlags& f) {
  ServerConfig c;
  c.grpc_listen = f.grpc_listen;
  c.data_dir = f.data_dir;
  c.max_concurrent_rpcs = f.max_concurrent;
  c.limits.max_points = f.max_points;
  c.limits.max_dimension = f.max_dimension;
  c.limits.stream_threads = f.threads;
  c.memory_why = "--max-memory";
  auto memory = f.max_memory == "auto" ? Result<std::uint64_t>(default_memory_budget(c.memory_why))
                                       : parse_bytes(f.max_memory, "--max-memory");
  if (f.max_memory == "auto") c.memory_why = "half of " + c.memory_why;
  auto deadline = parse_duration(f.default_deadline, "--default-deadline");
  auto grace_ms = parse_duration(f.grace, "--grace-period");
  auto idle_ms = parse_duration(f.upload_idle, "--upload-idle-timeout");
  auto header_ms = parse_duration(f.http_header_timeout, "--http-header-timeout");
  auto body_ms = parse_duration(f.http_body_timeout, "--http-body-timeout");
  auto keepalive_ms = parse_duration(f.http_idle_timeout, "--http-idle-timeout");
  auto write_ms = parse_duration(f.http_write_timeout, "--http-write-timeout");
  auto handshake_ms = parse_duration(f.tls_handshake_timeout, "--tls-handshake-timeout");
  auto drain_ms = f.drain == "0" || f.drain == "0s" ? Result<std::chrono::milliseconds>(std::chrono::milliseconds(0))
                                                    : parse_duration(f.drain, "--drain-delay");
  auto body = parse_bytes(f.max_body, "--max-body-bytes");
  auto cache =
      f.stream_cache == "0" ? Result<std::uint64_t>(std::uint64_t{0}) : parse_bytes(f.stream_cache, "--stream-cache");
  for (const Status* s : {&memory.status(), &deadline.status(), &grace_ms.status(), &drain_ms.status(), &body.status(),
                          &cache.status(), &idle_ms.status(), &header_ms.status(), &body_ms.status(),
                          &keepalive_ms.status(), &write_ms.status(), &handshake_ms.status()}) {
    if (!s->is_ok()) return *s;
  }
  c.limits.max_memory = memory.value();
  c.limits.stream_cache_bytes = static_cast<std::size_t>(cache.value());
  c.limits.keep_triangulations = f.keep_triangulations;
  c.limits.default_deadline = deadline.value();
  c.limits.upload_idle_timeout = idle_ms.value();
  c.drain = drain_ms.value();
  c.grace = grace_ms.value();
  c.drain_text = f.drain;
  c.grace_text = f.grace;

  c.http.listen = f.http_listen;
  c.http.max_body_bytes = body.value();
  c.http.max_connections = f.http_max_connections;
  c.http.max_connections_per_address = f.http_per_address;
  c.http.max_in_flight = f.http_in_flight;
  c.http.header_timeout = header_ms.value();
  c.http.body_timeout = body_ms.value();
  c.http.idle_timeout = keepalive_ms.value();
  c.http.write_timeout = write_ms.value();
  c.http.handshake_timeout = handshake_ms.value();

  if (f.tls_cert.empty() != f.tls_key.empty()) return invalid_argument("--tls-cert and --tls-key go together");
  if (!f.tls_client_ca.empty() && f.tls_cert.empty()) {
    return invalid_argument("--tls-client-ca needs --tls-cert and --tls-key");
  }
  c.tls_cert = f.tls_cert;
  c.tls_key = f.tls_key;
  c.tls_client_ca = f.tls_client_ca;
  if (!f.auth_token_file.empty()) {
    auto text = read_text_file(f.auth_token_file, "--auth-token-file");
    if (!text.is_ok()) return text.status();
    c.token = text.value();
    while (!c.token.empty() && std::isspace(static_cast<unsigned char>(c.token.back()))) c.token.pop_back();
    if (c.token.empty()) return invalid_argument("--auth-token-file: " + f.auth_token_file + " is empty");
  }
  c.keys_file = f.keys_file;
  if (!f.shard.empty()) {
    const std::size_t slash = f.shard.find('/');
    std::uint64_t k = 0, n = 0;
    const bool parsed = slash != std::string::npos && slash > 0 && slash + 1 < f.shard.size() &&
                        f.shard.find_first_not_of("0123456789/") == std::string::npos &&
                        f.shard.find('/', slash + 1) == std::string::npos;
    if (parsed) {
      k = std::stoull(f.shard.substr(0, slash));
      n = std::stoull(f.shard.substr(slash + 1));
    }
    if (!parsed || n == 0 || k >= n || n > 4096) {
      return invalid_argument("--shard: \"" + f.shard + "\" is not K/N with 0 <= K < N <= 4096 (e.g. 0/4)");
    }
    if (!f.tls_cert.empty()) {
      return invalid_argument(
          "--shard with --tls-cert: the hop between shards is plain; serve TLS at the front door instead");
    }
    for (const auto* t : {&f.shard_http, &f.shard_grpc}) {
      const bool listed = static_cast<std::uint64_t>(std::count(t->begin(), t->end(), ';')) + 1 == n;
      if (t->find(':') == std::string::npos || (t->find("{shard}") == std::string::npos && !listed)) {
        return invalid_argument(std::string(t == &f.shard_http ? "--shard-http" : "--shard-grpc") + ": \"" + *t +
                                "\" must be HOST:PORT with {shard} where the shard's number goes, or " +
                                std::to_string(n) + " entries separated by ';' (one per shard, replicas by ',')");
      }
    }
    c.shards.index = static_cast<std::uint32_t>(k);
    c.shards.count = static_cast<std::uint32_t>(n);
  }
  c.shard_http = f.shard_http;
  c.shard_grpc = f.shard_grpc;
  c.shards.piece_points = f.piece_points;
  if (f.pieces_above == "auto") {
    c.shards.pieces_above = c.shards.sharded() ? 8000000 : 0;
  } else if (!f.pieces_above.empty() && f.pieces_above.find_first_not_of("0123456789") == std::string::npos &&
             f.pieces_above.size() < 19) {
    c.shards.pieces_above = std::stoull(f.pieces_above);
  } else {
    return invalid_argument("--pieces-above: \"" + f.pieces_above + "\" is not a number of points or auto");
  }
  c.ui = !f.no_ui;
  c.ui_three_dir = f.ui_three_dir;
  return c;
}

}  // namespace spokemesh::service
