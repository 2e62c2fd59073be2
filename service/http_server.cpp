#include "http_server.hpp"

#include <sys/socket.h>

#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>

#include <array>
#include <cerrno>
#include <future>
#include <optional>
#include <sstream>
#include <type_traits>

#include "status_map.hpp"

namespace spokemesh::service {

namespace net = boost::asio;
using tcp = net::ip::tcp;

Result<tcp::endpoint> parse_endpoint(const std::string& listen, const std::string& flag) {
  const std::size_t colon = listen.rfind(':');
  if (colon == std::string::npos || colon + 1 == listen.size()) {
    return invalid_argument(flag + ": \"" + listen + "\" is not HOST:PORT");
  }
  std::string host = listen.substr(0, colon);
  const std::string port_text = listen.substr(colon + 1);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
  if (host.empty() || host == "localhost") host = "127.0.0.1";
  unsigned long port = 0;
  try {
    std::size_t used = 0;
    port = std::stoul(port_text, &used);
    if (used != port_text.size() || port > 65535) throw std::out_of_range("port");
  } catch (const std::exception&) {
    return invalid_argument(flag + ": \"" + port_text + "\" is not a port number");
  }
  boost::system::error_code ec;
  const auto address = net::ip::make_address(host, ec);
  if (ec) return invalid_argument(flag + ": \"" + host + "\" is not an IP address (use e.g. 0.0.0.0 or 127.0.0.1)");
  return tcp::endpoint(address, static_cast<unsigned short>(port));
}

namespace beast = boost::beast;

namespace {

// A complete one-off response (a 503 when a cap is reached, a 413, a 400), then close.
std::string one_off_response(http::status status, const Status& error, bool retry_after) {
  http::response<http::string_body> res{status, 11};
  res.set(http::field::server, "spokemesh");
  res.set(http::field::content_type, "application/json");
  if (retry_after) res.set(http::field::retry_after, "1");
  res.keep_alive(false);
  res.body() = error_json(error, static_cast<int>(status));
  res.prepare_payload();  // Content-Length from the body itself
  std::ostringstream out;
  out << res;
  return out.str();
}

// Errors that only mean the connection ended or timed out: closed without a word.
bool quiet_end(const boost::system::error_code& ec) {
  return ec == http::error::end_of_stream || ec == net::error::eof || ec == net::error::connection_reset ||
         ec == net::error::operation_aborted || ec == net::error::bad_descriptor || ec == beast::error::timeout ||
         ec == net::ssl::error::stream_truncated || ec == net::error::broken_pipe;
}

}  // namespace

// The part of a session the server can reach without knowing its stream type.
class HttpServer::SessionBase : public std::enable_shared_from_this<SessionBase> {
 public:
  virtual ~SessionBase() = default;
  // Both post onto the session's event loop (run by one thread: every handler of a
  // session runs there, one at a time, with no strand needed), so they may be called
  // from any thread.
  virtual void close() = 0;
  virtual void close_if_idle() = 0;
};

template <class Stream>
class HttpServer::Session final : public HttpServer::SessionBase {
 public:
  Session(HttpServer& server, Stream stream, net::ip::address from, ShardPeers::RelayPool& relays)
      : server_(server),
        options_(server.options_),
        stream_(std::move(stream)),
        from_(std::move(from)),
        relays_(relays) {}
  ~Session() override { server_.release(from_, this); }

  void run() {
    {
      std::lock_guard lock(server_.mutex_);
      server_.sessions_[this] = weak_from_this();
    }
    if constexpr (kTls) {
      lowest().expires_after(options_.handshake_timeout);
      stream_.async_handshake(net::ssl::stream_base::server, [self = shared()](boost::system::error_code ec) {
        if (ec) return self->do_close();
        self->read_request();
      });
    } else {
      read_request();
    }
  }

  void close() override {
    net::post(lowest().get_executor(), [self = shared()] { self->do_close(); });
  }
  void close_if_idle() override {
    net::post(lowest().get_executor(), [self = shared()] {
      if (self->idle_) self->do_close();
    });
  }

