// Telemetry: structured logs (one JSON object per line on stderr) and Prometheus
// metrics (prometheus-cpp core; rendered by our HTTP server at /metrics).
//
// A finished request's line is written within kLogFlushEvery by a flusher thread (one
// write for many requests, off the request's path); warnings, errors and log() lines
// are written at once, after the lines before them.
//
// Thread safety: all member functions are safe to call concurrently.
#pragma once

#include <prometheus/counter.h>
#include <prometheus/family.h>
#include <prometheus/gauge.h>
#include <prometheus/histogram.h>
#include <prometheus/registry.h>

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>

#include "spokemesh/status.hpp"

namespace spokemesh::service {

class Telemetry {
 public:
  Telemetry();
  ~Telemetry();  // writes what is still buffered
  Telemetry(const Telemetry&) = delete;
  Telemetry& operator=(const Telemetry&) = delete;
  static constexpr std::chrono::milliseconds kLogFlushEvery{100};

  // {"time":..., "level":..., "message":..., extra fields...} on one line.
  void log(const std::string& level, const std::string& message);

  // One finished request: a log line and the request counter / latency histogram.
  struct Request {
    std::string transport;  // "grpc" or "http"
    std::string method;     // e.g. "GetStar"
    std::string point_set;  // may be empty
    std::optional<std::uint64_t> seed;
    Code code = Code::kOk;
    std::string message;  // the error message, if any
    double seconds = 0;
  };
  void record(const Request& r);

  void add_simplices_served(std::uint64_t n) { simplices_->Increment(static_cast<double>(n)); }
  void add_points_uploaded(std::uint64_t n) { points_->Increment(static_cast<double>(n)); }
  // store_bytes: loaded sets and trees; budget_used/budget_limit: the whole
  // --max-memory budget (sets, caches, stream windows, upload buffers).
  void set_memory(std::uint64_t store_bytes, std::size_t sets, std::uint64_t budget_used, std::uint64_t budget_limit) {
    memory_->Set(static_cast<double>(store_bytes));
    loaded_->Set(static_cast<double>(sets));
    budget_used_->Set(static_cast<double>(budget_used));
    budget_limit_->Set(static_cast<double>(budget_limit));
  }

  // Sharded serving: which shard this replica serves, the pieces it holds, and the
  // requests it handed to other shards (by shard and outcome: ok, or the error's code).
  void set_shard(std::uint32_t index, std::uint32_t count);
  void set_pieces(std::size_t pieces, std::uint64_t bytes, std::uint64_t points_from_whole) {
    pieces_->Set(static_cast<double>(pieces));
    piece_bytes_->Set(static_cast<double>(bytes));
    points_from_whole_->Set(static_cast<double>(points_from_whole));
  }
  void add_forwarded(std::uint32_t shard, Code code);

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
  prometheus::Gauge* budget_used_;
  prometheus::Gauge* budget_limit_;
  prometheus::Gauge* heap_in_use_;
  prometheus::Gauge* heap_held_;
  prometheus::Gauge* pieces_;
  prometheus::Gauge* piece_bytes_;
  prometheus::Gauge* points_from_whole_;
  prometheus::Family<prometheus::Counter>* forwarded_;
  prometheus::Family<prometheus::Gauge>* shard_;
  // One request series' metrics, found once per (transport, method, status).
  struct Series {
    prometheus::Counter* count;
    prometheus::Histogram* latency;
  };
  Series series(const std::string& transport, const std::string& method, const char* status);
  std::mutex series_mutex_;
  std::unordered_map<std::string, Series> series_;
  // Buffered log lines, written by the flusher (or at once: write_now).
  void append_log(const std::string& line, bool write_now);
  void flush_locked();
  std::mutex log_mutex_;
  std::condition_variable log_cv_;
  std::string log_buffer_;
  bool stopping_ = false;
  std::thread flusher_;
};

// Measures a request from construction; record() logs it once.
class RequestTimer {
 public:
  RequestTimer() : start_(std::chrono::steady_clock::now()) {}
  double seconds() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count(); }

 private:
  std::chrono::steady_clock::time_point start_;
};

}  // namespace spokemesh::service
