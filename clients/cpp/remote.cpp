#include "remote.hpp"

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <thread>
#include <vector>

#include "cell_print.hpp"
#include "commands.hpp"
#include "grpc/health/v1/health.grpc.pb.h"
#include "spokemesh/cell_io.hpp"
#include "spokemesh/domain.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/periodic_box.hpp"
#include "spokemesh/shape_io.hpp"
#include "spokemesh/v1/mesher.grpc.pb.h"

namespace spokemesh::remote {
namespace {

namespace pb = ::spokemesh::v1;
constexpr int kExitOk = 0, kExitFailure = 1, kExitUsage = 2;

int report(const RemoteOptions& o, const grpc::Status& s) {
  static const char* names[] = {
      "OK",        "CANCELLED",      "UNKNOWN",           "INVALID_ARGUMENT",   "DEADLINE_EXCEEDED",
      "NOT_FOUND", "ALREADY_EXISTS", "PERMISSION_DENIED", "RESOURCE_EXHAUSTED", "FAILED_PRECONDITION",
      "ABORTED",   "OUT_OF_RANGE",   "UNIMPLEMENTED",     "INTERNAL",           "UNAVAILABLE",
      "DATA_LOSS", "UNAUTHENTICATED"};
  const int code = static_cast<int>(s.error_code());
  std::cerr << "spokemesh: " << o.server << ": " << (code >= 0 && code <= 16 ? names[code] : "UNKNOWN") << ": "
            << s.error_message() << "\n";
  switch (s.error_code()) {
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::OUT_OF_RANGE:
    case grpc::StatusCode::NOT_FOUND:
      return kExitUsage;
    default:
      return kExitFailure;
  }
}

int report(const Status& s) {
  std::cerr << "spokemesh: " << s.message() << "\n";
  return s.code() == Code::kInvalidArgument || s.code() == Code::kOutOfRange ? kExitUsage : kExitFailure;
}

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// A channel to `o.server`, or to `address` (one shard's replicas: HOST:PORT, or several
// comma-separated IPv4 ones, spread over with round_robin as the server's relay does).
std::shared_ptr<grpc::Channel> channel(const RemoteOptions& o, const std::string& address = "") {
  std::shared_ptr<grpc::ChannelCredentials> creds = grpc::InsecureChannelCredentials();
  if (!o.tls_ca.empty()) {
    grpc::SslCredentialsOptions ssl;
    ssl.pem_root_certs = slurp(o.tls_ca);
    if (!o.tls_cert.empty()) {
      ssl.pem_cert_chain = slurp(o.tls_cert);
      ssl.pem_private_key = slurp(o.tls_key);
    }
    creds = grpc::SslCredentials(ssl);
  }
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  // Every RPC is idempotent (reads are pure, uploads content-addressed), so a call that
  // fails with UNAVAILABLE before any answer (a replica stopping, a proxy's 502) is
  // retried by gRPC: up to 3 more attempts, 0.1 s to 1 s apart, within the deadline.
  args.SetInt(GRPC_ARG_ENABLE_RETRIES, 1);
  args.SetServiceConfigJSON(R"({"methodConfig": [{"name": [{"service": "spokemesh.v1.Mesher"}],
      "retryPolicy": {"maxAttempts": 4, "initialBackoff": "0.1s", "maxBackoff": "1s", "backoffMultiplier": 2,
                      "retryableStatusCodes": ["UNAVAILABLE"]}}]})");
  if (address.find(',') != std::string::npos) {
    args.SetLoadBalancingPolicyName("round_robin");
    return grpc::CreateCustomChannel("ipv4:" + address, creds, args);
  }
  return grpc::CreateCustomChannel(address.empty() ? o.server : address, creds, args);
}

void prepare(const RemoteOptions& o, grpc::ClientContext& ctx) {
  ctx.set_deadline(std::chrono::system_clock::now() + o.deadline);
  if (!o.token.empty()) ctx.AddMetadata("authorization", "Bearer " + o.token);
}

}  // namespace

