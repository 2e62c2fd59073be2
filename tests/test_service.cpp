// In-process tests of the service layer: the store (durability layout, verification,
// quarantine, memory budget, a data dir shared by two stores), the Engine (limits,
// every error, deadlines, cancellation, shards), the REST handler as a pure function,
// and the gRPC service on a real server in this process.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <openssl/sha.h>
#include <unistd.h>

#include <boost/beast/core.hpp>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "engine.hpp"
#include "grpc/health/v1/health.grpc.pb.h"
#include "grpc_health.hpp"
#include "grpc_service.hpp"
#include "http_api.hpp"
#include "http_server.hpp"
#include "inputs.hpp"  // bench/: the shape families
#include "spokemesh/mesh.hpp"
#include "spokemesh/periodic.hpp"
#include "spokemesh/periodic_cells.hpp"
#include "support.hpp"

namespace spokemesh::service {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using spokemesh::testing::uniform_points;

// A fresh data directory per test, removed afterwards.
class TempDir {
 public:
  TempDir() {
    char tmpl[] = "/tmp/spokemesh-test-XXXXXX";
    path_ = ::mkdtemp(tmpl);
  }
  ~TempDir() { fs::remove_all(path_); }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

std::string sha256_hex(const std::string& bytes) {
  unsigned char md[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(bytes.data()), bytes.size(), md);
  char hex[2 * SHA256_DIGEST_LENGTH + 1];
  for (int i = 0; i < SHA256_DIGEST_LENGTH; ++i) std::snprintf(hex + 2 * i, 3, "%02x", md[i]);
  return hex;
}

std::string raw_bytes(int d, const std::vector<double>& coords) {
  return point_set_header_bytes(static_cast<std::uint32_t>(d), coords.size() / d) +
         std::string(reinterpret_cast<const char*>(coords.data()), coords.size() * 8);
}

// The authenticator of a server run with --auth-token-file holding `token` ("" = open).
std::shared_ptr<const Authenticator> token_auth(const std::string& token) {
  return Authenticator::create("", token).value();
}

std::unique_ptr<Engine> make_engine(const std::string& dir, Limits limits = {}) {
  auto store = PointSetStore::open(dir, limits.max_memory, {});
  EXPECT_TRUE(store.is_ok()) << store.status().message();
  return std::make_unique<Engine>(std::move(store).value(), limits);
}

UploadHeader header_of(std::int64_t d, std::int64_t n, std::string name) {
  UploadHeader h;
  h.dimension = d;
  h.count = n;
  h.display_name = std::move(name);
  return h;
}

Result<PointSetInfo> upload(Engine& engine, int d, const std::vector<double>& coords, const std::string& name = "") {
  auto session = engine.begin_upload(header_of(d, static_cast<std::int64_t>(coords.size() / d), name));
  if (!session.is_ok()) return session.status();
  // In uneven chunks, as a client may send them.
  const char* bytes = reinterpret_cast<const char*>(coords.data());
  const std::size_t total = coords.size() * 8;
  for (std::size_t at = 0; at < total; at += 1000) {
    if (Status s = session.value()->append(bytes + at, std::min<std::size_t>(1000, total - at)); !s.is_ok()) return s;
  }
  return engine.finish_upload(*session.value());
}

CallControl no_deadline() { return CallControl(Clock::now() + std::chrono::hours(1)); }

// One batch of stars' answers, in order (a failed batch fails the test).
std::vector<BatchAnswer> batch_stars(Engine& engine, const std::string& id, const std::vector<std::uint64_t>& seeds,
                                     const CallControl& control) {
  std::vector<BatchAnswer> answers;
  EXPECT_TRUE(engine
                  .batch(id, seeds, BatchKind::kStars, {}, {}, control,
                         [&](std::span<const BatchAnswer> got, std::size_t) {
                           answers.insert(answers.end(), got.begin(), got.end());
                           return Status::ok();
                         })
                  .is_ok());
  return answers;
}

TEST(Store, Sha256MatchesOpenSslOneShot) {
  Sha256 sha;
  sha.update("ab", 2);
  sha.update("c", 1);
  EXPECT_EQ(sha.hex_digest(), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
}

TEST(Store, UploadStoresExactlyTheHashedBytesAndIsIdempotent) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  const auto coords = uniform_points(3, 500, 1);
  auto first = upload(*engine, 3, coords, "ball");
  ASSERT_TRUE(first.is_ok()) << first.status().message();
  EXPECT_FALSE(first->already_existed);
  EXPECT_EQ(first->id, sha256_hex(raw_bytes(3, coords)));
  std::ifstream in(dir.path() + "/" + first->id + ".points", std::ios::binary);
  const std::string stored((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(stored, raw_bytes(3, coords));
  auto again = upload(*engine, 3, coords, "other name");
  ASSERT_TRUE(again.is_ok());
  EXPECT_TRUE(again->already_existed);
  EXPECT_EQ(again->id, first->id);
  EXPECT_EQ(again->display_name, "ball");  // the first upload's name stays
  // No temporary files are left behind.
  for (const auto& e : fs::directory_iterator(dir.path())) {
    EXPECT_NE(e.path().filename().string().rfind(".tmp-", 0), 0u) << e.path();
  }
}

TEST(Store, UploadErrorsNameTheFieldAndLeaveNothingBehind) {
  TempDir dir;
  Limits limits;
  limits.max_points = 1000;
  limits.max_dimension = 4;
  auto engine = make_engine(dir.path(), limits);
  auto expect = [&](Code code, const std::string& fragment, auto&& run) {
    const Status s = run();
    EXPECT_EQ(s.code(), code) << s.message();
    EXPECT_NE(s.message().find(fragment), std::string::npos) << s.message();
  };
  expect(Code::kInvalidArgument, "dimension: 1", [&] { return engine->begin_upload(header_of(1, 10, "")).status(); });
  expect(Code::kResourceExhausted, "--max-dimension=4",
         [&] { return engine->begin_upload(header_of(5, 10, "")).status(); });
  expect(Code::kResourceExhausted, "--max-points=1000",
         [&] { return engine->begin_upload(header_of(2, 1001, "")).status(); });
  expect(Code::kInvalidArgument, "count: 2", [&] { return engine->begin_upload(header_of(2, 2, "")).status(); });
  expect(Code::kInvalidArgument, "display_name",
         [&] { return engine->begin_upload(header_of(2, 3, std::string(300, 'x'))).status(); });
  // Byte counts: too many is refused at once, too few at the end.
  {
    auto s = engine->begin_upload(header_of(2, 3, ""));
    ASSERT_TRUE(s.is_ok());
    std::vector<double> seven(7, 0.5);
    expect(Code::kInvalidArgument, "more than the 48 bytes", [&] { return s.value()->append(seven.data(), 56); });
    auto t = engine->begin_upload(header_of(2, 3, ""));
    // An empty chunk first (found by fuzz_grpc_requests: memcpy into an empty buffer).
    ASSERT_TRUE(t.value()->append(nullptr, 0).is_ok());
    ASSERT_TRUE(t.value()->append(seven.data(), 40).is_ok());
    expect(Code::kInvalidArgument, "received 40 bytes", [&] { return engine->finish_upload(*t.value()).status(); });
  }
  std::vector<double> c = {0, 0, 1, 0, 0, 1, 1, 1};
  c[5] = std::nan("");
  expect(Code::kInvalidArgument, "point 2, coordinate 1", [&] { return upload(*engine, 2, c).status(); });
  c[5] = INFINITY;
  expect(Code::kInvalidArgument, "point 2, coordinate 1", [&] { return upload(*engine, 2, c).status(); });
  expect(Code::kInvalidArgument, "points 0 and 3", [&] {
    return upload(*engine, 2, {0, 0, 1, 0, 0, 1, 0, 0}).status();
  });
  expect(Code::kInvalidArgument, "span only a 1", [&] {
    return upload(*engine, 2, {0, 0, 1, 1, 2, 2, 3, 3}).status();
  });
  for (const auto& e : fs::directory_iterator(dir.path())) EXPECT_TRUE(e.is_directory()) << e.path();
}

TEST(Store, CorruptFilesAreQuarantinedAndOthersKeepWorking) {
  TempDir dir;
  std::string good, bad;
  {
    auto engine = make_engine(dir.path());
    good = upload(*engine, 2, uniform_points(2, 100, 1)).value().id;
    bad = upload(*engine, 2, uniform_points(2, 100, 2)).value().id;
  }
  {  // Flip one byte of `bad`'s coordinates.
    std::fstream f(dir.path() + "/" + bad + ".points", std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(40);
    f.put('\x7f');
  }
  std::vector<std::string> logs;
  auto store =
      PointSetStore::open(dir.path(), 1 << 30, [&](const std::string&, const std::string& m) { logs.push_back(m); });
  ASSERT_TRUE(store.is_ok());
  EXPECT_EQ(store.value()->load_all(), 1u);
  ASSERT_EQ(logs.size(), 1u);
  EXPECT_NE(logs[0].find(bad), std::string::npos);
  EXPECT_NE(logs[0].find("quarantined"), std::string::npos);
  EXPECT_EQ(store.value()->get(bad).status().code(), Code::kNotFound);
  EXPECT_TRUE(store.value()->get(good).is_ok());
  EXPECT_FALSE(fs::exists(dir.path() + "/" + bad + ".points"));
  EXPECT_FALSE(fs::is_empty(dir.path() + "/quarantine"));
}

TEST(Store, TruncatedFileFoundLazilyIsQuarantined) {
  TempDir dir;
  std::string id;
  {
    auto engine = make_engine(dir.path());
    id = upload(*engine, 3, uniform_points(3, 50, 3)).value().id;
  }
  fs::resize_file(dir.path() + "/" + id + ".points", 100);
  auto engine = make_engine(dir.path());
  const auto control = no_deadline();
  const auto star = engine->star(id, 0, control);
  EXPECT_EQ(star.status().code(), Code::kNotFound);
  EXPECT_NE(star.status().message().find("quarantined"), std::string::npos);
}

TEST(Store, SharedDataDirServesUploadsAndDeletesOfOtherReplicas) {
  TempDir dir;
  auto a = make_engine(dir.path());
  auto b = make_engine(dir.path());
  const auto coords = uniform_points(2, 300, 4);
  const std::string id = upload(*a, 2, coords).value().id;
  const auto control = no_deadline();
  auto sa = a->star(id, 7, control);
  auto sb = b->star(id, 7, control);  // b loads it lazily from disk
  ASSERT_TRUE(sa.is_ok() && sb.is_ok());
  EXPECT_EQ(sa->star.simplices, sb->star.simplices);
  EXPECT_EQ(sa->circumcentres, sb->circumcentres);
  for (int asked = 0; asked < 3; ++asked) ASSERT_TRUE(a->star(id, 7, control).is_ok());  // a's file check kept
  ASSERT_TRUE(b->delete_point_set(id).is_ok());
  EXPECT_EQ(a->star(id, 7, control).status().code(), Code::kNotFound);
  EXPECT_EQ(a->get_point_set(id).status().code(), Code::kNotFound);
  EXPECT_FALSE(a->hold_at_hand(id, 7));
  // Uploaded again through b (a new file, the same id): a answers it again, and a
  // second delete is seen as the first was.
  ASSERT_EQ(upload(*b, 2, coords).value().id, id);
  auto again = a->star(id, 7, control);
  ASSERT_TRUE(again.is_ok()) << again.status().message();
  EXPECT_EQ(again->star.simplices, sa->star.simplices);
  ASSERT_TRUE(b->delete_point_set(id).is_ok());
  EXPECT_EQ(a->star(id, 7, control).status().code(), Code::kNotFound);
}

TEST(MemoryBudget, HeapTrimmerTrimsAfterChurnOnlyAndStops) {
  MemoryBudget budget(64u << 20);
  HeapTrimmer trimmer(budget, std::chrono::milliseconds(10), 1u << 20);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(trimmer.trims(), 0u);                 // idle: nothing released, nothing to do
  { auto charge = budget.try_charge(2u << 20); }  // 2 MB charged and given back
  EXPECT_EQ(budget.released(), 2u << 20);
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (trimmer.trims() == 0 && std::chrono::steady_clock::now() < until) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_EQ(trimmer.trims(), 1u);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  EXPECT_EQ(trimmer.trims(), 1u);  // once per churn, not on every wake-up
}  // the destructor stops and joins its thread

TEST(Store, MemoryBudgetDropsLeastRecentlyUsedButKeepsThemOnDisk) {
  TempDir dir;
  Limits limits;
  limits.max_memory = estimated_memory(1000, 2) * 2 + 10;  // room for two sets
  // (Their triangulations would take room too, as they are built in the background.)
  limits.keep_triangulations = false;
  auto engine = make_engine(dir.path(), limits);
  std::vector<std::string> ids;
  for (int k = 0; k < 4; ++k) ids.push_back(upload(*engine, 2, uniform_points(2, 1000, 10 + k)).value().id);
  // An upload is stored, not loaded: memory is spent when a set is first queried.
  EXPECT_EQ(engine->store().loaded_count(), 0u);
  EXPECT_EQ(engine->store().memory_in_use(), 0u);
  const auto control = no_deadline();
  for (const auto& id : ids) EXPECT_TRUE(engine->star(id, 0, control).is_ok()) << id;
  EXPECT_EQ(engine->store().loaded_count(), 2u);
  EXPECT_LE(engine->store().memory_in_use(), limits.max_memory);
  EXPECT_EQ(engine->begin_upload(header_of(2, 1000000, "")).status().code(), Code::kResourceExhausted);
}

TEST(Store, ListPaginatesInIdOrder) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  std::vector<std::string> ids;
  for (int k = 0; k < 5; ++k) ids.push_back(upload(*engine, 2, uniform_points(2, 10, 100 + k)).value().id);
  std::sort(ids.begin(), ids.end());
  std::vector<std::string> seen;
  std::string token;
  int pages = 0;
  do {
    std::string next;
    auto page = engine->list_point_sets(2, token, &next);
    ASSERT_TRUE(page.is_ok());
    for (const auto& p : page.value()) seen.push_back(p.id);
    token = next;
    ++pages;
  } while (!token.empty());
  EXPECT_EQ(seen, ids);
  EXPECT_EQ(pages, 3);
  // AIP-158: above the maximum page size, the maximum (all 5 sets fit).
  EXPECT_EQ(engine->list_point_sets(5000, "", nullptr).value().size(), ids.size());
  EXPECT_EQ(engine->list_point_sets(2, "junk", nullptr).status().code(), Code::kInvalidArgument);
}

TEST(Engine, AnswersEqualTheCoreAndShardsUniteToTheMesh) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  const auto coords = uniform_points(3, 2000, 5);
  const std::string id = upload(*engine, 3, coords).value().id;
  PointSet ps(3, coords);
  ASSERT_TRUE(ps.validate("test").is_ok());
  KdTree tree(ps);
  StarWalker walker(tree);
  const auto control = no_deadline();
  for (std::uint32_t seed : {0u, 17u, 1999u}) {
    Star expected;
    ASSERT_TRUE(walker.compute(seed, expected).is_ok());
    auto got = engine->star(id, seed, control);
    ASSERT_TRUE(got.is_ok());
    EXPECT_EQ(got->star.simplices, expected.simplices);
    EXPECT_EQ(got->circumcentres.size(), expected.size() * 3);
    EXPECT_EQ(engine->neighbors(id, seed, {}, control).value().neighbors, star_neighbors(expected));
    EXPECT_EQ(engine->cell(id, seed, {}, control).value().facets.size(), star_neighbors(expected).size());
  }
  std::vector<std::uint32_t> whole;
  ASSERT_TRUE(mesh_seeds(tree, {}, [&](std::span<const std::uint32_t> b, std::uint64_t) {
                whole.insert(whole.end(), b.begin(), b.end());
                return Status::ok();
              }).is_ok());
  for (std::uint32_t shards : {1u, 3u, 7u}) {
    std::vector<std::uint32_t> united;
    std::uint32_t next_seed = 0;
    for (std::uint32_t k = 0; k < shards; ++k) {
      StreamPart range;
      std::size_t batches = 0;
      Status s = engine->stream_simplices(
          id, k, shards, 100, control,
          [&](std::span<const std::uint32_t> b, std::span<const std::int32_t>, std::uint64_t) {
            EXPECT_LE(b.size(), 400u);
            ++batches;
            united.insert(united.end(), b.begin(), b.end());
            return Status::ok();
          },
          &range);
      ASSERT_TRUE(s.is_ok()) << s.message();
      EXPECT_EQ(range.begin, next_seed);
      EXPECT_GE(batches, 1u);
      next_seed = range.end;
    }
    EXPECT_EQ(next_seed, 2000u);
    // Shards are parts of the sweep: in order, they are the whole run, byte for byte.
    EXPECT_EQ(united, whole) << shards << " shards";
  }
  EXPECT_EQ(engine->stream_simplices(id, 3, 3, 0, control, {}).code(), Code::kInvalidArgument);
  EXPECT_EQ(engine->stream_simplices(id, 0, 1, 70000, control, {}).code(), Code::kInvalidArgument);
}

TEST(Engine, HighDimensionalSetsServeApproximateNeighboursAndRefuseExactWork) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  const auto coords = uniform_points(12, 300, 8);
  auto info = upload(*engine, 12, coords);
  ASSERT_TRUE(info.is_ok()) << info.status().message();
  const auto control = no_deadline();
  const Status star = engine->star(info->id, 0, control).status();
  EXPECT_EQ(star.code(), Code::kResourceExhausted);
  EXPECT_NE(star.message().find("APPROXIMATE"), std::string::npos) << star.message();
  EXPECT_EQ(engine->neighbors(info->id, 0, {}, control).status().code(), Code::kResourceExhausted);
  EXPECT_EQ(engine->stream_simplices(info->id, 0, 1, 0, control, {}).code(), Code::kResourceExhausted);
  NeighborQuery q;
  q.mode = NeighborQuery::Mode::kApproximate;
  q.max_consecutive_misses = 20;
  auto a = engine->neighbors(info->id, 0, q, control);
  ASSERT_TRUE(a.is_ok()) << a.status().message();
  EXPECT_FALSE(a->exact);
  EXPECT_FALSE(a->neighbors.empty());
  // A second engine on the same data dir (a replica) gives the same answer.
  auto replica = make_engine(dir.path());
  EXPECT_EQ(replica->neighbors(info->id, 0, q, control).value().neighbors, a->neighbors);
}

// A simplex stream charges its budget for what its seeds share: in 2-d and 3-d its
// local triangulations as they grow (a region per worker: one 16 MiB step for a small
// set); in 4-d the sweep's memo, the front's mail at an estimate of the front plus the
// workers' block tables (a few MB for a small set, not a table for the whole run).
// Nothing with --stream-cache 0, and the same rows.
TEST(Engine, SimplexStreamsChargeWhatTheySeedsShare) {
  for (const int d : {3, 4}) {
    std::vector<std::uint32_t> rows_with_cache;
    for (const std::size_t cap : {std::size_t{256} << 20, std::size_t{0}}) {
      SCOPED_TRACE("d " + std::to_string(d) + ", stream cache " + std::to_string(cap));
      TempDir dir;
      Limits limits;
      limits.stream_cache_bytes = cap;
      auto engine = make_engine(dir.path(), limits);
      const std::string id = upload(*engine, d, uniform_points(d, d == 3 ? 2000 : 600, 8)).value().id;
      const auto control = no_deadline();
      std::uint64_t during = 0;
      std::vector<std::uint32_t> rows;
      auto stream = [&] {
        rows.clear();
        return engine->stream_simplices(
            id, 0, 1, 0, control, [&](std::span<const std::uint32_t> b, std::span<const std::int32_t>, std::uint64_t) {
              during = std::max(during, engine->store().budget().used());
              rows.insert(rows.end(), b.begin(), b.end());
              return Status::ok();
            });
      };
      ASSERT_TRUE(stream().is_ok());  // loads the set and its tree, which stay charged
      const std::uint64_t before = engine->store().budget().used();
      during = 0;
      ASSERT_TRUE(stream().is_ok());
      const std::uint64_t shared = during - before - kStreamWindowBytes;
      if (cap == 0) {
        EXPECT_EQ(shared, 0u);
        EXPECT_EQ(rows, rows_with_cache) << "the same rows without the shared work";
      } else {
        EXPECT_GT(shared, 0u) << "a small set's stream shares nothing";
        EXPECT_LE(shared, std::uint64_t{16} << 20) << "charged like a run-wide table";
        rows_with_cache = rows;
      }
      EXPECT_EQ(engine->store().budget().used(), before) << "the charge outlives the stream";
    }
  }
}

// A batch of many seeds computes their stars together (the whole mesh's local
// triangulations, restricted to them): each answer equals the single call's, on the
// shapes whose stars reach far (points on a sphere, contour lines), repeats included.
TEST(Engine, BatchesOfStarsEqualSingleCalls) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  const auto control = no_deadline();
  for (const auto& [d, coords] :
       {std::pair{3, bench::sphere_surface(800, 3)}, std::pair{2, bench::contours(5, 0.5, 4)}}) {
    SCOPED_TRACE(d);
    const std::string id = upload(*engine, d, coords).value().id;
    std::vector<std::uint64_t> seeds;
    for (std::uint64_t s = 1; s < coords.size() / d; s += 9) seeds.push_back(s);
    seeds.push_back(1);
    for (const BatchKind kind : {BatchKind::kStars, BatchKind::kNeighbors, BatchKind::kCells}) {
      std::vector<BatchAnswer> answers;
      ASSERT_TRUE(engine
                      ->batch(id, seeds, kind, {}, {}, control,
                              [&](std::span<const BatchAnswer> got, std::size_t) {
                                answers.insert(answers.end(), got.begin(), got.end());
                                return Status::ok();
                              })
                      .is_ok());
      ASSERT_EQ(answers.size(), seeds.size());
      for (std::size_t i = 0; i < seeds.size(); ++i) {
        ASSERT_EQ(answers[i].seed, seeds[i]);
        if (kind == BatchKind::kStars) {
          const auto one = engine->star(id, seeds[i], control).value();
          EXPECT_EQ(answers[i].star.star.simplices, one.star.simplices) << "seed " << seeds[i];
          EXPECT_EQ(answers[i].star.circumcentres, one.circumcentres) << "seed " << seeds[i];
        } else if (kind == BatchKind::kNeighbors) {
          EXPECT_EQ(answers[i].neighbors.neighbors, engine->neighbors(id, seeds[i], {}, control).value().neighbors);
        } else {
          const VoronoiCell one = engine->cell(id, seeds[i], {}, control).value();
          EXPECT_EQ(answers[i].cell.facets.size(), one.facets.size());
          EXPECT_EQ(answers[i].cell.vertices, one.vertices);
        }
      }
    }
  }
}

// On a closed surface a batch's stars need the triangulation of every point (its
// Delaunay balls reach across the set); the set keeps it, charged to the budget, and
// later batches read it instead of building it again: the same answers, nothing more
// charged, and the charge goes with the set.
TEST(Engine, BatchesKeepTheTriangulationOfAClosedSurface) {
  TempDir dir;
  Limits limits;
  limits.keep_triangulations = false;  // the batch's own, not the background build's
  auto engine = make_engine(dir.path(), limits);
  const auto control = no_deadline();
  const std::size_t n = 70000;  // more than a 3-d region's points, so regions are tried first
  const std::string id = upload(*engine, 3, bench::sphere_surface(n, 11)).value().id;
  std::vector<std::uint64_t> seeds;
  // An eighth of the points: more than a sixteenth of every region, so no region walks
  // its seeds' stars (on a sphere each walk asks about the whole set).
  for (std::uint64_t s = 5; s < n; s += 8) seeds.push_back(s);
  ASSERT_TRUE(engine->star(id, 0, control).is_ok());  // loaded, tree built
  const MemoryBudget& budget = engine->store().budget();
  const std::uint64_t loaded = budget.used();
  auto batch = [&] { return batch_stars(*engine, id, seeds, control); };
  const std::vector<BatchAnswer> first = batch();
  const std::uint64_t kept = budget.used() - loaded;
  EXPECT_GT(kept, n * 40) << "the triangulation of every point is kept with the set, charged";
  const std::vector<BatchAnswer> second = batch();
  EXPECT_EQ(budget.used(), loaded + kept) << "read, not built again";
  ASSERT_EQ(first.size(), seeds.size());
  ASSERT_EQ(second.size(), seeds.size());
  for (std::size_t i = 0; i < seeds.size(); ++i) {
    EXPECT_EQ(second[i].star.star.simplices, first[i].star.star.simplices) << "seed " << seeds[i];
    EXPECT_EQ(second[i].star.circumcentres, first[i].star.circumcentres) << "seed " << seeds[i];
  }
  for (std::size_t i = 0; i < seeds.size(); i += seeds.size() / 2) {
    EXPECT_EQ(second[i].star.star.simplices, engine->star(id, seeds[i], control).value().star.simplices);
  }
  // A stream of the set's simplices in two shards reads the kept triangulation too:
  // the whole mesh's bytes, nothing more charged.
  const PointSet points = testing::make_points(3, bench::sphere_surface(n, 11));
  const testing::Simplices expected = testing::mesh_rows(points, MeshOptions{});
  testing::Simplices streamed;
  for (std::uint32_t k = 0; k < 2; ++k) {
    ASSERT_TRUE(
        engine
            ->stream_simplices(id, k, 2, 4096, control,
                               [&](std::span<const std::uint32_t> b, std::span<const std::int32_t>, std::uint64_t) {
                                 streamed.insert(streamed.end(), b.begin(), b.end());
                                 return Status::ok();
                               })
            .is_ok());
  }
  EXPECT_EQ(streamed, expected);
  EXPECT_EQ(budget.used(), loaded + kept);
  ASSERT_TRUE(engine->delete_point_set(id).is_ok());
  EXPECT_LT(budget.used(), loaded) << "the kept triangulation goes with the set";
}

// The set's triangulation of every point, built in the background after its first
// request and kept with it (charged; gone with the set): single star, neighbour and
// cell requests (unclipped, in a box, in halfspaces) and batches then read it, and
// answer exactly what walked stars answer, on a closed surface, a scan, and a grid.
// A set made by an append to a set that holds its triangulation gets its own from the
// parent's (copied, the new points inserted: not built again), and its per-seed answers
// are the walked ones, the new points' included.
TEST(Engine, AnAppendedSetExtendsItsParentsTriangulation) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  const auto control = no_deadline();
  const std::vector<double> parent_coords = bench::sphere_surface(5000, 21), added = bench::sphere_surface(60, 22);
  const std::string parent_id = upload(*engine, 3, parent_coords).value().id;
  auto wait_for_whole = [](const std::shared_ptr<const StoredSet>& set) {
    for (int wait = 0; wait < 600 && set->kept_whole() == nullptr; ++wait) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    return set->kept_whole() != nullptr;
  };
  ASSERT_TRUE(engine->star(parent_id, 0, control).is_ok());
  auto parent = engine->point_set(parent_id).value();
  ASSERT_TRUE(wait_for_whole(parent)) << "the parent's triangulation was not built";
  auto session = engine->begin_append(parent_id, header_of(3, 60, ""));
  ASSERT_TRUE(session.is_ok()) << session.status().message();
  ASSERT_TRUE(session.value()->append(added.data(), added.size() * 8).is_ok());
  const auto child = engine->finish_upload(*session.value());
  ASSERT_TRUE(child.is_ok()) << child.status().message();
  ASSERT_TRUE(engine->star(child->id, 0, control).is_ok());
  auto set = engine->point_set(child->id).value();
  ASSERT_TRUE(wait_for_whole(set)) << "the appended set's triangulation was not built";
  EXPECT_EQ(engine->triangulations_extended(), 1U) << "built from its parent's";
  std::vector<double> all = parent_coords;
  all.insert(all.end(), added.begin(), added.end());
  const PointSet points = testing::make_points(3, all);
  const KdTree tree(points);
  StarWalker walker(tree);
  Star star;
  for (std::uint32_t seed = 0; seed < points.size(); seed += seed < 5000 ? 97 : 1) {
    ASSERT_TRUE(walker.compute(seed, star).is_ok());
    const auto answer = engine->star(child->id, seed, control);
    ASSERT_TRUE(answer.is_ok());
    EXPECT_EQ(answer->star.simplices, star.simplices) << "seed " << seed;
  }
}

