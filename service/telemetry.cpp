#include "telemetry.hpp"

#include <prometheus/text_serializer.h>

#include <malloc.h>

#include <unistd.h>
#include <charconv>
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

// `text` as a JSON string: as it is when it is plain printable ASCII (ids, method names),
// else escaped by nlohmann (invalid UTF-8 replaced).
void append_json_string(std::string& out, const std::string& text) {
  for (const char ch : text) {
    if (ch < 0x20 || ch > 0x7e || ch == '"' || ch == '\\') {
      out += nlohmann::json(text).dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
      return;
    }
  }
  out += '"';
  out += text;
  out += '"';
}

}  // namespace

Telemetry::~Telemetry() {
  {
    std::lock_guard lock(log_mutex_);
    stopping_ = true;
  }
  log_cv_.notify_all();
  if (flusher_.joinable()) flusher_.join();
  std::lock_guard lock(log_mutex_);
  flush_locked();
}

void Telemetry::flush_locked() {
  std::size_t at = 0;
  while (at < log_buffer_.size()) {
    const ssize_t wrote = ::write(STDERR_FILENO, log_buffer_.data() + at, log_buffer_.size() - at);
    if (wrote <= 0) break;  // stderr closed or full: the lines are dropped, the server goes on
    at += static_cast<std::size_t>(wrote);
  }
  log_buffer_.clear();
}

void Telemetry::append_log(const std::string& line, bool write_now) {
  std::lock_guard lock(log_mutex_);
  log_buffer_ += line;
  if (write_now || log_buffer_.size() > (64u << 10)) {
    flush_locked();
  } else if (!flusher_.joinable()) {
    flusher_ = std::thread([this] {
      std::unique_lock guard(log_mutex_);
      while (!stopping_) {
        log_cv_.wait_for(guard, kLogFlushEvery);
        flush_locked();
      }
    });
  }
}

Telemetry::Series Telemetry::series(const std::string& transport, const std::string& method, const char* status) {
  std::string key = transport;
  key += '\0';
  key += method;
  key += '\0';
  key += status;
  std::lock_guard lock(series_mutex_);
  if (const auto it = series_.find(key); it != series_.end()) return it->second;
  static const prometheus::Histogram::BucketBoundaries buckets{0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1,
                                                               0.25,   0.5,   1,      2.5,   5,    10,    30};
  const prometheus::Labels labels{{"transport", transport}, {"method", method}, {"status", status}};
  const Series made{&requests_->Add(labels), &latency_->Add(labels, buckets)};
  series_.emplace(std::move(key), made);
  return made;
}

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
  points_from_whole_ =
      gauge("spokemesh_point_queries_from_whole_set",
            "Point queries (:locate, :interpolate) on sets kept as pieces that no piece held what they "
            "rest on, answered from the set's own file, since start");
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
  append_log(line.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace) + "\n", true);
}

void Telemetry::record(const Request& r) {
  const char* status = code_name(r.code);
  const char* level = r.code == Code::kOk ? "info" : (r.code == Code::kInternal ? "error" : "warning");
  // The line by hand, keys in order as the other lines' (a request's cost is a few
  // microseconds; building a JSON document for its log line was one of the larger).
  std::string line;
  line.reserve(256);
  char number[32];
  line += "{\"duration_ms\":";
  line.append(number, std::to_chars(number, number + sizeof number, r.seconds * 1e3).ptr);
  line += ",\"level\":\"";
  line += level;
  line += '"';
  if (!r.message.empty()) {
    line += ",\"message\":";
    append_json_string(line, r.message);
  }
  line += ",\"method\":";
  append_json_string(line, r.method);
  if (!r.point_set.empty()) {
    line += ",\"point_set\":";
    append_json_string(line, r.point_set);
  }
  if (r.seed) {
    line += ",\"seed\":";
    line.append(number, std::to_chars(number, number + sizeof number, *r.seed).ptr);
  }
  line += ",\"status\":\"";
  line += status;
  line += "\",\"time\":\"";
  line += utc_now();
  line += "\",\"transport\":";
  append_json_string(line, r.transport);
  line += "}\n";
  append_log(line, r.code != Code::kOk);
  const Series s = series(r.transport, r.method, status);
  s.count->Increment();
  s.latency->Observe(r.seconds);
}

std::string Telemetry::render_metrics() const {
  const struct mallinfo2 heap = ::mallinfo2();
  heap_in_use_->Set(static_cast<double>(heap.uordblks + heap.hblkhd));
  heap_held_->Set(static_cast<double>(heap.arena + heap.hblkhd));
  prometheus::TextSerializer serializer;
  return serializer.Serialize(registry_->Collect());
}

}  // namespace spokemesh::service