namespace {

// Sends a header message and then the coordinates (then an upload's weights) in 1 MiB
// chunks on an upload's or an append's stream; prints the new id (and, unless quiet,
// what was stored).
template <class Request>
int send_points(const RemoteOptions& o, grpc::ClientContext& ctx, std::unique_ptr<grpc::ClientWriter<Request>> writer,
                Request message, const PointSet& points, const pb::PointSet& response,
                std::span<const double> weights = {}) {
  bool ok = writer->Write(message);
  const auto coords = points.coordinates();
  const char* bytes = reinterpret_cast<const char*>(coords.data());
  constexpr std::size_t kChunk = 1 << 20;
  for (std::size_t at = 0; ok && at < coords.size_bytes(); at += kChunk) {
    message.set_coordinates(bytes + at, std::min(kChunk, coords.size_bytes() - at));
    ok = writer->Write(message);
  }
  if constexpr (std::is_same_v<Request, pb::UploadPointSetRequest>) {
    const char* w = reinterpret_cast<const char*>(weights.data());
    for (std::size_t at = 0; ok && at < weights.size_bytes(); at += kChunk) {
      message.set_weights(w + at, std::min(kChunk, weights.size_bytes() - at));
      ok = writer->Write(message);
    }
  }
  writer->WritesDone();
  const grpc::Status s = writer->Finish();
  (void)ctx;
  if (!s.ok()) return report(o, s);
  std::cout << response.id() << "\n";
  if (!o.quiet) {
    std::cerr << "spokemesh: " << (response.already_existed() ? "already stored: " : "stored: ") << response.count()
              << (response.weighted() ? " weighted" : "") << " points in " << response.dimension() << "-d"
              << (response.periodic_box_size() > 0 ? " on a periodic box" : "");
    if (!response.parent_id().empty())
      std::cerr << " (the points of " << response.parent_id() << ", then the new ones)";
    std::cerr << "\n";
  }
  return kExitOk;
}

}  // namespace

int upload(const RemoteOptions& o, const std::string& input, const std::string& name, const UploadExtras& extras) {
  auto points = read_points(input);  // file:line errors for malformed files, before any network
  if (!points.is_ok()) return report(points.status());
  std::vector<double> weights, box;
  if (!extras.weights.empty()) {
    auto w =
        read_weights(extras.weights, points->size(), extras.radii ? WeightKind::kRadius : WeightKind::kPowerWeight);
    if (!w.is_ok()) return report(w.status());
    weights = std::move(w).value();
  }
  if (!extras.periodic.empty()) {
    // Checked here too, so that a point outside is named with the file's name.
    auto b = PeriodicBox::parse(extras.periodic, "--periodic");
    if (!b.is_ok()) return report(b.status());
    if (Status s = b->check_contains(points.value(), input); !s.is_ok()) return report(s);
    box = b->lo();
    box.insert(box.end(), b->hi().begin(), b->hi().end());
  }
  auto stub = pb::Mesher::NewStub(channel(o));
  grpc::ClientContext ctx;
  prepare(o, ctx);
  pb::PointSet response;
  pb::UploadPointSetRequest message;
  message.mutable_header()->set_dimension(static_cast<std::uint32_t>(points->dimension()));
  message.mutable_header()->set_count(points->size());
  message.mutable_header()->set_display_name(name);
  message.mutable_header()->set_weighted(!weights.empty());
  message.mutable_header()->mutable_periodic_box()->Add(box.begin(), box.end());
  return send_points(o, ctx, stub->UploadPointSet(&ctx, &response), std::move(message), points.value(), response,
                     weights);
}

int append(const RemoteOptions& o, const std::string& id, const std::string& input, const std::string& name) {
  auto points = read_points(input);  // file:line errors first; the server validates the whole set
  if (!points.is_ok()) return report(points.status());
  auto stub = pb::Mesher::NewStub(channel(o));
  grpc::ClientContext ctx;
  prepare(o, ctx);
  pb::PointSet response;
  pb::AppendPointsRequest message;
  message.mutable_header()->set_point_set_id(id);
  message.mutable_header()->set_count(points->size());
  message.mutable_header()->set_display_name(name);
  return send_points(o, ctx, stub->AppendPoints(&ctx, &response), std::move(message), points.value(), response);
}