 private:
  static constexpr bool kTls = !std::is_same_v<Stream, beast::tcp_stream>;

  std::shared_ptr<Session> shared() { return std::static_pointer_cast<Session>(shared_from_this()); }
  beast::tcp_stream& lowest() { return beast::get_lowest_layer(stream_); }

  // Waits for a request: the keep-alive idle timeout until its first bytes (the header
  // timeout for a connection's first request), then the header timeout for the rest
  // of the header, then the body timeout. A trickling client is cut off at a timeout
  // without ever holding a thread.
  void read_request() {
    if (closed_ || server_.stopping_.load()) return do_close();
    idle_ = true;
    body_charge_.reset();
    parser_.emplace();
    parser_->body_limit(options_.max_body_bytes);
    lowest().expires_after(requests_ == 0 ? options_.header_timeout : options_.idle_timeout);
    http::async_read_some(stream_, buffer_, *parser_,
                          [self = shared()](boost::system::error_code ec, std::size_t) { self->on_first_bytes(ec); });
  }
  void on_first_bytes(boost::system::error_code ec) {
    idle_ = false;
    if (ec) return fail_read(ec);
    if (parser_->is_header_done()) return on_header({});
    if (requests_ != 0) lowest().expires_after(options_.header_timeout);
    http::async_read_header(stream_, buffer_, *parser_,
                            [self = shared()](boost::system::error_code e, std::size_t) { self->on_header(e); });
  }
  void on_header(boost::system::error_code ec) {
    if (ec) return fail_read(ec);
    // The body's memory is charged before a byte of it is held: from its
    // Content-Length, or the body limit when it is chunked.
    if (options_.budget != nullptr) {
      const std::uint64_t bytes = parser_->content_length().value_or(parser_->chunked() ? options_.max_body_bytes : 0);
      if (bytes != 0 && bytes <= options_.max_body_bytes) {
        auto charge = options_.budget->try_charge(bytes);
        if (!charge) {
          return write_one_off(one_off_response(http::status::service_unavailable,
                                                options_.budget->over_budget("a request body", bytes), true));
        }
        body_charge_ = std::move(*charge);
      }
    }
    if (parser_->is_done()) return on_request();
    lowest().expires_after(options_.body_timeout);
    http::async_read(stream_, buffer_, *parser_, [self = shared()](boost::system::error_code e, std::size_t) {
      if (e) return self->fail_read(e);
      self->on_request();
    });
  }
  void fail_read(boost::system::error_code ec) {
    if (ec == http::error::body_limit) {
      return write_one_off(
          one_off_response(http::status::payload_too_large,
                           resource_exhausted("body: larger than this server's limit --max-body-bytes=" +
                                              std::to_string(options_.max_body_bytes)),
                           false));
    }
    if (quiet_end(ec) || !parser_->got_some()) return do_close();
    write_one_off(one_off_response(http::status::bad_request,
                                   invalid_argument("malformed HTTP request: " + ec.message()), false));
  }
  void write_one_off(std::string bytes) {
    auto text = std::make_shared<std::string>(std::move(bytes));
    lowest().expires_after(options_.write_timeout);
    net::async_write(stream_, net::buffer(*text), [self = shared(), text](boost::system::error_code ec, std::size_t) {
      if (ec) return self->do_close();
      self->linger();
    });
  }
  // A lingering close (as nginx's): after an early answer (413, 503) the client may
  // still be sending its body; closing at once would reset the connection before it
  // reads the answer. So: stop sending, read and discard what still comes for a
  // few seconds, then close.
  void linger() {
    boost::system::error_code ec;
    lowest().socket().shutdown(net::ip::tcp::socket::shutdown_send, ec);
    lowest().expires_after(std::chrono::seconds(5));
    discard();
  }
  void discard() {
    lowest().async_read_some(net::buffer(drain_), [self = shared()](boost::system::error_code ec, std::size_t) {
      if (ec) return self->do_close();
      self->discard();
    });
  }

