// A small, fast client for bench/serving.py: the per-request latencies ab does not give
// at microsecond resolution, and gRPC from C++. One connection (HTTP keep-alive, or one
// gRPC channel), requests one after another; prints one JSON line.
//
//   spokemesh_serving_client http HOST:PORT TARGETS_FILE [--requests N] [--post BODY_FILE] [--accept TYPE]
//       GET each target of the file (one per line, cycled) N times, or POST the body to
//       the first target (with Accept: TYPE); reads every response whole. {"requests", "seconds",
//       "p50_us", "p99_us", "mean_us", "bytes"}
//   spokemesh_serving_client grpc HOST:PORT SET_ID --seeds N [--requests N] [--seed S]
//       GetStar of random seeds below N, one at a time.
//   spokemesh_serving_client grpc-batch HOST:PORT SET_ID --seeds N --batch B [--requests R]
//       BatchSeeds (stars) of B random seeds below N, R times.
//   spokemesh_serving_client grpc-meta HOST:PORT SET_ID [--requests N]
//       GetPointSet, one at a time: a unary call with no geometry.
//   spokemesh_serving_client grpc-floor-server HOST:PORT
//       A bare synchronous gRPC server (gRPC's defaults, no interceptors, no health
//       service) answering GetPointSet with a constant: the floor of a unary call on this
//       machine, measured by grpc-meta beside spokemesh-server as nginx is beside REST.
//
// Written here (not ab, h2load or ghz): ab reports whole milliseconds for percentiles,
// and Debian bookworm packages no gRPC load tool.
#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <boost/asio/connect.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "spokemesh/v1/mesher.grpc.pb.h"

namespace {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using Clock = std::chrono::steady_clock;

double micros(Clock::duration d) { return std::chrono::duration<double, std::micro>(d).count(); }

void report(std::vector<double> us, double seconds, std::uint64_t bytes) {
  std::sort(us.begin(), us.end());
  double sum = 0;
  for (double v : us) sum += v;
  const auto at = [&](double q) { return us.empty() ? 0.0 : us[std::min(us.size() - 1, std::size_t(q * us.size()))]; };
  std::printf(
      "{\"requests\": %zu, \"seconds\": %.6f, \"p50_us\": %.1f, \"p99_us\": %.1f, \"mean_us\": %.1f, \"bytes\": "
      "%llu}\n",
      us.size(), seconds, at(0.5), at(0.99), us.empty() ? 0.0 : sum / us.size(),
      static_cast<unsigned long long>(bytes));
}

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string option(int argc, char** argv, const char* name, const std::string& fallback) {
  for (int i = 1; i + 1 < argc; ++i) {
    if (std::strcmp(argv[i], name) == 0) return argv[i + 1];
  }
  return fallback;
}

int run_http(const std::string& address, const std::string& targets_file, int argc, char** argv) {
  std::vector<std::string> targets;
  {
    std::ifstream in(targets_file);
    for (std::string line; std::getline(in, line);) {
      if (!line.empty()) targets.push_back(line);
    }
  }
  if (targets.empty()) return std::fprintf(stderr, "no targets in %s\n", targets_file.c_str()), 2;
  const std::size_t requests = std::stoull(option(argc, argv, "--requests", "10000"));
  const std::string post_file = option(argc, argv, "--post", "");
  const std::string body = post_file.empty() ? "" : read_file(post_file);
  const std::string accept = option(argc, argv, "--accept", "");
  const std::size_t colon = address.rfind(':');
  net::io_context io;
  net::ip::tcp::resolver resolver(io);
  beast::tcp_stream stream(io);
  stream.connect(resolver.resolve(address.substr(0, colon), address.substr(colon + 1)));
  stream.socket().set_option(net::ip::tcp::no_delay(true));
  beast::flat_buffer buffer;
  std::vector<double> us;
  us.reserve(requests);
  std::uint64_t bytes = 0;
  const auto start = Clock::now();
  for (std::size_t i = 0; i < requests; ++i) {
    http::request<http::string_body> req{post_file.empty() ? http::verb::get : http::verb::post,
                                         targets[i % targets.size()], 11};
    req.set(http::field::host, address);
    req.keep_alive(true);
    if (!accept.empty()) req.set(http::field::accept, accept);
    if (!post_file.empty()) {
      req.set(http::field::content_type, "application/json");
      req.body() = body;
      req.prepare_payload();
    }
    const auto t0 = Clock::now();
    http::write(stream, req);
    http::response_parser<http::string_body> parser;
    parser.body_limit(std::uint64_t(1) << 34);
    http::read(stream, buffer, parser);
    us.push_back(micros(Clock::now() - t0));
    const auto& res = parser.get();
    if (res.result_int() != 200) {
      std::fprintf(stderr, "%s -> %u %s\n", req.target().to_string().c_str(), res.result_int(),
                   res.body().substr(0, 300).c_str());
      return 1;
    }
    bytes += res.body().size();
  }
  report(std::move(us), std::chrono::duration<double>(Clock::now() - start).count(), bytes);
  return 0;
}

enum class GrpcMode { kStar, kBatch, kMeta };

int run_grpc(const std::string& address, const std::string& set_id, GrpcMode mode, int argc, char** argv) {
  const bool batch = mode == GrpcMode::kBatch;
  const std::uint64_t n = std::stoull(option(argc, argv, "--seeds", "1000000"));
  const std::size_t requests = std::stoull(option(argc, argv, "--requests", batch ? "5" : "10000"));
  const std::size_t batch_size = std::stoull(option(argc, argv, "--batch", "10000"));
  std::mt19937_64 rng(std::stoull(option(argc, argv, "--seed", "7")));
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(-1);
  auto channel = grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args);
  auto stub = spokemesh::v1::Mesher::NewStub(channel);
  std::vector<double> us;
  std::uint64_t bytes = 0;
  const auto start = Clock::now();
  for (std::size_t i = 0; i < requests; ++i) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(600));
    const auto t0 = Clock::now();
    if (mode == GrpcMode::kMeta) {
      spokemesh::v1::GetPointSetRequest req;
      req.set_point_set_id(set_id);
      spokemesh::v1::PointSet set;
      const grpc::Status s = stub->GetPointSet(&context, req, &set);
      if (!s.ok()) return std::fprintf(stderr, "GetPointSet: %s\n", s.error_message().c_str()), 1;
      bytes += set.ByteSizeLong();
    } else if (!batch) {
      spokemesh::v1::SeedRequest req;
      req.set_point_set_id(set_id);
      req.set_seed(rng() % n);
      spokemesh::v1::Star star;
      const grpc::Status s = stub->GetStar(&context, req, &star);
      if (!s.ok()) return std::fprintf(stderr, "GetStar: %s\n", s.error_message().c_str()), 1;
      bytes += star.ByteSizeLong();
    } else {
      spokemesh::v1::BatchSeedsRequest req;
      req.set_point_set_id(set_id);
      for (std::size_t k = 0; k < batch_size; ++k) req.add_seeds(rng() % n);
      auto reader = stub->BatchSeeds(&context, req);
      spokemesh::v1::BatchSeedsResponse part;
      while (reader->Read(&part)) bytes += part.ByteSizeLong();
      const grpc::Status s = reader->Finish();
      if (!s.ok()) return std::fprintf(stderr, "BatchSeeds: %s\n", s.error_message().c_str()), 1;
    }
    us.push_back(micros(Clock::now() - t0));
  }
  report(std::move(us), std::chrono::duration<double>(Clock::now() - start).count(), bytes);
  return 0;
}