namespace {

// gRPC's own retries stop once an answer has begun. A unary call that this client
// never cancels yet ends CANCELLED (or UNAVAILABLE) was cut off in transit: a replica
// died mid-answer and a proxy reset the stream. Every RPC is idempotent, so it is sent
// again, twice at most, within the same deadline.
template <class Response, class Call>
int unary(const RemoteOptions& o, Call&& call, Response& response) {
  auto stub = pb::Mesher::NewStub(channel(o));
  const auto deadline = std::chrono::system_clock::now() + o.deadline;
  for (int attempt = 0;; ++attempt) {
    grpc::ClientContext ctx;
    prepare(o, ctx);
    ctx.set_deadline(deadline);
    response.Clear();
    const grpc::Status s = call(*stub, ctx, response);
    if (s.ok()) return kExitOk;
    const auto backoff = std::chrono::milliseconds(100 * (attempt + 1));
    const bool cut_off =
        s.error_code() == grpc::StatusCode::CANCELLED || s.error_code() == grpc::StatusCode::UNAVAILABLE;
    if (!cut_off || attempt == 2 || std::chrono::system_clock::now() + backoff >= deadline) return report(o, s);
    std::this_thread::sleep_for(backoff);
  }
}

pb::SeedRequest seed_request(const std::string& id, std::uint64_t seed) {
  pb::SeedRequest r;
  r.set_point_set_id(id);
  r.set_seed(seed);
  return r;
}

}  // namespace

int star(const RemoteOptions& o, const std::string& id, std::uint64_t seed) {
  pb::Star response;
  const int rc = unary(
      o, [&](auto& stub, auto& ctx, auto& r) { return stub.GetStar(&ctx, seed_request(id, seed), &r); }, response);
  if (rc != kExitOk) return rc;
  std::string out;
  const auto w = static_cast<std::size_t>(response.dimension()) + 1;
  if (response.offsets_size() > 0) {
    // A periodic set's star as the local `star --periodic` prints it: indices, then offsets.
    const std::size_t d = w - 1;
    for (std::size_t r = 0; r < static_cast<std::size_t>(response.simplices_size()) / w; ++r) {
      for (std::size_t v = 0; v < w; ++v)
        out.append(v ? " " : "").append(std::to_string(response.simplices(static_cast<int>(r * w + v))));
      for (std::size_t k = 0; k < w * d; ++k)
        out.append(" ").append(std::to_string(response.offsets(static_cast<int>(r * w * d + k))));
      out += "\n";
    }
  } else {
    append_index_lines(out, {response.simplices().data(), static_cast<std::size_t>(response.simplices().size())},
                       static_cast<int>(w));
  }
  std::fwrite(out.data(), 1, out.size(), stdout);
  return kExitOk;
}

int neighbors(const RemoteOptions& o, const std::string& id, std::uint64_t seed, const std::string& mode,
              std::uint32_t misses, std::uint32_t max_vertices) {
  pb::GetNeighborsRequest request;
  request.set_point_set_id(id);
  request.set_seed(seed);
  request.set_mode(mode == "approximate" ? pb::NEIGHBOR_MODE_APPROXIMATE
                   : mode == "spokes"    ? pb::NEIGHBOR_MODE_SPOKES
                                         : pb::NEIGHBOR_MODE_EXACT);
  request.set_max_consecutive_misses(misses);
  request.set_max_vertices(max_vertices);
  pb::Neighbors response;
  const int rc = unary(
      o, [&](auto& stub, auto& ctx, auto& r) { return stub.GetNeighbors(&ctx, request, &r); }, response);
  if (rc != kExitOk) return rc;
  const int k = response.neighbors_size();
  const int d = k == 0 ? 0 : response.offsets_size() / k;
  for (int i = 0; i < k; ++i) {
    std::printf("%u", response.neighbors(i));
    for (int c = 0; c < d; ++c) std::printf(" %d", response.offsets(i * d + c));  // periodic sets: the image
    std::printf("\n");
  }
  if (!response.exact() && !o.quiet) {
    std::fprintf(stderr,
                 "spokemesh: %d certified neighbours (approximate): %llu vertices visited, %llu consecutive misses\n",
                 response.neighbors_size(), static_cast<unsigned long long>(response.vertices_visited()),
                 static_cast<unsigned long long>(response.consecutive_misses()));
  }
  return kExitOk;
}