TEST(Engine, PerSeedAnswersFromTheKeptTriangulationAreTheWalkedOnes) {
  struct Case {
    std::string name;
    int d;
    std::vector<double> coords;
  };
  const std::vector<Case> cases = {{"sphere", 3, bench::sphere_surface(6000, 12)},
                                   {"grid", 3, testing::grid_points(3, 14)},
                                   {"uniform-2d", 2, uniform_points(2, 5000, 13)}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    TempDir dir;
    auto engine = make_engine(dir.path());
    const auto control = no_deadline();
    const std::string id = upload(*engine, c.d, c.coords).value().id;
    const MemoryBudget& budget = engine->store().budget();
    ASSERT_TRUE(engine->star(id, 0, control).is_ok());  // loaded; its triangulation asked for
    auto set = engine->point_set(id).value();
    for (int wait = 0; wait < 600 && set->kept_whole() == nullptr; ++wait) {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    ASSERT_NE(set->kept_whole(), nullptr) << "the triangulation was not built";
    EXPECT_GE(budget.used(), set->kept_whole()->bytes()) << "charged";
    // The reference: walked stars over the same points.
    const PointSet points = testing::make_points(c.d, c.coords);
    const KdTree tree(points);
    StarWalker walker(tree);
    std::vector<double> lo(points.point(0), points.point(0) + c.d), hi = lo;
    for (std::size_t i = 0; i < points.size(); ++i) {
      for (int k = 0; k < c.d; ++k) {
        lo[static_cast<std::size_t>(k)] = std::min(lo[static_cast<std::size_t>(k)], points.point(i)[k]);
        hi[static_cast<std::size_t>(k)] = std::max(hi[static_cast<std::size_t>(k)], points.point(i)[k]);
      }
    }
    const Domain box = Domain::box(lo, hi).value();
    ClippedCellBuilder builder(tree, box);
    DomainSpec in_box;
    in_box.bounding_box = true;
    Star star;
    for (std::uint32_t seed = 0; seed < points.size(); seed += 97) {
      ASSERT_TRUE(walker.compute(seed, star).is_ok());
      const auto answer = engine->star(id, seed, control);
      ASSERT_TRUE(answer.is_ok());
      EXPECT_EQ(answer->star.simplices, star.simplices) << "seed " << seed;
      const auto neighbors = engine->neighbors(id, seed, {}, control);
      ASSERT_TRUE(neighbors.is_ok());
      EXPECT_EQ(neighbors->neighbors, star_neighbors(star)) << "seed " << seed;
      const auto unclipped = engine->cell(id, seed, {}, control);
      ASSERT_TRUE(unclipped.is_ok());
      EXPECT_EQ(unclipped->volume, voronoi_cell(points, star).volume) << "seed " << seed;
      const auto clipped = engine->cell(id, seed, in_box, control);
      ASSERT_TRUE(clipped.is_ok()) << clipped.status().message();
      const VoronoiCell walked = builder.cell(seed).value();
      EXPECT_EQ(clipped->volume, walked.volume) << "seed " << seed;
      EXPECT_EQ(clipped->centroid, walked.centroid) << "seed " << seed;
      ASSERT_EQ(clipped->facets.size(), walked.facets.size()) << "seed " << seed;
      for (std::size_t k = 0; k < walked.facets.size(); ++k) {
        EXPECT_EQ(clipped->facets[k].neighbor, walked.facets[k].neighbor);
        EXPECT_EQ(clipped->facets[k].area, walked.facets[k].area);
      }
    }
    // A batch of stars reads it too.
    std::vector<std::uint64_t> seeds;
    for (std::uint64_t s = 1; s < points.size(); s += 53) seeds.push_back(s);
    const std::vector<BatchAnswer> answers = batch_stars(*engine, id, seeds, control);
    ASSERT_EQ(answers.size(), seeds.size());
    for (std::size_t i = 0; i < seeds.size(); ++i) {
      ASSERT_TRUE(walker.compute(static_cast<std::uint32_t>(seeds[i]), star).is_ok());
      EXPECT_EQ(answers[i].star.star.simplices, star.simplices) << "seed " << seeds[i];
    }
    const std::uint64_t with = budget.used(), kept = set->kept_whole()->bytes();
    set.reset();
    ASSERT_TRUE(engine->delete_point_set(id).is_ok());
    EXPECT_LE(budget.used() + kept, with) << "the kept triangulation goes with the set";
  }
}

TEST(Engine, SeedAndIdErrors) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  const std::string id = upload(*engine, 2, uniform_points(2, 10, 6)).value().id;
  const auto control = no_deadline();
  const auto oor = engine->star(id, 10, control).status();
  EXPECT_EQ(oor.code(), Code::kOutOfRange);
  EXPECT_NE(oor.message().find("seed: 10"), std::string::npos);
  EXPECT_EQ(engine->star(std::string(64, 'a'), 0, control).status().code(), Code::kNotFound);
  EXPECT_EQ(engine->star("nope", 0, control).status().code(), Code::kInvalidArgument);
  EXPECT_EQ(engine->delete_point_set(std::string(64, 'b')).code(), Code::kNotFound);
}

