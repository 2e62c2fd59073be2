#include "http_server.hpp"

#include <sys/socket.h>

#include <cerrno>

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl/stream.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/http.hpp>

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

HttpServer::HttpServer(HttpApi& api, Telemetry& telemetry, HttpServerOptions options)
    : api_(api), telemetry_(telemetry), options_(std::move(options)) {}

HttpServer::~HttpServer() { stop(std::chrono::milliseconds(0)); }

Result<unsigned short> HttpServer::start() {
  auto endpoint = parse_endpoint(options_.listen, "--http-listen");
  if (!endpoint.is_ok()) return endpoint.status();
  acceptor_ = std::make_unique<tcp::acceptor>(io_);
  boost::system::error_code ec;
  acceptor_->open(endpoint->protocol(), ec);
  if (!ec) acceptor_->set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) acceptor_->bind(endpoint.value(), ec);
  if (!ec) acceptor_->listen(net::socket_base::max_listen_connections, ec);
  if (ec) {
    return Status{Code::kUnavailable, "--http-listen: cannot listen on " + options_.listen + ": " + ec.message()};
  }
  const unsigned short port = acceptor_->local_endpoint().port();
  accept_thread_ = std::thread([this] { accept_loop(); });
  reaper_thread_ = std::thread([this] { reap_idle(); });
  return port;
}

void HttpServer::reap_idle() {
  std::unique_lock lock(mutex_);
  while (!stopping_.load()) {
    cv_.wait_for(lock, std::chrono::seconds(1));
    const auto limit = Clock::now() - options_.idle_timeout;
    for (const auto& [fd, idle_since] : connections_) {
      if (idle_since < limit) ::shutdown(fd, SHUT_RDWR);  // wakes the blocked read
    }
  }
}

void HttpServer::accept_loop() {
  while (!stopping_.load()) {
    tcp::socket socket(io_);
    boost::system::error_code ec;
    acceptor_->accept(socket, ec);
    if (stopping_.load()) break;
    if (ec) {
      // Out of descriptors and the like: back off instead of spinning.
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      continue;
    }
    {
      std::lock_guard lock(mutex_);
      if (threads_ >= options_.max_connections) {
        static const std::string busy =
            "HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\nConnection: close\r\n"
            "Content-Length: 94\r\n\r\n"
            "{\"error\":{\"code\":503,\"status\":\"UNAVAILABLE\",\"message\":\"too many connections; retry later\"}}\n";
        net::write(socket, net::buffer(busy), ec);
        continue;
      }
      ++threads_;
    }
    std::thread([this, s = std::move(socket)]() mutable { serve(std::move(s)); }).detach();
  }
}

void HttpServer::serve(tcp::socket socket) {
  const int fd = socket.native_handle();
  {
    std::lock_guard lock(mutex_);
    connections_[fd] = Clock::now();
  }
  boost::system::error_code ec;
  if (options_.tls) {
    net::ssl::stream<tcp::socket> stream(std::move(socket), *options_.tls);
    stream.handshake(net::ssl::stream_base::server, ec);
    if (!ec) session(stream, fd);
    {
      std::lock_guard lock(mutex_);
      connections_.erase(fd);
    }
    stream.next_layer().shutdown(tcp::socket::shutdown_both, ec);
    stream.next_layer().close(ec);
  } else {
    session(socket, fd);
    {
      std::lock_guard lock(mutex_);
      connections_.erase(fd);
    }
    socket.shutdown(tcp::socket::shutdown_both, ec);
    socket.close(ec);
  }
  std::lock_guard lock(mutex_);
  --threads_;
  cv_.notify_all();
}

namespace {

// A one-off JSON error response, then the connection closes.
template <class Stream>
void write_error(Stream& stream, http::status status, const Status& error) {
  http::response<http::string_body> res{status, 11};
  res.set(http::field::content_type, "application/json");
  res.keep_alive(false);
  res.body() = error_json(error, static_cast<int>(status));
  res.prepare_payload();
  boost::system::error_code ec;
  http::write(stream, res, ec);
}

}  // namespace