namespace {

VoronoiCell from_proto(const pb::VoronoiCell& c) {
  VoronoiCell cell;
  cell.seed = static_cast<std::uint32_t>(c.seed());
  cell.dimension = static_cast<int>(c.dimension());
  cell.vertices.assign(c.vertices().begin(), c.vertices().end());
  cell.vertex_simplices.assign(c.vertex_simplices().begin(), c.vertex_simplices().end());
  for (const pb::VoronoiFacet& f : c.facets()) {
    VoronoiFacet facet;
    facet.neighbor = f.has_wall() ? -1 - static_cast<std::int64_t>(f.wall()) : static_cast<std::int64_t>(f.neighbor());
    facet.vertices.assign(f.vertices().begin(), f.vertices().end());
    facet.area = f.area();
    facet.normal.assign(f.normal().begin(), f.normal().end());
    cell.facets.push_back(std::move(facet));
  }
  cell.bounded = c.bounded();
  cell.clipped = c.clipped();
  cell.volume = c.volume();
  cell.centroid.assign(c.centroid().begin(), c.centroid().end());
  cell.facet_offsets.assign(c.facet_offsets().begin(), c.facet_offsets().end());
  cell.hidden = c.hidden();
  return cell;
}

// The proto Domain for --box / --halfspaces (the file is read here, checked against d).
Result<pb::Domain> domain_proto(const std::string& box, const std::string& halfspaces, int d,
                                const std::string& shape) {
  pb::Domain domain;
  if (!box.empty() + !halfspaces.empty() + !shape.empty() > 1) {
    return invalid_argument("--box, --halfspaces and --domain exclude each other");
  }
  if (!shape.empty()) {
    // Checked here first, so that a fault names the user's file; then sent as bytes.
    auto checked = cli::read_domain(shape);
    if (!checked.is_ok()) return checked.status();
    if (checked->dimension() != d) {
      return invalid_argument("--domain " + shape + " is " + std::to_string(checked->dimension()) +
                              "-d; the point set is " + std::to_string(d) + "-d");
    }
    std::ifstream in(shape, std::ios::binary);
    std::ostringstream bytes;
    bytes << in.rdbuf();
    domain.mutable_shape()->set_format(shape_domain_format(shape));
    domain.mutable_shape()->set_data(bytes.str());
  }
  if (!box.empty()) {
    auto b = Domain::parse_box(box);
    if (!b.is_ok()) return b.status();
    const std::vector<double> lo = b->lower(), hi = b->upper();
    domain.mutable_box()->Add(lo.begin(), lo.end());
    domain.mutable_box()->Add(hi.begin(), hi.end());
  }
  if (!halfspaces.empty()) {
    auto h = read_halfspaces(halfspaces, d);
    if (!h.is_ok()) return h.status();
    for (std::size_t k = 0; k < h->wall_count(); ++k) {
      domain.mutable_halfspaces()->Add(h->normal(k), h->normal(k) + d);
      domain.add_halfspaces(h->offset(k));
    }
  }
  return domain;
}

Result<pb::PointSet> info_of(const RemoteOptions& o, pb::Mesher::Stub& stub, const std::string& id,
                             grpc::Status& status) {
  grpc::ClientContext ctx;
  prepare(o, ctx);
  pb::GetPointSetRequest r;
  r.set_point_set_id(id);
  pb::PointSet info;
  status = stub.GetPointSet(&ctx, r, &info);
  if (!status.ok()) return internal_error("GetPointSet");
  return info;
}

// Fills `out` from --box / --halfspaces for the set's dimension; an exit code.
int set_domain(const RemoteOptions& o, pb::Mesher::Stub& stub, const std::string& id, const std::string& box,
               const std::string& halfspaces, pb::Domain& out, const std::string& shape = "") {
  grpc::Status status;
  auto info = info_of(o, stub, id, status);
  if (!info.is_ok()) return report(o, status);
  auto domain = domain_proto(box, halfspaces, static_cast<int>(info->dimension()), shape);
  if (!domain.is_ok()) return report(domain.status());
  out = domain.value();
  return kExitOk;
}

}  // namespace

int cell(const RemoteOptions& o, const std::string& id, std::uint64_t seed, bool json, const std::string& box,
         const std::string& halfspaces, const std::string& shape) {
  pb::GetVoronoiCellRequest request;
  request.set_point_set_id(id);
  request.set_seed(seed);
  if (!box.empty() || !halfspaces.empty() || !shape.empty()) {
    auto stub = pb::Mesher::NewStub(channel(o));
    if (const int rc = set_domain(o, *stub, id, box, halfspaces, *request.mutable_domain(), shape); rc != kExitOk)
      return rc;
  }
  pb::VoronoiCell c;
  const int rc = unary(
      o, [&](auto& stub, auto& ctx, auto& r) { return stub.GetVoronoiCell(&ctx, request, &r); }, c);
  if (rc != kExitOk) return rc;
  c.set_seed(seed);
  // The same layout as the local `cell` command.
  cli::print_cell(from_proto(c), seed, json, [](std::uint32_t i) { return i; });
  return kExitOk;
}

