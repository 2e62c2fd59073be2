#include "grpc_health.hpp"

#include <chrono>
#include <string_view>

namespace spokemesh::service {
namespace {

using grpc::health::v1::HealthCheckResponse;

bool is_served(std::string_view name) { return name.empty() || name == "spokemesh.v1.Mesher"; }

}  // namespace

void HealthService::set_serving(bool serving) {
  {
    std::lock_guard lock(mutex_);
    serving_ = serving;
  }
  changed_.notify_all();
}

void HealthService::stop() {
  {
    std::lock_guard lock(mutex_);
    stopped_ = true;
  }
  changed_.notify_all();
}

grpc::Status HealthService::Check(grpc::ServerContext*, const grpc::health::v1::HealthCheckRequest* request,
                                  HealthCheckResponse* response) {
  if (!is_served(request->service())) {
    return {grpc::StatusCode::NOT_FOUND,
            "service '" + request->service() + "' is not served here (\"\" is the server)"};
  }
  std::lock_guard lock(mutex_);
  response->set_status(serving_ ? HealthCheckResponse::SERVING : HealthCheckResponse::NOT_SERVING);
  return grpc::Status::OK;
}

grpc::Status HealthService::Watch(grpc::ServerContext* ctx, const grpc::health::v1::HealthCheckRequest* request,
                                  grpc::ServerWriter<HealthCheckResponse>* writer) {
  std::unique_lock lock(mutex_);
  if (watches_ >= kMaxWatches) {
    return {grpc::StatusCode::RESOURCE_EXHAUSTED,
            "health Watch: " + std::to_string(kMaxWatches) + " streams are open already; poll Check instead"};
  }
  ++watches_;
  const bool served = is_served(request->service());
  int sent = -1;
  while (!stopped_ && !ctx->IsCancelled()) {
    const int now = !served ? HealthCheckResponse::SERVICE_UNKNOWN
                            : (serving_ ? HealthCheckResponse::SERVING : HealthCheckResponse::NOT_SERVING);
    if (now != sent) {
      HealthCheckResponse response;
      response.set_status(static_cast<HealthCheckResponse::ServingStatus>(now));
      lock.unlock();
      const bool written = writer->Write(response);
      lock.lock();
      if (!written) break;
      sent = now;
    }
    // A cancelled client is noticed within 200 ms (the sync API has no wake-up for it).
    changed_.wait_for(lock, std::chrono::milliseconds(200));
  }
  --watches_;
  return ctx->IsCancelled() ? grpc::Status::CANCELLED : grpc::Status::OK;
}

}  // namespace spokemesh::service
