#include "router.hpp"

#include "shard_peers.hpp"

namespace spokemesh::service {

Router::Router(Engine& engine, const ShardPeers* peers) : engine_(engine), peers_(peers) {}

std::uint32_t Router::here() const { return peers_ == nullptr ? 0 : peers_->shards().index; }

SeedRoute Router::route(const std::string& id, std::uint64_t seed, bool forwarded) const {
  if (peers_ == nullptr || forwarded) return SeedRoute{};
  return engine_.route_seed(id, seed);
}

Result<std::vector<std::uint32_t>> Router::batch_routes(const std::string& id, const std::vector<std::uint64_t>& seeds,
                                                        bool forwarded) const {
  if (peers_ == nullptr || forwarded) return std::vector<std::uint32_t>{};
  auto routes = engine_.batch_routes(id, seeds);
  if (!routes.is_ok()) return routes.status();
  const std::uint32_t mine = here();
  if (std::all_of(routes->begin(), routes->end(), [&](std::uint32_t s) { return s == mine; })) {
    return std::vector<std::uint32_t>{};
  }
  return routes;
}

Result<Router::Map> Router::shard_map(const std::string& id) const {
  auto map = engine_.shard_map(id);
  if (!map.is_ok()) return map.status();
  Map out;
  out.map = std::move(map).value();
  if (out.map.sharded && peers_ != nullptr) {
    for (std::uint32_t k = 0; k < out.map.shard_count; ++k) {
      out.grpc_addresses.push_back(peers_->grpc_address(k));
      out.http_addresses.push_back(peers_->http_address(k));
    }
  }
  return out;
}

}  // namespace spokemesh::service
