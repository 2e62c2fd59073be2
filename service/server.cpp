// run_server(): the store, the engine, the gRPC and REST fronts, signals and the
// orderly shutdown (server.hpp).
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/security/server_credentials.h>
#include <signal.h>
#include <sys/resource.h>

#include <boost/asio/ssl/context.hpp>
#include <iostream>
#include <thread>

#include "auth.hpp"
#include "grpc_guards.hpp"
#include "grpc_health.hpp"
#include "grpc_service.hpp"
#include "http_api.hpp"
#include "server.hpp"
#include "telemetry.hpp"

namespace spokemesh::service {

namespace {

constexpr int kExitStartFailure = 1, kExitBadConfig = 2;

int config_error(const Status& s) {
  std::cerr << "spokemesh-server: " << s.message() << "\n";
  return kExitBadConfig;
}

// TLS for both fronts from the PEM files: gRPC's credentials and Asio's context.
Status setup_tls(const ServerConfig& c, std::shared_ptr<grpc::ServerCredentials>& grpc_credentials,
                 std::shared_ptr<boost::asio::ssl::context>& http_tls) {
  auto cert = read_text_file(c.tls_cert, "--tls-cert");
  auto key = read_text_file(c.tls_key, "--tls-key");
  if (!cert.is_ok()) return cert.status();
  if (!key.is_ok()) return key.status();
  grpc::SslServerCredentialsOptions ssl(c.tls_client_ca.empty()
                                            ? GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE
                                            : GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY);
  ssl.pem_key_cert_pairs.push_back({key.value(), cert.value()});
  auto tls = std::make_shared<boost::asio::ssl::context>(boost::asio::ssl::context::tls_server);
  try {
    tls->set_options(boost::asio::ssl::context::default_workarounds | boost::asio::ssl::context::no_sslv2 |
                     boost::asio::ssl::context::no_sslv3 | boost::asio::ssl::context::no_tlsv1 |
                     boost::asio::ssl::context::no_tlsv1_1);
    tls->use_certificate_chain_file(c.tls_cert);
    tls->use_private_key_file(c.tls_key, boost::asio::ssl::context::pem);
    if (!c.tls_client_ca.empty()) {
      auto ca = read_text_file(c.tls_client_ca, "--tls-client-ca");
      if (!ca.is_ok()) return ca.status();
      ssl.pem_root_certs = ca.value();
      tls->load_verify_file(c.tls_client_ca);
      tls->set_verify_mode(boost::asio::ssl::verify_peer | boost::asio::ssl::verify_fail_if_no_peer_cert);
    }
  } catch (const boost::system::system_error& e) {
    return invalid_argument(std::string("--tls-cert/--tls-key: ") + e.what());
  }
  grpc_credentials = grpc::SslServerCredentials(ssl);
  http_tls = std::move(tls);
  return Status::ok();
}

}  // namespace

int run_server(const ServerConfig& config) {
  auto auth_created = Authenticator::create(config.keys_file, config.token);
  if (!auth_created.is_ok()) return config_error(auth_created.status());
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
  auto store =
      PointSetStore::open(config.data_dir, config.limits.max_memory,
                          [&telemetry](const std::string& level, const std::string& m) { telemetry.log(level, m); });
  if (!store.is_ok()) return config_error(store.status());
  Engine engine(std::move(store).value(), config.limits, config.shards);
  // A shard replica loads the pieces it is asked for, never a set kept as pieces whole.
  const std::size_t loaded = engine.store().load_all([&](const std::string& id) {
    if (!config.shards.sharded()) return false;
    auto layout = engine.store().layout(id);
    return !layout.is_ok() || layout.value() != nullptr;
  });
  std::unique_ptr<ShardPeers> peers;
  telemetry.set_shard(config.shards.index, config.shards.count);
  if (config.shards.sharded()) {
    peers = std::make_unique<ShardPeers>(config.shards, config.shard_http, config.shard_grpc);
    telemetry.log("info", "serving shard " + std::to_string(config.shards.index) + " of " +
                              std::to_string(config.shards.count) + "; other shards at " + config.shard_http +
                              " (REST) and " + config.shard_grpc + " (gRPC)");
  }
  // Free pages back to the system after every 4 MB of churn, checked twice a second.
  HeapTrimmer trimmer(engine.store().budget(), std::chrono::milliseconds(500), 4u << 20);
  telemetry.log("info",
                "memory budget: " + std::to_string(config.limits.max_memory) + " bytes (" + config.memory_why + ")");
  telemetry.log("info", "data dir " + config.data_dir + ": " + std::to_string(loaded) + " point sets verified");

  std::atomic<bool> ready{false};
  HttpServerOptions http_options = config.http;
  http_options.budget = &engine.store().budget();
  std::shared_ptr<grpc::ServerCredentials> grpc_credentials = grpc::InsecureServerCredentials();
  if (!config.tls_cert.empty()) {
    if (Status s = setup_tls(config, grpc_credentials, http_options.tls); !s.is_ok()) return config_error(s);
  }

  MesherService mesher(engine, telemetry, auth, peers.get());
  std::shared_ptr<const UiAssets> ui;
  if (config.ui) {
    ui = UiAssets::load(config.ui_three_dir);
    if (!ui->missing().empty()) {
      telemetry.log("warning", "the browser page cannot draw: three.js not found at " + ui->missing() +
                                   " (install Debian's libjs-three, or give --ui-three-dir)");
    }
  }
  HttpApi api(
      engine, telemetry, auth, [&ready] { return ready.load(); }, ui, peers.get());
  HttpServer http_server(api, telemetry, http_options);

  // Our synchronous health service, not gRPC's built-in one (grpc_health.hpp says why).
  grpc::EnableDefaultHealthCheckService(false);
  HealthService health;
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  int grpc_port = 0;
  if (auto ep = parse_endpoint(config.grpc_listen, "--grpc-listen"); !ep.is_ok()) return config_error(ep.status());
  builder.AddListeningPort(config.grpc_listen, grpc_credentials, &grpc_port);
  builder.RegisterService(&mesher);
  builder.RegisterService(&health);
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> interceptors;
  interceptors.push_back(std::make_unique<ReflectionGuardFactory>(auth));
  interceptors.push_back(std::make_unique<DecodeGuardFactory>());
  builder.experimental().SetInterceptorCreators(std::move(interceptors));
  grpc::ResourceQuota quota("spokemesh");
  // Sync gRPC runs one thread per call, plus a few pollers per completion queue.
  quota.SetMaxThreads(config.max_concurrent_rpcs +
                      4 * static_cast<int>(std::max(2u, std::thread::hardware_concurrency())));
  builder.SetResourceQuota(quota);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (!server || grpc_port == 0) {
    telemetry.log("error", "--grpc-listen: cannot listen on " + config.grpc_listen);
    return kExitStartFailure;
  }
  auto http_port = http_server.start();
  if (!http_port.is_ok()) {
    telemetry.log("error", http_port.status().message());
    server->Shutdown();
    return kExitStartFailure;
  }
  health.set_serving(true);
  ready = true;
  const std::string grpc_host = config.grpc_listen.substr(0, config.grpc_listen.rfind(':'));
  const std::string http_host = config.http.listen.substr(0, config.http.listen.rfind(':'));
  telemetry.log("info", "serving gRPC on " + grpc_host + ":" + std::to_string(grpc_port) + " and HTTP on " + http_host +
                            ":" + std::to_string(http_port.value()) + (config.tls_cert.empty() ? "" : " (TLS)") +
                            (auth->enabled() ? " (" + std::to_string(auth->key_count()) + " API keys)" : ""));
  if (ui) {
    telemetry.log("info", std::string("the browser page: ") + (config.tls_cert.empty() ? "http" : "https") + "://" +
                              http_host + ":" + std::to_string(http_port.value()) + "/ (API documentation at /docs)");
  }

  int signal_number = 0;
  for (;;) {
    sigwait(&signals, &signal_number);
    if (signal_number != SIGHUP) break;
    if (config.keys_file.empty()) {
      telemetry.log("info", "received SIGHUP: no --keys file to re-read");
    } else if (Status s = auth->reload(); s.is_ok()) {
      telemetry.log("info", "received SIGHUP: " + config.keys_file + " re-read, " + std::to_string(auth->key_count()) +
                                " API keys");
    } else {
      telemetry.log("error", "received SIGHUP: " + s.message() + "; the previous keys stay in force");
    }
  }
  telemetry.log("info", std::string("received ") + (signal_number == SIGTERM ? "SIGTERM" : "SIGINT") +
                            ": health NOT_SERVING; stopping after --drain-delay " + config.drain_text +
                            ", then in-flight requests have up to " + config.grace_text);
  ready = false;
  health.set_serving(false);
  std::this_thread::sleep_for(config.drain);
  const auto until = std::chrono::system_clock::now() + config.grace;
  // With clients still connected, gRPC 1.51's Shutdown takes up to ~5 s even when idle
  // (bounded by the grace period); both fronts stop in parallel.
  std::thread grpc_stop([&] {
    health.stop();
    server->Shutdown(until);
  });
  http_server.stop(config.grace);
  grpc_stop.join();
  telemetry.log("info", "stopped");
  return 0;
}

}  // namespace spokemesh::service