TEST(Engine, DeadlinesAndCancellationStopWork) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  const std::string id = upload(*engine, 3, uniform_points(3, 30000, 7)).value().id;
  auto ignore = [](std::span<const std::uint32_t>, std::span<const std::int32_t>, std::uint64_t) {
    return Status::ok();
  };
  {
    CallControl control(Clock::now() + std::chrono::milliseconds(20));
    const auto start = Clock::now();
    const Status s = engine->stream_simplices(id, 0, 1, 0, control, ignore);
    EXPECT_EQ(s.code(), Code::kDeadlineExceeded) << s.message();
    EXPECT_NE(s.message().find("deadline"), std::string::npos);
    EXPECT_LT(Clock::now() - start, std::chrono::seconds(5));
  }
  {
    std::atomic<bool> gone{false};
    CallControl control(Clock::now() + std::chrono::hours(1), [&] { return gone.load(); });
    std::thread canceller([&] {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      gone = true;
    });
    const Status s = engine->stream_simplices(id, 0, 1, 0, control, ignore);
    canceller.join();
    EXPECT_EQ(s.code(), Code::kCancelled) << s.message();
  }
  {
    // A deadline that has passed stops a single star too (checked between wraps).
    CallControl control(Clock::now() - std::chrono::milliseconds(1));
    std::this_thread::sleep_for(std::chrono::milliseconds(30));  // the watchdog has polled
    EXPECT_EQ(engine->star(id, 0, control).status().code(), Code::kDeadlineExceeded);
  }
  // And the engine still answers.
  EXPECT_TRUE(engine->star(id, 0, no_deadline()).is_ok());
}

// ---- weighted and periodic sets ---------------------------------------------

// Uploads coordinates, then weights (if any), in uneven chunks, with a periodic box (if any).
Result<PointSetInfo> upload_extras(Engine& engine, int d, const std::vector<double>& coords,
                                   const std::vector<double>& weights, const std::vector<double>& box) {
  UploadHeader h = header_of(d, static_cast<std::int64_t>(coords.size() / d), "");
  h.weighted = !weights.empty();
  h.periodic_box = box;
  auto session = engine.begin_upload(h);
  if (!session.is_ok()) return session.status();
  const char* bytes = reinterpret_cast<const char*>(coords.data());
  for (std::size_t at = 0; at < coords.size() * 8; at += 1000) {
    if (Status s = session.value()->append(bytes + at, std::min<std::size_t>(1000, coords.size() * 8 - at));
        !s.is_ok()) {
      return s;
    }
  }
  const char* w = reinterpret_cast<const char*>(weights.data());
  for (std::size_t at = 0; at < weights.size() * 8; at += 700) {
    if (Status s = session.value()->append_weights(w + at, std::min<std::size_t>(700, weights.size() * 8 - at));
        !s.is_ok()) {
      return s;
    }
  }
  return engine.finish_upload(*session.value());
}

std::string double_bytes(const std::vector<double>& v) {
  return std::string(reinterpret_cast<const char*>(v.data()), v.size() * 8);
}

