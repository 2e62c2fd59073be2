// libFuzzer target: the gRPC request handlers (service/grpc_service.cpp) as a client
// reaches them. One in-process server (MesherService over an Engine on a temporary
// data dir, with small limits and budget) holds a few point sets, 2-d to 5-d, one a
// grid, one weighted, one weighted and periodic; each input is one call:
//   byte 0        which RPC (modulo the ten methods);
//   the rest      its request message, protobuf-encoded. An empty or one-byte
//                 point_set_id is replaced by a stored set's id (so that fuzzed seeds,
//                 modes, shards and page tokens reach the geometry, not only
//                 NOT_FOUND). Bytes that do not parse as the request are sent as they
//                 are through the generic stub: the server must refuse them with
//                 INVALID_ARGUMENT (service/grpc_guards.hpp). For UploadPointSet the rest is a sequence of messages,
//                 each prefixed by its length in one byte.
// Every call has a 2 s deadline. Invariants: nothing crashes or leaks (ASan, UBSan,
// LeakSanitizer), every error carries a message, answers are well formed (a star's
// simplices come in whole simplices that contain the seed), and no byte stays charged
// to the budget after a call returns.
//
// Run with -close_fd_mask=2 (scripts/fuzz.sh does): the server logs every request.
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <future>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "auth.hpp"
#include "engine.hpp"
#include "grpc_guards.hpp"
#include "grpc_service.hpp"
#include "store.hpp"
#include "telemetry.hpp"

namespace {

using namespace spokemesh::service;
namespace fs = std::filesystem;

std::string g_dir;  // the temporary data dir, removed at exit

struct Harness {
  std::string dir;
  std::unique_ptr<Engine> engine;
  Telemetry telemetry;
  std::unique_ptr<MesherService> service;
  std::unique_ptr<grpc::Server> server;
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<pb::Mesher::Stub> stub;
  std::unique_ptr<grpc::GenericStub> generic;
  std::vector<std::string> ids;

  Harness() {
    char templ[] = "/tmp/spokemesh-fuzz-grpc-XXXXXX";
    if (::mkdtemp(templ) == nullptr) std::abort();
    dir = g_dir = templ;
    Limits limits;
    limits.max_points = 5000;
    limits.max_dimension = 12;
    limits.max_memory = 32u << 20;
    limits.stream_cache_bytes = 1u << 20;
    // No background triangulations: each call's end is checked to leave only the stored
    // sets charged (a kept triangulation stays charged with its set; test_service checks
    // that charge and its release).
    limits.keep_triangulations = false;
    auto store = PointSetStore::open(dir, limits.max_memory, nullptr);
    if (!store.is_ok()) std::abort();
    engine = std::make_unique<Engine>(std::move(store).value(), limits);
    auto auth = Authenticator::create("", "");
    if (!auth.is_ok()) std::abort();
    service = std::make_unique<MesherService>(*engine, telemetry, std::move(auth).value());
    grpc::ServerBuilder builder;
    builder.RegisterService(service.get());
    std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> interceptors;
    interceptors.push_back(std::make_unique<DecodeGuardFactory>());
    builder.experimental().SetInterceptorCreators(std::move(interceptors));
    server = builder.BuildAndStart();
    channel = server->InProcessChannel(grpc::ChannelArguments());
    stub = pb::Mesher::NewStub(channel);
    generic = std::make_unique<grpc::GenericStub>(channel);
    // The stored sets: uniform points in 2-d to 5-d, and a 6 x 6 grid (cocircular
    // quadruples everywhere: the symbolic perturbation's path).
    std::uint64_t state = 12345;
    const auto next = [&state] {
      state = state * 6364136223846793005ull + 1442695040888963407ull;
      return static_cast<double>(state >> 11) / 9007199254740992.0;
    };
    for (const auto& [n, d] : std::vector<std::pair<int, int>>{{60, 2}, {80, 3}, {50, 4}, {40, 5}}) {
      std::vector<double> coords(static_cast<std::size_t>(n * d));
      for (double& x : coords) x = next();
      ids.push_back(upload(d, coords));
    }
    std::vector<double> grid;
    for (int i = 0; i < 6; ++i) {
      for (int j = 0; j < 6; ++j) grid.insert(grid.end(), {double(i), double(j)});
    }
    ids.push_back(upload(2, grid));
    // Issue 28: a weighted 3-d set, and a weighted periodic 2-d set (offsets, hidden seeds).
    std::vector<double> coords(60 * 3), weights(60);
    for (double& x : coords) x = next();
    for (double& w : weights) w = next() * 0.02 - 0.005;
    ids.push_back(upload(3, coords, weights));
    std::vector<double> torus(70 * 2), torus_weights(70);
    for (double& x : torus) x = next();
    for (double& w : torus_weights) w = next() * 0.002;
    ids.push_back(upload(2, torus, torus_weights, {0, 0, 1, 1}));
  }