  // A whole request has arrived: answered here on the I/O thread when that cannot block
  // (HttpApi::answer_at_once), else it gets a thread of its own (computations block),
  // unless too many are in flight.
  void on_request() {
    lowest().expires_never();
    std::optional<HttpResponse> at_once;
    try {
      at_once = server_.api_.answer_at_once(parser_->get());
    } catch (const std::exception& e) {  // as handle(): one failed request
      at_once = failure(e);
    }
    ++requests_;
    request_ = parser_->release();
    if (at_once && at_once->relay) return relay_at_once(at_once->relay);
    if (at_once) return write_at_once(std::move(*at_once));
    to_thread();
  }

  // The request (request_) on a thread of its own, unless too many are in flight.
  void to_thread() {
    if (!server_.begin_request()) {
      return write_one_off(one_off_response(http::status::service_unavailable,
                                            Status{Code::kUnavailable, "too many requests in flight; retry later"},
                                            true));
    }
    if (!server_.workers_.run([self = shared()] { self->handle(); })) {  // no thread to be had
      server_.end_request();
      write_one_off(one_off_response(http::status::service_unavailable,
                                     Status{Code::kUnavailable, "the server is out of threads; retry later"}, true));
    }
  }

  // Another shard's seed, relayed on this loop without a thread (counted in flight as
  // any request); a thread relays it when that cannot be done without one (see
  // ShardPeers::forward_http_async). The answer may come before forward_http_async
  // returns (a deadline already past), so request_ is set before it is called.
  void relay_at_once(const std::shared_ptr<PendingRelay>& pending) {
    if (!server_.begin_request()) return to_thread();  // which answers the 503
    ShardPeers::ForwardDone done = [self = shared(), pending](Result<ShardPeers::HttpResponse> relayed) {
      HttpResponse response;
      try {
        response = pending->finish(std::move(relayed));
      } catch (const std::exception& e) {
        response = self->failure(e);
      }
      self->server_.end_request();
      self->write_at_once(std::move(response));
    };
    if (pending->peers->forward_http_async(relays_, pending->shard, pending->request, pending->deadline, done)) {
      ++server_.relayed_at_once_;
      return;
    }
    server_.end_request();
    to_thread();
  }

  HttpResponse failure(const std::exception& e) {
    HttpResponse response;
    response.status = 500;
    response.body = error_json(internal_error(std::string("internal error: ") + e.what()));
    server_.telemetry_.log("error", std::string("request failed with an exception: ") + e.what());
    return response;
  }

  // The whole response of a request, headers and body.
  std::shared_ptr<http::response<http::string_body>> whole_response(HttpResponse&& response, bool keep_alive) {
    auto res = std::make_shared<http::response<http::string_body>>();
    res->version(request_.version());
    res->result(response.status);
    res->set(http::field::server, "spokemesh");
    res->set(http::field::content_type, response.content_type);
    for (const auto& [name, value] : response.headers) res->set(name, value);
    res->keep_alive(keep_alive);
    if (response.status == 503) res->set(http::field::retry_after, "1");
    res->body() = std::move(response.body);
    res->prepare_payload();
    return res;
  }

  // On the loop: an answer made at once, written without a thread; then the next
  // request (keep-alive), as handle() ends.
  void write_at_once(HttpResponse response) {
    const bool keep_alive = request_.keep_alive() && !server_.stopping_.load();
    auto res = whole_response(std::move(response), keep_alive);
    request_ = {};
    lowest().expires_after(options_.write_timeout);
    http::async_write(stream_, *res, [self = shared(), res, keep_alive](boost::system::error_code ec, std::size_t) {
      self->body_charge_.reset();
      if (ec || !keep_alive) return self->do_close();
      self->read_request();
    });
  }