int cells(const RemoteOptions& o, const std::string& id, const std::string& output, const std::string& box,
          const std::string& halfspaces, const std::string& shape) {
  auto stub = pb::Mesher::NewStub(channel(o));
  grpc::Status status;
  auto info = info_of(o, *stub, id, status);
  if (!info.is_ok()) return report(o, status);
  const int d = static_cast<int>(info->dimension());
  auto domain = domain_proto(box, halfspaces, d, shape);
  if (!domain.is_ok()) return report(domain.status());
  auto writer = CellWriter::open(output, d, info->periodic_box_size() > 0);
  if (!writer.is_ok()) return report(writer.status());
  if (!shape.empty() && writer.value()->needs_vertices()) {
    return report(
        invalid_argument("-o " + output + ": cells in a domain of any shape are written as measures: use .npz"));
  }
  grpc::ClientContext ctx;
  prepare(o, ctx);
  pb::StreamCellsRequest r;
  r.set_point_set_id(id);
  *r.mutable_domain() = domain.value();
  r.set_measures_only(!writer.value()->needs_vertices());
  auto reader = stub->StreamCells(&ctx, r);
  pb::CellBatch batch;
  std::vector<VoronoiCell> cells;
  std::uint64_t total = 0;
  const auto start = std::chrono::steady_clock::now();
  while (reader->Read(&batch)) {
    cells.clear();
    for (const pb::VoronoiCell& c : batch.cells()) cells.push_back(from_proto(c));
    if (Status s = writer.value()->write(cells); !s.is_ok()) {
      ctx.TryCancel();
      reader->Finish();
      return report(s);
    }
    total += cells.size();
  }
  if (grpc::Status s = reader->Finish(); !s.ok()) return report(o, s);
  if (Status s = writer.value()->commit(); !s.is_ok()) return report(s);
  if (!o.quiet) {
    std::fprintf(stderr, "spokemesh: %llu cells from %s, %.2f s -> %s\n", static_cast<unsigned long long>(total),
                 o.server.c_str(), std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(),
                 output.c_str());
  }
  return kExitOk;
}

// The answers of a BatchSeeds call, all its messages merged (repeated fields append).
Result<pb::BatchSeedsResponse> batch_answers(const RemoteOptions& o, pb::Mesher::Stub& stub,
                                             const pb::BatchSeedsRequest& r) {
  grpc::ClientContext ctx;
  prepare(o, ctx);
  auto reader = stub.BatchSeeds(&ctx, r);
  pb::BatchSeedsResponse all, part;
  while (reader->Read(&part)) all.MergeFrom(part);
  if (const grpc::Status s = reader->Finish(); !s.ok()) return Status{Code::kUnavailable, s.error_message()};
  return all;
}

// About what one answer of a batch weighs (a 3-d star is ~1 KB): the shard map (2 bytes
// a seed of the set) is fetched only when it weighs no more than the batch's answers.
constexpr std::uint64_t kAnswerBytes = 1000;