TEST(Engine, WeightedSetsAnswerThePowerDiagramThroughEveryRoute) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  const auto coords = uniform_points(3, 800, 31);
  std::vector<double> weights(800);
  std::mt19937_64 rng(32);
  std::uniform_real_distribution<double> u(0.0, 0.004);
  for (double& w : weights) w = u(rng);
  weights[5] = -1;  // far below its neighbours': hidden
  auto info = upload_extras(*engine, 3, coords, weights, {});
  ASSERT_TRUE(info.is_ok()) << info.status().message();
  // The id hashes the weights after the coordinates; the plain set is another set.
  EXPECT_EQ(info->id, sha256_hex(raw_bytes(3, coords) + "W" + double_bytes(weights)));
  EXPECT_TRUE(info->weighted);
  const std::string plain = upload(*engine, 3, coords).value().id;
  EXPECT_NE(plain, info->id);
  EXPECT_FALSE(engine->get_point_set(plain).value().weighted);

  PointSet ps(3, coords);
  ASSERT_TRUE(ps.validate("test").is_ok());
  KdTree tree(ps);
  StarOptions options;
  options.weights = weights;
  StarWalker walker(tree, options);
  const auto control = no_deadline();
  // Answers from a server that loaded the set from disk (a fresh engine on the same dir).
  auto reloaded = make_engine(dir.path());
  EXPECT_TRUE(reloaded->get_point_set(info->id).value().weighted);
  for (std::uint32_t seed : {0u, 5u, 77u}) {
    Star expected;
    ASSERT_TRUE(walker.compute(seed, expected).is_ok());
    auto got = reloaded->star(info->id, seed, control);
    ASSERT_TRUE(got.is_ok()) << got.status().message();
    EXPECT_EQ(got->star.simplices, expected.simplices) << "seed " << seed;
    EXPECT_EQ(got->star.hidden, seed == 5u);
    const VoronoiCell cell = reloaded->cell(info->id, seed, {}, control).value();
    EXPECT_EQ(cell.hidden, seed == 5u);
    EXPECT_EQ(cell.facets.size(), star_neighbors(expected).size());
    EXPECT_EQ(reloaded->neighbors(info->id, seed, {}, control).value().neighbors, star_neighbors(expected));
  }
  // The whole mesh: the regular triangulation, shards uniting to the core's run.
  std::vector<std::uint32_t> whole;
  MeshOptions mesh;
  mesh.star.weights = weights;
  ASSERT_TRUE(mesh_seeds(tree, mesh, [&](std::span<const std::uint32_t> b, std::uint64_t) {
                whole.insert(whole.end(), b.begin(), b.end());
                return Status::ok();
              }).is_ok());
  for (std::uint32_t shards : {1u, 3u}) {
    std::vector<std::uint32_t> united;
    for (std::uint32_t k = 0; k < shards; ++k) {
      ASSERT_TRUE(
          engine
              ->stream_simplices(info->id, k, shards, 0, control,
                                 [&](std::span<const std::uint32_t> b, std::span<const std::int32_t> o, std::uint64_t) {
                                   EXPECT_TRUE(o.empty());
                                   united.insert(united.end(), b.begin(), b.end());
                                   return Status::ok();
                                 })
              .is_ok());
    }
    EXPECT_EQ(united, whole) << shards << " shards";
  }
  // Cells streamed: power cells, the hidden ones (as the walker says) empty; volumes
  // fill the bounding box.
  std::vector<bool> hidden(800);
  for (std::uint32_t seed = 0; seed < 800; ++seed) {
    Star star;
    ASSERT_TRUE(walker.compute(seed, star).is_ok());
    hidden[seed] = star.hidden;
  }
  EXPECT_TRUE(hidden[5]);
  double volume = 0;
  ASSERT_TRUE(engine
                  ->stream_cells(info->id, 0, 1, 0, {}, true, control,
                                 [&](std::span<const VoronoiCell> cells, std::uint64_t) {
                                   for (const VoronoiCell& c : cells) {
                                     EXPECT_EQ(c.hidden, hidden[c.seed]) << c.seed;
                                     volume += c.volume;
                                   }
                                   return Status::ok();
                                 })
                  .is_ok());
  const Domain bounds = Domain::bounding_box(ps);
  double box_volume = 1;
  for (std::size_t c = 0; c < 3; ++c) box_volume *= bounds.upper()[c] - bounds.lower()[c];
  EXPECT_NEAR(volume, box_volume, 1e-12);

  // Bad weights: one clear error each, nothing stored.
  const std::size_t stored = engine->list_point_sets(100, "", nullptr).value().size();
  auto bad = weights;
  bad[3] = std::nan("");
  auto e = upload_extras(*engine, 3, coords, bad, {});
  EXPECT_EQ(e.status().code(), Code::kInvalidArgument);
  EXPECT_NE(e.status().message().find("weights: index 3"), std::string::npos) << e.status().message();
  bad[3] = 1e300;
  EXPECT_NE(upload_extras(*engine, 3, coords, bad, {}).status().message().find("index 3"), std::string::npos);
  auto fewer = weights;
  fewer.pop_back();
  UploadHeader h = header_of(3, 800, "");
  h.weighted = true;
  auto session = engine->begin_upload(h);
  ASSERT_TRUE(session.is_ok());
  EXPECT_NE(session.value()->append_weights(fewer.data(), 8).message().find("before all the coordinates"),
            std::string::npos);
  ASSERT_TRUE(session.value()->append(coords.data(), coords.size() * 8).is_ok());
  ASSERT_TRUE(session.value()->append_weights(fewer.data(), fewer.size() * 8).is_ok());
  EXPECT_NE(session.value()->append_weights(weights.data(), 16).message().find("more than the 6400 bytes"),
            std::string::npos);
  auto finished = engine->finish_upload(*session.value());
  EXPECT_NE(finished.status().message().find("received 799 weights"), std::string::npos) << finished.status().message();
  EXPECT_EQ(engine->list_point_sets(100, "", nullptr).value().size(), stored);
  // Approximate neighbours and appends are refused, naming why.
  NeighborQuery approx;
  approx.mode = NeighborQuery::Mode::kApproximate;
  EXPECT_NE(engine->neighbors(info->id, 0, approx, control).status().message().find("weighted"), std::string::npos);
  EXPECT_EQ(engine->begin_append(info->id, header_of(0, 1, "")).status().code(), Code::kFailedPrecondition);
  UploadHeader weighted_append = header_of(0, 1, "");
  weighted_append.weighted = true;
  EXPECT_EQ(engine->begin_append(plain, weighted_append).status().code(), Code::kFailedPrecondition);
}

// Rows as sortable (point, offset) keys, for comparing meshes as sets of simplices.
std::vector<std::vector<std::int64_t>> periodic_rows(int d, std::span<const std::uint32_t> simplices,
                                                     std::span<const std::int32_t> offsets) {
  const auto du = static_cast<std::size_t>(d);
  std::vector<std::vector<std::int64_t>> rows;
  for (std::size_t r = 0; r < simplices.size() / (du + 1); ++r) {
    std::vector<std::int64_t> row;
    for (std::size_t v = 0; v <= du; ++v) {
      row.push_back(simplices[r * (du + 1) + v]);
      for (std::size_t c = 0; c < du; ++c) row.push_back(offsets[(r * (du + 1) + v) * du + c]);
    }
    rows.push_back(std::move(row));
  }
  std::sort(rows.begin(), rows.end());
  return rows;
}

TEST(Engine, PeriodicSetsAnswerOnTheTorusThroughEveryRoute) {
  for (const int d : {2, 3}) {
    SCOPED_TRACE("d = " + std::to_string(d));
    TempDir dir;
    auto engine = make_engine(dir.path());
    const std::size_t n = d == 2 ? 400 : 500;
    std::vector<double> coords = uniform_points(d, n, 40 + static_cast<std::uint64_t>(d));
    std::vector<double> box(2 * static_cast<std::size_t>(d), 0.0);
    for (int c = 0; c < d; ++c) {
      box[static_cast<std::size_t>(c)] = -0.5;
      box[static_cast<std::size_t>(d + c)] = 1.5;
    }
    for (double& v : coords) v = v * 2 - 0.5;
    auto info = upload_extras(*engine, d, coords, {}, box);
    ASSERT_TRUE(info.is_ok()) << info.status().message();
    EXPECT_EQ(info->id, sha256_hex(raw_bytes(d, coords) + "P" + double_bytes(box)));
    EXPECT_EQ(info->periodic_box, box);
    auto reloaded = make_engine(dir.path());
    EXPECT_EQ(reloaded->get_point_set(info->id).value().periodic_box, box);

    PointSet ps(d, coords);
    ASSERT_TRUE(ps.validate("test").is_ok());
    const PeriodicBox torus =
        PeriodicBox::of({box.begin(), box.begin() + d}, {box.begin() + d, box.end()}, "box").value();
    const auto control = no_deadline();
    for (std::uint32_t seed : {0u, 9u, static_cast<std::uint32_t>(n - 1)}) {
      VoronoiCell expected_cell;
      auto expected = periodic_star(ps, torus, seed, {}, "test", &expected_cell);
      ASSERT_TRUE(expected.is_ok());
      auto got = reloaded->star(info->id, seed, control);
      ASSERT_TRUE(got.is_ok()) << got.status().message();
      EXPECT_EQ(got->star.simplices, expected->simplices);
      EXPECT_EQ(got->offsets, expected->offsets);
      EXPECT_EQ(got->circumcentres.size(), expected->size(d) * static_cast<std::size_t>(d));
      std::vector<std::uint32_t> points;
      std::vector<std::int32_t> offsets;
      periodic_neighbors(expected.value(), d, points, offsets);
      const NeighborAnswer neighbours = reloaded->neighbors(info->id, seed, {}, control).value();
      EXPECT_EQ(neighbours.neighbors, points);
      EXPECT_EQ(neighbours.offsets, offsets);
      const VoronoiCell cell = reloaded->cell(info->id, seed, {}, control).value();
      EXPECT_EQ(cell.facet_offsets, expected_cell.facet_offsets);
      EXPECT_EQ(cell.volume, expected_cell.volume);
    }
    // The whole torus: shards (seed ranges) concatenate to the same bytes for any
    // count, and are mesh_periodic's simplices, each once.
    std::vector<std::uint32_t> mesh_rows;
    std::vector<std::int32_t> mesh_offsets;
    ASSERT_TRUE(mesh_periodic(
                    ps, torus, {},
                    [&](std::span<const std::uint32_t> s, std::span<const std::int32_t> o, std::uint64_t) {
                      mesh_rows.insert(mesh_rows.end(), s.begin(), s.end());
                      mesh_offsets.insert(mesh_offsets.end(), o.begin(), o.end());
                      return Status::ok();
                    },
                    nullptr, "test")
                    .is_ok());
    std::vector<std::uint32_t> first_rows;
    std::vector<std::int32_t> first_offsets;
    for (std::uint32_t shards : {1u, 3u}) {
      std::vector<std::uint32_t> rows;
      std::vector<std::int32_t> offsets;
      for (std::uint32_t k = 0; k < shards; ++k) {
        ASSERT_TRUE(engine
                        ->stream_simplices(
                            info->id, k, shards, 50, control,
                            [&](std::span<const std::uint32_t> b, std::span<const std::int32_t> o, std::uint64_t) {
                              EXPECT_LE(b.size(), 50u * static_cast<std::size_t>(d + 1));
                              EXPECT_EQ(o.size(), b.size() * static_cast<std::size_t>(d));
                              rows.insert(rows.end(), b.begin(), b.end());
                              offsets.insert(offsets.end(), o.begin(), o.end());
                              return Status::ok();
                            })
                        .is_ok());
      }
      if (shards == 1) {
        first_rows = rows;
        first_offsets = offsets;
      }
      EXPECT_EQ(rows, first_rows);
      EXPECT_EQ(offsets, first_offsets);
      EXPECT_EQ(periodic_rows(d, rows, offsets), periodic_rows(d, mesh_rows, mesh_offsets));
    }
    // The cells tile the torus: volumes sum to the box's, every facet has its offset.
    double volume = 0;
    for (std::uint32_t k = 0; k < 2; ++k) {
      ASSERT_TRUE(engine
                      ->stream_cells(info->id, k, 2, 64, {}, false, control,
                                     [&](std::span<const VoronoiCell> cells, std::uint64_t) {
                                       for (const VoronoiCell& c : cells) {
                                         EXPECT_EQ(c.facet_offsets.size(),
                                                   c.facets.size() * static_cast<std::size_t>(d));
                                         volume += c.volume;
                                       }
                                       return Status::ok();
                                     })
                      .is_ok());
    }
    EXPECT_NEAR(volume, std::pow(2.0, d), 1e-12);
    // What does not apply to a torus is refused, naming why.
    DomainSpec clip;
    clip.bounding_box = true;
    EXPECT_NE(engine->cell(info->id, 0, clip, control).status().message().find("periodic"), std::string::npos);
    NeighborQuery approx;
    approx.mode = NeighborQuery::Mode::kSpokes;
    EXPECT_EQ(engine->neighbors(info->id, 0, approx, control).status().code(), Code::kInvalidArgument);
    EXPECT_EQ(engine->begin_append(info->id, header_of(0, 1, "")).status().code(), Code::kFailedPrecondition);
    // Bad boxes and points outside: one error each, nothing stored.
    auto outside = coords;
    outside[7 * static_cast<std::size_t>(d) + 1] = 1.5;
    auto e = upload_extras(*engine, d, outside, {}, box);
    EXPECT_NE(e.status().message().find("point 7 lies outside the periodic box: coordinate 1"), std::string::npos)
        << e.status().message();
    auto flat = box;
    flat[0] = flat[static_cast<std::size_t>(d)];
    EXPECT_NE(upload_extras(*engine, d, coords, {}, flat).status().message().find("periodic_box"), std::string::npos);
    EXPECT_NE(upload_extras(*engine, d, coords, {}, {0, 1}).status().message().find("periodic_box: 2 values"),
              std::string::npos);
    EXPECT_EQ(engine->list_point_sets(100, "", nullptr).value().size(), 1u);
  }
}

// ---- REST as a pure function ----------------------------------------------------------

struct Rest {
  TempDir dir;
  std::unique_ptr<Engine> engine = make_engine(dir.path());
  Telemetry telemetry;
  bool ready = true;
  HttpApi api{*engine, telemetry, token_auth(""), [this] { return ready; }};

