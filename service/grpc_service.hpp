// MesherService: the gRPC adapter (sync API) over Engine. Each handler decodes the
// request, calls one Engine function under a CallControl (deadline + cancellation),
// and encodes the result; no geometry lives here.
//
// Thread safety: handlers run concurrently on gRPC's thread pool; the service is
// stateless apart from the Engine, which is thread-safe.
#pragma once

#include <grpcpp/grpcpp.h>

#include <string>

#include "auth.hpp"
#include "engine.hpp"
#include "router.hpp"
#include "shard_peers.hpp"
#include "spokemesh/v1/mesher.grpc.pb.h"
#include "telemetry.hpp"

namespace spokemesh::service {

namespace pb = ::spokemesh::v1;

grpc::Status to_grpc(const Status& s);

class MesherService final : public pb::Mesher::Service {
 public:
  // auth: who may call and which sets they see (auth.hpp); shared with the REST API.
  // peers: on a sharded replica, the way to the other shards (null otherwise).
  MesherService(Engine& engine, Telemetry& telemetry, std::shared_ptr<const Authenticator> auth,
                ShardPeers* peers = nullptr);

  grpc::Status UploadPointSet(grpc::ServerContext* ctx, grpc::ServerReader<pb::UploadPointSetRequest>* reader,
                              pb::PointSet* response) override;
  grpc::Status AppendPoints(grpc::ServerContext* ctx, grpc::ServerReader<pb::AppendPointsRequest>* reader,
                            pb::PointSet* response) override;
  grpc::Status GetPointSet(grpc::ServerContext* ctx, const pb::GetPointSetRequest* request,
                           pb::PointSet* response) override;
  grpc::Status ListPointSets(grpc::ServerContext* ctx, const pb::ListPointSetsRequest* request,
                             pb::ListPointSetsResponse* response) override;
  grpc::Status DeletePointSet(grpc::ServerContext* ctx, const pb::DeletePointSetRequest* request,
                              pb::DeletePointSetResponse* response) override;
  grpc::Status DownloadPointSet(grpc::ServerContext* ctx, const pb::GetPointSetRequest* request,
                                grpc::ServerWriter<pb::CoordinateChunk>* writer) override;
  grpc::Status GetStar(grpc::ServerContext* ctx, const pb::SeedRequest* request, pb::Star* response) override;
  grpc::Status GetNeighbors(grpc::ServerContext* ctx, const pb::GetNeighborsRequest* request,
                            pb::Neighbors* response) override;
  grpc::Status GetVoronoiCell(grpc::ServerContext* ctx, const pb::GetVoronoiCellRequest* request,
                              pb::VoronoiCell* response) override;
  grpc::Status StreamSimplices(grpc::ServerContext* ctx, const pb::StreamSimplicesRequest* request,
                               grpc::ServerWriter<pb::SimplexBatch>* writer) override;
  grpc::Status StreamCells(grpc::ServerContext* ctx, const pb::StreamCellsRequest* request,
                           grpc::ServerWriter<pb::CellBatch>* writer) override;
  grpc::Status BatchSeeds(grpc::ServerContext* ctx, const pb::BatchSeedsRequest* request,
                          grpc::ServerWriter<pb::BatchSeedsResponse>* writer) override;
  grpc::Status GetShardMap(grpc::ServerContext* ctx, const pb::GetPointSetRequest* request,
                           grpc::ServerWriter<pb::ShardMapChunk>* writer) override;
  grpc::Status Locate(grpc::ServerContext* ctx, const pb::LocateRequest* request,
                      grpc::ServerWriter<pb::LocateResponse>* writer) override;
  grpc::Status Interpolate(grpc::ServerContext* ctx, const pb::InterpolateRequest* request,
                           grpc::ServerWriter<pb::InterpolateResponse>* writer) override;
  grpc::Status PutValues(grpc::ServerContext* ctx, grpc::ServerReader<pb::PutValuesRequest>* reader,
                         pb::ValuesInfo* response) override;

 private:
  class Call;
  // An upload's or an append's stream: the header (opening the session), then chunks
  // of coordinates, ended by the client, kept alive by arrivals (--upload-idle-timeout).
  template <class Request, class Open>
  grpc::Status receive_points(Call& call, grpc::ServerContext* ctx, grpc::ServerReader<Request>* reader,
                              const Open& open, pb::PointSet* response);
  // One answer of a batch into `response` (its kind's list); returns its size.
  std::size_t add_answer(const BatchAnswer& a, BatchKind kind, pb::NeighborMode mode, pb::BatchSeedsResponse& response);
  // A batch whose seeds lie in several shards' pieces: each shard's seeds answered
  // there (this one's here), written in the request's order.
  Status relay_batch(Call& call, grpc::ServerContext* ctx, const pb::BatchSeedsRequest& request,
                     const std::vector<std::uint64_t>& seeds, const std::vector<std::uint32_t>& routes, BatchKind kind,
                     const NeighborQuery& query, grpc::ServerWriter<pb::BatchSeedsResponse>* writer);
  // A seed's call for another shard's piece, answered by a replica of that shard
  // (nullopt: answer it here). UNAVAILABLE names the shard when none answers.
  template <class Request, class Response, class Method>
  std::optional<grpc::Status> relay(Call& call, grpc::ServerContext* ctx, const Request& request, Response* response,
                                    Method method);
  Engine& engine_;
  Telemetry& telemetry_;
  std::shared_ptr<const Authenticator> auth_;
  ShardPeers* peers_;
  Router router_;
};

void fill_point_set(const PointSetInfo& info, pb::PointSet* out);
// One convention for unbounded cells (docs/service.md): +infinity where a number is typed.
void fill_cell(const VoronoiCell& cell, pb::VoronoiCell* out);
void fill_star(const StarAnswer& answer, pb::Star* out);
void fill_neighbors(const NeighborAnswer& answer, pb::NeighborMode mode, pb::Neighbors* out);
Result<NeighborQuery> neighbor_query(int mode, std::uint32_t misses, std::uint32_t max_vertices);
pb::NeighborMode neighbor_mode_proto(NeighborQuery::Mode mode);
// One batch answer added to `response` as its kind's message (with its seed); returns it.
const google::protobuf::MessageLite& add_batch_answer(const BatchAnswer& a, BatchKind kind, pb::NeighborMode mode,
                                                      pb::BatchSeedsResponse& response);
DomainSpec domain_spec(const pb::Domain& domain);

}  // namespace spokemesh::service