// A batch sent by shard (docs/service.md, "Clients that route themselves"): the set's
// shard map, then each shard's seeds asked of its replicas at once, the answers put
// back in request order. nullopt: not routed - the set is not sharded, the map would
// weigh more than the answers, a seed lies beyond the set, or a shard's call failed -
// and the caller asks `o.server`, whose answer (errors included) is one replica's.
std::optional<pb::BatchSeedsResponse> routed_batch(const RemoteOptions& o, pb::Mesher::Stub& stub,
                                                   const pb::BatchSeedsRequest& r) {
  grpc::ClientContext ctx;
  prepare(o, ctx);
  pb::GetPointSetRequest q;
  q.set_point_set_id(r.point_set_id());
  auto reader = stub.GetShardMap(&ctx, q);
  pb::ShardMapChunk head;
  const auto give_up = [&] {
    ctx.TryCancel();
    reader->Finish();
    return std::nullopt;
  };
  if (!reader->Read(&head) || !head.sharded() || head.shard_count() == 0 ||
      head.grpc_addresses_size() != static_cast<int>(head.shard_count()) ||
      2 * head.count() > kAnswerBytes * static_cast<std::uint64_t>(r.seeds_size())) {
    return give_up();
  }
  for (const std::uint64_t seed : r.seeds()) {
    if (seed >= head.count()) return give_up();  // its error is the deployment's
  }
  std::string seed_shards = head.seed_shards();
  for (pb::ShardMapChunk chunk; reader->Read(&chunk);) seed_shards += chunk.seed_shards();
  if (!reader->Finish().ok() || seed_shards.size() != 2 * head.count()) return std::nullopt;
  const auto shard_of = [&](std::uint64_t seed) {
    return static_cast<std::uint32_t>(static_cast<unsigned char>(seed_shards[2 * seed])) |
           static_cast<std::uint32_t>(static_cast<unsigned char>(seed_shards[2 * seed + 1])) << 8;
  };
  pb::BatchSeedsRequest seedless = r;  // each part: the request with its shard's seeds
  seedless.clear_seeds();
  std::vector<pb::BatchSeedsRequest> parts(head.shard_count(), seedless);
  for (const std::uint64_t seed : r.seeds()) {
    const std::uint32_t shard = shard_of(seed);
    if (shard >= head.shard_count()) return std::nullopt;
    parts[shard].add_seeds(seed);
  }
  // Each shard's part at once, on a thread each.
  std::vector<std::optional<Result<pb::BatchSeedsResponse>>> answers(parts.size());
  std::vector<std::thread> calls;
  for (std::size_t k = 0; k < parts.size(); ++k) {
    if (parts[k].seeds_size() == 0) continue;
    calls.emplace_back([&, k] {
      auto shard_stub = pb::Mesher::NewStub(channel(o, head.grpc_addresses(static_cast<int>(k))));
      answers[k] = batch_answers(o, *shard_stub, parts[k]);
    });
  }
  for (std::thread& t : calls) t.join();
  for (std::size_t k = 0; k < parts.size(); ++k) {
    if (parts[k].seeds_size() == 0) continue;
    const auto& got = *answers[k];
    if (!got.is_ok() || got->stars_size() + got->neighbors_size() + got->cells_size() != parts[k].seeds_size()) {
      return std::nullopt;
    }
  }
  // Back in request order: each shard's answers are in its part's order.
  pb::BatchSeedsResponse merged;
  std::vector<int> next(parts.size(), 0);
  for (const std::uint64_t seed : r.seeds()) {
    const std::uint32_t k = shard_of(seed);
    const pb::BatchSeedsResponse& got = answers[k]->value();
    const int at = next[k]++;
    if (got.stars_size() > 0) *merged.add_stars() = got.stars(at);
    if (got.neighbors_size() > 0) *merged.add_neighbors() = got.neighbors(at);
    if (got.cells_size() > 0) *merged.add_cells() = got.cells(at);
  }
  return merged;
}

int batch(const RemoteOptions& o, const std::string& id, const std::string& kind,
          const std::vector<std::uint64_t>& seeds, const std::string& mode, std::uint32_t misses,
          std::uint32_t max_vertices, const std::string& box, const std::string& halfspaces, const std::string& shape,
          bool route) {
  auto stub = pb::Mesher::NewStub(channel(o));
  pb::BatchSeedsRequest r;
  r.set_point_set_id(id);
  r.mutable_seeds()->Add(seeds.begin(), seeds.end());
  r.set_kind(kind == "stars"       ? pb::BATCH_KIND_STARS
             : kind == "neighbors" ? pb::BATCH_KIND_NEIGHBORS
                                   : pb::BATCH_KIND_CELLS);
  r.set_mode(mode == "approximate" ? pb::NEIGHBOR_MODE_APPROXIMATE
             : mode == "spokes"    ? pb::NEIGHBOR_MODE_SPOKES
                                   : pb::NEIGHBOR_MODE_EXACT);
  r.set_max_consecutive_misses(misses);
  r.set_max_vertices(max_vertices);
  if (!box.empty() || !halfspaces.empty() || !shape.empty()) {
    if (const int rc = set_domain(o, *stub, id, box, halfspaces, *r.mutable_domain(), shape); rc != kExitOk) return rc;
  }
  const auto print = [&](const pb::BatchSeedsResponse& response) {
    for (const pb::Star& s : response.stars()) {
      const int d = static_cast<int>(s.dimension());
      nlohmann::json j = {{"seed", s.seed()}, {"dimension", d}, {"hull_facets", s.hull_facets()}};
      j["simplices"] = nlohmann::json::array();
      for (int i = 0; i + d < s.simplices_size(); i += d + 1) {
        j["simplices"].push_back(
            std::vector<std::uint32_t>(s.simplices().begin() + i, s.simplices().begin() + i + d + 1));
      }
      j["circumcenters"] = nlohmann::json::array();
      for (int i = 0; i + d <= s.circumcenters_size(); i += d) {
        j["circumcenters"].push_back(
            std::vector<double>(s.circumcenters().begin() + i, s.circumcenters().begin() + i + d));
      }
      std::cout << j.dump() << "\n";
    }
    for (const pb::Neighbors& n : response.neighbors()) {
      nlohmann::json j = {{"seed", n.seed()},
                          {"neighbors", std::vector<std::uint32_t>(n.neighbors().begin(), n.neighbors().end())},
                          {"exact", n.exact()},
                          {"mode", mode}};
      if (!n.exact()) {
        j["vertices_visited"] = n.vertices_visited();
        j["consecutive_misses"] = n.consecutive_misses();
        j["rays"] = n.rays();
        j["walk_exhausted"] = n.walk_exhausted();
      }
      std::cout << j.dump() << "\n";
    }
    for (const pb::VoronoiCell& c : response.cells()) {
      std::cout << cli::cell_json(from_proto(c), c.seed(), [](std::uint32_t i) { return i; }).dump() << "\n";
    }
  };
  // On a sharded deployment, a large enough batch goes to each seed's shard itself.
  if (const auto routed = route ? routed_batch(o, *stub, r) : std::nullopt) {
    print(*routed);
    std::cout.flush();
    return kExitOk;
  }
  grpc::ClientContext ctx;
  prepare(o, ctx);
  auto reader = stub->BatchSeeds(&ctx, r);
  pb::BatchSeedsResponse response;
  while (reader->Read(&response)) print(response);
  std::cout.flush();
  if (grpc::Status s = reader->Finish(); !s.ok()) return report(o, s);
  return kExitOk;
}