  HttpResponse call(http::verb verb, const std::string& target, const std::string& body = "",
                    const std::string& type = "application/json") {
    http::request<http::string_body> req{verb, target, 11};
    if (!body.empty()) {
      req.set(http::field::content_type, type);
      req.body() = body;
      req.prepare_payload();
    }
    return api.handle_request(req);
  }
  json get(const std::string& target, unsigned expect_status = 200) {
    HttpResponse r = call(http::verb::get, target);
    EXPECT_EQ(r.status, expect_status) << target << " -> " << r.body;
    return json::parse(r.body);
  }
};

void expect_error(const HttpResponse& r, unsigned status, const std::string& code, const std::string& fragment) {
  EXPECT_EQ(r.status, status) << r.body;
  const json j = json::parse(r.body);
  EXPECT_EQ(j["error"]["code"], status);
  EXPECT_EQ(j["error"]["status"], code);
  EXPECT_NE(j["error"]["message"].get<std::string>().find(fragment), std::string::npos) << r.body;
}

// GET .../points: a .npy that numpy's format 1.0 reader takes: magic, a padded header
// naming dtype and shape, the values from a 64-byte boundary, float64 exact or float32.
TEST(Rest, PointsRouteIsANpyFile) {
  Rest rest;
  std::vector<double> raw;
  for (int i = 0; i < 300; ++i) raw.push_back(0.1 * i + 1.0 / 3.0);  // 100 points in 3-d
  HttpResponse up =
      rest.call(http::verb::post, "/v1/pointsets?dimension=3",
                std::string(reinterpret_cast<const char*>(raw.data()), raw.size() * 8), "application/octet-stream");
  ASSERT_EQ(up.status, 201u) << up.body;
  const std::string id = json::parse(up.body)["id"];
  auto fetch = [&](const std::string& query) {
    HttpResponse r = rest.call(http::verb::get, "/v1/pointsets/" + id + "/points" + query);
    EXPECT_TRUE(r.stream) << r.body;
    std::string body;
    if (r.stream) {
      EXPECT_TRUE(r.stream([&](std::string_view chunk) {
                     body += chunk;
                     return true;
                   }).is_ok());
    }
    EXPECT_EQ(r.content_type, "application/octet-stream");
    return body;
  };
  for (const bool wide : {true, false}) {
    const std::string body = fetch(wide ? "" : "?dtype=float32");
    ASSERT_GT(body.size(), 10u);
    EXPECT_EQ(body.substr(0, 8), std::string("\x93NUMPY\x01\x00", 8));
    const std::size_t header = static_cast<unsigned char>(body[8]) | (static_cast<unsigned char>(body[9]) << 8);
    EXPECT_EQ((10 + header) % 64, 0u);
    const std::string dict = body.substr(10, header);
    EXPECT_NE(dict.find(wide ? "'descr': '<f8'" : "'descr': '<f4'"), std::string::npos) << dict;
    EXPECT_NE(dict.find("'shape': (100, 3)"), std::string::npos) << dict;
    EXPECT_EQ(dict.back(), '\n');
    const std::size_t width = wide ? 8 : 4;
    ASSERT_EQ(body.size(), 10 + header + raw.size() * width);
    for (std::size_t i = 0; i < raw.size(); ++i) {
      if (wide) {
        double v;
        std::memcpy(&v, body.data() + 10 + header + 8 * i, 8);
        ASSERT_EQ(v, raw[i]) << i;
      } else {
        float v;
        std::memcpy(&v, body.data() + 10 + header + 4 * i, 4);
        ASSERT_EQ(v, static_cast<float>(raw[i])) << i;
      }
    }
  }
  expect_error(rest.call(http::verb::get, "/v1/pointsets/" + id + "/points?dtype=int8"), 400, "INVALID_ARGUMENT",
               "dtype: \"int8\" is not float64 or float32");
  expect_error(rest.call(http::verb::get, "/v1/pointsets/" + std::string(64, '0') + "/points"), 404, "NOT_FOUND",
               std::string(64, '0'));
  expect_error(rest.call(http::verb::post, "/v1/pointsets/" + id + "/points"), 501, "UNIMPLEMENTED", "POST");
}

// The page: served with its Content-Security-Policy when the server has it, and not at
// all (404, like any unknown path) when started with --no-ui.
TEST(Rest, PageIsServedOnlyWithUi) {
  Rest plain;  // no UiAssets: --no-ui
  for (const char* path : {"/", "/docs", "/ui/app.js", "/ui/three.min.js"}) {
    expect_error(plain.call(http::verb::get, path), 404, "NOT_FOUND", "no route");
  }
  TempDir three;
  std::filesystem::create_directories(three.path() + "/build");
  std::ofstream(three.path() + "/build/three.min.js") << "var THREE = {};";
  Telemetry telemetry;
  const auto ui = UiAssets::load(three.path());
  EXPECT_NE(ui->missing().find("OrbitControls.js"), std::string::npos);  // the other file is absent
  EXPECT_LE(ui->embedded_bytes(), std::size_t{1} << 20);                 // the issue's budget for the page's own files
  HttpApi api(
      *plain.engine, telemetry, token_auth("s3cret"), [] { return true; }, ui);
  auto get = [&](const std::string& target) {
    http::request<http::string_body> req{http::verb::get, target, 11};
    return api.handle_request(req);
  };
  for (const char* path : {"/", "/docs", "/ui/app.js", "/ui/app.css", "/ui/docs.js", "/ui/three.min.js"}) {
    HttpResponse r = get(path);  // no token needed: the files hold no data
    EXPECT_EQ(r.status, 200u) << path << " " << r.body;
    bool csp = false;
    for (const auto& [name, value] : r.headers) {
      if (name == "Content-Security-Policy") {
        csp = true;
        EXPECT_NE(value.find("script-src 'self'"), std::string::npos);
        EXPECT_EQ(value.find("unsafe-inline"), std::string::npos);
      }
    }
    EXPECT_TRUE(csp) << path;
  }
  EXPECT_EQ(get("/").content_type, "text/html; charset=utf-8");
  EXPECT_EQ(get("/ui/app.js").content_type, "text/javascript; charset=utf-8");
  EXPECT_EQ(get("/ui/three.min.js").body, "var THREE = {};");
  expect_error(get("/ui/OrbitControls.js"), 404, "NOT_FOUND", "no route");
  expect_error(get("/ui/missing.js"), 404, "NOT_FOUND", "no route");
  // The data still needs the token.
  expect_error(get("/v1/pointsets"), 401, "UNAUTHENTICATED", "Authorization");
}

TEST(Rest, EveryRoute) {
  Rest rest;
  const json pts = {{"points", {{0, 0}, {1, 0}, {0, 1}, {1, 1}, {0.5, 0.4}}}, {"display_name", "tiny"}};
  HttpResponse up = rest.call(http::verb::post, "/v1/pointsets", pts.dump());
  ASSERT_EQ(up.status, 201u) << up.body;
  const std::string id = json::parse(up.body)["id"];
  // The flat form and the raw form of the same data give the same id, and no work.
  const json flat = {{"dimension", 2}, {"coordinates", {0, 0, 1, 0, 0, 1, 1, 1, 0.5, 0.4}}};
  HttpResponse again = rest.call(http::verb::post, "/v1/pointsets", flat.dump());
  EXPECT_EQ(again.status, 200u);
  EXPECT_EQ(json::parse(again.body)["id"], id);
  EXPECT_EQ(json::parse(again.body)["already_existed"], true);
  const std::vector<double> raw = {0, 0, 1, 0, 0, 1, 1, 1, 0.5, 0.4};
  HttpResponse binary =
      rest.call(http::verb::post, "/v1/pointsets?dimension=2",
                std::string(reinterpret_cast<const char*>(raw.data()), raw.size() * 8), "application/octet-stream");
  EXPECT_EQ(json::parse(binary.body)["id"], id);

  EXPECT_EQ(rest.get("/v1/pointsets/" + id)["count"], 5);
  EXPECT_EQ(rest.get("/v1/pointsets")["point_sets"].size(), 1u);
  const json star = rest.get("/v1/pointsets/" + id + "/seeds/4/star");
  // Counter-clockwise: (0, 2, 4) and (2, 3, 4) are clockwise, so their last two swap.
  EXPECT_EQ(star["simplices"], json({{0, 1, 4}, {0, 4, 2}, {1, 3, 4}, {2, 4, 3}}));
  EXPECT_EQ(star["circumcenters"].size(), 4u);
  EXPECT_EQ(rest.get("/v1/pointsets/" + id + "/seeds/0/neighbors")["neighbors"], json({1, 2, 4}));
  const json cell = rest.get("/v1/pointsets/" + id + "/seeds/4/cell");
  EXPECT_EQ(cell["bounded"], true);
  EXPECT_GT(cell["volume"].get<double>(), 0.0);
  EXPECT_TRUE(rest.get("/v1/pointsets/" + id + "/seeds/0/cell")["volume"].is_null());

  HttpResponse stream = rest.call(http::verb::get, "/v1/pointsets/" + id + "/simplices?shard=0&shards=1");
  ASSERT_TRUE(stream.stream);
  EXPECT_EQ(stream.content_type, "application/x-ndjson");
  std::string body;
  EXPECT_TRUE(stream
                  .stream([&](std::string_view chunk) {
                    body += chunk;
                    return true;
                  })
                  .is_ok());
  // Sweep order: five points are one leaf, seeds in lexicographic order of coordinates.
  EXPECT_EQ(body, "[0,1,4]\n[0,4,2]\n[2,4,3]\n[1,3,4]\n");

  EXPECT_EQ(rest.get("/healthz")["status"], "SERVING");
  EXPECT_EQ(rest.get("/readyz")["status"], "READY");
  rest.ready = false;
  expect_error(rest.call(http::verb::get, "/readyz"), 503, "UNAVAILABLE", "not ready");
  HttpResponse metrics = rest.call(http::verb::get, "/metrics");
  EXPECT_NE(metrics.body.find("spokemesh_requests_total{method=\"GetStar\",status=\"OK\",transport=\"http\"} 1"),
            std::string::npos)
      << metrics.body;
  EXPECT_NE(metrics.body.find("spokemesh_request_duration_seconds_bucket"), std::string::npos);
  EXPECT_NE(metrics.body.find("spokemesh_points_uploaded_total 5"), std::string::npos);

  EXPECT_EQ(rest.call(http::verb::delete_, "/v1/pointsets/" + id).status, 200u);
  expect_error(rest.call(http::verb::get, "/v1/pointsets/" + id), 404, "NOT_FOUND", id);
}

TEST(Rest, ErrorsInOneShape) {
  Rest rest;
  const std::string id = json::parse(
      rest.call(http::verb::post, "/v1/pointsets", json({{"points", {{0, 0}, {1, 0}, {0, 1}}}}).dump()).body)["id"];
  auto post = [&](const std::string& body) { return rest.call(http::verb::post, "/v1/pointsets", body); };
  expect_error(post("{\"points\": [[0,0],[1,0,2]]}"), 400, "INVALID_ARGUMENT", "points[1]: 3 coordinates");
  expect_error(post("{\"points\": [[0,0],[1,\"x\"],[2,2]]}"), 400, "INVALID_ARGUMENT", "points[1][1]");
  expect_error(post("{\"points\": [[0,0],[1,1e999],[2,3]]}"), 400, "INVALID_ARGUMENT", "number overflow");
  expect_error(post("{\"points\": [[0,0],[1,1e200],[2,3]]}"), 400, "INVALID_ARGUMENT", "point 1, coordinate 1");
  expect_error(post("{\"dimension\": 2, \"coordinates\": [0,0,1]}"), 400, "INVALID_ARGUMENT", "not a multiple");
  expect_error(post("{\"points\": [[0,0],[1,0],[0,0]]}"), 400, "INVALID_ARGUMENT", "points 0 and 2");
  expect_error(post("{\"points\": [[0,0],[1,1],[2,2]]}"), 400, "INVALID_ARGUMENT", "span only");
  expect_error(post("{\"points\": "), 400, "INVALID_ARGUMENT", "invalid JSON");
  expect_error(post("[1,2]"), 400, "INVALID_ARGUMENT", "expected a JSON object");
  expect_error(post(json({{"points", {std::vector<double>(200, 0.0)}}}).dump()), 429, "RESOURCE_EXHAUSTED",
               "--max-dimension");
  expect_error(
      rest.call(http::verb::post, "/v1/pointsets?dimension=2", std::string(20, '\0'), "application/octet-stream"), 400,
      "INVALID_ARGUMENT", "20 bytes");
  expect_error(rest.call(http::verb::post, "/v1/pointsets", "a", "text/plain"), 400, "INVALID_ARGUMENT",
               "Content-Type");
  expect_error(rest.call(http::verb::get, "/v1/pointsets/" + id + "/seeds/3/star"), 400, "OUT_OF_RANGE", "seed: 3");
  expect_error(rest.call(http::verb::get, "/v1/pointsets/" + id + "/seeds/-1/star"), 400, "INVALID_ARGUMENT", "seed");
  expect_error(rest.call(http::verb::get, "/v1/pointsets/" + std::string(64, 'c') + "/seeds/0/star"), 404, "NOT_FOUND",
               "not found");
  expect_error(rest.call(http::verb::get, "/v1/pointsets/xyz"), 400, "INVALID_ARGUMENT", "point_set_id");
  expect_error(rest.call(http::verb::get, "/v1/nothing"), 404, "NOT_FOUND", "no route");
  expect_error(rest.call(http::verb::put, "/v1/pointsets/" + id), 501, "UNIMPLEMENTED", "PUT");
  expect_error(rest.call(http::verb::get, "/v1/pointsets?page_size=abc"), 400, "INVALID_ARGUMENT", "page_size");
  // A bad shard is an ordinary error: the stream fails before its first chunk.
  HttpResponse bad_shard = rest.call(http::verb::get, "/v1/pointsets/" + id + "/simplices?shard=2&shards=2");
  ASSERT_TRUE(bad_shard.stream);
  const Status s = bad_shard.stream([](std::string_view) { return true; });
  EXPECT_EQ(s.code(), Code::kInvalidArgument);
  EXPECT_NE(s.message().find("shard_index: 2"), std::string::npos);
}

