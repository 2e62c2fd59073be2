#include "shard_peers.hpp"

#include <grpcpp/grpcpp.h>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>

#include <netinet/in.h>
#include <netinet/tcp.h>

#include <optional>

namespace spokemesh::service {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;
using SteadyClock = std::chrono::steady_clock;

namespace {

// How long an address that refused a connection is passed over.
constexpr auto kRefusedFor = std::chrono::seconds(3);
// A connection attempt to a replica (on the deployment's network: a dead address costs
// this, then the next is tried, as nginx's proxy_connect_timeout in docker/nginx.conf).
constexpr auto kConnectTimeout = std::chrono::milliseconds(250);
// How long a relayed request's bytes may go unacknowledged before the connection is
// dropped (TCP_USER_TIMEOUT): a replica killed without closing its connections is found
// out in this long, and the request goes to another, instead of waiting for an answer
// that never comes.
constexpr unsigned kUnacknowledgedMs = 500;
// How long a name's addresses are kept before it is resolved again (nginx: valid=2s).
constexpr auto kResolvedFor = std::chrono::seconds(2);
// The most a forwarded answer may hold (a cell of a high-dimensional seed is the largest).
constexpr std::uint64_t kMaxForwardedBody = std::uint64_t{256} << 20;
// A relay connection's read buffer from the start: a star's or cell's answer arrives in
// one read, not in the growing reads of an empty buffer (each one more system call).
constexpr std::size_t kRelayReadBytes = 16384;
// Idle kept-alive connections kept per replica address (per pool).
constexpr std::size_t kIdlePerAddress = 64;

// A template with {shard} replaced; or, from a list "A1,A2;B1;C1,C2" (one entry per
// shard, each a comma-separated list of replicas), the shard's entry.
std::string with_shard(const std::string& pattern, std::uint32_t shard) {
  std::string out = pattern;
  const std::string key = "{shard}";
  if (out.find(key) == std::string::npos) {
    std::size_t begin = 0;
    for (std::uint32_t k = 0; k < shard && begin != std::string::npos; ++k) {
      begin = out.find(';', begin);
      if (begin != std::string::npos) ++begin;
    }
    if (begin == std::string::npos) return "";
    const std::size_t end = out.find(';', begin);
    return out.substr(begin, end == std::string::npos ? std::string::npos : end - begin);
  }
  for (std::size_t at = out.find(key); at != std::string::npos; at = out.find(key, at)) {
    out.replace(at, key.size(), std::to_string(shard));
  }
  return out;
}

std::vector<std::string> split_commas(const std::string& text) {
  std::vector<std::string> out;
  std::size_t begin = 0;
  while (begin <= text.size()) {
    const std::size_t end = text.find(',', begin);
    std::string part = text.substr(begin, end == std::string::npos ? std::string::npos : end - begin);
    if (!part.empty()) out.push_back(std::move(part));
    if (end == std::string::npos) break;
    begin = end + 1;
  }
  return out;
}

// HOST:PORT split at the last colon ([v6]:port too).
std::pair<std::string, std::string> host_port(const std::string& address) {
  const std::size_t colon = address.rfind(':');
  if (colon == std::string::npos) return {address, "80"};
  std::string host = address.substr(0, colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
  return {host, address.substr(colon + 1)};
}

}  // namespace

// One kept-alive connection to one replica, with its own io_context so that a request
// runs its operations (with their deadline) on the calling thread alone.
struct ShardPeers::Connection {
  Connection() { buffer.reserve(kRelayReadBytes); }
  asio::io_context io;
  beast::tcp_stream stream{io};
  beast::flat_buffer buffer;
  std::string endpoint;

