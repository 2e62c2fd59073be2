// spokemesh-server's entry point in the shape of grpc's route_guide: the command
// line becomes a ServerConfig (server_config.cpp), and run_server() serves it until
// SIGTERM or SIGINT (server.cpp). main.cpp only joins the two.
//
// Thread safety: add_server_flags/make_config on the main thread, before any other
// thread starts; run_server() once per process (it takes the process's signals).
#pragma once

#include <CLI/CLI.hpp>

#include <chrono>
#include <string>

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
  HttpServerOptions http;  // its `tls` and `budget` are set by run_server
  std::string tls_cert, tls_key, tls_client_ca;  // PEM files; empty: plain
  std::string token;                             // from --auth-token-file
  std::string keys_file;                         // --keys, re-read on SIGHUP
  std::chrono::milliseconds drain{0}, grace{0};
  std::string drain_text, grace_text;  // as given, for the log
};

// The flags as given (text for sizes and durations, parsed by make_config).
struct ServerFlags {
  std::string grpc_listen = "127.0.0.1:50051", http_listen = "127.0.0.1:8080", data_dir = "./spokemesh-data";
  unsigned threads = 0;  // 0: the machine's threads
  std::uint64_t max_points = 0;
  int max_dimension = 0;
  int max_concurrent = 0;
  std::string max_memory = "auto", stream_cache, default_deadline, grace, drain, max_body, upload_idle;
  std::size_t http_max_connections = 0, http_per_address = 0, http_in_flight = 0;
  std::string http_header_timeout, http_body_timeout, http_idle_timeout, http_write_timeout, tls_handshake_timeout;
  std::string tls_cert, tls_key, tls_client_ca, auth_token_file, keys_file;
};

// Adds every flag to `app`, with the defaults of limits.hpp.
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
