// HttpServer: Boost.Beast over Boost.Asio, serving HttpApi on one port, plain or TLS.
//
// Deliberately synchronous, one thread per connection (capped by max_connections):
// a long computation or a slow NDJSON reader then blocks only its own thread, a
// blocking chunk write is the flow control that keeps a streamed shard's memory
// bounded, and there is no callback state to get wrong. Requests are parsed with a
// body limit, so an oversized body is refused from its Content-Length (413) without
// being buffered.
//
// Thread safety: start() once, then stop() from any thread.
#pragma once

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl/context.hpp>

#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <map>
#include <string>
#include <thread>

#include "http_api.hpp"

namespace spokemesh::service {

struct HttpServerOptions {
  std::string listen = "127.0.0.1:8080";  // host:port; port 0 picks a free one
  std::size_t max_body_bytes = 256u << 20;
  std::size_t max_connections = 512;
  std::chrono::seconds idle_timeout{120};  // a keep-alive connection with no request is closed
  std::shared_ptr<boost::asio::ssl::context> tls;  // null: plain HTTP
};

class HttpServer {
 public:
  HttpServer(HttpApi& api, Telemetry& telemetry, HttpServerOptions options);
  ~HttpServer();

  // Binds and starts accepting. Returns the bound port.
  Result<unsigned short> start();
  // Stops accepting, lets in-flight requests finish for up to `grace`, then closes
  // every connection and joins.
  void stop(std::chrono::milliseconds grace);

 private:
  void accept_loop();
  void reap_idle();
  void serve(boost::asio::ip::tcp::socket socket);
  template <class Stream>
  void session(Stream& stream, int fd);

  HttpApi& api_;
  Telemetry& telemetry_;
  HttpServerOptions options_;
  boost::asio::io_context io_;
  std::unique_ptr<boost::asio::ip::tcp::acceptor> acceptor_;
  std::thread accept_thread_;
  std::thread reaper_thread_;
  std::atomic<bool> stopping_{false};

  std::mutex mutex_;
  std::condition_variable cv_;
  // Open sockets -> when they became idle (max() while a request runs).
  std::map<int, Clock::time_point> connections_;
  std::size_t threads_ = 0;    // live connection threads
  std::size_t busy_ = 0;       // requests being handled
};

// host:port -> endpoint (IPv4/IPv6 literal or "localhost").
Result<boost::asio::ip::tcp::endpoint> parse_endpoint(const std::string& listen, const std::string& flag);

}  // namespace spokemesh::service
