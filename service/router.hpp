// Router: the one request path's routing, for both transports (docs/service.md, "One
// request path"). Where a seed's request is answered, the relay-once rule, and the
// scatter-gather of a batch whose seeds lie in several shards' pieces live here; REST
// and gRPC keep only their codecs (how to ask another shard over their own wire, and
// how to write answers).
//
// The relay-once rule: a request that came from another shard's replica (REST header,
// gRPC metadata x-spokemesh-forwarded) is answered here, from the piece holding the
// seed, whatever shard owns it: a replica whose map has changed answers once rather
// than relaying in a loop.
//
// Thread safety: const after construction; every member function may be called
// concurrently.
#pragma once

#include <algorithm>
#include <cstdint>
#include <functional>
#include <future>
#include <map>
#include <string>
#include <vector>

#include "engine.hpp"

namespace spokemesh::service {

class ShardPeers;

class Router {
 public:
  // peers: the way to the other shards on a sharded replica; null otherwise (every
  // request is answered here).
  Router(Engine& engine, const ShardPeers* peers);

  bool sharded() const { return peers_ != nullptr; }
  // This replica's shard (0 when not sharded).
  std::uint32_t here() const;

  // Where a seed's request is answered: here when not sharded, when `forwarded`, for a
  // set held whole and for any error (which the local call names); else the shard
  // whose pieces hold the seed.
  SeedRoute route(const std::string& id, std::uint64_t seed, bool forwarded) const;

  // The shard of each of a batch's seeds, in the request's order; empty when the batch
  // is answered here whole (not sharded, forwarded, a set held whole, or every seed
  // this shard's). The batch's seed errors (none, too many, one out of range).
  Result<std::vector<std::uint32_t>> batch_routes(const std::string& id, const std::vector<std::uint64_t>& seeds,
                                                  bool forwarded) const;

  // The set's shard map and every shard's addresses (as --shard-http and --shard-grpc
  // name them), for clients that route themselves. Not sharded: map.sharded false.
  struct Map {
    ShardMap map;
    std::vector<std::string> grpc_addresses, http_addresses;
  };
  Result<Map> shard_map(const std::string& id) const;

  // Scatter-gather of a batch over shards, in bounded parts of kPart seeds: each part's
  // seeds of other shards asked of them concurrently (`ask`, on threads of their own),
  // this shard's answered here (`local`), and the part's answers handed to `emit` in
  // the request's order. A shard's UNAVAILABLE is asked again (at most kAttempts in
  // all) while the call's deadline allows. A failure ends the batch with the error one
  // replica holding the whole set gives: the first failing seed's in the request's
  // order (first_failure); a shard that answers another number of items than it was
  // asked is UNAVAILABLE naming it.
  static constexpr std::size_t kPart = 1024;
  static constexpr int kAttempts = 3;
  template <class Item>
  using Part = std::function<Result<std::vector<Item>>(const std::vector<std::uint64_t>& seeds)>;
  template <class Item>
  Status scatter_gather(
      const std::vector<std::uint64_t>& seeds, const std::vector<std::uint32_t>& routes, const CallControl& control,
      const std::function<Result<std::vector<Item>>(std::uint32_t shard, const std::vector<std::uint64_t>& seeds)>& ask,
      const Part<Item>& local, const std::function<Status(std::vector<Item>& answers, std::uint64_t done)>& emit) const;

 private:
  // The error a replica holding the whole set would give for a part some shards failed.
  template <class Item, class Ask, class Local>
  static Status first_failure(const std::map<std::uint32_t, Status>& failed,
                              const std::map<std::uint32_t, std::vector<std::size_t>>& by_shard,
                              const std::vector<std::uint64_t>& seeds, std::uint32_t mine, Ask& ask, Local& local);