// GetPointSet answered with a constant, nothing else served.
class FloorService final : public spokemesh::v1::Mesher::Service {
  grpc::Status GetPointSet(grpc::ServerContext*, const spokemesh::v1::GetPointSetRequest* request,
                           spokemesh::v1::PointSet* response) override {
    response->set_id(request->point_set_id());
    response->set_dimension(3);
    response->set_count(1000000);
    return grpc::Status::OK;
  }
};

int run_floor_server(const std::string& address) {
  FloorService service;
  grpc::ServerBuilder builder;
  builder.AddListeningPort(address, grpc::InsecureServerCredentials());
  builder.RegisterService(&service);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (!server) return std::fprintf(stderr, "cannot listen on %s\n", address.c_str()), 1;
  server->Wait();  // until killed
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc == 3 && std::strcmp(argv[1], "grpc-floor-server") == 0) return run_floor_server(argv[2]);
  if (argc < 4) {
    std::fprintf(stderr,
                 "usage: %s http HOST:PORT TARGETS_FILE [--requests N] [--post BODY_FILE]\n"
                 "       %s grpc HOST:PORT SET_ID [--seeds N] [--requests N]\n"
                 "       %s grpc-batch HOST:PORT SET_ID [--seeds N] [--batch B] [--requests R]\n"
                 "       %s grpc-meta HOST:PORT SET_ID [--requests N]\n"
                 "       %s grpc-floor-server HOST:PORT\n",
                 argv[0], argv[0], argv[0], argv[0], argv[0]);
    return 2;
  }
  const std::string mode = argv[1];
  try {
    if (mode == "http") return run_http(argv[2], argv[3], argc, argv);
    if (mode == "grpc") return run_grpc(argv[2], argv[3], GrpcMode::kStar, argc, argv);
    if (mode == "grpc-batch") return run_grpc(argv[2], argv[3], GrpcMode::kBatch, argc, argv);
    if (mode == "grpc-meta") return run_grpc(argv[2], argv[3], GrpcMode::kMeta, argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
  std::fprintf(stderr, "unknown mode %s\n", mode.c_str());
  return 2;
}
