// The standard gRPC health service (grpc.health.v1.Health), answered by a synchronous
// service of ours instead of gRPC's built-in one.
//
// Why not grpc::EnableDefaultHealthCheckService: in gRPC 1.51 the built-in service is a
// callback service, and one callback service makes the whole server poll a second
// completion queue, so every synchronous call (GetStar, ...) paid a thread hand-off
// more: about 10-15 us of a 50 us unary call on loopback (bench/README.md, "Serving at
// the speed of the wire"). Served names: "" (the whole server) and "spokemesh.v1.Mesher";
// any other name is NOT_FOUND (Check) or SERVICE_UNKNOWN (Watch), as gRPC's own does.
//
// Watch holds one of the synchronous server's threads while it streams, so at most
// kMaxWatches run at once (RESOURCE_EXHAUSTED beyond); each ends when the client
// cancels, its deadline passes, or the server stops (stop()).
//
// Thread safety: every member may be called from any thread.
#pragma once

#include <condition_variable>
#include <mutex>

#include "grpc/health/v1/health.grpc.pb.h"

namespace spokemesh::service {

class HealthService final : public grpc::health::v1::Health::Service {
 public:
  static constexpr int kMaxWatches = 16;

  // SERVING or NOT_SERVING for every served name; Watch streams see the change.
  void set_serving(bool serving);
  // Ends every Watch stream (before the server's Shutdown, which waits for them).
  void stop();

  grpc::Status Check(grpc::ServerContext* ctx, const grpc::health::v1::HealthCheckRequest* request,
                     grpc::health::v1::HealthCheckResponse* response) override;
  grpc::Status Watch(grpc::ServerContext* ctx, const grpc::health::v1::HealthCheckRequest* request,
                     grpc::ServerWriter<grpc::health::v1::HealthCheckResponse>* writer) override;

 private:
  std::mutex mutex_;
  std::condition_variable changed_;
  bool serving_ = false;
  bool stopped_ = false;
  int watches_ = 0;
};

}  // namespace spokemesh::service
