#include "grpc_service.hpp"

#include <algorithm>
#include <cstring>
#include <future>
#include <limits>
#include <map>
#include <optional>
#include <type_traits>

namespace spokemesh::service {

grpc::Status to_grpc(const Status& s) {
  if (s.is_ok()) return grpc::Status::OK;
  return {static_cast<grpc::StatusCode>(static_cast<int>(s.code())), s.message()};
}

void fill_point_set(const PointSetInfo& info, pb::PointSet* out) {
  out->set_id(info.id);
  out->set_dimension(static_cast<std::uint32_t>(info.dimension));
  out->set_count(info.count);
  out->set_display_name(info.display_name);
  out->set_already_existed(info.already_existed);
  out->set_weighted(info.weighted);
  out->mutable_periodic_box()->Add(info.periodic_box.begin(), info.periodic_box.end());
}

// One RPC: authentication, the deadline, cancellation, and the log/metrics record.
class MesherService::Call {
 public:
  Call(MesherService& service, grpc::ServerContext* ctx, const char* method, std::string point_set = {},
       std::optional<std::uint64_t> seed = std::nullopt)
      : service_(service), control_(deadline_of(ctx, service.engine_.limits()), [ctx] { return ctx->IsCancelled(); }) {
    record_.transport = "grpc";
    record_.method = method;
    record_.point_set = std::move(point_set);
    record_.seed = seed;
    // Who is calling, and whether they may see the set named (auth.hpp).
    const auto& md = ctx->client_metadata();
    const auto it = md.find("authorization");
    const std::string_view presented =
        it == md.end() ? std::string_view{} : std::string_view(it->second.data(), it->second.size());
    auto principal = service.auth_->authenticate(presented, "'authorization' metadata");
    if (!principal.is_ok()) {
      auth_ = principal.status();
    } else {
      principal_ = std::move(principal).value();
      if (!record_.point_set.empty()) auth_ = service.engine_.authorize(record_.point_set, principal_);
    }
  }

  // UNAUTHENTICATED, or NOT_FOUND for a set the caller may not see; OK otherwise.
  const Status& auth() const { return auth_; }
  const Principal& principal() const { return principal_; }
  const CallControl& control() const { return control_; }

  // A call answered by another shard's replica, recorded with its code.
  grpc::Status finish_relayed(const grpc::Status& s) {
    record_.code = static_cast<Code>(s.error_code());
    record_.message = s.error_message();
    record_.seconds = timer_.seconds();
    service_.telemetry_.record(record_);
    return s;
  }

  grpc::Status finish(const Status& s) {
    record_.code = s.code();
    record_.message = s.message();
    record_.seconds = timer_.seconds();
    service_.telemetry_.record(record_);
    return to_grpc(s);
  }

 private:
  static Clock::time_point deadline_of(grpc::ServerContext* ctx, const Limits& limits) {
    const auto fallback = Clock::now() + limits.default_deadline;
    const auto client = ctx->deadline();
    if (client == std::chrono::system_clock::time_point::max()) return fallback;
    // The client's deadline, moved onto the steady clock.
    const auto remaining = client - std::chrono::system_clock::now();
    return Clock::now() + std::chrono::duration_cast<Clock::duration>(remaining);
  }