int mesh(const RemoteOptions& o, const std::string& id, const std::string& output, unsigned shards) {
  auto ch = channel(o);
  auto stub = pb::Mesher::NewStub(ch);
  pb::PointSet info;
  {
    grpc::ClientContext ctx;
    prepare(o, ctx);
    pb::GetPointSetRequest r;
    r.set_point_set_id(id);
    if (grpc::Status s = stub->GetPointSet(&ctx, r, &info); !s.ok()) return report(o, s);
  }
  const int d = static_cast<int>(info.dimension());
  const bool periodic = info.periodic_box_size() > 0;
  std::unique_ptr<PeriodicMeshWriter> periodic_writer;
  if (periodic) {
    // The torus's simplices with their offsets (.npz or text, as the local mesh --periodic).
    auto w = PeriodicMeshWriter::open(output, d);
    if (!w.is_ok()) return report(w.status());
    periodic_writer = std::move(w).value();
  }
  MeshWriter::Format format = MeshWriter::Format::kText;  // a periodic mesh needs no coordinates
  if (!periodic) {
    auto f = MeshWriter::format_for(output, d);
    if (!f.is_ok()) return report(f.status());
    format = f.value();
  }
  // Coordinates are needed only by the formats that draw the mesh.
  std::vector<double> coords;
  if (format != MeshWriter::Format::kText && format != MeshWriter::Format::kNpy) {
    grpc::ClientContext ctx;
    prepare(o, ctx);
    pb::GetPointSetRequest r;
    r.set_point_set_id(id);
    auto reader = stub->DownloadPointSet(&ctx, r);
    pb::CoordinateChunk chunk;
    std::string bytes;
    while (reader->Read(&chunk)) bytes += chunk.coordinates();
    if (grpc::Status s = reader->Finish(); !s.ok()) return report(o, s);
    coords.resize(bytes.size() / 8);
    std::memcpy(coords.data(), bytes.data(), coords.size() * 8);
  }
  const PointSet points(d, std::move(coords));
  std::unique_ptr<MeshWriter> writer;
  if (!periodic) {
    auto w = MeshWriter::open(output, points);
    if (!w.is_ok()) return report(w.status());
    writer = std::move(w).value();
  }

  // One stream per shard, each spooled to an anonymous temporary file so memory stays
  // bounded; shards are concatenated in order (shard k is the part of the sweep
  // before shard k+1's, so the result is the local command's, byte for byte).
  if (shards == 0) shards = 1;
  struct Shard {
    std::FILE* spool = nullptr;
    std::FILE* offsets = nullptr;  // periodic sets
    grpc::Status status;
    std::uint64_t simplices = 0;
  };
  std::vector<Shard> parts(shards);
  std::vector<std::thread> threads;
  const auto start = std::chrono::steady_clock::now();
  for (unsigned k = 0; k < shards; ++k) {
    threads.emplace_back([&, k] {
      Shard& part = parts[k];
      part.spool = std::tmpfile();
      if (periodic) part.offsets = std::tmpfile();
      grpc::ClientContext ctx;
      prepare(o, ctx);
      pb::StreamSimplicesRequest r;
      r.set_point_set_id(id);
      r.set_shard_index(k);
      r.set_shard_count(shards);
      auto reader = stub->StreamSimplices(&ctx, r);
      pb::SimplexBatch batch;
      while (reader->Read(&batch)) {
        std::fwrite(batch.simplices().data(), 4, static_cast<std::size_t>(batch.simplices_size()), part.spool);
        if (periodic)
          std::fwrite(batch.offsets().data(), 4, static_cast<std::size_t>(batch.offsets_size()), part.offsets);
        part.simplices += static_cast<std::uint64_t>(batch.simplices_size()) / (d + 1);
      }
      part.status = reader->Finish();
      if (part.spool == nullptr || std::ferror(part.spool) ||
          (periodic && (part.offsets == nullptr || std::ferror(part.offsets)))) {
        part.status = grpc::Status(grpc::StatusCode::INTERNAL,
                                   "cannot spool shard " + std::to_string(k) + " to a temporary file");
      }
    });
  }
  for (auto& t : threads) t.join();
  std::uint64_t total = 0;
  std::vector<std::uint32_t> buffer(1 << 16);
  for (Shard& part : parts) {
    if (!part.status.ok()) return report(o, part.status);
    std::rewind(part.spool);
    std::size_t got = 0;
    const std::size_t width = static_cast<std::size_t>(d) + 1;
    if (periodic) {
      std::rewind(part.offsets);
      std::vector<std::int32_t> offsets(buffer.size() * static_cast<std::size_t>(d));
      while ((got = std::fread(buffer.data(), 4, buffer.size() - buffer.size() % width, part.spool)) > 0) {
        const std::size_t want = got * static_cast<std::size_t>(d);
        if (std::fread(offsets.data(), 4, want, part.offsets) != want) {
          return report(internal_error("cannot read back a shard's offsets from its temporary file"));
        }
        if (Status s = periodic_writer->write({buffer.data(), got}, {offsets.data(), want}); !s.is_ok())
          return report(s);
      }
      std::fclose(part.offsets);
    } else {
      while ((got = std::fread(buffer.data(), 4, buffer.size() - buffer.size() % width, part.spool)) > 0) {
        if (Status s = writer->write({buffer.data(), got}); !s.is_ok()) return report(s);
      }
    }
    std::fclose(part.spool);
    total += part.simplices;
  }
  if (Status s = periodic ? periodic_writer->commit() : writer->commit(); !s.is_ok()) return report(s);
  if (!o.quiet) {
    const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::fprintf(stderr, "spokemesh: %llu points, %llu simplices from %u shards, %.2f s -> %s\n",
                 static_cast<unsigned long long>(info.count()), static_cast<unsigned long long>(total), shards, t,
                 output.c_str());
  }
  return kExitOk;
}

