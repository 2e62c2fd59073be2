// spokemesh-server: the meshing service (gRPC + REST) over a durable point-set store.
//
// Exit codes: 0 after a clean shutdown (SIGTERM/SIGINT), 2 bad flags, 1 failure to start.
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/security/server_credentials.h>
#include <malloc.h>
#include <signal.h>
#include <sys/resource.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <boost/asio/ssl/context.hpp>
#include <fstream>
#include <iostream>
#include <sstream>
#include <thread>

#include "auth.hpp"
#include "engine.hpp"
#include "spokemesh/approx.hpp"
#include "grpc_guards.hpp"
#include "grpc_service.hpp"
#include "http_api.hpp"
#include "http_server.hpp"
#include "spokemesh/units.hpp"
#include "telemetry.hpp"

namespace {

using namespace spokemesh;
using namespace spokemesh::service;

Result<std::string> read_text_file(const std::string& path, const std::string& flag) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return invalid_argument(flag + ": cannot read " + path);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

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
    } catch (const std::exception&) {
    }
    break;
  }
  return limit / 2;
}

int usage_error(const Status& s) {
  std::cerr << "spokemesh-server: " << s.message() << "\n";
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  // The memory budget counts what the server holds; for the process's RSS to follow
  // it, freed memory must go back to the system. glibc's default raises its mmap
  // threshold after each large free (to 32 MB), after which large buffers (point
  // sets, trees, request bodies) come from arenas that never shrink; and each thread
  // may get its own arena. A fixed 64 KiB threshold maps and unmaps every buffer of
  // a point set, tree, cache or stream window (small sets' arrays too: in arenas,
  // thousands of them fragment the heap by tens of MB over a soak run), and a few
  // arenas bound fragmentation across many request threads.
  ::mallopt(M_MMAP_THRESHOLD, 64 << 10);
  ::mallopt(M_TRIM_THRESHOLD, 4 << 20);
  ::mallopt(M_ARENA_MAX, 4);
  CLI::App app{"spokemesh-server: exact Delaunay/Voronoi meshing service (gRPC and REST).\n"
               "Point sets are uploaded once, stored durably in --data-dir, and queried per seed."};
  std::string grpc_listen = "127.0.0.1:50051", http_listen = "127.0.0.1:8080", data_dir = "./spokemesh-data";
  unsigned threads = std::max(1u, std::thread::hardware_concurrency());
  // Every default from limits.hpp (sizes and durations as the flags write them).
  using defaults::bytes_text;
  using defaults::duration_text;
  std::uint64_t max_points = defaults::kMaxPoints;
  int max_dimension = defaults::kMaxDimension;
  int max_concurrent = defaults::kMaxConcurrentRpcs;
  std::string max_memory = "auto", stream_cache = bytes_text(defaults::kStreamCacheBytes),
              default_deadline = duration_text(defaults::kDefaultDeadline),
              grace = duration_text(defaults::kGracePeriod), drain = duration_text(defaults::kDrainDelay),
              max_body = bytes_text(defaults::kMaxBodyBytes);
  std::string upload_idle = duration_text(defaults::kUploadIdleTimeout);
  std::size_t http_max_connections = defaults::kHttpMaxConnections;
  std::size_t http_per_address = defaults::kHttpMaxConnectionsPerAddress;
  std::size_t http_in_flight = defaults::kHttpMaxInFlight;
  std::string http_header_timeout = duration_text(defaults::kHttpHeaderTimeout),
              http_body_timeout = duration_text(defaults::kHttpBodyTimeout),
              http_idle_timeout = duration_text(defaults::kHttpIdleTimeout),
              http_write_timeout = duration_text(defaults::kHttpWriteTimeout),
              tls_handshake_timeout = duration_text(defaults::kTlsHandshakeTimeout);
  std::string tls_cert, tls_key, tls_client_ca, auth_token_file, keys_file;
  app.add_option("--grpc-listen", grpc_listen, "gRPC address HOST:PORT (port 0 picks a free port)")->capture_default_str();
  app.add_option("--http-listen", http_listen, "REST address HOST:PORT (port 0 picks a free port)")->capture_default_str();
  app.add_option("--data-dir", data_dir, "Directory of stored point sets (may be shared by replicas)")->capture_default_str();
  app.add_option("--threads", threads, "Worker threads per streamed shard")
      ->check(CLI::Range(1u, 1024u))
      ->capture_default_str();
  app.add_option("--max-points", max_points, "Largest point set accepted")->check(CLI::PositiveNumber)->capture_default_str();
  app.add_option("--max-concurrent-rpcs", max_concurrent,
                 "gRPC calls served at once; beyond it gRPC answers RESOURCE_EXHAUSTED (load shedding)")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  app.add_option("--max-dimension", max_dimension,
                 "Largest dimension accepted (exact answers need d <= 8; above, approximate neighbours only)")
      ->check(CLI::Range(2, kMaxApproxDimension))
      ->capture_default_str();
  app.add_option("--max-memory", max_memory,
                 "The one memory budget: loaded point sets and trees (the least recently used leave memory, "
                 "they stay on disk), stream caches and windows, upload buffers; over it requests get 503 / "
                 "RESOURCE_EXHAUSTED. auto: half the cgroup limit or physical memory")
      ->capture_default_str();
  app.add_option("--stream-cache", stream_cache,
                 "Memory per streamed shard for sharing facets between its seeds' stars (0 = none: same "
                 "simplices, slower)")
      ->capture_default_str();
  app.add_option("--default-deadline", default_deadline, "Deadline of requests that carry none (500ms, 30s, 2m)")
      ->capture_default_str();
  app.add_option("--upload-idle-timeout", upload_idle,
                 "An upload that sends nothing for this long is ended and its memory returned (gRPC "
                 "upload streams; 1s, 30s, 2m)")
      ->capture_default_str();
  app.add_option("--http-max-connections", http_max_connections,
                 "REST connections open at once; beyond it a complete 503 with Retry-After")
      ->check(CLI::Range(std::size_t{1}, std::size_t{1000000}))
      ->capture_default_str();
  app.add_option("--http-max-connections-per-address", http_per_address,
                 "REST connections open at once from one client address")
      ->check(CLI::Range(std::size_t{1}, std::size_t{1000000}))
      ->capture_default_str();
  app.add_option("--http-max-in-flight", http_in_flight, "REST requests handled at once (one thread each)")
      ->check(CLI::Range(std::size_t{1}, std::size_t{100000}))
      ->capture_default_str();
  app.add_option("--http-header-timeout", http_header_timeout, "Time for a REST request's header to arrive")
      ->capture_default_str();
  app.add_option("--http-body-timeout", http_body_timeout, "Time for a REST request's body to arrive")
      ->capture_default_str();
  app.add_option("--http-idle-timeout", http_idle_timeout, "A keep-alive REST connection with no request is closed")
      ->capture_default_str();
  app.add_option("--http-write-timeout", http_write_timeout,
                 "A REST client that reads nothing of a response this long is disconnected")
      ->capture_default_str();
  app.add_option("--tls-handshake-timeout", tls_handshake_timeout, "Time for a REST client's TLS handshake")
      ->capture_default_str();
  app.add_option("--drain-delay", drain,
                 "On SIGTERM, keep serving this long while health says NOT_SERVING (lets load balancers "
                 "move traffic away), then stop accepting")
      ->capture_default_str();
  app.add_option("--grace-period", grace, "On SIGTERM, how long in-flight requests may then finish")
      ->capture_default_str();
  app.add_option("--max-body-bytes", max_body, "Largest REST request body")->capture_default_str();
  app.add_option("--tls-cert", tls_cert, "PEM certificate chain: serve TLS on both ports");
  app.add_option("--tls-key", tls_key, "PEM private key for --tls-cert");
  app.add_option("--tls-client-ca", tls_client_ca, "PEM CA bundle: require client certificates signed by it (mTLS)");
  app.add_option("--auth-token-file", auth_token_file,
                 "File holding a bearer token that every request must carry (health and readiness exempt); it "
                 "acts as one admin key");
  app.add_option("--keys", keys_file,
                 "API keys with tenants, one `key tenant [admin]` per line (re-read on SIGHUP): a tenant sees only "
                 "its own point sets, an admin all");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }

  Limits limits;
  limits.max_points = max_points;
  limits.max_dimension = max_dimension;
  limits.stream_threads = threads;
  std::string memory_why = "--max-memory";
  auto memory = max_memory == "auto" ? Result<std::uint64_t>(default_memory_budget(memory_why))
                                     : parse_bytes(max_memory, "--max-memory");
  if (max_memory == "auto") memory_why = "half of " + memory_why;
  auto deadline = parse_duration(default_deadline, "--default-deadline");
  auto grace_ms = parse_duration(grace, "--grace-period");
  auto idle_ms = parse_duration(upload_idle, "--upload-idle-timeout");
  auto header_ms = parse_duration(http_header_timeout, "--http-header-timeout");
  auto body_ms = parse_duration(http_body_timeout, "--http-body-timeout");
  auto keepalive_ms = parse_duration(http_idle_timeout, "--http-idle-timeout");
  auto write_ms = parse_duration(http_write_timeout, "--http-write-timeout");
  auto handshake_ms = parse_duration(tls_handshake_timeout, "--tls-handshake-timeout");
  auto drain_ms = drain == "0" || drain == "0s" ? Result<std::chrono::milliseconds>(std::chrono::milliseconds(0))
                                                : parse_duration(drain, "--drain-delay");
  auto body = parse_bytes(max_body, "--max-body-bytes");
  auto cache = stream_cache == "0" ? Result<std::uint64_t>(std::uint64_t{0}) : parse_bytes(stream_cache, "--stream-cache");
  for (const Status* s : {&memory.status(), &deadline.status(), &grace_ms.status(), &drain_ms.status(), &body.status(),
                          &cache.status(), &idle_ms.status(), &header_ms.status(), &body_ms.status(),
                          &keepalive_ms.status(), &write_ms.status(), &handshake_ms.status()}) {
    if (!s->is_ok()) return usage_error(*s);
  }
  limits.max_memory = memory.value();
  limits.stream_cache_bytes = static_cast<std::size_t>(cache.value());
  limits.default_deadline = deadline.value();
  limits.upload_idle_timeout = idle_ms.value();
  if (tls_cert.empty() != tls_key.empty()) return usage_error(invalid_argument("--tls-cert and --tls-key go together"));
  if (!tls_client_ca.empty() && tls_cert.empty()) {
    return usage_error(invalid_argument("--tls-client-ca needs --tls-cert and --tls-key"));
  }
  std::string token;
  if (!auth_token_file.empty()) {
    auto text = read_text_file(auth_token_file, "--auth-token-file");
    if (!text.is_ok()) return usage_error(text.status());
    token = text.value();
    while (!token.empty() && std::isspace(static_cast<unsigned char>(token.back()))) token.pop_back();
    if (token.empty()) return usage_error(invalid_argument("--auth-token-file: " + auth_token_file + " is empty"));
  }

  auto auth_created = Authenticator::create(keys_file, token);
  if (!auth_created.is_ok()) return usage_error(auth_created.status());
  const std::shared_ptr<Authenticator> auth = std::move(auth_created).value();

  // SIGTERM/SIGINT/SIGHUP are taken by sigwait() below, so every thread must block them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  signal(SIGPIPE, SIG_IGN);
  // Every connection is a descriptor: take the hard limit (the default soft limit of
  // 1024 would cap the server far below --http-max-connections).
  if (rlimit files{}; ::getrlimit(RLIMIT_NOFILE, &files) == 0 && files.rlim_cur < files.rlim_max) {
    files.rlim_cur = files.rlim_max;
    ::setrlimit(RLIMIT_NOFILE, &files);
  }

  Telemetry telemetry;
  auto store = PointSetStore::open(data_dir, limits.max_memory,
                                   [&telemetry](const std::string& level, const std::string& m) { telemetry.log(level, m); });
  if (!store.is_ok()) return usage_error(store.status());
  Engine engine(std::move(store).value(), limits);
  const std::size_t loaded = engine.store().load_all();
  // Free pages back to the system after every 4 MB of churn, checked twice a second.
  HeapTrimmer trimmer(engine.store().budget(), std::chrono::milliseconds(500), 4u << 20);
  telemetry.log("info", "memory budget: " + std::to_string(limits.max_memory) + " bytes (" + memory_why + ")");
  telemetry.log("info", "data dir " + data_dir + ": " + std::to_string(loaded) + " point sets verified");

  std::atomic<bool> ready{false};
  HttpServerOptions http_options;
  http_options.listen = http_listen;
  http_options.max_body_bytes = body.value();
  http_options.budget = &engine.store().budget();
  http_options.max_connections = http_max_connections;
  http_options.max_connections_per_address = http_per_address;
  http_options.max_in_flight = http_in_flight;
  http_options.header_timeout = header_ms.value();
  http_options.body_timeout = body_ms.value();
  http_options.idle_timeout = keepalive_ms.value();
  http_options.write_timeout = write_ms.value();
  http_options.handshake_timeout = handshake_ms.value();
  std::shared_ptr<grpc::ServerCredentials> grpc_credentials = grpc::InsecureServerCredentials();
  if (!tls_cert.empty()) {
    auto cert = read_text_file(tls_cert, "--tls-cert");
    auto key = read_text_file(tls_key, "--tls-key");
    if (!cert.is_ok()) return usage_error(cert.status());
    if (!key.is_ok()) return usage_error(key.status());
    grpc::SslServerCredentialsOptions ssl(tls_client_ca.empty()
                                              ? GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE
                                              : GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY);
    ssl.pem_key_cert_pairs.push_back({key.value(), cert.value()});
    auto tls = std::make_shared<boost::asio::ssl::context>(boost::asio::ssl::context::tls_server);
    try {
      tls->set_options(boost::asio::ssl::context::default_workarounds | boost::asio::ssl::context::no_sslv2 |
                       boost::asio::ssl::context::no_sslv3 | boost::asio::ssl::context::no_tlsv1 |
                       boost::asio::ssl::context::no_tlsv1_1);
      tls->use_certificate_chain_file(tls_cert);
      tls->use_private_key_file(tls_key, boost::asio::ssl::context::pem);
      if (!tls_client_ca.empty()) {
        auto ca = read_text_file(tls_client_ca, "--tls-client-ca");
        if (!ca.is_ok()) return usage_error(ca.status());
        ssl.pem_root_certs = ca.value();
        tls->load_verify_file(tls_client_ca);
        tls->set_verify_mode(boost::asio::ssl::verify_peer | boost::asio::ssl::verify_fail_if_no_peer_cert);
      }
    } catch (const boost::system::system_error& e) {
      return usage_error(invalid_argument(std::string("--tls-cert/--tls-key: ") + e.what()));
    }
    grpc_credentials = grpc::SslServerCredentials(ssl);
    http_options.tls = tls;
  }

  MesherService mesher(engine, telemetry, auth);
  HttpApi api(engine, telemetry, auth, [&ready] { return ready.load(); });
  HttpServer http_server(api, telemetry, http_options);

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  int grpc_port = 0;
  if (auto ep = parse_endpoint(grpc_listen, "--grpc-listen"); !ep.is_ok()) return usage_error(ep.status());
  builder.AddListeningPort(grpc_listen, grpc_credentials, &grpc_port);
  builder.RegisterService(&mesher);
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> interceptors;
  interceptors.push_back(std::make_unique<ReflectionGuardFactory>(auth));
  interceptors.push_back(std::make_unique<DecodeGuardFactory>());
  builder.experimental().SetInterceptorCreators(std::move(interceptors));
  grpc::ResourceQuota quota("spokemesh");
  // Sync gRPC runs one thread per call, plus a few pollers per completion queue.
  quota.SetMaxThreads(max_concurrent + 4 * static_cast<int>(std::max(2u, std::thread::hardware_concurrency())));
  builder.SetResourceQuota(quota);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (!server || grpc_port == 0) {
    telemetry.log("error", "--grpc-listen: cannot listen on " + grpc_listen);
    return 1;
  }
  auto http_port = http_server.start();
  if (!http_port.is_ok()) {
    telemetry.log("error", http_port.status().message());
    server->Shutdown();
    return 1;
  }
  server->GetHealthCheckService()->SetServingStatus(true);
  ready = true;
  const std::string grpc_host = grpc_listen.substr(0, grpc_listen.rfind(':'));
  const std::string http_host = http_listen.substr(0, http_listen.rfind(':'));
  telemetry.log("info", "serving gRPC on " + grpc_host + ":" + std::to_string(grpc_port) + " and HTTP on " +
                            http_host + ":" + std::to_string(http_port.value()) + (tls_cert.empty() ? "" : " (TLS)") +
                            (auth->enabled() ? " (" + std::to_string(auth->key_count()) + " API keys)" : ""));

  int signal_number = 0;
  for (;;) {
    sigwait(&signals, &signal_number);
    if (signal_number != SIGHUP) break;
    if (keys_file.empty()) {
      telemetry.log("info", "received SIGHUP: no --keys file to re-read");
    } else if (Status s = auth->reload(); s.is_ok()) {
      telemetry.log("info", "received SIGHUP: " + keys_file + " re-read, " + std::to_string(auth->key_count()) +
                                " API keys");
    } else {
      telemetry.log("error", "received SIGHUP: " + s.message() + "; the previous keys stay in force");
    }
  }
  telemetry.log("info", std::string("received ") + (signal_number == SIGTERM ? "SIGTERM" : "SIGINT") +
                            ": health NOT_SERVING; stopping after --drain-delay " + drain +
                            ", then in-flight requests have up to " + grace);
  ready = false;
  server->GetHealthCheckService()->SetServingStatus(false);
  std::this_thread::sleep_for(drain_ms.value());
  const auto until = std::chrono::system_clock::now() + grace_ms.value();
  // With clients still connected, gRPC 1.51's Shutdown takes up to ~5 s even when idle
  // (bounded by the grace period); both fronts stop in parallel.
  std::thread grpc_stop([&] { server->Shutdown(until); });
  http_server.stop(grace_ms.value());
  grpc_stop.join();
  telemetry.log("info", "stopped");
  return 0;
}