  Engine& engine_;
  const ShardPeers* peers_;
};

template <class Item>
Status Router::scatter_gather(
    const std::vector<std::uint64_t>& seeds, const std::vector<std::uint32_t>& routes, const CallControl& control,
    const std::function<Result<std::vector<Item>>(std::uint32_t shard, const std::vector<std::uint64_t>& seeds)>& ask,
    const Part<Item>& local, const std::function<Status(std::vector<Item>& answers, std::uint64_t done)>& emit) const {
  const std::uint32_t mine = here();
  auto ask_again = [&](std::uint32_t shard, const std::vector<std::uint64_t>& part) {
    Result<std::vector<Item>> answer = ask(shard, part);
    for (int attempt = 1;
         attempt < kAttempts && !answer.is_ok() && answer.status().code() == Code::kUnavailable && !control.stopped();
         ++attempt) {
      answer = ask(shard, part);
    }
    return answer;
  };
  for (std::size_t at = 0; at < seeds.size(); at += kPart) {
    const std::size_t end = std::min(seeds.size(), at + kPart);
    std::map<std::uint32_t, std::vector<std::size_t>> by_shard;
    for (std::size_t i = at; i < end; ++i) by_shard[routes[i]].push_back(i);
    auto part_of = [&](const std::vector<std::size_t>& positions) {
      std::vector<std::uint64_t> part;
      part.reserve(positions.size());
      for (const std::size_t i : positions) part.push_back(seeds[i]);
      return part;
    };
    std::vector<std::pair<std::uint32_t, std::future<Result<std::vector<Item>>>>> asked;
    for (const auto& [shard, positions] : by_shard) {
      if (shard == mine) continue;
      asked.emplace_back(shard, std::async(std::launch::async, ask_again, shard, part_of(positions)));
    }
    std::vector<Item> answers(end - at);
    std::map<std::uint32_t, Status> failed;  // by shard
    auto place = [&](std::uint32_t shard, Result<std::vector<Item>> got) {
      if (!got.is_ok()) {
        failed.emplace(shard, got.status());
        return;
      }
      const std::vector<std::size_t>& positions = by_shard[shard];
      if (got->size() != positions.size()) {
        failed.emplace(shard, Status{Code::kUnavailable, "shard " + std::to_string(shard) + " answered " +
                                                             std::to_string(got->size()) + " of " +
                                                             std::to_string(positions.size()) + " seeds"});
        return;
      }
      for (std::size_t k = 0; k < positions.size(); ++k) answers[positions[k] - at] = std::move(got.value()[k]);
    };
    if (const auto here_part = by_shard.find(mine); here_part != by_shard.end()) {
      place(mine, local(part_of(here_part->second)));
    }
    for (auto& [shard, future] : asked) place(shard, future.get());  // every thread joined
    if (!failed.empty()) return first_failure<Item>(failed, by_shard, seeds, mine, ask_again, local);
    if (Status s = emit(answers, end); !s.is_ok()) return s;
  }
  return Status::ok();
}

template <class Item, class Ask, class Local>
Status Router::first_failure(const std::map<std::uint32_t, Status>& failed,
                             const std::map<std::uint32_t, std::vector<std::size_t>>& by_shard,
                             const std::vector<std::uint64_t>& seeds, std::uint32_t mine, Ask& ask, Local& local) {
  // A failure that is not a seed's (a shard out of reach, the deadline, the budget)
  // is the batch's.
  for (const auto& [shard, status] : failed) {
    const Code c = status.code();
    if (c != Code::kInvalidArgument && c != Code::kOutOfRange && c != Code::kFailedPrecondition) return status;
  }
  // Seeds' errors: the first failing seed in the request's order is the batch's error,
  // as one replica holding the whole set says (each shard said its own first). Only
  // the failed shards' seeds can fail (answers are functions of the seed): they are
  // asked one at a time, in order, until one fails.
  std::vector<std::pair<std::size_t, std::uint32_t>> suspects;  // (position, shard)
  for (const auto& [shard, status] : failed) {
    for (const std::size_t i : by_shard.at(shard)) suspects.emplace_back(i, shard);
  }
  std::sort(suspects.begin(), suspects.end());
  for (const auto& [i, shard] : suspects) {
    const std::vector<std::uint64_t> one{seeds[i]};
    Result<std::vector<Item>> got = shard == mine ? local(one) : ask(shard, one);
    if (!got.is_ok()) return got.status();
  }
  return failed.begin()->second;
}

}  // namespace spokemesh::service