TEST(Rest, WeightedAndPeriodicSets) {
  Rest rest;
  // A 4 x 4 grid on the unit torus, with weights: JSON and raw uploads agree.
  json points = json::array();
  std::vector<double> raw;
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) {
      points.push_back({i * 0.25, j * 0.25});
      raw.insert(raw.end(), {i * 0.25, j * 0.25});
    }
  }
  const std::vector<double> weights(16, 0.001);
  const json body = {{"points", points}, {"weights", weights}, {"periodic_box", {0, 0, 1, 1}}};
  HttpResponse up = rest.call(http::verb::post, "/v1/pointsets", body.dump());
  ASSERT_EQ(up.status, 201u) << up.body;
  const json info = json::parse(up.body);
  EXPECT_EQ(info["weighted"], true);
  EXPECT_EQ(info["periodic_box"], json({0, 0, 1, 1}));
  const std::string id = info["id"];
  HttpResponse binary = rest.call(http::verb::post, "/v1/pointsets?dimension=2&weighted=true&periodic_box=0,0,1,1",
                                  double_bytes(raw) + double_bytes(weights), "application/octet-stream");
  EXPECT_EQ(json::parse(binary.body)["id"], id) << binary.body;
  EXPECT_EQ(rest.get("/v1/pointsets/" + id)["periodic_box"], json({0, 0, 1, 1}));
  // Point 5 = (0.25, 0.25): six triangles around it, each with its vertices' offsets.
  const json star = rest.get("/v1/pointsets/" + id + "/seeds/0/star");
  ASSERT_EQ(star["simplices"].size(), 6u) << star.dump();
  ASSERT_EQ(star["offsets"].size(), 6u);
  EXPECT_EQ(star["offsets"][0].size(), 3u);
  const json neighbours = rest.get("/v1/pointsets/" + id + "/seeds/0/neighbors");
  EXPECT_EQ(neighbours["neighbors"].size(), 6u);
  EXPECT_EQ(neighbours["offsets"].size(), 6u);
  const json cell = rest.get("/v1/pointsets/" + id + "/seeds/0/cell");
  EXPECT_NEAR(cell["volume"].get<double>(), 1.0 / 16, 1e-15);
  EXPECT_EQ(cell["facets"][0]["offset"].size(), 2u);
  HttpResponse stream = rest.call(http::verb::get, "/v1/pointsets/" + id + "/simplices?shard=0&shards=1");
  std::string lines;
  ASSERT_TRUE(stream
                  .stream([&](std::string_view chunk) {
                    lines += chunk;
                    return true;
                  })
                  .is_ok());
  std::size_t count = 0;
  for (std::size_t at = 0; at < lines.size(); at = lines.find('\n', at) + 1) {
    const json line = json::parse(lines.substr(at, lines.find('\n', at) - at));
    EXPECT_EQ(line["simplex"].size(), 3u);
    EXPECT_EQ(line["offsets"].size(), 3u);
    ++count;
  }
  EXPECT_EQ(count, 32u);  // 2 n triangles on a 2-d torus
  expect_error(rest.call(http::verb::post, "/v1/pointsets", json({{"points", points}, {"weights", {1, 2}}}).dump()),
               400, "INVALID_ARGUMENT", "weights");
  expect_error(
      rest.call(http::verb::post, "/v1/pointsets", json({{"points", points}, {"periodic_box", {0, 0, 0.5, 1}}}).dump()),
      400, "INVALID_ARGUMENT", "lies outside the periodic box");
  expect_error(rest.call(http::verb::post, "/v1/pointsets", json({{"points", points}, {"weights", {{1}}}}).dump()), 400,
               "INVALID_ARGUMENT", "weights[0]");
  expect_error(rest.call(http::verb::get, "/v1/pointsets/" + id + "/seeds/0/cell?box=0,0,1,1"), 400, "INVALID_ARGUMENT",
               "periodic");
}

TEST(Rest, BearerTokenGuardsEverythingButProbes) {
  TempDir dir;
  auto engine = make_engine(dir.path());
  Telemetry telemetry;
  HttpApi api(*engine, telemetry, token_auth("s3cret"), [] { return true; });
  auto call = [&](const std::string& target, const std::string& auth) {
    http::request<http::string_body> req{http::verb::get, target, 11};
    if (!auth.empty()) req.set(http::field::authorization, auth);
    return api.handle_request(req);
  };
  EXPECT_EQ(call("/healthz", "").status, 200u);
  EXPECT_EQ(call("/readyz", "").status, 200u);
  expect_error(call("/v1/pointsets", ""), 401, "UNAUTHENTICATED", "bearer token");
  expect_error(call("/metrics", "Bearer wrong!"), 401, "UNAUTHENTICATED", "bearer token");
  EXPECT_EQ(call("/v1/pointsets", "Bearer s3cret").status, 200u);
}

// Answers given on the connection's I/O thread (HttpApi::answer_at_once) are the ones
// a request's own thread gives, byte for byte; what could block is left to the thread:
// a set not in memory or without its kept triangulation, approximate walks, the errors
// of seeds and sets that must be looked up (out of range, unknown), anything but a
// seed's GET.
TEST(Rest, AnswersAtOnceAreTheThreadsAnswers) {
  Rest rest;
  const auto coords = uniform_points(3, 3000, 61);
  const std::string id = upload(*rest.engine, 3, coords).value().id;
  const std::string base = "/v1/pointsets/" + id;
  auto request = [](http::verb verb, const std::string& target) {
    return http::request<http::string_body>{verb, target, 11};
  };
  // Before its triangulation is kept, no seed is answered at once.
  EXPECT_FALSE(rest.api.answer_at_once(request(http::verb::get, base + "/seeds/5/star")));
  EXPECT_EQ(rest.call(http::verb::get, base + "/seeds/5/star").status, 200u);  // asks for it
  auto set = rest.engine->point_set(id).value();
  for (int wait = 0; wait < 600 && set->kept_whole() == nullptr; ++wait) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_NE(set->kept_whole(), nullptr);
  int answered = 0;
  for (std::uint64_t seed = 0; seed < 3000; seed += 37) {
    const std::string at = base + "/seeds/" + std::to_string(seed);
    for (const std::string route : {"/star", "/neighbors", "/cell", "/cell?bounding_box=true",
                                    "/cell?box=0.2,0.2,0.2,0.8,0.8,0.8", "/neighbors?mode=exact"}) {
      const auto req = request(http::verb::get, at + route);
      const auto quick = rest.api.answer_at_once(req);
      const HttpResponse slow = rest.api.handle_request(req);
      ASSERT_TRUE(quick.has_value()) << at + route;
      EXPECT_EQ(quick->status, slow.status) << at + route;
      EXPECT_EQ(quick->body, slow.body) << at + route;
      ++answered;
    }
  }
  EXPECT_GT(answered, 400);
  EXPECT_EQ(rest.api.answer_at_once(request(http::verb::get, "/healthz"))->body, R"({"status":"SERVING"})");
  for (const std::string& target :
       std::vector<std::string>{base + "/seeds/5/neighbors?mode=approximate", base + "/seeds/3000/star",
                                "/v1/pointsets/" + std::string(64, 'a') + "/seeds/1/star", base, base + "/points",
                                "/metrics", base + "/simplices?shard=0&shards=1"}) {
    EXPECT_FALSE(rest.api.answer_at_once(request(http::verb::get, target))) << target;
  }
  // A malformed seed's error needs nothing held: said at once, as a thread says it.
  const auto malformed = request(http::verb::get, base + "/seeds/x/star");
  EXPECT_EQ(rest.api.answer_at_once(malformed)->body, rest.api.handle_request(malformed).body);
  EXPECT_FALSE(rest.api.answer_at_once(request(http::verb::post, base + "/stars:batch")));
  EXPECT_FALSE(rest.api.answer_at_once(request(http::verb::delete_, base)));
  // A set not in memory (another replica's engine on the same directory) is read from
  // disk by a thread, not at once.
  auto other = make_engine(rest.dir.path());
  HttpApi other_api{*other, rest.telemetry, token_auth(""), [] { return true; }};
  EXPECT_FALSE(other_api.answer_at_once(request(http::verb::get, base + "/seeds/5/star")));
  EXPECT_EQ(other_api.handle_request(request(http::verb::get, base + "/seeds/5/star")).body,
            rest.api.handle_request(request(http::verb::get, base + "/seeds/5/star")).body);
}

// ---- sharded engines on one data directory ------------------------------------------

// A sharded deployment in one process: a whole engine and `shards` sharded ones (shard
// k of `shards`, sets of 1,000 points and more kept as pieces of at most 500) over one
// data directory, each behind its REST handler. No peers: each engine answers every
// seed from the piece holding it, as a replica answers a relayed request.
struct ShardedDeployment {
  ShardedDeployment(const std::string& dir, std::uint32_t shards) {
    engines.push_back(make_engine(dir));
    for (std::uint32_t k = 0; k < shards; ++k) {
      ShardSettings settings;
      settings.index = k;
      settings.count = shards;
      settings.pieces_above = 1000;
      settings.piece_points = 500;
      auto store = PointSetStore::open(dir, Limits{}.max_memory, {});
      EXPECT_TRUE(store.is_ok());
      engines.push_back(std::make_unique<Engine>(std::move(store).value(), Limits{}, settings));
    }
    for (auto& engine : engines) {
      apis.push_back(std::make_unique<HttpApi>(*engine, telemetry, token_auth(""), [] { return true; }));
    }
  }
  // Status, body, and a stream's output with its final status, as one text.
  std::string call(std::size_t k, http::verb verb, const std::string& target, const std::string& body = "") {
    http::request<http::string_body> req{verb, target, 11};
    if (!body.empty()) {
      req.set(http::field::content_type, "application/json");
      req.body() = body;
      req.prepare_payload();
    }
    HttpResponse r = apis[k]->handle_request(req);
    std::string out = std::to_string(r.status) + " " + r.body;
    if (r.stream) {
      const Status s = r.stream([&](std::string_view chunk) {
        out += chunk;
        return true;
      });
      out += "\nend: " + std::string(code_name(s.code())) + " " + s.message();
    }
    return out;
  }
  // The GET's answer given at once (HttpApi::answer_at_once), as call() writes it.
  std::optional<std::string> at_once(std::size_t k, const std::string& target) {
    auto r = apis[k]->answer_at_once(http::request<http::string_body>{http::verb::get, target, 11});
    if (!r) return std::nullopt;
    return std::to_string(r->status) + " " + r->body;
  }
  std::vector<std::unique_ptr<Engine>> engines;  // [0] whole, then shard 0, 1, ...
  Telemetry telemetry;
  std::vector<std::unique_ptr<HttpApi>> apis;
};