  // Runs an asynchronous write on the session's loop and waits for it (from the
  // request's own thread). The write timeout ends a client that stopped reading.
  template <class Start>
  boost::system::error_code write_and_wait(Start&& start) {
    std::promise<boost::system::error_code> done;
    std::future<boost::system::error_code> result = done.get_future();
    net::post(lowest().get_executor(), [&] {
      if (closed_) return done.set_value(net::error::operation_aborted);
      lowest().expires_after(options_.write_timeout);
      start([&done](boost::system::error_code ec, std::size_t) { done.set_value(ec); });
    });
    return result.get();
  }

  // On the request's thread: the transport-neutral handler, then the response.
  void handle() {
    const int fd = lowest().socket().native_handle();
    // Gone when the connection is reset or closed by the server; end-of-file alone is
    // not enough: a client may shut down its sending side after its request (a
    // half-close) and still read the answer.
    auto client_gone = [fd, self = shared()] {
      if (self->closed_.load()) return true;
      char c;
      if (::recv(fd, &c, 1, MSG_PEEK | MSG_DONTWAIT) >= 0) return false;
      return errno == ECONNRESET || errno == EPIPE || errno == ENOTCONN;
    };
    HttpResponse response;
    try {
      response = server_.api_.handle_request(request_, client_gone);
    } catch (const std::exception& e) {  // e.g. bad_alloc: one failed request, not a dead server
      response = failure(e);
    }
    const bool keep_alive = request_.keep_alive() && !server_.stopping_.load();
    bool ok = true;
    if (response.stream) {
      http::response<http::empty_body> head{http::status::ok, request_.version()};
      head.set(http::field::server, "spokemesh");
      head.set(http::field::content_type, response.content_type);
      for (const auto& [name, value] : response.headers) head.set(name, value);
      head.keep_alive(keep_alive);
      head.chunked(true);
      http::response_serializer<http::empty_body> serializer{head};
      bool head_sent = false;
      auto write_chunk = [&](std::string_view data) -> bool {
        if (!head_sent) {
          if (write_and_wait([&](auto done) { http::async_write_header(stream_, serializer, std::move(done)); })) {
            return false;
          }
          head_sent = true;
        }
        if (data.empty()) return true;
        const auto chunk = http::make_chunk(net::const_buffer(data.data(), data.size()));
        return !write_and_wait([&](auto done) { net::async_write(stream_, chunk, std::move(done)); });
      };
      const Status s = response.stream(write_chunk);
      if (!head_sent && !s.is_ok()) {
        response.stream = nullptr;
        response.headers.clear();  // a download's name is no error's
        response.status = static_cast<unsigned>(http_status(s));
        response.content_type = "application/json";
        response.body = error_json(s);
      } else if (s.is_ok()) {
        ok = write_chunk("") &&
             !write_and_wait([&](auto done) { net::async_write(stream_, http::make_chunk_last(), std::move(done)); });
      } else {
        // Mid-stream failure: say why on a last line, then drop the connection without
        // the terminating chunk so no client can take the partial shard as complete.
        write_chunk(error_json(s) + "\n");
        ok = false;
      }
    }
    if (!response.stream) {
      auto res = whole_response(std::move(response), keep_alive);
      ok = !write_and_wait([&](auto done) { http::async_write(stream_, *res, std::move(done)); });
    }
    request_ = {};
    body_charge_.reset();
    server_.end_request();
    net::post(lowest().get_executor(), [self = shared(), next = ok && keep_alive] {
      if (next) return self->read_request();
      self->do_close();
    });
  }

  void do_close() {
    if (closed_.exchange(true)) return;
    idle_ = false;
    boost::system::error_code ec;
    lowest().socket().shutdown(net::ip::tcp::socket::shutdown_both, ec);
    lowest().cancel();  // pending reads and writes end; the socket closes with the session
  }