  std::string upload(int d, const std::vector<double>& coords, const std::vector<double>& weights = {},
                     const std::vector<double>& box = {}) {
    grpc::ClientContext ctx;
    pb::PointSet answer;
    auto writer = stub->UploadPointSet(&ctx, &answer);
    pb::UploadPointSetRequest m;
    m.mutable_header()->set_dimension(static_cast<std::uint32_t>(d));
    m.mutable_header()->set_count(coords.size() / static_cast<std::size_t>(d));
    m.mutable_header()->set_weighted(!weights.empty());
    m.mutable_header()->mutable_periodic_box()->Add(box.begin(), box.end());
    writer->Write(m);
    m.set_coordinates(coords.data(), coords.size() * sizeof(double));
    writer->Write(m);
    if (!weights.empty()) {
      m.set_weights(weights.data(), weights.size() * sizeof(double));
      writer->Write(m);
    }
    writer->WritesDone();
    if (!writer->Finish().ok()) std::abort();
    return answer.id();
  }
};

// Never destroyed (the server's threads outlive static destruction); its data dir is
// removed at exit.
Harness& harness() {
  static Harness* h = [] {
    auto* made = new Harness();
    std::atexit([] {
      std::error_code ignored;
      fs::remove_all(g_dir, ignored);
    });
    return made;
  }();
  return *h;
}

void expect_message(const grpc::Status& s) {
  if (!s.ok() && s.error_message().empty()) {
    std::fprintf(stderr, "status %d with no message\n", static_cast<int>(s.error_code()));
    __builtin_trap();  // every error says what and where
  }
}

void with_deadline(grpc::ClientContext& ctx) {
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
}

// A parsed request's id: one of the stored sets when it is empty or one byte.
template <class Request>
void aim(Request& r, const Harness& h) {
  if constexpr (requires { r.point_set_id(); }) {
    if (r.point_set_id().size() > 1) return;
    const std::size_t k = r.point_set_id().empty() ? 0 : static_cast<unsigned char>(r.point_set_id()[0]);
    r.set_point_set_id(h.ids[k % h.ids.size()]);
  }
}

// Raw bytes to `method` through the generic stub; the server must refuse or answer.
void send_raw(Harness& h, const char* method, const std::string& bytes) {
  grpc::ClientContext ctx;
  with_deadline(ctx);
  grpc::Slice slice(bytes);
  grpc::ByteBuffer request(&slice, 1), response;
  std::promise<grpc::Status> done;
  h.generic->UnaryCall(&ctx, method, grpc::StubOptions(), &request, &response,
                       [&done](grpc::Status s) { done.set_value(std::move(s)); });
  const grpc::Status s = done.get_future().get();
  expect_message(s);
  if (s.error_code() == grpc::StatusCode::INTERNAL) __builtin_trap();  // a bad request is the client's error
}

template <class Request, class Call>
void unary(Harness& h, const char* method, const std::string& bytes, Call call) {
  Request r;
  if (!r.ParseFromString(bytes)) return send_raw(h, method, bytes);
  aim(r, h);
  grpc::ClientContext ctx;
  with_deadline(ctx);
  expect_message(call(ctx, r));
}

template <class Request, class Reply, class Open>
void server_stream(Harness& h, const char* method, const std::string& bytes, Open open) {
  Request r;
  if (!r.ParseFromString(bytes)) return send_raw(h, method, bytes);
  aim(r, h);
  grpc::ClientContext ctx;
  with_deadline(ctx);
  auto reader = open(ctx, r);
  Reply reply;
  for (int k = 0; k < 10000 && reader->Read(&reply); ++k) {}
  ctx.TryCancel();
  expect_message(reader->Finish());
}

void upload(Harness& h, const std::uint8_t* data, std::size_t size) {
  grpc::ClientContext ctx;
  with_deadline(ctx);
  pb::PointSet answer;
  auto writer = h.stub->UploadPointSet(&ctx, &answer);
  std::size_t at = 0;
  while (at < size) {
    const std::size_t len = std::min<std::size_t>(data[at], size - at - 1);
    pb::UploadPointSetRequest m;
    if (m.ParseFromArray(data + at + 1, static_cast<int>(len)) && !writer->Write(m)) break;
    at += 1 + len;
  }
  writer->WritesDone();
  const grpc::Status s = writer->Finish();
  expect_message(s);
  if (s.ok() && answer.id().size() != 64) __builtin_trap();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  Harness& h = harness();
  const std::string rest(reinterpret_cast<const char*>(data) + 1, size - 1);
  auto& stub = *h.stub;
  switch (data[0] % 10) {
    case 0:
      upload(h, data + 1, size - 1);
      break;
    case 1:
      unary<pb::GetPointSetRequest>(h, "/spokemesh.v1.Mesher/GetPointSet", rest, [&](auto& ctx, auto& r) {
        pb::PointSet a;
        return stub.GetPointSet(&ctx, r, &a);
      });
      break;
    case 2:
      unary<pb::ListPointSetsRequest>(h, "/spokemesh.v1.Mesher/ListPointSets", rest, [&](auto& ctx, auto& r) {
        pb::ListPointSetsResponse a;
        const grpc::Status s = stub.ListPointSets(&ctx, r, &a);
        // page_size is a uint32: compared as one (a size of 2^31 or more is no limit below 1000).
        if (s.ok() && r.page_size() != 0 && static_cast<std::uint32_t>(a.point_sets_size()) > r.page_size()) {
          __builtin_trap();
        }
        return s;
      });
      break;
    case 3:
      // Deletes only what this input uploaded: the stored sets stay for the others.
      unary<pb::DeletePointSetRequest>(h, "/spokemesh.v1.Mesher/DeletePointSet", rest, [&](auto& ctx, auto& r) {
        if (std::find(h.ids.begin(), h.ids.end(), r.point_set_id()) != h.ids.end()) r.set_point_set_id("0");
        pb::DeletePointSetResponse a;
        return stub.DeletePointSet(&ctx, r, &a);
      });
      break;
    case 4:
      server_stream<pb::GetPointSetRequest, pb::CoordinateChunk>(
          h, "/spokemesh.v1.Mesher/DownloadPointSet", rest,
          [&](auto& ctx, auto& r) { return stub.DownloadPointSet(&ctx, r); });
      break;
    case 5:
      unary<pb::SeedRequest>(h, "/spokemesh.v1.Mesher/GetStar", rest, [&](auto& ctx, auto& r) {
        pb::Star a;
        const grpc::Status s = stub.GetStar(&ctx, r, &a);
        if (s.ok()) {
          const int k = static_cast<int>(a.dimension()) + 1;
          if (k < 3 || a.simplices_size() % k != 0) __builtin_trap();
          // A periodic set's offsets: d per vertex.
          if (a.offsets_size() != 0 && a.offsets_size() != a.simplices_size() * (k - 1)) __builtin_trap();
          for (int i = 0; i < a.simplices_size(); i += k) {
            const auto* first = a.simplices().data() + i;
            if (std::find(first, first + k, a.seed()) == first + k) __builtin_trap();  // the star contains its seed
          }
        }
        return s;
      });
      break;
    case 6:
      unary<pb::GetNeighborsRequest>(h, "/spokemesh.v1.Mesher/GetNeighbors", rest, [&](auto& ctx, auto& r) {
        pb::Neighbors a;
        return stub.GetNeighbors(&ctx, r, &a);
      });
      break;
    case 7:
      unary<pb::GetVoronoiCellRequest>(h, "/spokemesh.v1.Mesher/GetVoronoiCell", rest, [&](auto& ctx, auto& r) {
        pb::VoronoiCell a;
        return stub.GetVoronoiCell(&ctx, r, &a);
      });
      break;
    case 8:
      server_stream<pb::StreamCellsRequest, pb::CellBatch>(
          h, "/spokemesh.v1.Mesher/StreamCells", rest, [&](auto& ctx, auto& r) { return stub.StreamCells(&ctx, r); });
      break;
    default:
      server_stream<pb::StreamSimplicesRequest, pb::SimplexBatch>(
          h, "/spokemesh.v1.Mesher/StreamSimplices", rest,
          [&](auto& ctx, auto& r) { return stub.StreamSimplices(&ctx, r); });
      break;
  }
  // Everything a finished call held is given back: only the stored sets stay charged
  // (a cancelled stream's handler may take a moment to notice and return).
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (h.engine->store().budget().used() != h.engine->store().memory_in_use()) {
    if (std::chrono::steady_clock::now() > until) __builtin_trap();
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  return 0;
}