  // Runs the pending operations until done or `deadline`; false on timeout.
  void run(SteadyClock::time_point deadline) {
    io.restart();
    stream.expires_at(deadline);
    io.run();
  }
};

ShardPeers::ShardPeers(ShardSettings shards, std::string http_template, std::string grpc_template)
    : shards_(shards), http_template_(std::move(http_template)), grpc_template_(std::move(grpc_template)) {}

ShardPeers::~ShardPeers() = default;

std::string ShardPeers::http_address(std::uint32_t shard) const { return with_shard(http_template_, shard); }
std::string ShardPeers::grpc_address(std::uint32_t shard) const { return with_shard(grpc_template_, shard); }

Status ShardPeers::unavailable(std::uint32_t shard, const std::string& address, const std::string& why) const {
  return Status{Code::kUnavailable, "shard " + std::to_string(shard) + " of " + std::to_string(shards_.count) + " (" +
                                        address + ") has no replica answering: " + why + "; retry later"}
      .with_reason("SHARD_UNAVAILABLE");
}

std::unique_ptr<ShardPeers::Connection> ShardPeers::take_idle(std::uint32_t shard, const std::string& endpoint) {
  std::lock_guard lock(mutex_);
  auto it = idle_.find({shard, endpoint});
  if (it == idle_.end() || it->second.empty()) return nullptr;
  auto c = std::move(it->second.back());
  it->second.pop_back();
  return c;
}

void ShardPeers::give_back(std::uint32_t shard, std::unique_ptr<Connection> c) {
  std::lock_guard lock(mutex_);
  auto& pool = idle_[{shard, c->endpoint}];
  if (pool.size() < kIdlePerAddress) pool.push_back(std::move(c));
}

bool ShardPeers::recently_refused(const std::string& endpoint) {
  std::lock_guard lock(mutex_);
  auto it = refused_until_.find(endpoint);
  return it != refused_until_.end() && SteadyClock::now() < it->second;
}

void ShardPeers::note_refused(const std::string& endpoint) {
  std::lock_guard lock(mutex_);
  refused_until_[endpoint] = SteadyClock::now() + kRefusedFor;
}

void ShardPeers::prepare(HttpRequest& request, const std::string& first_replica) const {
  request.set(kForwardedHeader, std::to_string(shards_.index));
  request.set(http::field::host, first_replica);
  request.keep_alive(true);
  request.prepare_payload();
}

std::vector<tcp::endpoint> ShardPeers::addresses(std::uint32_t shard, bool may_resolve, std::string& why) {
  {
    std::lock_guard lock(mutex_);
    if (auto it = resolved_.find(shard); it != resolved_.end() && SteadyClock::now() < it->second.second) {
      return it->second.first;
    }
  }
  if (!may_resolve) {
    why = "its addresses are not resolved";
    return {};
  }
  std::vector<tcp::endpoint> endpoints;
  for (const std::string& replica : split_commas(http_address(shard))) {
    const auto [host, port] = host_port(replica);
    asio::io_context io;
    tcp::resolver resolver(io);
    beast::error_code ec;
    const auto found = resolver.resolve(host, port, ec);
    if (ec) why = "cannot resolve " + host + ": " + ec.message();
    if (!ec) {
      for (const auto& e : found) endpoints.push_back(e.endpoint());
    }
  }
  if (endpoints.empty()) {
    if (why.empty()) why = "it names no address";
    return {};
  }
  std::lock_guard lock(mutex_);
  resolved_[shard] = {endpoints, SteadyClock::now() + kResolvedFor};
  return endpoints;
}

std::size_t ShardPeers::next_turn(std::size_t count) {
  std::lock_guard lock(mutex_);
  return static_cast<std::size_t>(turn_++ % count);
}

void ShardPeers::forget_addresses(std::uint32_t shard) {
  std::lock_guard lock(mutex_);
  resolved_.erase(shard);  // resolved again by the next request
}

namespace {

// A connection to a replica just made: the socket options every relay connection has.
void tune_relay_socket(tcp::socket& socket) {
  const int ms = static_cast<int>(kUnacknowledgedMs), one = 1;
  ::setsockopt(socket.native_handle(), IPPROTO_TCP, TCP_USER_TIMEOUT, &ms, sizeof ms);
  ::setsockopt(socket.native_handle(), IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
}

std::string endpoint_name(const tcp::endpoint& e) { return e.address().to_string() + ":" + std::to_string(e.port()); }

}  // namespace

// The order a relay tries a shard's addresses in, for forward_http and its asynchronous
// twin alike: from a rotating start, those that did not refuse a connection lately;
// then, once each, those that did (one may be back). Whether an address refused lately
// is asked as it is reached.
class ShardPeers::AddressOrder {
 public:
  AddressOrder(ShardPeers& peers, std::vector<tcp::endpoint> endpoints)
      : peers_(peers),
        endpoints_(std::move(endpoints)),
        start_(peers.next_turn(endpoints_.size())),
        skipped_(endpoints_.size(), false) {}

  // The next address to try (its name in `name`), or null once every one was tried.
  const tcp::endpoint* next(std::string& name) {
    for (; pass_ < 2; ++pass_, k_ = 0) {
      while (k_ < endpoints_.size()) {
        const std::size_t k = k_++;
        const tcp::endpoint& e = endpoints_[(start_ + k) % endpoints_.size()];
        if (pass_ == 1 && !skipped_[k]) continue;
        name = endpoint_name(e);
        if (pass_ == 0 && peers_.recently_refused(name)) {
          skipped_[k] = true;
          continue;
        }
        return &e;
      }
    }
    return nullptr;
  }

