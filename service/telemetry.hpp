// Telemetry: structured logs (one JSON object per line on stderr) and Prometheus
// metrics (prometheus-cpp core; rendered by our HTTP server at /metrics).
//
// Thread safety: all member functions are safe to call concurrently.
#pragma once

#include <prometheus/counter.h>
#include <prometheus/family.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>

#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "spokemesh/status.hpp"

namespace spokemesh::service {

class Telemetry {
 public:
  Telemetry();

  // {"time":..., "level":..., "message":..., extra fields...} on one line.
  void log(const std::string& level, const std::string& message);

  // One finished request: a log line and the request counter / latency histogram.
  struct Request {
    std::string transport;  // "grpc" or "http"
    std::string method;     // e.g. "GetStar"
    std::string point_set;  // may be empty
    std::optional<std::uint64_t> seed;
    Code code = Code::kOk;
    std::string message;    // the error message, if any
    double seconds = 0;
  };
  void record(const Request& r);

  void add_simplices_served(std::uint64_t n) { simplices_->Increment(static_cast<double>(n)); }
  void add_points_uploaded(std::uint64_t n) { points_->Increment(static_cast<double>(n)); }
  void set_memory(std::uint64_t bytes, std::size_t sets) {
    memory_->Set(static_cast<double>(bytes));
    loaded_->Set(static_cast<double>(sets));
  }

  // The Prometheus text exposition of every metric.
  std::string render_metrics() const;

 private:
  std::shared_ptr<prometheus::Registry> registry_;
  prometheus::Family<prometheus::Counter>* requests_;
  prometheus::Family<prometheus::Histogram>* latency_;
  prometheus::Counter* simplices_;
  prometheus::Counter* points_;
  prometheus::Gauge* memory_;
  prometheus::Gauge* loaded_;
  std::mutex log_mutex_;
};

// Measures a request from construction; record() logs it once.
class RequestTimer {
 public:
  RequestTimer() : start_(std::chrono::steady_clock::now()) {}
  double seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  std::chrono::steady_clock::time_point start_;
};

}  // namespace spokemesh::service