  HttpServer& server_;
  const HttpServerOptions& options_;
  Stream stream_;
  net::ip::address from_;
  ShardPeers::RelayPool& relays_;  // this connection's loop's (relay_at_once)
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  http::request<http::string_body> request_;
  MemoryBudget::Charge body_charge_;  // the request body's bytes, until it is handled
  std::array<char, 4096> drain_{};    // discarded bytes of a lingering close
  std::size_t requests_ = 0;
  bool idle_ = false;  // waiting for a request (on the loop's thread only)
  std::atomic<bool> closed_{false};
};

HttpServer::HttpServer(HttpApi& api, Telemetry& telemetry, HttpServerOptions options)
    : api_(api), telemetry_(telemetry), options_(std::move(options)) {}

HttpServer::~HttpServer() { stop(std::chrono::milliseconds(0)); }

// How long a request's thread waits for the next request before it ends.
constexpr auto kIdleWorkerFor = std::chrono::seconds(10);

HttpServer::Workers::~Workers() {
  std::lock_guard lock(state_->mutex);
  state_->stop = true;
  state_->cv.notify_all();
}

bool HttpServer::Workers::run(std::function<void()> job) {
  {
    std::lock_guard lock(state_->mutex);
    if (state_->idle > state_->jobs.size()) {
      state_->jobs.push_back(std::move(job));
      state_->cv.notify_one();
      return true;
    }
  }
  try {
    std::thread([state = state_, first = std::move(job)]() mutable {
      first();
      first = nullptr;  // an idle thread keeps no request's session alive
      serve(state);
    }).detach();
    return true;
  } catch (const std::system_error&) {
    return false;
  }
}

void HttpServer::Workers::serve(const std::shared_ptr<State>& state) {
  std::unique_lock lock(state->mutex);
  for (;;) {
    ++state->idle;
    const bool got = state->cv.wait_for(lock, kIdleWorkerFor, [&] { return state->stop || !state->jobs.empty(); });
    --state->idle;
    if (!got || state->jobs.empty()) return;  // idle too long, or stopping
    std::function<void()> job = std::move(state->jobs.front());
    state->jobs.pop_front();
    lock.unlock();
    job();
    job = nullptr;
    lock.lock();
  }
}

Result<unsigned short> HttpServer::start() {
  auto endpoint = parse_endpoint(options_.listen, "--http-listen");
  if (!endpoint.is_ok()) return endpoint.status();
  const unsigned loops = std::max(1u, options_.io_threads);
  for (unsigned i = 0; i < loops; ++i) {
    io_.push_back(std::make_unique<net::io_context>(1));  // one thread runs it
    work_.push_back(net::make_work_guard(*io_.back()));
    relay_pools_.push_back(std::make_unique<ShardPeers::RelayPool>(*io_.back()));
  }
  acceptor_ = std::make_unique<tcp::acceptor>(*io_[0]);
  boost::system::error_code ec;
  acceptor_->open(endpoint->protocol(), ec);
  if (!ec) acceptor_->set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) acceptor_->bind(endpoint.value(), ec);
  if (!ec) acceptor_->listen(net::socket_base::max_listen_connections, ec);
  if (ec) {
    return Status{Code::kUnavailable, "--http-listen: cannot listen on " + options_.listen + ": " + ec.message()};
  }
  const unsigned short port = acceptor_->local_endpoint().port();
  do_accept();
  for (auto& io : io_) io_threads_.emplace_back([loop = io.get()] { loop->run(); });
  return port;
}

