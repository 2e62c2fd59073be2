// HttpServer: Boost.Beast over Boost.Asio, serving HttpApi on one port, plain or TLS.
//
// In the shape of Beast's advanced server: the connections live on a few I/O threads
// (an event loop each, a connection on one loop) as asynchronous sessions, each with its own timeouts (TLS handshake,
// request header, request body, keep-alive idle, response write), so an idle, trickling or never handshaking connection
// costs a socket and a small buffer, never a thread. Only a request that has fully arrived gets a thread of its own,
// which runs the transport- neutral HttpApi::handle_request (computations block; a streamed shard writes chunk by
// chunk, each write waiting for the client: that wait is the flow control that keeps
// the shard's memory bounded, and the write timeout ends a client that stopped
// reading). Connections are capped per client address and in all; requests in flight
// are capped too; beyond a cap the answer is a complete 503 with Retry-After.
//
// Thread safety: start() once, then stop() from any thread.
#pragma once

#include <boost/asio/executor_work_guard.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl/context.hpp>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "http_api.hpp"
#include "limits.hpp"

namespace spokemesh::service {

struct HttpServerOptions {
  std::string listen = "127.0.0.1:8080";  // host:port; port 0 picks a free one
  // Defaults: limits.hpp.
  std::size_t max_body_bytes = defaults::kMaxBodyBytes;
  std::size_t max_connections = defaults::kHttpMaxConnections;                        // open connections in all
  std::size_t max_connections_per_address = defaults::kHttpMaxConnectionsPerAddress;  // from one client address
  std::size_t max_in_flight = defaults::kHttpMaxInFlight;  // requests being handled at once (one thread each)
  std::chrono::milliseconds handshake_timeout = defaults::kTlsHandshakeTimeout;  // TLS handshake
  std::chrono::milliseconds header_timeout = defaults::kHttpHeaderTimeout;  // a request's header, from its first byte
  std::chrono::milliseconds body_timeout = defaults::kHttpBodyTimeout;      // a request's body, after its header
  std::chrono::milliseconds idle_timeout = defaults::kHttpIdleTimeout;      // keep-alive between requests
  std::chrono::milliseconds write_timeout = defaults::kHttpWriteTimeout;    // each response write (a stalled reader)
  unsigned io_threads = 2;
  std::shared_ptr<boost::asio::ssl::context> tls;  // null: plain HTTP
  // Request bodies are charged here from their Content-Length before they are read
  // (not owned; null: not charged).
  MemoryBudget* budget = nullptr;
};

class HttpServer {
 public:
  HttpServer(HttpApi& api, Telemetry& telemetry, HttpServerOptions options);
  ~HttpServer();

  // Binds and starts accepting. Returns the bound port.
  Result<unsigned short> start();
  // Stops accepting and closes idle connections, lets requests in flight finish for up
  // to `grace`, then closes every connection and joins.
  void stop(std::chrono::milliseconds grace);

  // For tests and metrics: open connections and requests in flight.
  std::size_t connections() const;
  std::size_t in_flight() const;
  // Requests relayed to another shard's replica on an I/O loop, without a thread.
  std::size_t relayed_at_once() const { return relayed_at_once_.load(); }

 private:
  class SessionBase;
  template <class Stream>
  class Session;
  friend class SessionBase;
  template <class Stream>
  friend class Session;

  void do_accept();
  // Admission of a new connection; false (and the reason) when a cap is reached.
  bool admit(const boost::asio::ip::address& from, std::string& why);
  void release(const boost::asio::ip::address& from, SessionBase* session);
  bool begin_request();
  void end_request();

  HttpApi& api_;
  Telemetry& telemetry_;
  HttpServerOptions options_;
  std::atomic<bool> stopping_{false};
  std::atomic<std::size_t> relayed_at_once_{0};

  // Declared before io_: sessions still held by io_'s handlers reach these as io_ is
  // destroyed (members are destroyed in reverse order).
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::map<boost::asio::ip::address, std::size_t> per_address_;  // open connections per client address
  std::map<SessionBase*, std::weak_ptr<SessionBase>> sessions_;
  std::size_t open_ = 0;       // open connections
  std::size_t in_flight_ = 0;  // requests being handled

  // One event loop per I/O thread, each connection on one of them (given in turn at
  // accept): a request is read, answered at once and written by one thread, without
  // waking another (on a single shared loop, every handler could run on either thread,
  // and the hand-offs between them were futex calls on every request). io_[0] accepts.
  std::vector<std::unique_ptr<boost::asio::io_context>> io_;
  std::vector<boost::asio::executor_work_guard<boost::asio::io_context::executor_type>> work_;
  // Each loop's kept-alive connections to other shards' replicas (relays made at once);
  // declared after io_, so destroyed before the loops.
  std::vector<std::unique_ptr<ShardPeers::RelayPool>> relay_pools_;
  std::size_t next_io_ = 0;  // the loop the next connection goes to (the acceptor's handler only)
  // Threads for requests, kept a while once their request is done: a request takes an
  // idle one, or a new one (computations block, so each request in flight has its own).
  // Reuse saves a thread's creation per request, which a relayed request pays twice
  // (bench/README.md, "Sharded serving").
  // The threads share their state (not the server): destroying Workers tells the idle
  // ones to end and waits for none, as a request's thread ends with its request.
  class Workers {
   public:
    Workers() : state_(std::make_shared<State>()) {}
    ~Workers();
    // Runs `job` on a thread of its own; false when no thread can be had.
    bool run(std::function<void()> job);

   private:
    struct State {
      std::mutex mutex;
      std::condition_variable cv;
      std::deque<std::function<void()>> jobs;
      std::size_t idle = 0;
      bool stop = false;
    };
    static void serve(const std::shared_ptr<State>& state);
    std::shared_ptr<State> state_;
  };
  std::unique_ptr<boost::asio::ip::tcp::acceptor> acceptor_;
  std::vector<std::thread> io_threads_;
  Workers workers_;
};

// host:port -> endpoint (IPv4/IPv6 literal or "localhost").
Result<boost::asio::ip::tcp::endpoint> parse_endpoint(const std::string& listen, const std::string& flag);

}  // namespace spokemesh::service
