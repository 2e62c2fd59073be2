// spokemesh-server's entry point in the shape of grpc's route_guide: the command
// line becomes a ServerConfig (server_config.cpp), and run_server() serves it until
// SIGTERM or SIGINT (server.cpp). main.cpp only joins the two.
//
// Thread safety: add_server_flags/make_config on the main thread, before any other
// thread starts; run_server() once per process (it takes the process's signals).
#pragma once

#include <CLI/CLI.hpp>

#include <algorithm>
#include <chrono>
#include <string>
#include <thread>

#include "engine.hpp"
#include "http_server.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::service {

// Everything the server needs, checked: sizes and durations parsed, TLS flags
// consistent, the token read.
struct ServerConfig {
  std::string grpc_listen = "127.0.0.1:50051";
  std::string data_dir = "./spokemesh-data";
  Limits limits;
  std::string memory_why;  // where the memory budget comes from, for the log
  int max_concurrent_rpcs = 0;
  HttpServerOptions http;                                    // its `tls` and `budget` are set by run_server
  std::string tls_cert, tls_key, tls_client_ca;              // PEM files; empty: plain
  std::string token;                                         // from --auth-token-file
  std::string keys_file;                                     // --keys, re-read on SIGHUP
  bool ui = true;                                            // serve the browser page (--no-ui: not)
  std::string ui_three_dir = "/usr/share/javascript/three";  // Debian's libjs-three
  ShardSettings shards;                                      // --shard, --pieces-above, --piece-points
  std::string shard_http, shard_grpc;                        // the other shards' addresses ({shard} templates)
  std::chrono::milliseconds drain{0}, grace{0};
  std::string drain_text, grace_text;  // as given, for the log
};

// The flags as given (text for sizes and durations, parsed by make_config), with every
// default from limits.hpp written as the flags write them.
struct ServerFlags {
  std::string grpc_listen = "127.0.0.1:50051", http_listen = "127.0.0.1:8080", data_dir = "./spokemesh-data";
  unsigned threads = std::max(1u, std::thread::hardware_concurrency());
  std::uint64_t max_points = defaults::kMaxPoints;
  int max_dimension = defaults::kMaxUploadDimension;
  int max_concurrent = defaults::kMaxConcurrentRpcs;
  std::string max_memory = "auto";
  std::string stream_cache = defaults::bytes_text(defaults::kStreamCacheBytes);
  bool keep_triangulations = true;
  std::string default_deadline = defaults::duration_text(defaults::kDefaultDeadline);
  std::string grace = defaults::duration_text(defaults::kGracePeriod);
  std::string drain = defaults::duration_text(defaults::kDrainDelay);
  std::string max_body = defaults::bytes_text(defaults::kMaxBodyBytes);
  std::string upload_idle = defaults::duration_text(defaults::kUploadIdleTimeout);
  std::size_t http_max_connections = defaults::kHttpMaxConnections;
  std::size_t http_per_address = defaults::kHttpMaxConnectionsPerAddress;
  std::size_t http_in_flight = defaults::kHttpMaxInFlight;
  std::string http_header_timeout = defaults::duration_text(defaults::kHttpHeaderTimeout);
  std::string http_body_timeout = defaults::duration_text(defaults::kHttpBodyTimeout);
  std::string http_idle_timeout = defaults::duration_text(defaults::kHttpIdleTimeout);
  std::string http_write_timeout = defaults::duration_text(defaults::kHttpWriteTimeout);
  std::string tls_handshake_timeout = defaults::duration_text(defaults::kTlsHandshakeTimeout);
  std::string tls_cert, tls_key, tls_client_ca, auth_token_file, keys_file;
  bool no_ui = false;
  std::string ui_three_dir = "/usr/share/javascript/three";
  std::string shard;  // K/N
  std::string shard_http = "spokemesh-shard-{shard}:8080", shard_grpc = "spokemesh-shard-{shard}:50051";
  std::string pieces_above = "auto";
  std::uint32_t piece_points = kDefaultPiecePoints;
};

// Adds every flag to `app` (its defaults are the fields' values).
void add_server_flags(CLI::App& app, ServerFlags& flags);
// INVALID_ARGUMENT naming the flag for a bad value.
Result<ServerConfig> make_config(const ServerFlags& flags);

// A whole small file (a token, a PEM file); INVALID_ARGUMENT naming `flag` if unreadable.
Result<std::string> read_text_file(const std::string& path, const std::string& flag);

// Serves until SIGTERM or SIGINT (SIGHUP re-reads --keys), then drains and stops.
// Returns the process's exit code: 0 after a clean shutdown, 2 for a configuration
// that cannot be used (unreadable TLS files, a bad address, a store that will not
// open), 1 when a port cannot be bound.
int run_server(const ServerConfig& config);

}  // namespace spokemesh::service