// Every answer of every sharded engine, errors included, is the whole engine's byte for
// byte: stars, neighbours, cells bare, in the bounding box, in a box and halfspaces that
// leave seeds outside (whose errors name the seed by its index in the whole set), out of
// range seeds, and batches of all of these.
TEST(ShardedEngines, EveryAnswerAndErrorIsTheWholeEngines) {
  for (const std::uint32_t shards : {2u, 3u}) {
    for (const int d : {2, 3}) {
      SCOPED_TRACE("shards " + std::to_string(shards) + ", " + std::to_string(d) + "-d");
      TempDir dir;
      ShardedDeployment deployment(dir.path(), shards);
      const std::size_t n = 3000;
      const auto coords = uniform_points(d, n, 40 + d);
      // Uploaded through shard 0, which cuts the set into pieces for all.
      auto info = upload(*deployment.engines[1], d, coords);
      ASSERT_TRUE(info.is_ok()) << info.status().message();
      const std::string id = info->id;
      auto layout = deployment.engines[1]->store().layout(id);
      ASSERT_TRUE(layout.is_ok() && layout.value());
      ASSERT_GE(layout.value()->pieces(), 4u);
      const std::string box = d == 2 ? "0,0,0.5,1" : "0,0,0,0.5,1,1";
      const std::string halfspaces = d == 2 ? "1,1,1.2" : "1,1,1,1.2";
      const std::string base = "/v1/pointsets/" + id;
      std::vector<std::string> targets;
      std::vector<std::uint64_t> seeds;
      for (std::uint64_t seed = 0; seed < n; seed += 11) seeds.push_back(seed);
      for (std::uint64_t seed : seeds) {
        const std::string at = base + "/seeds/" + std::to_string(seed);
        for (const std::string& route : std::vector<std::string>{"/star", "/neighbors", "/neighbors?mode=approximate",
                                                                 "/cell", "/cell?bounding_box=true", "/cell?box=" + box,
                                                                 "/cell?halfspaces=" + halfspaces}) {
          targets.push_back(at + route);
        }
      }
      for (const std::uint64_t seed : {n, n + 7}) targets.push_back(base + "/seeds/" + std::to_string(seed) + "/star");
      std::size_t at_once = 0;
      for (const std::string& target : targets) {
        const std::string expected = deployment.call(0, http::verb::get, target);
        for (std::size_t k = 1; k < deployment.apis.size(); ++k) {
          ASSERT_EQ(deployment.call(k, http::verb::get, target), expected)
              << "engine of shard " << k - 1 << ": " << target;
          // At once only from a kept triangulation of this shard's own piece.
          if (const auto quick = deployment.at_once(k, target)) {
            ASSERT_EQ(*quick, expected) << "at once, engine of shard " << k - 1 << ": " << target;
            const std::size_t seeds_at = target.find("/seeds/") + 7;
            const SeedRoute route = deployment.engines[k]->route_seed(
                id, std::stoull(target.substr(seeds_at, target.find('/', seeds_at) - seeds_at)));
            EXPECT_EQ(route.shard, k - 1) << target;
            ++at_once;
          }
        }
      }
      EXPECT_GT(at_once, targets.size() / 4);
      int errors = 0;
      for (const std::string& target : targets) errors += deployment.call(0, http::verb::get, target)[0] != '2';
      EXPECT_GT(errors, 100);  // the box and the halfspaces leave many seeds outside
      // Batches, answered and refused.
      json some = json::array();
      for (std::uint64_t seed = 1; seed < n; seed += 5) some.push_back(seed);
      json inside = json::array();  // seeds of the box
      for (const auto& s : some) {
        if (coords[s.get<std::uint64_t>() * d] <= 0.5) inside.push_back(s);
      }
      json box_values = json::array();
      {
        std::stringstream text(box);
        for (std::string x; std::getline(text, x, ',');) box_values.push_back(std::stod(x));
      }
      const std::vector<std::pair<std::string, json>> batches = {
          {"/stars:batch", {{"seeds", some}}},
          {"/neighbors:batch", {{"seeds", some}}},
          {"/cells:batch", {{"seeds", some}, {"bounding_box", true}}},
          {"/cells:batch", {{"seeds", inside}, {"box", box_values}}},
          {"/cells:batch", {{"seeds", some}, {"box", box_values}}},  // stops at the first seed outside
          {"/stars:batch", {{"seeds", {1, 2, n + 3}}}},
      };
      for (const auto& [route, body] : batches) {
        const std::string expected = deployment.call(0, http::verb::post, base + route, body.dump());
        for (std::size_t k = 1; k < deployment.apis.size(); ++k) {
          ASSERT_EQ(deployment.call(k, http::verb::post, base + route, body.dump()), expected)
              << "engine of shard " << k - 1 << ": " << route << " " << body.dump().substr(0, 200);
        }
      }
    }
  }
}

// A free loopback port (bound, read, released: another process could take it between,
// which a test run does not).
unsigned short free_port() {
  boost::asio::io_context io;
  boost::asio::ip::tcp::acceptor a(io, {boost::asio::ip::make_address("127.0.0.1"), 0});
  return a.local_endpoint().port();
}

// Two shard replicas' real HTTP servers in-process: a seed of shard 0's piece asked of
// shard 1's server is relayed, on its I/O loop without a thread once shard 0's address
// is known (HttpServer::relayed_at_once), and answers the owner's bytes (a whole
// engine's), naming the shard; with shard 0's server gone, the relay made at once and
// the one made from a thread both answer 503 naming shard 0.
TEST(ShardedServers, RelaysOnTheLoopAreTheOwnersAnswers) {
  TempDir dir;
  Telemetry telemetry;
  const std::array<unsigned short, 2> ports{free_port(), free_port()};
  const std::string peers_list = "127.0.0.1:" + std::to_string(ports[0]) + ";127.0.0.1:" + std::to_string(ports[1]);
  auto whole = make_engine(dir.path());
  HttpApi whole_api{*whole, telemetry, token_auth(""), [] { return true; }};
  std::vector<std::unique_ptr<Engine>> engines;
  std::vector<std::unique_ptr<ShardPeers>> peers;
  std::vector<std::unique_ptr<HttpApi>> apis;
  std::vector<std::unique_ptr<HttpServer>> servers;
  for (std::uint32_t k = 0; k < 2; ++k) {
    ShardSettings settings;
    settings.index = k;
    settings.count = 2;
    settings.pieces_above = 1000;
    settings.piece_points = 500;
    auto store = PointSetStore::open(dir.path(), Limits{}.max_memory, {});
    ASSERT_TRUE(store.is_ok());
    engines.push_back(std::make_unique<Engine>(std::move(store).value(), Limits{}, settings));
    peers.push_back(std::make_unique<ShardPeers>(settings, peers_list, peers_list));
    apis.push_back(std::make_unique<HttpApi>(
        *engines.back(), telemetry, token_auth(""), [] { return true; }, nullptr, peers.back().get()));
    HttpServerOptions options;
    options.listen = "127.0.0.1:" + std::to_string(ports[k]);
    servers.push_back(std::make_unique<HttpServer>(*apis.back(), telemetry, options));
    ASSERT_TRUE(servers.back()->start().is_ok());
  }
  const std::size_t n = 3000;
  auto info = upload(*engines[0], 3, uniform_points(3, n, 52));
  ASSERT_TRUE(info.is_ok()) << info.status().message();
  const std::string base = "/v1/pointsets/" + info->id;
  std::vector<std::uint64_t> shard0_seeds;
  for (std::uint64_t seed = 0; seed < n && shard0_seeds.size() < 40; seed += 7) {
    if (engines[1]->route_seed(info->id, seed).shard == 0) shard0_seeds.push_back(seed);
  }
  ASSERT_GE(shard0_seeds.size(), 20u);

  namespace beast = boost::beast;
  boost::asio::io_context io;
  beast::tcp_stream stream(io);
  stream.connect({boost::asio::ip::make_address("127.0.0.1"), ports[1]});
  beast::flat_buffer buffer;
  auto get = [&](const std::string& target) {
    http::request<http::string_body> req{http::verb::get, target, 11};
    req.set(http::field::host, "127.0.0.1");
    req.keep_alive(true);
    http::write(stream, req);
    http::response<http::string_body> res;
    http::read(stream, buffer, res);
    return res;
  };
  for (const std::uint64_t seed : shard0_seeds) {
    for (const std::string route : {"/star", "/neighbors", "/cell", "/cell?box=0,0,0,0.5,1,1"}) {
      const std::string target = base + "/seeds/" + std::to_string(seed) + route;
      const HttpResponse expected =
          whole_api.handle_request(http::request<http::string_body>{http::verb::get, target, 11});
      const auto relayed = get(target);
      ASSERT_EQ(relayed.result_int(), expected.status) << target;
      ASSERT_EQ(relayed.body(), expected.body) << target;
      EXPECT_EQ(relayed["X-Spokemesh-Shard"], "0") << target;
    }
  }
  // The first relay resolves shard 0's address from a thread; the rest go at once while
  // it stays resolved (2 s; a slow machine may see it resolved again from a thread).
  EXPECT_GE(servers[1]->relayed_at_once(), shard0_seeds.size() * 3);
  {
    // A deadline already past: answered (504) before the relay starts, and the
    // connection goes on.
    http::request<http::string_body> req{http::verb::get, base + "/seeds/" + std::to_string(shard0_seeds[1]) + "/star",
                                         11};
    req.set(http::field::host, "127.0.0.1");
    req.set("X-Timeout-Ms", "0");
    req.keep_alive(true);
    http::write(stream, req);
    http::response<http::string_body> res;
    http::read(stream, buffer, res);
    EXPECT_EQ(res.result_int(), 504u) << res.body();
    EXPECT_NE(res.body().find("DEADLINE_EXCEEDED"), std::string::npos) << res.body();
    EXPECT_EQ(get(base + "/seeds/" + std::to_string(shard0_seeds[1]) + "/star").result_int(), 200u);
  }

  // A relay at once just before shard 0 stops, so its address is known for the next.
  const std::string target = base + "/seeds/" + std::to_string(shard0_seeds[0]) + "/star";
  for (int tries = 0; tries < 3; ++tries) {
    const std::size_t was = servers[1]->relayed_at_once();
    ASSERT_EQ(get(target).result_int(), 200u);
    if (servers[1]->relayed_at_once() > was) break;
  }
  servers[0]->stop(std::chrono::milliseconds(0));
  const std::size_t before = servers[1]->relayed_at_once();
  const auto at_once = get(target);  // at once while the address is known (within 2 s)
  const bool went_at_once = servers[1]->relayed_at_once() == before + 1;
  const auto threaded = get(target);  // the failure forgot the address: from a thread
  EXPECT_EQ(servers[1]->relayed_at_once(), before + (went_at_once ? 1 : 0));
  if (!went_at_once) std::printf("note: shard 0's address expired before the failed relay; both from threads\n");
  for (const auto* res : {&at_once, &threaded}) {
    EXPECT_EQ(res->result_int(), 503u);
    EXPECT_NE(res->body().find("shard 0 of 2"), std::string::npos) << res->body();
    EXPECT_NE(res->body().find("SHARD_UNAVAILABLE"), std::string::npos) << res->body();
  }
  EXPECT_EQ(at_once.body(), threaded.body());
  servers[1]->stop(std::chrono::milliseconds(0));
}

// ---- gRPC on a real in-process server -----------------------------------------------

struct GrpcFixture {
  TempDir dir;
  std::unique_ptr<Engine> engine = make_engine(dir.path());
  Telemetry telemetry;
  MesherService service{*engine, telemetry, token_auth("tok")};
  HealthService health;
  std::unique_ptr<grpc::Server> server;
  std::unique_ptr<pb::Mesher::Stub> stub;
  std::shared_ptr<grpc::Channel> channel;

  GrpcFixture() {
    grpc::EnableDefaultHealthCheckService(false);
    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
    builder.RegisterService(&service);
    builder.RegisterService(&health);
    health.set_serving(true);
    server = builder.BuildAndStart();
    channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials());
    stub = pb::Mesher::NewStub(channel);
  }
  ~GrpcFixture() {
    health.stop();
    server->Shutdown();
  }

  std::unique_ptr<grpc::ClientContext> ctx(std::chrono::milliseconds deadline = std::chrono::seconds(30)) {
    auto c = std::make_unique<grpc::ClientContext>();
    c->AddMetadata("authorization", "Bearer tok");
    c->set_deadline(std::chrono::system_clock::now() + deadline);
    return c;
  }

  grpc::Status upload(int d, const std::vector<double>& coords, pb::PointSet* out,
                      const std::vector<double>& weights = {}, const std::vector<double>& box = {}) {
    auto c = ctx();
    auto writer = stub->UploadPointSet(c.get(), out);
    pb::UploadPointSetRequest m;
    m.mutable_header()->set_dimension(static_cast<std::uint32_t>(d));
    m.mutable_header()->set_count(coords.size() / d);
    m.mutable_header()->set_weighted(!weights.empty());
    m.mutable_header()->mutable_periodic_box()->Add(box.begin(), box.end());
    writer->Write(m);
    const char* bytes = reinterpret_cast<const char*>(coords.data());
    for (std::size_t at = 0; at < coords.size() * 8; at += 4096) {
      m.set_coordinates(bytes + at, std::min<std::size_t>(4096, coords.size() * 8 - at));
      writer->Write(m);
    }
    const char* w = reinterpret_cast<const char*>(weights.data());
    for (std::size_t at = 0; at < weights.size() * 8; at += 4096) {
      m.set_weights(w + at, std::min<std::size_t>(4096, weights.size() * 8 - at));
      writer->Write(m);
    }
    writer->WritesDone();
    return writer->Finish();
  }
};

