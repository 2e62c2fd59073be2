// Every limit and default of spokemesh-server, defined once.
//
// The flags (main.cpp) take their defaults from here, and so do the option structs
// (Limits, HttpServerOptions) and the request checks (page and batch sizes).
// docs/service.md's flag table is checked against `spokemesh-server --help`, which
// prints these values (tests/python/test_hardening.py), so the documentation cannot
// drift from the code.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <string>

namespace spokemesh::service::defaults {

using std::chrono::milliseconds;

// Point sets and requests.
inline constexpr std::uint64_t kMaxPoints = 10'000'000;
// The largest dimension uploads accept by default (--max-dimension raises it up to
// core's kMaxApproxDimension, 1024); exact answers need d <= core's kMaxDimension, 8.
inline constexpr int kMaxUploadDimension = 128;
inline constexpr std::size_t kMaxDisplayName = 256;
inline constexpr std::uint32_t kPageSize = 100, kMaxPageSize = 1000;
// Simplices per message of the whole-mesh streams; cells per message of the cell stream.
inline constexpr std::uint32_t kBatchSize = 4096, kMaxBatchSize = 65536;
inline constexpr std::uint32_t kCellBatchSize = 256, kMaxCellBatchSize = 4096;
// Domains of any shape kept parsed between requests (Engine::shape_for).
inline constexpr std::size_t kKeptShapes = 4;
// Seeds in one batch call (BatchSeeds, REST .../stars:batch and friends).
inline constexpr std::size_t kMaxBatchSeeds = 100000;
// A batch of exact stars (and what comes from them) of a 2-d or 3-d set with at least
// this many seeds computes them together, by the whole mesh's local triangulations
// (smaller batches walk each star).
inline constexpr std::size_t kBatchTogetherAtLeast = 32;
// Payload per gRPC message: coordinate chunks of a download, and the size at which a
// batch of answers or a mesh batch is sent early (gRPC's default limit is 4 MiB).
inline constexpr std::size_t kDownloadChunkBytes = std::size_t{1} << 20;
inline constexpr std::size_t kMessagePayloadBytes = std::size_t{2} << 20;
inline constexpr milliseconds kDefaultDeadline{60'000};
inline constexpr int kMaxConcurrentRpcs = 64;

// Memory (the budget itself defaults to half the cgroup limit or RAM: main.cpp).
inline constexpr std::size_t kStreamCacheBytes = std::size_t{256} << 20;
// The smallest stream cache or front mail worth charging when the budget is short
// (halved down to this; below it, none: the same answers, only slower).
inline constexpr std::size_t kMinStreamCacheBytes = std::size_t{1} << 20;
// Charged per streamed shard for its output: the mesh's window of blocks in flight (a
// few MB: mesh.cpp) and one batch being assembled (at most 65,536 x 9 x 4 bytes).
inline constexpr std::uint64_t kStreamWindowBytes = std::uint64_t{16} << 20;
inline constexpr std::size_t kMaxBodyBytes = std::size_t{256} << 20;
inline constexpr milliseconds kUploadIdleTimeout{30'000};

// REST connections.
inline constexpr std::size_t kHttpMaxConnections = 10'000;
inline constexpr std::size_t kHttpMaxConnectionsPerAddress = 256;
inline constexpr std::size_t kHttpMaxInFlight = 256;
inline constexpr milliseconds kHttpHeaderTimeout{10'000};
inline constexpr milliseconds kHttpBodyTimeout{120'000};
inline constexpr milliseconds kHttpIdleTimeout{60'000};
inline constexpr milliseconds kHttpWriteTimeout{60'000};
inline constexpr milliseconds kTlsHandshakeTimeout{10'000};

// Shutdown.
inline constexpr milliseconds kDrainDelay{0};
inline constexpr milliseconds kGracePeriod{10'000};

// A duration as the flags write it: 30s or 500ms.
inline std::string duration_text(milliseconds d) {
  const auto ms = d.count();
  if (ms % 1000 == 0) return std::to_string(ms / 1000) + "s";
  return std::to_string(ms) + "ms";
}
// A size as the flags write it: 256M, 4K, 2G or bytes.
inline std::string bytes_text(std::uint64_t b) {
  if (b != 0 && b % (std::uint64_t{1} << 30) == 0) return std::to_string(b >> 30) + "G";
  if (b != 0 && b % (std::uint64_t{1} << 20) == 0) return std::to_string(b >> 20) + "M";
  if (b != 0 && b % (std::uint64_t{1} << 10) == 0) return std::to_string(b >> 10) + "K";
  return std::to_string(b);
}

}  // namespace spokemesh::service::defaults