  MesherService& service_;
  RequestTimer timer_;
  CallControl control_;
  Status auth_;
  Principal principal_;
  Telemetry::Request record_;
};

MesherService::MesherService(Engine& engine, Telemetry& telemetry, std::shared_ptr<const Authenticator> auth,
                             ShardPeers* peers)
    : engine_(engine), telemetry_(telemetry), auth_(std::move(auth)), peers_(peers), router_(engine, peers) {}

template <class Request, class Open>
grpc::Status MesherService::receive_points(Call& call, grpc::ServerContext* ctx, grpc::ServerReader<Request>* reader,
                                           const Open& open, pb::PointSet* response) {
  if (!call.auth().is_ok()) return call.finish(call.auth());
  // A stream that sends nothing for the idle timeout is cancelled (its blocked Read
  // returns), so a stalled client holds neither a thread nor memory for long.
  const auto idle = engine_.limits().upload_idle_timeout;
  CallControl idle_control(Clock::now() + idle, {}, [ctx] { ctx->TryCancel(); });
  const auto idle_status = [&] {
    return Status{Code::kDeadlineExceeded, "upload: nothing arrived for " + std::to_string(idle.count()) +
                                               " ms (--upload-idle-timeout); the upload was ended"};
  };
  Request message;
  if (!reader->Read(&message)) {
    if (idle_control.stopped()) return call.finish(idle_status());
    return call.finish(invalid_argument("header: the stream ended before any message"));
  }
  idle_control.extend_deadline(Clock::now() + idle);
  if (!message.has_header()) return call.finish(invalid_argument("header: the first message must carry the header"));
  Result<std::unique_ptr<UploadSession>> session = open(message.header());
  if (!session.is_ok()) return call.finish(session.status());
  std::uint64_t index = 1;
  while (reader->Read(&message)) {
    idle_control.extend_deadline(Clock::now() + idle);
    if (message.has_header()) {
      return call.finish(invalid_argument("message " + std::to_string(index) + ": a second header"));
    }
    if constexpr (requires { message.weights(); }) {
      if (message.part_case() == Request::kWeights) {
        const std::string& chunk = message.weights();
        if (Status s = session.value()->append_weights(chunk.data(), chunk.size()); !s.is_ok()) return call.finish(s);
        ++index;
        continue;
      }
    }
    const std::string& chunk = message.coordinates();
    if (Status s = session.value()->append(chunk.data(), chunk.size()); !s.is_ok()) return call.finish(s);
    ++index;
  }
  if (idle_control.stopped()) return call.finish(idle_status());
  if (ctx->IsCancelled()) return call.finish(cancelled("upload cancelled by the client"));
  auto info = engine_.finish_upload(*session.value(), call.principal());
  if (!info.is_ok()) return call.finish(info.status());
  if (!info->already_existed) telemetry_.add_points_uploaded(info->count);
  fill_point_set(info.value(), response);
  return call.finish(Status::ok());
}

grpc::Status MesherService::UploadPointSet(grpc::ServerContext* ctx,
                                           grpc::ServerReader<pb::UploadPointSetRequest>* reader,
                                           pb::PointSet* response) {
  Call call(*this, ctx, "UploadPointSet");
  return receive_points(
      call, ctx, reader,
      [&](const pb::PointSetHeader& h) {
        UploadHeader header;
        header.dimension = h.dimension();
        header.count = static_cast<std::int64_t>(std::min<std::uint64_t>(h.count(), INT64_MAX));
        header.display_name = h.display_name();
        header.weighted = h.weighted();
        header.periodic_box.assign(h.periodic_box().begin(), h.periodic_box().end());
        return engine_.begin_upload(header);
      },
      response);
}

grpc::Status MesherService::AppendPoints(grpc::ServerContext* ctx, grpc::ServerReader<pb::AppendPointsRequest>* reader,
                                         pb::PointSet* response) {
  Call call(*this, ctx, "AppendPoints");
  std::string parent;
  const grpc::Status done = receive_points(
      call, ctx, reader,
      [&](const pb::AppendPointsHeader& h) {
        parent = h.point_set_id();
        UploadHeader added;
        added.count = static_cast<std::int64_t>(std::min<std::uint64_t>(h.count(), INT64_MAX));
        added.display_name = h.display_name();
        return engine_.begin_append(parent, added, call.principal());
      },
      response);
  if (done.ok()) response->set_parent_id(parent);
  return done;
}

grpc::Status MesherService::GetPointSet(grpc::ServerContext* ctx, const pb::GetPointSetRequest* request,
                                        pb::PointSet* response) {
  Call call(*this, ctx, "GetPointSet", request->point_set_id());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  auto info = engine_.get_point_set(request->point_set_id(), call.principal());
  if (!info.is_ok()) return call.finish(info.status());
  fill_point_set(info.value(), response);
  return call.finish(Status::ok());
}

grpc::Status MesherService::ListPointSets(grpc::ServerContext* ctx, const pb::ListPointSetsRequest* request,
                                          pb::ListPointSetsResponse* response) {
  Call call(*this, ctx, "ListPointSets");
  if (!call.auth().is_ok()) return call.finish(call.auth());
  std::string next;
  auto page = engine_.list_point_sets(request->page_size(), request->page_token(), &next, call.principal());
  if (!page.is_ok()) return call.finish(page.status());
  for (const PointSetInfo& info : page.value()) fill_point_set(info, response->add_point_sets());
  response->set_next_page_token(next);
  return call.finish(Status::ok());
}

grpc::Status MesherService::DeletePointSet(grpc::ServerContext* ctx, const pb::DeletePointSetRequest* request,
                                           pb::DeletePointSetResponse*) {
  Call call(*this, ctx, "DeletePointSet", request->point_set_id());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  return call.finish(engine_.delete_point_set(request->point_set_id(), call.principal()));
}

grpc::Status MesherService::DownloadPointSet(grpc::ServerContext* ctx, const pb::GetPointSetRequest* request,
                                             grpc::ServerWriter<pb::CoordinateChunk>* writer) {
  Call call(*this, ctx, "DownloadPointSet", request->point_set_id());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  auto set = engine_.point_set(request->point_set_id());
  if (!set.is_ok()) return call.finish(set.status());
  const auto coords = set.value()->points.coordinates();
  const char* bytes = reinterpret_cast<const char*>(coords.data());
  constexpr std::size_t kChunk = defaults::kDownloadChunkBytes;
  pb::CoordinateChunk chunk;
  for (std::size_t at = 0; at < coords.size_bytes(); at += kChunk) {
    chunk.set_coordinates(bytes + at, std::min(kChunk, coords.size_bytes() - at));
    if (!writer->Write(chunk)) return call.finish(cancelled("download stopped: the client went away"));
  }
  return call.finish(Status::ok());
}

template <class Request, class Response, class Method>
std::optional<grpc::Status> MesherService::relay(Call& call, grpc::ServerContext* ctx, const Request& request,
                                                 Response* response, Method method) {
  const auto& md = ctx->client_metadata();
  // Router: a seed of another shard's piece is answered there, relayed once.
  const SeedRoute route = router_.route(request.point_set_id(), request.seed(), md.find(kForwardedHeader) != md.end());
  if (route.here) return std::nullopt;
  auto stub = pb::Mesher::NewStub(peers_->grpc_channel(route.shard));
  grpc::ClientContext client;
  client.set_deadline(
      std::chrono::system_clock::now() +
      std::chrono::duration_cast<std::chrono::system_clock::duration>(call.control().deadline() - Clock::now()));
  client.AddMetadata(kForwardedHeader, std::to_string(peers_->shards().index));
  if (const auto it = md.find("authorization"); it != md.end()) {
    client.AddMetadata("authorization", std::string(it->second.data(), it->second.size()));
  }
  grpc::Status status = ((*stub).*method)(&client, request, response);
  telemetry_.add_forwarded(route.shard, static_cast<Code>(status.error_code()));
  // Which shard answered: a client routing by an older shard map fetches it again.
  ctx->AddInitialMetadata("x-spokemesh-shard", std::to_string(route.shard));
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE) {
    response->Clear();
    return call.finish(peers_->unavailable(route.shard, peers_->grpc_address(route.shard), status.error_message()));
  }
  return call.finish_relayed(status);
}