int health(const RemoteOptions& o) {
  auto stub = grpc::health::v1::Health::NewStub(channel(o));
  grpc::ClientContext ctx;
  prepare(o, ctx);
  grpc::health::v1::HealthCheckRequest request;
  grpc::health::v1::HealthCheckResponse response;
  const grpc::Status s = stub->Check(&ctx, request, &response);
  if (!s.ok()) return report(o, s);
  const bool serving = response.status() == grpc::health::v1::HealthCheckResponse::SERVING;
  std::printf("%s\n", serving ? "SERVING" : "NOT_SERVING");
  return serving ? kExitOk : kExitFailure;
}

int list(const RemoteOptions& o) {
  auto stub = pb::Mesher::NewStub(channel(o));
  std::string token;
  do {
    grpc::ClientContext ctx;
    prepare(o, ctx);
    pb::ListPointSetsRequest r;
    r.set_page_token(token);
    pb::ListPointSetsResponse page;
    if (grpc::Status s = stub->ListPointSets(&ctx, r, &page); !s.ok()) return report(o, s);
    for (const auto& p : page.point_sets()) {
      std::printf("%s  %u-d  %llu points  %s\n", p.id().c_str(), p.dimension(),
                  static_cast<unsigned long long>(p.count()), p.display_name().c_str());
    }
    token = page.next_page_token();
  } while (!token.empty());
  return kExitOk;
}

int remove(const RemoteOptions& o, const std::string& id) {
  pb::DeletePointSetResponse response;
  pb::DeletePointSetRequest r;
  r.set_point_set_id(id);
  return unary(
      o, [&](auto& stub, auto& ctx, auto& resp) { return stub.DeletePointSet(&ctx, r, &resp); }, response);
}

}  // namespace spokemesh::remote
