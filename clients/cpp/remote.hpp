// Remote mode of the spokemesh CLI: the same commands against a spokemesh-server.
//
// Every call carries a deadline (--deadline). Exit codes as for local mode: 0 ok,
// 2 bad input (INVALID_ARGUMENT, OUT_OF_RANGE, NOT_FOUND), 1 any other failure.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

namespace spokemesh::remote {

struct RemoteOptions {
  std::string server;  // HOST:PORT
  std::chrono::milliseconds deadline{60'000};
  std::string token;              // bearer token ("" = none)
  std::string tls_ca;             // PEM file: use TLS, trusting this CA
  std::string tls_cert, tls_key;  // PEM files: client certificate (mTLS)
  bool quiet = false;
};

// What an upload carries besides its coordinates, both optional: a file of
// power weights, one per point (one a line, or .npy; with radii, Voro++'s radii,
// squared into weights), and a periodic box "LO1,...,LOd,HI1,...,HId". The server keeps
// them with the set (its id hashes them) and answers with power cells and offsets.
struct UploadExtras {
  std::string weights;
  bool radii = false;
  std::string periodic;
};

int upload(const RemoteOptions& o, const std::string& input, const std::string& name, const UploadExtras& extras = {});
// A new stored set: set `id`'s points, then the points of INPUT (AppendPoints); prints its id.
int append(const RemoteOptions& o, const std::string& id, const std::string& input, const std::string& name);
int star(const RemoteOptions& o, const std::string& id, std::uint64_t seed);
// mode: "exact", "approximate" or "spokes"; misses / max_vertices: 0 = server default.
int neighbors(const RemoteOptions& o, const std::string& id, std::uint64_t seed, const std::string& mode = "exact",
              std::uint32_t misses = 0, std::uint32_t max_vertices = 0);
// box: "LO1,...,HId" or ""; halfspaces: a local file of walls or "" (neither: unclipped).
// shape: a local domain file of any shape (--domain) or "", checked here, then sent.
int cell(const RemoteOptions& o, const std::string& id, std::uint64_t seed, bool json, const std::string& box,
         const std::string& halfspaces, const std::string& shape = "");
// All cells (StreamCells; default domain: the set's bounding box) into .npz or .vtu.
int cells(const RemoteOptions& o, const std::string& id, const std::string& output, const std::string& box,
          const std::string& halfspaces, const std::string& shape = "");
// Fetches all shards in parallel (one stream each) and writes OUTPUT in any format
// of the local `mesh` command.
int mesh(const RemoteOptions& o, const std::string& id, const std::string& output, unsigned shards);
// Many seeds in one BatchSeeds call; prints one JSON object per seed (NDJSON), as the
// REST .../{stars,neighbors,cells}:batch routes answer. kind: stars, neighbors, cells.
// With `route`, on a sharded deployment whose shard map weighs no more than the answers
// (2 bytes a point of the set against about 1 KB an answer), each shard's seeds go
// straight to its replicas; on any failure there, the whole batch is asked of o.server.
int batch(const RemoteOptions& o, const std::string& id, const std::string& kind,
          const std::vector<std::uint64_t>& seeds, const std::string& mode, std::uint32_t misses,
          std::uint32_t max_vertices, const std::string& box, const std::string& halfspaces,
          const std::string& shape = "", bool route = true);
int health(const RemoteOptions& o);
int list(const RemoteOptions& o);
int remove(const RemoteOptions& o, const std::string& id);

}  // namespace spokemesh::remote