grpc::Status MesherService::GetStar(grpc::ServerContext* ctx, const pb::SeedRequest* request, pb::Star* response) {
  Call call(*this, ctx, "GetStar", request->point_set_id(), request->seed());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  if (auto relayed = relay(call, ctx, *request, response, &pb::Mesher::Stub::GetStar)) return *relayed;
  auto answer = engine_.star(request->point_set_id(), request->seed(), call.control());
  if (!answer.is_ok()) return call.finish(answer.status());
  response->set_point_set_id(request->point_set_id());
  response->set_seed(request->seed());
  fill_star(answer.value(), response);
  telemetry_.add_simplices_served(answer->star.size());
  return call.finish(Status::ok());
}

grpc::Status MesherService::GetNeighbors(grpc::ServerContext* ctx, const pb::GetNeighborsRequest* request,
                                         pb::Neighbors* response) {
  Call call(*this, ctx, "GetNeighbors", request->point_set_id(), request->seed());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  if (auto relayed = relay(call, ctx, *request, response, &pb::Mesher::Stub::GetNeighbors)) return *relayed;
  auto query_or = neighbor_query(request->mode(), request->max_consecutive_misses(), request->max_vertices());
  if (!query_or.is_ok()) return call.finish(query_or.status());
  const NeighborQuery query = query_or.value();
  auto answer = engine_.neighbors(request->point_set_id(), request->seed(), query, call.control());
  if (!answer.is_ok()) return call.finish(answer.status());
  response->set_point_set_id(request->point_set_id());
  response->set_seed(request->seed());
  fill_neighbors(answer.value(), request->mode(), response);
  return call.finish(Status::ok());
}

void fill_star(const StarAnswer& answer, pb::Star* out) {
  const Star& star = answer.star;
  out->set_dimension(static_cast<std::uint32_t>(star.dimension));
  out->mutable_simplices()->Add(star.simplices.begin(), star.simplices.end());
  out->mutable_circumcenters()->Add(answer.circumcentres.begin(), answer.circumcentres.end());
  out->set_hull_facets(static_cast<std::uint32_t>(star.hull_facets));
  out->mutable_offsets()->Add(answer.offsets.begin(), answer.offsets.end());
  out->set_hidden(star.hidden);
}

