#include "telemetry.hpp"

#include <prometheus/text_serializer.h>

#include <malloc.h>

#include <chrono>
#include <cstdio>
#include <ctime>
#include <nlohmann/json.hpp>

namespace spokemesh::service {
namespace {

std::string utc_now() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[80];
  std::snprintf(buf, sizeof buf, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", tm.tm_year + 1900, tm.tm_mon + 1, tm.tm_mday,
                tm.tm_hour, tm.tm_min, tm.tm_sec, static_cast<int>(ms));
  return buf;
}

}  // namespace

Telemetry::Telemetry() : registry_(std::make_shared<prometheus::Registry>()) {
  requests_ = &prometheus::BuildCounter()
                   .Name("spokemesh_requests_total")
                   .Help("Requests finished, by transport, method and status code")
                   .Register(*registry_);
  latency_ = &prometheus::BuildHistogram()
                  .Name("spokemesh_request_duration_seconds")
                  .Help("Request latency, by transport, method and status code")
                  .Register(*registry_);
  simplices_ = &prometheus::BuildCounter()
                    .Name("spokemesh_simplices_served_total")
                    .Help("Delaunay simplices sent in stars and streamed shards")
                    .Register(*registry_)
                    .Add({});
  points_ = &prometheus::BuildCounter()
                 .Name("spokemesh_points_uploaded_total")
                 .Help("Points in newly stored point sets")
                 .Register(*registry_)
                 .Add({});
  // One unlabelled gauge each.
  const auto gauge = [this](const char* name, const char* help) {
    return &prometheus::BuildGauge().Name(name).Help(help).Register(*registry_).Add({});
  };
  memory_ = gauge("spokemesh_store_memory_bytes", "Estimated bytes of point sets and k-d trees held in memory");
  loaded_ = gauge("spokemesh_store_loaded_point_sets", "Point sets held in memory");
  budget_used_ = gauge("spokemesh_memory_budget_used_bytes",
                       "Bytes charged to --max-memory: sets, trees, caches, stream windows, uploads");
  budget_limit_ = gauge("spokemesh_memory_budget_limit_bytes", "The --max-memory budget");
  // The allocator's view beside the budget's: held minus in use is free memory the
  // allocator keeps (fragmentation); in use minus the budget's used is what is not
  // charged (the process's fixed cost and small per-request answers).
  heap_in_use_ =
      gauge("spokemesh_heap_in_use_bytes", "Bytes allocated with malloc and not yet freed (glibc mallinfo2)");
  heap_held_ =
      gauge("spokemesh_heap_held_bytes", "Bytes malloc holds from the system, in use or free (glibc mallinfo2)");
  pieces_ = gauge("spokemesh_pieces_loaded", "Pieces of sharded point sets held in memory (with their trees)");
  piece_bytes_ = gauge("spokemesh_pieces_memory_bytes", "Estimated bytes of the pieces held in memory");
  forwarded_ = &prometheus::BuildCounter()
                    .Name("spokemesh_forwarded_requests_total")
                    .Help("Requests handed to a replica of another shard, by shard and outcome")
                    .Register(*registry_);
  shard_ = &prometheus::BuildGauge()
                .Name("spokemesh_shard_info")
                .Help("1, labelled with the shard this replica serves and the number of shards (0 of 0: whole sets)")
                .Register(*registry_);
}

void Telemetry::set_shard(std::uint32_t index, std::uint32_t count) {
  shard_->Add({{"shard", std::to_string(index)}, {"shards", std::to_string(count)}}).Set(1);
}

void Telemetry::add_forwarded(std::uint32_t shard, Code code) {
  forwarded_->Add({{"shard", std::to_string(shard)}, {"outcome", code == Code::kOk ? "ok" : code_name(code)}})
      .Increment();
}

void Telemetry::log(const std::string& level, const std::string& message) {
  nlohmann::json line = {{"time", utc_now()}, {"level", level}, {"message", message}};
  const std::string text = line.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
  std::lock_guard lock(log_mutex_);
  std::fwrite(text.data(), 1, text.size(), stderr);
  std::fflush(stderr);
}

void Telemetry::record(const Request& r) {
  const std::string status = code_name(r.code);
  nlohmann::json line = {{"time", utc_now()},
                         {"level", r.code == Code::kOk ? "info" : (r.code == Code::kInternal ? "error" : "warning")},
                         {"transport", r.transport},
                         {"method", r.method},
                         {"status", status},
                         {"duration_ms", r.seconds * 1e3}};
  if (!r.point_set.empty()) line["point_set"] = r.point_set;
  if (r.seed) line["seed"] = *r.seed;
  if (!r.message.empty()) line["message"] = r.message;
  const std::string text = line.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
  {
    std::lock_guard lock(log_mutex_);
    std::fwrite(text.data(), 1, text.size(), stderr);
    std::fflush(stderr);
  }
  const prometheus::Labels labels{{"transport", r.transport}, {"method", r.method}, {"status", status}};
  requests_->Add(labels).Increment();
  static const prometheus::Histogram::BucketBoundaries buckets{0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1,
                                                               0.25,   0.5,   1,      2.5,   5,    10,    30};
  latency_->Add(labels, buckets).Observe(r.seconds);
}

std::string Telemetry::render_metrics() const {
  const struct mallinfo2 heap = ::mallinfo2();
  heap_in_use_->Set(static_cast<double>(heap.uordblks + heap.hblkhd));
  heap_held_->Set(static_cast<double>(heap.arena + heap.hblkhd));
  prometheus::TextSerializer serializer;
  return serializer.Serialize(registry_->Collect());
}

}  // namespace spokemesh::service
