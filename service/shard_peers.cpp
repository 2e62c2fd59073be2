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
  if (pool.size() < 64) pool.push_back(std::move(c));
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

Result<ShardPeers::HttpResponse> ShardPeers::forward_http(std::uint32_t shard, HttpRequest request,
                                                          SteadyClock::time_point deadline) {
  const std::string address = http_address(shard);
  const std::vector<std::string> replicas = split_commas(address);
  if (replicas.empty()) return unavailable(shard, address, "--shard-http names no address for it");
  request.set(kForwardedHeader, std::to_string(shards_.index));
  request.set(http::field::host, replicas.front());
  request.keep_alive(true);
  request.prepare_payload();

  std::vector<tcp::endpoint> endpoints;
  {
    std::lock_guard lock(mutex_);
    if (auto it = resolved_.find(shard); it != resolved_.end() && SteadyClock::now() < it->second.second) {
      endpoints = it->second.first;
    }
  }
  if (endpoints.empty()) {
    std::string resolve_error;
    for (const std::string& replica : replicas) {
      const auto [host, port] = host_port(replica);
      asio::io_context io;
      tcp::resolver resolver(io);
      beast::error_code ec;
      const auto found = resolver.resolve(host, port, ec);
      if (ec) resolve_error = "cannot resolve " + host + ": " + ec.message();
      if (!ec) {
        for (const auto& e : found) endpoints.push_back(e.endpoint());
      }
    }
    if (endpoints.empty()) {
      return unavailable(shard, address, resolve_error.empty() ? "it names no address" : resolve_error);
    }
    std::lock_guard lock(mutex_);
    resolved_[shard] = {endpoints, SteadyClock::now() + kResolvedFor};
  }
  std::size_t start = 0;
  {
    std::lock_guard lock(mutex_);
    start = static_cast<std::size_t>(turn_++ % endpoints.size());
  }
  std::string last_error = "no address tried";
  // Each address in turn: a kept-alive connection first (it may have been closed by
  // the peer: then once more on a new one), skipping addresses that just refused.
  // The addresses that refused lately are tried last (one may be back), once each.
  std::vector<bool> skipped(endpoints.size(), false);
  for (int pass = 0; pass < 2; ++pass) {
    for (std::size_t k = 0; k < endpoints.size(); ++k) {
      const tcp::endpoint& e = endpoints[(start + k) % endpoints.size()];
      std::string name = e.address().to_string() + ":" + std::to_string(e.port());
      if (pass == 0 && recently_refused(name)) {
        skipped[k] = true;
        continue;
      }
      if (pass == 1 && !skipped[k]) continue;
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
          if (!ec) {
            const int ms = static_cast<int>(kUnacknowledgedMs), one = 1;
            ::setsockopt(c->stream.socket().native_handle(), IPPROTO_TCP, TCP_USER_TIMEOUT, &ms, sizeof ms);
            ::setsockopt(c->stream.socket().native_handle(), IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
          }
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
  }
  {
    std::lock_guard lock(mutex_);
    resolved_.erase(shard);  // resolved again by the next request
  }
  return unavailable(shard, address, last_error);
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