void fill_neighbors(const NeighborAnswer& answer, pb::NeighborMode mode, pb::Neighbors* out) {
  out->mutable_neighbors()->Add(answer.neighbors.begin(), answer.neighbors.end());
  out->mutable_offsets()->Add(answer.offsets.begin(), answer.offsets.end());
  out->set_exact(answer.exact);
  out->set_mode(mode);
  if (!answer.exact) {
    out->set_vertices_visited(answer.walk.vertices);
    out->set_consecutive_misses(answer.walk.misses);
    out->set_rays(answer.walk.rays);
    out->set_walk_exhausted(answer.walk.exhausted);
  }
}

Result<NeighborQuery> neighbor_query(int mode, std::uint32_t misses, std::uint32_t max_vertices) {
  NeighborQuery query;
  switch (mode) {
    case pb::NEIGHBOR_MODE_EXACT:
      query.mode = NeighborQuery::Mode::kExact;
      break;
    case pb::NEIGHBOR_MODE_APPROXIMATE:
      query.mode = NeighborQuery::Mode::kApproximate;
      break;
    case pb::NEIGHBOR_MODE_SPOKES:
      query.mode = NeighborQuery::Mode::kSpokes;
      break;
    default:
      return invalid_argument("mode: " + std::to_string(mode) + " is not a NeighborMode");
  }
  query.max_consecutive_misses = misses;
  query.max_vertices = max_vertices;
  return query;
}

void fill_cell(const VoronoiCell& cell, pb::VoronoiCell* out) {
  out->set_dimension(static_cast<std::uint32_t>(cell.dimension));
  out->mutable_vertices()->Add(cell.vertices.begin(), cell.vertices.end());
  out->mutable_vertex_simplices()->Add(cell.vertex_simplices.begin(), cell.vertex_simplices.end());
  for (const VoronoiFacet& f : cell.facets) {
    pb::VoronoiFacet* facet = out->add_facets();
    if (f.is_wall()) {
      facet->set_wall(static_cast<std::uint32_t>(f.wall()));
    } else {
      facet->set_neighbor(static_cast<std::uint32_t>(f.neighbor));
    }
    facet->mutable_vertices()->Add(f.vertices.begin(), f.vertices.end());
    facet->set_area(f.area);
    facet->mutable_normal()->Add(f.normal.begin(), f.normal.end());
  }
  out->set_bounded(cell.bounded);
  out->set_volume(cell.bounded ? cell.volume : std::numeric_limits<double>::infinity());
  out->mutable_centroid()->Add(cell.centroid.begin(), cell.centroid.end());
  out->set_clipped(cell.clipped);
  out->mutable_facet_offsets()->Add(cell.facet_offsets.begin(), cell.facet_offsets.end());
  out->set_hidden(cell.hidden);
}

DomainSpec domain_spec(const pb::Domain& domain) {
  DomainSpec spec;
  spec.box.assign(domain.box().begin(), domain.box().end());
  spec.halfspaces.assign(domain.halfspaces().begin(), domain.halfspaces().end());
  spec.bounding_box = domain.bounding_box();
  if (domain.has_shape()) {
    spec.shape_format = domain.shape().format();
    spec.shape_data = domain.shape().data();
    if (spec.shape_format.empty()) spec.shape_format = "(none)";  // refused by name
  }
  return spec;
}

grpc::Status MesherService::GetVoronoiCell(grpc::ServerContext* ctx, const pb::GetVoronoiCellRequest* request,
                                           pb::VoronoiCell* response) {
  Call call(*this, ctx, "GetVoronoiCell", request->point_set_id(), request->seed());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  if (auto relayed = relay(call, ctx, *request, response, &pb::Mesher::Stub::GetVoronoiCell)) return *relayed;
  auto cell = engine_.cell(request->point_set_id(), request->seed(), domain_spec(request->domain()), call.control());
  if (!cell.is_ok()) return call.finish(cell.status());
  response->set_point_set_id(request->point_set_id());
  response->set_seed(request->seed());
  fill_cell(cell.value(), response);
  return call.finish(Status::ok());
}

grpc::Status MesherService::StreamSimplices(grpc::ServerContext* ctx, const pb::StreamSimplicesRequest* request,
                                            grpc::ServerWriter<pb::SimplexBatch>* writer) {
  Call call(*this, ctx, "StreamSimplices", request->point_set_id());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  pb::SimplexBatch batch;
  StreamPart range;
  int dimension = 0;
  // Write() blocks while the client's flow-control window is full, and the engine
  // computes only a bounded window ahead, so a slow reader holds memory bounded.
  auto emit = [&](std::span<const std::uint32_t> simplices, std::span<const std::int32_t> offsets,
                  std::uint64_t seeds_done) -> Status {
    batch.Clear();
    batch.set_dimension(static_cast<std::uint32_t>(dimension));
    batch.set_seed_begin(range.begin);
    batch.set_seed_end(range.end);
    batch.set_seeds_done(seeds_done);
    batch.mutable_simplices()->Add(simplices.begin(), simplices.end());
    batch.mutable_offsets()->Add(offsets.begin(), offsets.end());
    if (!writer->Write(batch)) return cancelled("streaming stopped: the client went away");
    telemetry_.add_simplices_served(simplices.size() / static_cast<std::size_t>(dimension + 1));
    return Status::ok();
  };
  return call.finish(engine_.stream_simplices(request->point_set_id(), request->shard_index(), request->shard_count(),
                                              request->batch_size(), call.control(), emit, &range, &dimension));
}