void HttpServer::do_accept() {
  const std::size_t turn = next_io_++ % io_.size();
  net::io_context& loop = *io_[turn];
  ShardPeers::RelayPool& relays = *relay_pools_[turn];
  // The connection's operations on its loop's own executor: one thread runs each loop,
  // so its handlers never run concurrently (a strand would only add a queue hop to each).
  acceptor_->async_accept(loop.get_executor(), [this, &relays](boost::system::error_code ec, tcp::socket socket) {
    if (stopping_.load() || ec == net::error::operation_aborted) return;
    if (ec) {
      // Out of descriptors and the like: back off instead of spinning.
      auto timer = std::make_shared<net::steady_timer>(*io_[0], std::chrono::milliseconds(10));
      timer->async_wait([this, timer](boost::system::error_code) { do_accept(); });
      return;
    }
    boost::system::error_code ep_ec;
    const net::ip::address from = socket.remote_endpoint(ep_ec).address();
    std::string why;
    if (ep_ec) {
      socket.close(ep_ec);
    } else if (!admit(from, why)) {
      // A complete 503 on plain HTTP (a TLS client could not read it: closed instead),
      // written without blocking: it fits the socket's buffer.
      if (!options_.tls) {
        const std::string busy =
            one_off_response(http::status::service_unavailable, Status{Code::kUnavailable, why}, true);
        socket.non_blocking(true, ep_ec);
        socket.write_some(net::buffer(busy), ep_ec);
      }
      socket.shutdown(tcp::socket::shutdown_both, ep_ec);
      socket.close(ep_ec);
    } else if (options_.tls) {
      std::make_shared<Session<beast::ssl_stream<beast::tcp_stream>>>(
          *this, beast::ssl_stream<beast::tcp_stream>(beast::tcp_stream(std::move(socket)), *options_.tls), from,
          relays)
          ->run();
    } else {
      std::make_shared<Session<beast::tcp_stream>>(*this, beast::tcp_stream(std::move(socket)), from, relays)->run();
    }
    do_accept();
  });
}

bool HttpServer::admit(const net::ip::address& from, std::string& why) {
  std::lock_guard lock(mutex_);
  if (open_ >= options_.max_connections) {
    why = "too many connections (" + std::to_string(options_.max_connections) + "); retry later";
    return false;
  }
  std::size_t& mine = per_address_[from];
  if (mine >= options_.max_connections_per_address) {
    why = "too many connections from one address (" + std::to_string(options_.max_connections_per_address) +
          "); retry later";
    if (mine == 0) per_address_.erase(from);
    return false;
  }
  ++mine;
  ++open_;
  return true;
}

void HttpServer::release(const net::ip::address& from, SessionBase* session) {
  std::lock_guard lock(mutex_);
  sessions_.erase(session);
  if (auto it = per_address_.find(from); it != per_address_.end() && --it->second == 0) per_address_.erase(it);
  --open_;
  cv_.notify_all();
}

bool HttpServer::begin_request() {
  std::lock_guard lock(mutex_);
  if (in_flight_ >= options_.max_in_flight) return false;
  ++in_flight_;
  return true;
}

void HttpServer::end_request() {
  std::lock_guard lock(mutex_);
  --in_flight_;
  cv_.notify_all();
}

std::size_t HttpServer::connections() const {
  std::lock_guard lock(mutex_);
  return open_;
}

std::size_t HttpServer::in_flight() const {
  std::lock_guard lock(mutex_);
  return in_flight_;
}

void HttpServer::stop(std::chrono::milliseconds grace) {
  if (stopping_.exchange(true)) return;
  if (!acceptor_) return;
  net::post(*io_[0], [this] {
    boost::system::error_code ec;
    acceptor_->close(ec);
  });
  auto each_session = [this](auto&& fn) {
    std::vector<std::shared_ptr<SessionBase>> live;
    {
      std::lock_guard lock(mutex_);
      for (const auto& [ptr, weak] : sessions_) {
        if (auto s = weak.lock()) live.push_back(std::move(s));
      }
    }
    for (const auto& s : live) fn(*s);
  };
  // Idle keep-alive connections now; requests in flight may finish within the grace.
  each_session([](SessionBase& s) { s.close_if_idle(); });
  {
    std::unique_lock lock(mutex_);
    cv_.wait_for(lock, grace, [this] { return in_flight_ == 0; });
  }
  each_session([](SessionBase& s) { s.close(); });
  {
    std::unique_lock lock(mutex_);
    if (!cv_.wait_for(lock, std::chrono::seconds(5), [this] { return in_flight_ == 0 && open_ == 0; })) {
      telemetry_.log("warning", "HTTP: " + std::to_string(in_flight_) + " requests still running at shutdown");
    }
  }
  work_.clear();
  for (auto& io : io_) io->stop();
  for (std::thread& t : io_threads_) t.join();
  io_threads_.clear();
}

}  // namespace spokemesh::service