TEST(Grpc, EveryMethodAndItsErrors) {
  GrpcFixture f;
  const auto coords = uniform_points(3, 3000, 9);
  pb::PointSet ps;
  ASSERT_TRUE(f.upload(3, coords, &ps).ok());
  EXPECT_EQ(ps.id(), sha256_hex(raw_bytes(3, coords)));
  EXPECT_FALSE(ps.already_existed());
  pb::PointSet again;
  ASSERT_TRUE(f.upload(3, coords, &again).ok());
  EXPECT_TRUE(again.already_existed());

  pb::GetPointSetRequest get;
  get.set_point_set_id(ps.id());
  pb::PointSet info;
  ASSERT_TRUE(f.stub->GetPointSet(f.ctx().get(), get, &info).ok());
  EXPECT_EQ(info.count(), 3000u);
  pb::ListPointSetsResponse listed;
  ASSERT_TRUE(f.stub->ListPointSets(f.ctx().get(), {}, &listed).ok());
  EXPECT_EQ(listed.point_sets_size(), 1);

  pb::SeedRequest seed;
  seed.set_point_set_id(ps.id());
  seed.set_seed(42);
  pb::Star star1, star2;
  ASSERT_TRUE(f.stub->GetStar(f.ctx().get(), seed, &star1).ok());
  ASSERT_TRUE(f.stub->GetStar(f.ctx().get(), seed, &star2).ok());
  EXPECT_EQ(star1.SerializeAsString(), star2.SerializeAsString());  // byte-identical answers
  EXPECT_EQ(star1.circumcenters_size(), star1.simplices_size() / 4 * 3);
  pb::Neighbors neighbors;
  pb::GetNeighborsRequest neighbors_request;
  neighbors_request.set_point_set_id(seed.point_set_id());
  neighbors_request.set_seed(seed.seed());
  ASSERT_TRUE(f.stub->GetNeighbors(f.ctx().get(), neighbors_request, &neighbors).ok());
  EXPECT_TRUE(neighbors.exact());
  // Approximate on the same set: a subset, flagged as such, with the walk's statistics.
  neighbors_request.set_mode(pb::NEIGHBOR_MODE_APPROXIMATE);
  pb::Neighbors approx;
  ASSERT_TRUE(f.stub->GetNeighbors(f.ctx().get(), neighbors_request, &approx).ok());
  EXPECT_FALSE(approx.exact());
  EXPECT_GT(approx.vertices_visited(), 0u);
  EXPECT_TRUE(std::includes(neighbors.neighbors().begin(), neighbors.neighbors().end(), approx.neighbors().begin(),
                            approx.neighbors().end()));
  EXPECT_GT(neighbors.neighbors_size(), 3);
  pb::VoronoiCell cell;
  pb::GetVoronoiCellRequest cell_request;
  cell_request.set_point_set_id(seed.point_set_id());
  cell_request.set_seed(seed.seed());
  ASSERT_TRUE(f.stub->GetVoronoiCell(f.ctx().get(), cell_request, &cell).ok());
  EXPECT_EQ(cell.facets_size(), neighbors.neighbors_size());

  // Download gives the upload back.
  {
    auto c = f.ctx();
    auto reader = f.stub->DownloadPointSet(c.get(), get);
    pb::CoordinateChunk chunk;
    std::string bytes;
    while (reader->Read(&chunk)) bytes += chunk.coordinates();
    ASSERT_TRUE(reader->Finish().ok());
    EXPECT_EQ(bytes, std::string(reinterpret_cast<const char*>(coords.data()), coords.size() * 8));
  }
  // Shards unite to the mesh.
  std::uint64_t simplices = 0;
  for (std::uint32_t k = 0; k < 2; ++k) {
    pb::StreamSimplicesRequest r;
    r.set_point_set_id(ps.id());
    r.set_shard_index(k);
    r.set_shard_count(2);
    auto c = f.ctx();
    auto reader = f.stub->StreamSimplices(c.get(), r);
    pb::SimplexBatch batch;
    while (reader->Read(&batch)) {
      simplices += static_cast<std::uint64_t>(batch.simplices_size()) / 4;
      EXPECT_EQ(batch.seed_begin(), k == 0 ? 0u : 1500u);
    }
    ASSERT_TRUE(reader->Finish().ok());
  }
  PointSet points(3, coords);
  ASSERT_TRUE(points.validate("t").is_ok());
  KdTree tree(points);
  EXPECT_EQ(simplices, mesh_seeds(tree, {}, [](auto, auto) { return Status::ok(); }).value().simplices);

  // Errors.
  seed.set_seed(3000);
  EXPECT_EQ(f.stub->GetStar(f.ctx().get(), seed, &star1).error_code(), grpc::StatusCode::OUT_OF_RANGE);
  seed.set_point_set_id(std::string(64, 'd'));
  EXPECT_EQ(f.stub->GetStar(f.ctx().get(), seed, &star1).error_code(), grpc::StatusCode::NOT_FOUND);
  {
    grpc::ClientContext no_token;
    EXPECT_EQ(f.stub->GetPointSet(&no_token, get, &info).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  }
  {
    pb::PointSet out;
    auto c = f.ctx();
    auto writer = f.stub->UploadPointSet(c.get(), &out);
    pb::UploadPointSetRequest m;
    m.set_coordinates("12345678");
    writer->Write(m);
    writer->WritesDone();
    const grpc::Status s = writer->Finish();
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("header"), std::string::npos);
  }
  {
    std::vector<double> nan_points = {0, 0, 1, 0, 0, std::nan("")};
    pb::PointSet out;
    const grpc::Status s = f.upload(2, nan_points, &out);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(s.error_message().find("point 2, coordinate 1"), std::string::npos) << s.error_message();
  }
  pb::DeletePointSetRequest del;
  del.set_point_set_id(ps.id());
  pb::DeletePointSetResponse deleted;
  EXPECT_TRUE(f.stub->DeletePointSet(f.ctx().get(), del, &deleted).ok());
  EXPECT_EQ(f.stub->GetPointSet(f.ctx().get(), get, &info).error_code(), grpc::StatusCode::NOT_FOUND);
}

// The health service (ours, synchronous: grpc_health.hpp) answers as gRPC's built-in one:
// Check of "" and of the Mesher, NOT_FOUND for another name, and Watch streams each change.
TEST(Grpc, HealthChecksAndWatches) {
  GrpcFixture f;
  namespace hv = grpc::health::v1;
  auto health = hv::Health::NewStub(f.channel);
  for (const char* name : {"", "spokemesh.v1.Mesher"}) {
    grpc::ClientContext c;
    hv::HealthCheckRequest r;
    r.set_service(name);
    hv::HealthCheckResponse status;
    ASSERT_TRUE(health->Check(&c, r, &status).ok()) << name;
    EXPECT_EQ(status.status(), hv::HealthCheckResponse::SERVING) << name;
  }
  {
    grpc::ClientContext c;
    hv::HealthCheckRequest r;
    r.set_service("no.such.Service");
    hv::HealthCheckResponse status;
    const grpc::Status s = health->Check(&c, r, &status);
    EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND);
    EXPECT_NE(s.error_message().find("no.such.Service"), std::string::npos) << s.error_message();
  }
  {
    grpc::ClientContext c;
    hv::HealthCheckRequest r;
    r.set_service("no.such.Service");
    auto reader = health->Watch(&c, r);
    hv::HealthCheckResponse status;
    ASSERT_TRUE(reader->Read(&status));
    EXPECT_EQ(status.status(), hv::HealthCheckResponse::SERVICE_UNKNOWN);
    c.TryCancel();
    reader->Finish();
  }
  grpc::ClientContext c;
  c.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  auto reader = health->Watch(&c, hv::HealthCheckRequest{});
  hv::HealthCheckResponse status;
  ASSERT_TRUE(reader->Read(&status));
  EXPECT_EQ(status.status(), hv::HealthCheckResponse::SERVING);
  f.health.set_serving(false);
  ASSERT_TRUE(reader->Read(&status));
  EXPECT_EQ(status.status(), hv::HealthCheckResponse::NOT_SERVING);
  f.health.set_serving(true);
  ASSERT_TRUE(reader->Read(&status));
  EXPECT_EQ(status.status(), hv::HealthCheckResponse::SERVING);
  // stop() (the server stopping) ends the stream with OK.
  f.health.stop();
  EXPECT_FALSE(reader->Read(&status));
  EXPECT_TRUE(reader->Finish().ok());
}

TEST(Grpc, WeightedPeriodicSetsCarryOffsets) {
  GrpcFixture f;
  // A 5 x 5 grid on the torus [0, 5)^2 with equal weights: the plain torus mesh.
  std::vector<double> coords;
  for (int i = 0; i < 5; ++i) {
    for (int j = 0; j < 5; ++j) coords.insert(coords.end(), {double(i), double(j)});
  }
  const std::vector<double> weights(25, 0.25), box = {0, 0, 5, 5};
  pb::PointSet ps;
  ASSERT_TRUE(f.upload(2, coords, &ps, weights, box).ok());
  EXPECT_EQ(ps.id(), sha256_hex(raw_bytes(2, coords) + "W" + double_bytes(weights) + "P" + double_bytes(box)));
  EXPECT_TRUE(ps.weighted());
  EXPECT_EQ(std::vector<double>(ps.periodic_box().begin(), ps.periodic_box().end()), box);
  pb::SeedRequest seed;
  seed.set_point_set_id(ps.id());
  seed.set_seed(12);
  pb::Star star;
  ASSERT_TRUE(f.stub->GetStar(f.ctx().get(), seed, &star).ok());
  EXPECT_EQ(star.simplices_size(), 6 * 3);
  EXPECT_EQ(star.offsets_size(), 6 * 3 * 2);
  pb::StreamSimplicesRequest request;
  request.set_point_set_id(ps.id());
  auto c = f.ctx();
  auto reader = f.stub->StreamSimplices(c.get(), request);
  pb::SimplexBatch batch;
  int simplices = 0;
  while (reader->Read(&batch)) {
    EXPECT_EQ(batch.offsets_size(), batch.simplices_size() * 2);
    simplices += batch.simplices_size() / 3;
  }
  ASSERT_TRUE(reader->Finish().ok());
  EXPECT_EQ(simplices, 50);
  // Weights that do not match the count: INVALID_ARGUMENT naming them, nothing stored.
  pb::PointSet refused;
  const grpc::Status bad = f.upload(2, coords, &refused, std::vector<double>(24, 0.25), box);
  EXPECT_EQ(bad.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(bad.error_message().find("weights: received 24"), std::string::npos) << bad.error_message();
  pb::ListPointSetsResponse listed;
  ASSERT_TRUE(f.stub->ListPointSets(f.ctx().get(), {}, &listed).ok());
  EXPECT_EQ(listed.point_sets_size(), 1);
}

TEST(Grpc, DeadlineAndCancellationOfAStream) {
  GrpcFixture f;
  pb::PointSet ps;
  ASSERT_TRUE(f.upload(3, uniform_points(3, 30000, 11), &ps).ok());
  pb::StreamSimplicesRequest r;
  r.set_point_set_id(ps.id());
  {
    auto c = f.ctx(std::chrono::milliseconds(50));
    auto reader = f.stub->StreamSimplices(c.get(), r);
    pb::SimplexBatch batch;
    while (reader->Read(&batch)) {}
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  }
  {
    // Read one batch, then cancel: the server stops (its log records CANCELLED).
    auto c = f.ctx();
    auto reader = f.stub->StreamSimplices(c.get(), r);
    pb::SimplexBatch batch;
    ASSERT_TRUE(reader->Read(&batch));
    c->TryCancel();
    while (reader->Read(&batch)) {}
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::CANCELLED);
  }
  // The server is still healthy.
  auto health = grpc::health::v1::Health::NewStub(f.channel);
  grpc::ClientContext hc;
  grpc::health::v1::HealthCheckResponse status;
  ASSERT_TRUE(health->Check(&hc, {}, &status).ok());
  EXPECT_EQ(status.status(), grpc::health::v1::HealthCheckResponse::SERVING);
  pb::SeedRequest seed;
  seed.set_point_set_id(ps.id());
  pb::Star star;
  EXPECT_TRUE(f.stub->GetStar(f.ctx().get(), seed, &star).ok());
}

}  // namespace
}  // namespace spokemesh::service