template <class Stream>
void HttpServer::session(Stream& stream, int fd) {
  namespace beast = boost::beast;
  beast::flat_buffer buffer;
  // A client is gone when its connection is reset. End-of-file alone is not enough:
  // a client may shut down its sending side after the request (a half-close) and
  // still read the answer; one that closed both sides is found when a write fails.
  auto client_gone = [fd] {
    char c;
    if (::recv(fd, &c, 1, MSG_PEEK | MSG_DONTWAIT) >= 0) return false;
    return errno == ECONNRESET || errno == EPIPE || errno == ENOTCONN;
  };
  for (;;) {
    http::request_parser<http::string_body> parser;
    parser.body_limit(options_.max_body_bytes);
    boost::system::error_code ec;
    // Idle keep-alive connections are closed by stop() or by the peer; reads block.
    http::read(stream, buffer, parser, ec);
    if (ec) {
      if (ec == http::error::body_limit) {
        write_error(stream, http::status::payload_too_large,
                    resource_exhausted("body: larger than this server's limit --max-body-bytes=" +
                                       std::to_string(options_.max_body_bytes)));
      } else if (ec != http::error::end_of_stream && ec != net::error::eof && ec != net::error::connection_reset &&
                 ec != net::ssl::error::stream_truncated && ec != net::error::operation_aborted &&
                 ec != net::error::bad_descriptor && parser.got_some()) {
        write_error(stream, http::status::bad_request, invalid_argument("malformed HTTP request: " + ec.message()));
      }
      return;
    }
    {
      std::lock_guard lock(mutex_);
      ++busy_;
      connections_[fd] = Clock::time_point::max();  // busy: never reaped as idle
    }
    const http::request<http::string_body> request = parser.release();
    HttpResponse response;
    try {
      response = api_.handle_request(request, client_gone);
    } catch (const std::exception& e) {  // e.g. bad_alloc: one failed request, not a dead server
      response.status = 500;
      response.body = error_json(internal_error(std::string("internal error: ") + e.what()));
      telemetry_.log("error", std::string("request failed with an exception: ") + e.what());
    }
    const bool keep_alive = request.keep_alive() && !stopping_.load();
    bool broken = false;
    if (response.stream) {
      http::response<http::empty_body> head{http::status::ok, request.version()};
      head.set(http::field::server, "spokemesh");
      head.set(http::field::content_type, response.content_type);
      head.keep_alive(keep_alive);
      head.chunked(true);
      bool head_sent = false;
      auto write_chunk = [&](std::string_view data) -> bool {
        boost::system::error_code wec;
        if (!head_sent) {
          http::response_serializer<http::empty_body> serializer{head};
          http::write_header(stream, serializer, wec);
          if (wec) return false;
          head_sent = true;
        }
        if (!data.empty()) net::write(stream, http::make_chunk(net::const_buffer(data.data(), data.size())), wec);
        return !wec;
      };
      const Status s = response.stream(write_chunk);
      if (!head_sent && !s.is_ok()) {
        response.stream = nullptr;
        response.status = static_cast<unsigned>(http_status(s));
        response.content_type = "application/json";
        response.body = error_json(s);
      } else if (s.is_ok()) {
        if (write_chunk("")) net::write(stream, http::make_chunk_last(), ec);
        broken = static_cast<bool>(ec);
      } else {
        // Mid-stream failure: say why on a last line, then drop the connection without
        // the terminating chunk so no client can take the partial shard as complete.
        write_chunk(error_json(s) + "\n");
        broken = true;
      }
    }
    if (!response.stream) {
      http::response<http::string_body> res;
      res.version(request.version());
      res.result(response.status);
      res.set(http::field::server, "spokemesh");
      res.set(http::field::content_type, response.content_type);
      res.keep_alive(keep_alive);
      res.body() = std::move(response.body);
      res.prepare_payload();
      http::write(stream, res, ec);
      broken = static_cast<bool>(ec);
    }
    {
      std::lock_guard lock(mutex_);
      --busy_;
      connections_[fd] = Clock::now();
    }
    cv_.notify_all();
    if (broken || !keep_alive) return;
  }
}

void HttpServer::stop(std::chrono::milliseconds grace) {
  if (stopping_.exchange(true)) return;
  if (acceptor_) {
    // Wakes the blocking accept().
    ::shutdown(acceptor_->native_handle(), SHUT_RDWR);
    if (accept_thread_.joinable()) accept_thread_.join();
    boost::system::error_code ec;
    acceptor_->close(ec);
  }
  cv_.notify_all();
  if (reaper_thread_.joinable()) reaper_thread_.join();
  std::unique_lock lock(mutex_);
  cv_.wait_for(lock, grace, [this] { return busy_ == 0; });
  // Idle keep-alive connections, and whatever outlived the grace period.
  for (const auto& entry : connections_) ::shutdown(entry.first, SHUT_RDWR);
  cv_.wait_for(lock, std::chrono::seconds(5), [this] { return threads_ == 0; });
}

}  // namespace spokemesh::service