grpc::Status MesherService::StreamCells(grpc::ServerContext* ctx, const pb::StreamCellsRequest* request,
                                        grpc::ServerWriter<pb::CellBatch>* writer) {
  Call call(*this, ctx, "StreamCells", request->point_set_id());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  pb::CellBatch batch;
  StreamPart range;
  auto emit = [&](std::span<const VoronoiCell> cells, std::uint64_t seeds_done) -> Status {
    batch.Clear();
    batch.set_seed_begin(range.begin);
    batch.set_seed_end(range.end);
    batch.set_seeds_done(seeds_done);
    for (const VoronoiCell& c : cells) {
      pb::VoronoiCell* out = batch.add_cells();
      out->set_seed(c.seed);
      fill_cell(c, out);
    }
    if (!writer->Write(batch)) return cancelled("streaming stopped: the client went away");
    return Status::ok();
  };
  return call.finish(engine_.stream_cells(request->point_set_id(), request->shard_index(), request->shard_count(),
                                          request->batch_size(), domain_spec(request->domain()),
                                          request->measures_only(), call.control(), emit, &range));
}

namespace {

// Answers written as messages of at most about 2 MiB (gRPC's default limit is 4 MiB):
// add(answer, response) puts one into the message and returns its size; each message's
// `done` counts the request's items answered with it. prepare(response), when given,
// runs before each write.
template <class Answer, class Response, class Add, class Prepare = std::nullptr_t>
Status write_in_messages(std::span<const Answer> answers, std::uint64_t done, Response& response,
                         grpc::ServerWriter<Response>* writer, Add&& add, Prepare&& prepare = nullptr) {
  std::size_t bytes = 0;
  for (std::size_t i = 0; i < answers.size(); ++i) {
    bytes += add(answers[i], response);
    if (bytes > defaults::kMessagePayloadBytes || i + 1 == answers.size()) {
      if constexpr (!std::is_same_v<std::decay_t<Prepare>, std::nullptr_t>) prepare(response);
      response.set_done(done - (answers.size() - 1 - i));
      if (!writer->Write(response)) return cancelled("streaming stopped: the client went away");
      response.Clear();
      bytes = 0;
    }
  }
  return Status::ok();
}

}  // namespace

grpc::Status MesherService::BatchSeeds(grpc::ServerContext* ctx, const pb::BatchSeedsRequest* request,
                                       grpc::ServerWriter<pb::BatchSeedsResponse>* writer) {
  Call call(*this, ctx, "BatchSeeds", request->point_set_id());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  BatchKind kind;
  switch (request->kind()) {
    case pb::BATCH_KIND_STARS:
      kind = BatchKind::kStars;
      break;
    case pb::BATCH_KIND_NEIGHBORS:
      kind = BatchKind::kNeighbors;
      break;
    case pb::BATCH_KIND_CELLS:
      kind = BatchKind::kCells;
      break;
    default:
      return call.finish(invalid_argument("kind: " + std::to_string(request->kind()) + " is not a BatchKind"));
  }
  auto query = neighbor_query(request->mode(), request->max_consecutive_misses(), request->max_vertices());
  if (!query.is_ok()) return call.finish(query.status());
  const std::vector<std::uint64_t> seeds(request->seeds().begin(), request->seeds().end());
  // On a sharded replica, the seeds of other shards' pieces go to those shards.
  auto routes = router_.batch_routes(request->point_set_id(), seeds,
                                     ctx->client_metadata().find(kForwardedHeader) != ctx->client_metadata().end());
  if (!routes.is_ok()) return call.finish(routes.status());
  if (!routes->empty()) {
    return call.finish(relay_batch(call, ctx, *request, seeds, routes.value(), kind, query.value(), writer));
  }
  pb::BatchSeedsResponse response;
  auto emit = [&](std::span<const BatchAnswer> answers, std::uint64_t done) -> Status {
    return write_in_messages(answers, done, response, writer, [&](const BatchAnswer& a, pb::BatchSeedsResponse& r) {
      return add_answer(a, kind, request->mode(), r);
    });
  };
  return call.finish(engine_.batch(request->point_set_id(), seeds, kind, query.value(), domain_spec(request->domain()),
                                   call.control(), emit));
}