 private:
  ShardPeers& peers_;
  std::vector<tcp::endpoint> endpoints_;
  std::size_t start_;
  std::vector<bool> skipped_;
  int pass_ = 0;
  std::size_t k_ = 0;
};

Result<ShardPeers::HttpResponse> ShardPeers::forward_http(std::uint32_t shard, HttpRequest request,
                                                          SteadyClock::time_point deadline) {
  const std::string address = http_address(shard);
  const std::vector<std::string> replicas = split_commas(address);
  if (replicas.empty()) return unavailable(shard, address, "--shard-http names no address for it");
  prepare(request, replicas.front());
  std::string why;
  std::vector<tcp::endpoint> endpoints = addresses(shard, true, why);
  if (endpoints.empty()) return unavailable(shard, address, why);
  std::string last_error = "no address tried";
  // Each address in turn (AddressOrder): a kept-alive connection first (it may have
  // been closed by the peer: then once more on a new one).
  AddressOrder order(*this, std::move(endpoints));
  std::string name;
  while (const tcp::endpoint* next = order.next(name)) {
    const tcp::endpoint& e = *next;
    for (int attempt = 0; attempt < 2; ++attempt) {
      if (SteadyClock::now() >= deadline)
        return Status{Code::kDeadlineExceeded, "deadline exceeded forwarding to shard " + std::to_string(shard)};
      std::unique_ptr<Connection> c = attempt == 0 ? take_idle(shard, name) : nullptr;
      const bool fresh = c == nullptr;
      if (fresh) {
        c = std::make_unique<Connection>();
        c->endpoint = name;
        beast::error_code ec;
        c->stream.async_connect(e, [&](beast::error_code e2) { ec = e2; });
        c->run(std::min(deadline, SteadyClock::now() + kConnectTimeout));
        if (!ec) tune_relay_socket(c->stream.socket());
        if (ec) {
          last_error = name + ": " + ec.message();
          note_refused(name);
          break;  // the next address
        }
      }
      beast::error_code ec;
      http::async_write(c->stream, request, [&](beast::error_code e2, std::size_t) { ec = e2; });
      c->run(deadline);
      http::response_parser<http::string_body> parser;
      parser.body_limit(kMaxForwardedBody);
      if (!ec) {
        http::async_read(c->stream, c->buffer, parser, [&](beast::error_code e2, std::size_t) { ec = e2; });
        c->run(deadline);
      }
      if (ec) {
        last_error = name + ": " + ec.message();
        if (ec == beast::error::timeout) {
          return Status{Code::kDeadlineExceeded,
                        "deadline exceeded waiting for shard " + std::to_string(shard) + " (" + name + ")"};
        }
        if (fresh) {
          note_refused(name);
          break;
        }
        continue;  // a stale kept-alive connection: once more on a new one
      }
      HttpResponse response = parser.release();
      if (response.keep_alive()) give_back(shard, std::move(c));
      return response;
    }
  }
  forget_addresses(shard);
  return unavailable(shard, address, last_error);
}

// ---- relays without a thread ----------------------------------------------------------

struct ShardPeers::RelayPool::Connection {
  explicit Connection(asio::io_context& io) : stream(io) { buffer.reserve(kRelayReadBytes); }
  beast::tcp_stream stream;
  beast::flat_buffer buffer;
};

ShardPeers::RelayPool::RelayPool(asio::io_context& io) : io_(io) {}
ShardPeers::RelayPool::~RelayPool() = default;

// forward_http's loop as a chain of asynchronous steps on the pool's loop: the same
// order of addresses, the same retry of a stale kept-alive connection, the same errors.
class ShardPeers::AsyncForward : public std::enable_shared_from_this<AsyncForward> {
 public:
  AsyncForward(ShardPeers& peers, RelayPool& pool, std::uint32_t shard, HttpRequest request,
               SteadyClock::time_point deadline, ForwardDone done)
      : peers_(peers),
        pool_(pool),
        shard_(shard),
        request_(std::move(request)),
        deadline_(deadline),
        done_(std::move(done)) {}

  void start(std::vector<tcp::endpoint> endpoints, std::string address) {
    order_.emplace(peers_, std::move(endpoints));
    address_ = std::move(address);
    next_address();
  }

 private:
  void next_address() {
    if (const tcp::endpoint* next = order_->next(name_)) {
      endpoint_ = *next;
      return attempt(0);
    }
    peers_.forget_addresses(shard_);
    finish(peers_.unavailable(shard_, address_, last_error_));
  }

