// ShardPeers: how a replica of one shard reaches the replicas of the others, to hand
// them the requests for seeds of their pieces (docs/service.md, "Sharded serving").
//
// A shard's replicas are found by name: the address template with {shard} replaced
// (`spokemesh-shard-{shard}:8080` for Kubernetes' per-shard Services, or compose's
// service names), resolved at each new connection to every address it names; a
// request tries them in turn from a rotating start (spreading load over the shard's
// replicas), and an address that refused a connection is skipped for a few seconds.
// REST requests are relayed as they came (plus X-Spokemesh-Forwarded, which stops a
// second hop), over kept-alive connections; gRPC calls go through one channel per
// shard with the round_robin policy over the same name. When no replica of the shard
// answers, the request gets UNAVAILABLE (HTTP 503) naming the shard; other shards and
// sets held whole are unaffected.
//
// The hop between shards is plain TCP inside the deployment's network (--shard is
// refused together with --tls-cert: put the shards behind one TLS front door).
//
// Thread safety: all member functions are safe to call concurrently.
#pragma once

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/http.hpp>

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "engine.hpp"
#include "spokemesh/status.hpp"

namespace grpc {
class Channel;
}

namespace spokemesh::service {

// The name carried by a forwarded request (REST header, gRPC metadata).
inline constexpr const char* kForwardedHeader = "x-spokemesh-forwarded";

class ShardPeers {
 public:
  // http_template / grpc_template: HOST:PORT with {shard} where the shard's number
  // goes; or one entry per shard separated by ';', each a comma-separated list of its
  // replicas' HOST:PORT (for gRPC several replicas must be IPv4 addresses).
  ShardPeers(ShardSettings shards, std::string http_template, std::string grpc_template);
  ~ShardPeers();
  ShardPeers(const ShardPeers&) = delete;
  ShardPeers& operator=(const ShardPeers&) = delete;

  const ShardSettings& shards() const { return shards_; }
  std::string http_address(std::uint32_t shard) const;
  std::string grpc_address(std::uint32_t shard) const;

  using HttpRequest = boost::beast::http::request<boost::beast::http::string_body>;
  using HttpResponse = boost::beast::http::response<boost::beast::http::string_body>;
  // Relays `request` to a replica of `shard` and returns its response as it came, or
  // UNAVAILABLE naming the shard when none answered before `deadline`.
  Result<HttpResponse> forward_http(std::uint32_t shard, HttpRequest request,
                                    std::chrono::steady_clock::time_point deadline);
  // The same without a thread (HttpServer's I/O loops, for a request answered at once):
  // every operation runs on `pool`'s event loop, and `done` is called there, once, with
  // what forward_http would have returned. False, with `request` and `done` untouched,
  // when that would need a name lookup (which could block the loop): the shard's
  // addresses were not resolved by a forward_http in the last 2 s. Then call forward_http.
  class RelayPool;
  using ForwardDone = std::function<void(Result<HttpResponse>)>;
  bool forward_http_async(RelayPool& pool, std::uint32_t shard, HttpRequest& request,
                          std::chrono::steady_clock::time_point deadline, ForwardDone& done);

  // The kept-alive connections of one event loop for forward_http_async, used on that
  // loop's thread only. Its owner destroys it before the loop.
  class RelayPool {
   public:
    explicit RelayPool(boost::asio::io_context& io);
    ~RelayPool();
    RelayPool(const RelayPool&) = delete;
    RelayPool& operator=(const RelayPool&) = delete;

   private:
    friend class ShardPeers;
    struct Connection;
    boost::asio::io_context& io_;
    std::map<std::pair<std::uint32_t, std::string>, std::vector<std::unique_ptr<Connection>>> idle_;
  };

  // The channel to `shard`'s replicas (created on first use).
  std::shared_ptr<grpc::Channel> grpc_channel(std::uint32_t shard);
  // UNAVAILABLE naming the shard and its address.
  Status unavailable(std::uint32_t shard, const std::string& address, const std::string& why) const;

 private:
  struct Connection;
  class AddressOrder;
  class AsyncForward;
  // The request as every relay sends it (forwarded mark, host, keep-alive).
  void prepare(HttpRequest& request, const std::string& first_replica) const;
  // The shard's resolved addresses (resolving them if `may_resolve`), or empty with `why`.
  std::vector<boost::asio::ip::tcp::endpoint> addresses(std::uint32_t shard, bool may_resolve, std::string& why);
  std::size_t next_turn(std::size_t count);
  void forget_addresses(std::uint32_t shard);
  std::unique_ptr<Connection> take_idle(std::uint32_t shard, const std::string& endpoint);
  void give_back(std::uint32_t shard, std::unique_ptr<Connection> c);
  bool recently_refused(const std::string& endpoint);
  void note_refused(const std::string& endpoint);

  ShardSettings shards_;
  std::string http_template_, grpc_template_;
  std::mutex mutex_;
  std::map<std::pair<std::uint32_t, std::string>, std::vector<std::unique_ptr<Connection>>> idle_;
  std::map<std::string, std::chrono::steady_clock::time_point> refused_until_;
  // Each shard's addresses, as last resolved, and until when they are used.
  std::map<std::uint32_t, std::pair<std::vector<boost::asio::ip::tcp::endpoint>, std::chrono::steady_clock::time_point>>
      resolved_;
  std::map<std::uint32_t, std::shared_ptr<grpc::Channel>> channels_;
  std::uint64_t turn_ = 0;
};

}  // namespace spokemesh::service