grpc::Status MesherService::Locate(grpc::ServerContext* ctx, const pb::LocateRequest* request,
                                   grpc::ServerWriter<pb::LocateResponse>* writer) {
  Call call(*this, ctx, "Locate", request->point_set_id());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  PointQuery query;
  query.natural = !request->skip_natural();
  pb::LocateResponse response;
  auto emit = [&](std::span<const PointResult> answers, std::uint64_t done) -> Status {
    return write_in_messages(answers, done, response, writer, [](const PointResult& r, pb::LocateResponse& m) {
      const PointAnswer& a = r.answer;
      pb::PointLocation* out = m.add_locations();
      const auto w = static_cast<std::ptrdiff_t>(a.vertex_count);
      out->mutable_simplex()->Add(a.simplex.begin(), a.simplex.begin() + w);
      out->mutable_barycentric()->Add(a.barycentric.begin(), a.barycentric.begin() + w);
      out->mutable_natural_neighbors()->Add(a.natural.neighbors.begin(), a.natural.neighbors.end());
      out->mutable_weights()->Add(a.natural.weights.begin(), a.natural.weights.end());
      return 12 * (static_cast<std::size_t>(w) + a.natural.neighbors.size()) + 8;
    });
  };
  return call.finish(engine_.points(request->point_set_id(),
                                    std::span<const double>(request->queries().data(), request->queries().size()),
                                    query, call.control(), emit));
}

grpc::Status MesherService::Interpolate(grpc::ServerContext* ctx, const pb::InterpolateRequest* request,
                                        grpc::ServerWriter<pb::InterpolateResponse>* writer) {
  Call call(*this, ctx, "Interpolate", request->point_set_id());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  const std::string& id = request->point_set_id();
  auto info = engine_.get_point_set(id, call.principal());
  if (!info.is_ok()) return call.finish(info.status());
  const int d = info->dimension;
  PointQuery query;
  switch (request->method()) {
    case pb::INTERPOLATION_METHOD_UNSPECIFIED:
      query.method = d == 2 || d == 3 ? PointMethod::kNatural : PointMethod::kLinear;
      break;
    case pb::INTERPOLATION_METHOD_NATURAL:
      query.method = PointMethod::kNatural;
      break;
    case pb::INTERPOLATION_METHOD_LINEAR:
      query.method = PointMethod::kLinear;
      break;
    case pb::INTERPOLATION_METHOD_NEAREST:
      query.method = PointMethod::kNearest;
      break;
    default:
      return call.finish(
          invalid_argument("method: " + std::to_string(request->method()) + " is not an InterpolationMethod"));
  }
  std::shared_ptr<const KeptValues> kept;
  if (!request->values_id().empty()) {
    if (!request->values().empty()) return call.finish(invalid_argument("values: give values or values_id, not both"));
    auto got = engine_.kept_values(id, request->values_id());
    if (!got.is_ok()) return call.finish(got.status());
    kept = std::move(got).value();
    query.values = kept->values;
    query.width = kept->width;
  } else {
    query.values = std::span<const double>(request->values().data(), request->values().size());
    query.width = request->width() == 0 ? 1 : request->width();
  }
  query.fill = request->has_fill_value() ? std::optional<double>(request->fill_value())
                                         : std::optional<double>(std::numeric_limits<double>::quiet_NaN());
  pb::InterpolateResponse response;
  auto emit = [&](std::span<const PointResult> answers, std::uint64_t done) -> Status {
    return write_in_messages(
        answers, done, response, writer,
        [](const PointResult& r, pb::InterpolateResponse& m) {
          m.mutable_values()->Add(r.values.begin(), r.values.end());
          if (r.nearest >= 0) m.add_nearest(static_cast<std::uint32_t>(r.nearest));
          return 8 * r.values.size() + 4;
        },
        [&](pb::InterpolateResponse& m) { m.set_width(static_cast<std::uint32_t>(query.width)); });
  };
  return call.finish(engine_.points(id, std::span<const double>(request->queries().data(), request->queries().size()),
                                    query, call.control(), emit));
}