  void attempt(int which) {
    if (SteadyClock::now() >= deadline_) {
      return finish(Status{Code::kDeadlineExceeded, "deadline exceeded forwarding to shard " + std::to_string(shard_)});
    }
    connection_ = which == 0 ? take_idle() : nullptr;
    fresh_ = connection_ == nullptr;
    if (!fresh_) return send();
    connection_ = std::make_unique<RelayPool::Connection>(pool_.io_);
    connection_->stream.expires_at(std::min(deadline_, SteadyClock::now() + kConnectTimeout));
    connection_->stream.async_connect(endpoint_, [self = shared_from_this()](beast::error_code ec) {
      if (ec) {
        self->last_error_ = self->name_ + ": " + ec.message();
        self->peers_.note_refused(self->name_);
        return self->next_address();
      }
      tune_relay_socket(self->connection_->stream.socket());
      self->send();
    });
  }

  void send() {
    connection_->stream.expires_at(deadline_);
    http::async_write(connection_->stream, request_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
      if (ec) return self->failed(ec);
      self->parser_.emplace();
      self->parser_->body_limit(kMaxForwardedBody);
      http::async_read(self->connection_->stream, self->connection_->buffer, *self->parser_,
                       [self](beast::error_code e, std::size_t) {
                         if (e) return self->failed(e);
                         HttpResponse response = self->parser_->release();
                         if (response.keep_alive()) self->give_back();
                         self->finish(std::move(response));
                       });
    });
  }

  void failed(beast::error_code ec) {
    last_error_ = name_ + ": " + ec.message();
    connection_.reset();
    if (ec == beast::error::timeout) {
      return finish(Status{Code::kDeadlineExceeded,
                           "deadline exceeded waiting for shard " + std::to_string(shard_) + " (" + name_ + ")"});
    }
    if (fresh_) {
      peers_.note_refused(name_);
      return next_address();
    }
    attempt(1);  // a stale kept-alive connection: once more on a new one
  }

  std::unique_ptr<RelayPool::Connection> take_idle() {
    auto it = pool_.idle_.find({shard_, name_});
    if (it == pool_.idle_.end() || it->second.empty()) return nullptr;
    auto c = std::move(it->second.back());
    it->second.pop_back();
    return c;
  }

  void give_back() {
    auto& idle = pool_.idle_[{shard_, name_}];
    if (idle.size() < kIdlePerAddress) idle.push_back(std::move(connection_));
  }

  void finish(Result<HttpResponse> result) {
    ForwardDone done = std::move(done_);
    done(std::move(result));
  }

  ShardPeers& peers_;
  RelayPool& pool_;
  std::uint32_t shard_;
  HttpRequest request_;
  SteadyClock::time_point deadline_;
  ForwardDone done_;
  std::optional<AddressOrder> order_;
  std::string address_;
  tcp::endpoint endpoint_;
  std::string name_, last_error_ = "no address tried";
  std::unique_ptr<RelayPool::Connection> connection_;
  bool fresh_ = false;
  std::optional<http::response_parser<http::string_body>> parser_;
};

bool ShardPeers::forward_http_async(RelayPool& pool, std::uint32_t shard, HttpRequest& request,
                                    SteadyClock::time_point deadline, ForwardDone& done) {
  std::string address = http_address(shard);
  const std::vector<std::string> replicas = split_commas(address);
  if (replicas.empty()) return false;
  std::string why;
  std::vector<tcp::endpoint> endpoints = addresses(shard, false, why);
  if (endpoints.empty()) return false;
  prepare(request, replicas.front());
  auto forward = std::make_shared<AsyncForward>(*this, pool, shard, std::move(request), deadline, std::move(done));
  forward->start(std::move(endpoints), std::move(address));
  return true;
}

std::shared_ptr<grpc::Channel> ShardPeers::grpc_channel(std::uint32_t shard) {
  std::lock_guard lock(mutex_);
  auto& channel = channels_[shard];
  if (!channel) {
    grpc::ChannelArguments args;
    args.SetLoadBalancingPolicyName("round_robin");
    // A replica restarted on a new address is found within a second, not the default 30.
    args.SetInt(GRPC_ARG_DNS_MIN_TIME_BETWEEN_RESOLUTIONS_MS, 1000);
    args.SetInt(GRPC_ARG_MAX_RECEIVE_MESSAGE_LENGTH, static_cast<int>(kMaxForwardedBody));
    // One name (resolved to every replica), or a list of IPv4 replicas.
    const std::vector<std::string> replicas = split_commas(grpc_address(shard));
    std::string target = replicas.size() == 1 ? "dns:///" + replicas.front() : "ipv4:";
    for (std::size_t k = 0; replicas.size() > 1 && k < replicas.size(); ++k) target += (k ? "," : "") + replicas[k];
    channel = grpc::CreateCustomChannel(target, grpc::InsecureChannelCredentials(), args);
  }
  return channel;
}

}  // namespace spokemesh::service