grpc::Status MesherService::PutValues(grpc::ServerContext* ctx, grpc::ServerReader<pb::PutValuesRequest>* reader,
                                      pb::ValuesInfo* response) {
  Call call(*this, ctx, "PutValues");
  if (!call.auth().is_ok()) return call.finish(call.auth());
  pb::PutValuesRequest message;
  if (!reader->Read(&message) || !message.has_header()) {
    return call.finish(invalid_argument("header: the first message must carry the header"));
  }
  const std::string id = message.header().point_set_id();
  if (Status s = engine_.authorize(id, call.principal()); !s.is_ok()) return call.finish(s);
  auto info = engine_.get_point_set(id, call.principal());
  if (!info.is_ok()) return call.finish(info.status());
  const std::uint32_t width = message.header().width() == 0 ? 1 : message.header().width();
  if (width > 1u << 20) return call.finish(invalid_argument("header.width: not between 1 and 1048576"));
  // Every byte held is charged as it arrives, up to what the header says.
  const std::uint64_t expected = info->count * width * sizeof(double);
  MemoryBudget::Charge charge = engine_.store().budget().empty_charge();
  std::string bytes = message.values();
  auto take = [&](const std::string& chunk) -> Status {
    if (bytes.size() + chunk.size() > expected) {
      return invalid_argument("values: more than the " + std::to_string(expected) + " bytes of " +
                              std::to_string(info->count) + " rows of " + std::to_string(width));
    }
    if (!charge.grow(chunk.size())) return engine_.store().budget().over_budget("values", chunk.size());
    bytes += chunk;
    return Status::ok();
  };
  if (!charge.grow(bytes.size())) return call.finish(engine_.store().budget().over_budget("values", bytes.size()));
  while (reader->Read(&message)) {
    if (call.control().stopped()) return call.finish(call.control().stopped_status("PutValues"));
    if (Status s = take(message.values()); !s.is_ok()) return call.finish(s);
  }
  if (bytes.size() % sizeof(double) != 0) {
    return call.finish(
        invalid_argument("values: " + std::to_string(bytes.size()) + " bytes are not whole float64 values"));
  }
  std::vector<double> values(bytes.size() / sizeof(double));
  std::memcpy(values.data(), bytes.data(), bytes.size());
  bytes = {};
  auto put = engine_.put_values(id, values, width);
  if (!put.is_ok()) return call.finish(put.status());
  response->set_values_id(put->values_id);
  response->set_point_set_id(put->point_set_id);
  response->set_width(put->width);
  response->set_count(put->count);
  response->set_already_existed(put->already_existed);
  return call.finish(Status::ok());
}

const google::protobuf::MessageLite& add_batch_answer(const BatchAnswer& a, BatchKind kind, pb::NeighborMode mode,
                                                      pb::BatchSeedsResponse& response) {
  if (kind == BatchKind::kStars) {
    pb::Star* out = response.add_stars();
    out->set_seed(a.seed);
    fill_star(a.star, out);
    return *out;
  }
  if (kind == BatchKind::kNeighbors) {
    pb::Neighbors* out = response.add_neighbors();
    out->set_seed(a.seed);
    fill_neighbors(a.neighbors, mode, out);
    return *out;
  }
  pb::VoronoiCell* out = response.add_cells();
  out->set_seed(a.seed);
  fill_cell(a.cell, out);
  return *out;
}

pb::NeighborMode neighbor_mode_proto(NeighborQuery::Mode mode) {
  switch (mode) {
    case NeighborQuery::Mode::kExact:
      return pb::NEIGHBOR_MODE_EXACT;
    case NeighborQuery::Mode::kApproximate:
      return pb::NEIGHBOR_MODE_APPROXIMATE;
    case NeighborQuery::Mode::kSpokes:
      return pb::NEIGHBOR_MODE_SPOKES;
  }
  return pb::NEIGHBOR_MODE_EXACT;
}

std::size_t MesherService::add_answer(const BatchAnswer& a, BatchKind kind, pb::NeighborMode mode,
                                      pb::BatchSeedsResponse& response) {
  if (kind == BatchKind::kStars) telemetry_.add_simplices_served(a.star.star.size());
  return add_batch_answer(a, kind, mode, response).ByteSizeLong();
}

grpc::Status MesherService::GetShardMap(grpc::ServerContext* ctx, const pb::GetPointSetRequest* request,
                                        grpc::ServerWriter<pb::ShardMapChunk>* writer) {
  Call call(*this, ctx, "GetShardMap", request->point_set_id());
  if (!call.auth().is_ok()) return call.finish(call.auth());
  auto map = router_.shard_map(request->point_set_id());
  if (!map.is_ok()) return call.finish(map.status());
  const ShardMap& m = map->map;
  pb::ShardMapChunk head;
  head.set_point_set_id(request->point_set_id());
  head.set_sharded(m.sharded);
  head.set_version(m.version);
  head.set_shard_count(m.shard_count);
  head.set_count(m.count);
  for (const std::string& a : map->grpc_addresses) head.add_grpc_addresses(a);
  for (const std::string& a : map->http_addresses) head.add_http_addresses(a);
  if (!writer->Write(head)) return call.finish(cancelled("the client went away"));
  const char* bytes = reinterpret_cast<const char*>(m.seed_shards.data());
  const std::size_t size = m.seed_shards.size() * 2;
  pb::ShardMapChunk chunk;
  for (std::size_t at = 0; at < size; at += defaults::kDownloadChunkBytes) {
    chunk.set_seed_shards(bytes + at, std::min(defaults::kDownloadChunkBytes, size - at));
    if (!writer->Write(chunk)) return call.finish(cancelled("the client went away"));
  }
  return call.finish(Status::ok());
}

namespace {

// A batch's answers one by one: each item holds one answer of the batch's kind.
void split_answers(pb::BatchSeedsResponse& all, std::vector<pb::BatchSeedsResponse>& out) {
  for (auto& star : *all.mutable_stars()) out.emplace_back().add_stars()->Swap(&star);
  for (auto& neighbors : *all.mutable_neighbors()) out.emplace_back().add_neighbors()->Swap(&neighbors);
  for (auto& cell : *all.mutable_cells()) out.emplace_back().add_cells()->Swap(&cell);
}

}  // namespace

Status MesherService::relay_batch(Call& call, grpc::ServerContext* ctx, const pb::BatchSeedsRequest& request,
                                  const std::vector<std::uint64_t>& seeds, const std::vector<std::uint32_t>& routes,
                                  BatchKind kind, const NeighborQuery& query,
                                  grpc::ServerWriter<pb::BatchSeedsResponse>* writer) {
  const std::uint32_t here = router_.here();
  const auto& md = ctx->client_metadata();
  std::string authorization;
  if (const auto it = md.find("authorization"); it != md.end()) {
    authorization.assign(it->second.data(), it->second.size());
  }
  pb::BatchSeedsRequest base = request;  // the request without its seeds, copied once
  base.clear_seeds();
  // Another shard's answers to its seeds (Router::scatter_gather asks again on UNAVAILABLE).
  using Items = std::vector<pb::BatchSeedsResponse>;
  auto ask = [&](std::uint32_t shard, const std::vector<std::uint64_t>& part) -> Result<Items> {
    pb::BatchSeedsRequest asked = base;
    for (const std::uint64_t seed : part) asked.add_seeds(seed);
    auto stub = pb::Mesher::NewStub(peers_->grpc_channel(shard));
    grpc::ClientContext client;
    client.set_deadline(
        std::chrono::system_clock::now() +
        std::chrono::duration_cast<std::chrono::system_clock::duration>(call.control().deadline() - Clock::now()));
    client.AddMetadata(kForwardedHeader, std::to_string(here));
    if (!authorization.empty()) client.AddMetadata("authorization", authorization);
    auto reader = stub->BatchSeeds(&client, asked);
    pb::BatchSeedsResponse all, message;
    while (reader->Read(&message)) all.MergeFrom(message);
    const grpc::Status status = reader->Finish();
    telemetry_.add_forwarded(shard, static_cast<Code>(status.error_code()));
    if (status.error_code() == grpc::StatusCode::UNAVAILABLE) {
      return peers_->unavailable(shard, peers_->grpc_address(shard), status.error_message());
    }
    if (!status.ok()) return Status{static_cast<Code>(status.error_code()), status.error_message()};
    Items items;
    split_answers(all, items);
    return items;
  };
  const DomainSpec spec = domain_spec(request.domain());
  auto local = [&](const std::vector<std::uint64_t>& part) -> Result<Items> {
    pb::BatchSeedsResponse all;
    Status s = engine_.batch(request.point_set_id(), part, kind, query, spec, call.control(),
                             [&](std::span<const BatchAnswer> answers, std::uint64_t) -> Status {
                               for (const BatchAnswer& a : answers) add_answer(a, kind, request.mode(), all);
                               return Status::ok();
                             });
    if (!s.is_ok()) return s;
    Items items;
    split_answers(all, items);
    return items;
  };
  // Written as the whole set's batch writes them: messages of about 2 MiB at most.
  auto emit = [&](Items& items, std::uint64_t done) -> Status {
    pb::BatchSeedsResponse response;
    std::size_t bytes = 0;
    for (std::size_t i = 0; i < items.size(); ++i) {
      bytes += items[i].ByteSizeLong();
      response.MergeFrom(items[i]);
      if (bytes > defaults::kMessagePayloadBytes || i + 1 == items.size()) {
        response.set_done(done - (items.size() - 1 - i));
        if (!writer->Write(response)) return cancelled("streaming stopped: the client went away");
        response.Clear();
        bytes = 0;
      }
    }
    return Status::ok();
  };
  return router_.scatter_gather<pb::BatchSeedsResponse>(seeds, routes, call.control(), ask, local, emit);
}

}  // namespace spokemesh::service
