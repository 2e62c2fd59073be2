// Engine: the service's operations, independent of gRPC and HTTP.
//
// Both transports are thin adapters over this class: they decode a request, call
// one Engine function, and encode its Result (status codes mapped once, in
// status_map.hpp). The Engine owns the point-set store and the limits, and runs
// every computation under a CallControl, which stops it at its deadline or when
// the client goes away.
//
// Thread safety: all member functions are safe to call concurrently.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "auth.hpp"
#include "limits.hpp"
#include "spokemesh/approx.hpp"
#include "spokemesh/cells.hpp"
#include "spokemesh/domain.hpp"
#include "spokemesh/periodic.hpp"
#include "spokemesh/periodic_cells.hpp"
#include "spokemesh/point_queries.hpp"
#include "spokemesh/shape_domain.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/voronoi.hpp"
#include "store.hpp"

namespace spokemesh::service {

using Clock = std::chrono::steady_clock;

using defaults::kStreamWindowBytes;

// The engine's limits (defaults: limits.hpp).
struct Limits {
  std::uint64_t max_points = defaults::kMaxPoints;
  int max_dimension = defaults::kMaxUploadDimension;  // uploads; exact answers are defined up to kMaxDimension (8)
  std::uint64_t max_memory = 4ull << 30;  // the memory budget (the server's default: half the cgroup limit or RAM)
  std::chrono::milliseconds default_deadline = defaults::kDefaultDeadline;
  std::chrono::milliseconds upload_idle_timeout = defaults::kUploadIdleTimeout;  // an idle upload stream ends
  unsigned stream_threads = 1;  // worker threads per StreamSimplices call
  std::size_t stream_cache_bytes =
      defaults::kStreamCacheBytes;  // per streamed shard: its local triangulations, or the front's mail (0: none)
  std::size_t max_display_name = defaults::kMaxDisplayName;
  // Build and keep each 2-d or 3-d set's triangulation of every point in the background
  // on its first request, within the budget (Engine::keep_triangulation); off: stars
  // are walked unless a batch or stream kept one.
  bool keep_triangulations = true;
};

// Stops one request's computation: at `deadline`, or once `client_gone()` says the
// client cancelled or disconnected. The Watchdog polls registered controls and sets
// the flag the core checks between wraps.
class CallControl {
 public:
  // on_stop, if given, runs once on the watchdog's thread when the flag is set (e.g.
  // grpc::ServerContext::TryCancel, to end a blocked Read).
  explicit CallControl(Clock::time_point deadline, std::function<bool()> client_gone = {},
                       std::function<void()> on_stop = {});
  ~CallControl();
  CallControl(const CallControl&) = delete;
  CallControl& operator=(const CallControl&) = delete;

  const std::atomic<bool>* stop_flag() const { return &stop_; }
  bool stopped() const { return stop_.load(std::memory_order_relaxed); }
  Clock::time_point deadline() const { return Clock::time_point(Clock::duration(deadline_.load())); }
  // Moves the deadline (an idle timeout restarted by each message that arrives).
  void extend_deadline(Clock::time_point deadline) { deadline_.store(deadline.time_since_epoch().count()); }
  // Called by the watchdog: sets the flag if the deadline passed or the client left.
  void poll(Clock::time_point now);
  // The status for a computation that was stopped: DEADLINE_EXCEEDED or CANCELLED.
  Status stopped_status(const std::string& what) const;

 private:
  std::atomic<Clock::rep> deadline_;
  Clock::time_point start_;
  std::function<bool()> client_gone_;
  std::function<void()> on_stop_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> client_left_{false};
};

// One thread that polls every live CallControl every few milliseconds.
class Watchdog {
 public:
  static Watchdog& instance();
  void add(CallControl* c);
  void remove(CallControl* c);

 private:
  Watchdog();
  ~Watchdog();
  void run();
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<CallControl*> controls_;
  bool quit_ = false;
  std::thread thread_;
};

// The caller in open mode (no keys configured): an admin of the empty tenant.
inline const Principal kOpenPrincipal{"", true};

struct UploadHeader {
  std::int64_t dimension = 0;
  std::int64_t count = 0;
  std::string display_name;
  // Issue 28: count power weights follow the coordinates (UploadSession::append_weights).
  bool weighted = false;
  // A periodic set's torus: LO_1..LO_d, HI_1..HI_d (every point in [LO, HI)); or empty.
  std::vector<double> periodic_box;
};

// A point set arriving in chunks. The id's SHA-256 is computed as bytes arrive; a
// chunk that would exceed dimension * count * 8 bytes is refused at once.
class UploadSession {
 public:
  Status append(const void* data, std::size_t size);
  // A weighted upload's weights (little-endian float64, one per point, in order),
  // after all the coordinates; charged to the budget as they arrive.
  Status append_weights(const void* data, std::size_t size);
  // The whole body at once, already as doubles (and what they are charged): taken
  // without a copy.
  Status adopt(std::vector<double>&& coords, MemoryBudget::Charge&& charge);
  std::uint64_t expected_bytes() const { return expected_; }
  std::uint64_t received_bytes() const { return received_; }

 private:
  friend class Engine;
  UploadHeader header_;
  std::uint64_t expected_ = 0;
  std::uint64_t received_ = 0;
  std::vector<double> coords_;
  MemoryBudget::Charge charge_;  // coords_'s and weights_'s capacity against the server's budget
  std::vector<double> weights_;
  std::uint64_t weight_bytes_ = 0;  // received
  const MemoryBudget* budget_ = nullptr;
  std::unique_ptr<Sha256> sha_;
  std::string parent_id_;  // an append's: the set whose points come first
};

struct NeighborQuery {
  using Mode = NeighborMode;  // approx.hpp: one vocabulary for every route
  Mode mode = Mode::kExact;
  std::uint32_t max_consecutive_misses = 0;  // 0 = kDefaultMaxMisses (approx.hpp)
  std::uint32_t max_vertices = 0;            // 0 = kDefaultMaxVertices (approx.hpp)
};

struct NeighborAnswer {
  std::vector<std::uint32_t> neighbors;
  std::vector<std::int32_t> offsets;  // periodic sets: d per neighbour, its image's offset
  bool exact = true;
  ApproxNeighbors walk;  // approximate modes: the walk's statistics
};

// A requested clipping domain, as the transports carry it (proto Domain; REST query
// parameters box=, halfspaces=, bounding_box=). At most one of the three is set.
struct DomainSpec {
  std::vector<double> box;         // LO_1..LO_d, HI_1..HI_d
  std::vector<double> halfspaces;  // d + 1 values per wall: a_1 .. a_d b (a . x <= b)
  bool bounding_box = false;
  // A domain of any shape (shape_domain.hpp): a file's bytes and its format, one of
  // off, obj, stl, rings, geojson (docs/cells.md, "Domains of any shape").
  std::string shape_format;
  std::string shape_data;
  bool empty() const { return box.empty() && halfspaces.empty() && !bounding_box && shape_format.empty(); }
};

enum class BatchKind { kStars, kNeighbors, kCells };

struct StarAnswer {
  Star star;
  std::vector<double> circumcentres;  // d per simplex (power centres for weighted sets)
  std::vector<std::int32_t> offsets;  // periodic sets: (d + 1) d per simplex, each vertex's image
};

// One seed's answer in a batch: the member for the batch's kind is set.
struct BatchAnswer {
  std::uint64_t seed = 0;
  StarAnswer star;
  NeighborAnswer neighbors;
  VoronoiCell cell;
  // The transport's encoding of it, when the batch was given an encoder (Engine::batch).
  std::string encoded;
};

// Point queries (:locate, :interpolate): answers at points that need not be in the set.
enum class PointMethod {
  kLocate,   // the canonical simplex holding the point, barycentric coordinates, natural neighbours
  kLinear,   // values interpolated by the barycentric coordinates
  kNatural,  // values interpolated by Sibson's coordinates (2-d and 3-d)
  kNearest,  // the nearest point's values
};

struct PointQuery {
  PointMethod method = PointMethod::kLocate;
  // kLocate: natural neighbours too (2-d and 3-d sets; ignored above).
  bool natural = true;
  // Interpolation: `width` values per point of the set, row-major (count * width), and
  // what a point outside the hull gets (none: no values).
  std::span<const double> values;
  std::size_t width = 0;
  std::optional<double> fill;
};

// One query point's answer, in the request's order.
struct PointResult {
  std::uint64_t index = 0;  // the query's position in the request
  PointAnswer answer;       // kLocate; kLinear and kNatural read theirs from it
  bool has_values = false;  // interpolation: false outside the hull without a fill
  std::vector<double> values;
  std::int64_t nearest = -1;  // kNearest: the point whose values these are
  std::string encoded;        // the transport's encoding (Engine::points' encoder)
};

// Values kept for a set's points (Engine::put_values), named by a content hash.
struct ValuesInfo {
  std::string values_id;
  std::string point_set_id;
  std::uint32_t width = 0;
  std::uint64_t count = 0;
  bool already_existed = false;
};

// A kept values array as loaded: shared by the requests reading it.
struct KeptValues {
  std::uint32_t width = 0;
  std::vector<double> values;
};

// Two meanings, two words (docs/service.md, "Words"): a *shard* is a deployment's
// (replicas serving some of the pieces of every set kept as pieces: ShardSettings); a
// *part* is one of the n pieces of work a whole-mesh or cell stream is cut into by the
// client (the API's shard_index/shard_count and ?shard=&shards=, named so before the
// deployment's shards existed, and kept for compatibility). Part k of n owns the
// positions [floor(k N / n), floor((k + 1) N / n)).
struct StreamPart {
  std::uint32_t begin = 0, end = 0;
};
StreamPart stream_part(std::uint64_t n, std::uint32_t part_index, std::uint32_t part_count);

// Sharded serving (docs/service.md, "Sharded serving"): sets of at least
// `pieces_above` points are also stored as pieces (pieces.hpp), and a replica of shard
// `index` of `count` answers the seeds of its pieces from them alone.
struct ShardSettings {
  std::uint32_t index = 0;
  std::uint32_t count = 0;         // 0: not sharded (sets are held whole)
  std::uint64_t pieces_above = 0;  // 0: uploads are not cut into pieces
  std::uint32_t piece_points = kDefaultPiecePoints;
  bool sharded() const { return count > 0; }
};

// What one seed's request is answered from: the set held whole, or on a sharded replica
// the piece holding the seed, and the seed's index in it. Held, the set stays in memory
// while the request runs.
struct Holding {
  std::shared_ptr<const StoredSet> set;
  std::uint32_t index = 0;
};

// Which shard answers each seed of a set kept as pieces (docs/service.md, "Clients
// that route themselves"). version: the first 16 hex digits of the SHA-256 of the
// manifest and the shard count (every replica computes the same).
struct ShardMap {
  bool sharded = false;  // false: a set held whole, or a replica that is not sharded
  std::string version;
  std::uint32_t shard_count = 0;
  std::uint64_t count = 0;
  std::vector<std::uint16_t> seed_shards;  // per seed (empty when not sharded)
};

// Where a seed's request is answered: here, or by a replica of `shard`.
struct SeedRoute {
  bool here = true;
  std::uint32_t shard = 0;
  std::uint32_t piece = 0;
};

class Engine {
 public:
  Engine(std::unique_ptr<PointSetStore> store, Limits limits, ShardSettings shards = {});

  const ShardSettings& shards() const { return shards_; }
  // Point queries on sets kept as pieces answered from the set's own file so far.
  std::uint64_t point_queries_from_whole() const { return completed_from_whole_.load(); }
  // A batch's seeds' shards on a sharded replica, in the request's order; empty when
  // the batch is answered here whole (a set held whole, a replica that is not sharded).
  // The errors batch() gives for the seeds (none, too many, one out of range).
  Result<std::vector<std::uint32_t>> batch_routes(const std::string& id, const std::vector<std::uint64_t>& seeds);
  // The shard whose replicas answer `seed` of set `id` (here for a set held whole, for
  // a replica that is not sharded, and for any error, which the local call reports).
  SeedRoute route_seed(const std::string& id, std::uint64_t seed);
  // The set's shard map (read from its owner map; charged to the budget while it is
  // made): NOT_FOUND for an unknown set.
  Result<ShardMap> shard_map(const std::string& id);

  const Limits& limits() const { return limits_; }
  PointSetStore& store() { return *store_; }
  // Kept triangulations built from an append's parent's (extend_whole) so far.
  std::uint64_t triangulations_extended() const;

  // Uploads: begin() checks the header against the limits; finish() checks the byte
  // count, validates the points (NaN/Inf, range, duplicates, affine span) and stores
  // them durably before returning.
  Result<std::unique_ptr<UploadSession>> begin_upload(const UploadHeader& header) const;
  // Tenancy (auth.hpp): `who` becomes an owner of the set it uploads (the set is
  // stored once whoever uploads it); already_existed says whether `who` had it.
  Result<PointSetInfo> finish_upload(UploadSession& session, const Principal& who = kOpenPrincipal);
  // Appending: a session for a new point set made of the stored set `parent_id`'s
  // points followed by `added.count` new ones, whose coordinates the caller then
  // appends as an upload's (finish_upload stores it). The new set's id is the hash of
  // the whole, as if it had been uploaded whole (ids stay content hashes); the parent
  // is unchanged. What is reused: the parent's stored coordinates (the client sends
  // only the new points). added.dimension 0 takes the parent's; another than the
  // parent's is INVALID_ARGUMENT; an unknown parent, or another tenant's, NOT_FOUND;
  // the whole set is held to the upload limits.
  Result<std::unique_ptr<UploadSession>> begin_append(const std::string& parent_id, UploadHeader added,
                                                      const Principal& who = kOpenPrincipal);

  // NOT_FOUND unless `who` may see the set (an owner, or an admin): other tenants'
  // sets are indistinguishable from absent ones.
  Status authorize(const std::string& id, const Principal& who);
  Result<PointSetInfo> get_point_set(const std::string& id, const Principal& who = kOpenPrincipal);
  // page_token is the last id of the previous page ("" for the first); only `who`'s sets.
  Result<std::vector<PointSetInfo>> list_point_sets(std::uint32_t page_size, const std::string& page_token,
                                                    std::string* next_page_token,
                                                    const Principal& who = kOpenPrincipal);
  // A tenant gives up its ownership (the set goes when no owner is left); an admin
  // deletes the set for everyone.
  Status delete_point_set(const std::string& id, const Principal& who = kOpenPrincipal);
  Result<std::shared_ptr<const StoredSet>> point_set(const std::string& id) { return store_->get(id); }

  // The holding that answers `seed` of set `id` (with `pieces`, on a sharded replica the
  // piece holding it), read from disk if it is not in memory: NOT_FOUND, OUT_OF_RANGE
  // naming the seed and the set's size, or the store's errors.
  Result<Holding> hold(const std::string& id, std::uint64_t seed, bool pieces = true);
  // The holding when an answer from it cannot block: the set (on a sharded replica the
  // seed's piece, of this replica's shard) is in memory with its kept triangulation.
  // nullopt otherwise, errors included (hold() names them). Reads no file but the
  // owner map's entry of the seed (a pread of the page cache).
  std::optional<Holding> hold_at_hand(const std::string& id, std::uint64_t seed);

  // One seed's answers, by id (hold() first) or from a holding.
  Result<StarAnswer> star(const std::string& id, std::uint64_t seed, const CallControl& control);
  Result<StarAnswer> star(const Holding& held, const CallControl& control);
  Result<NeighborAnswer> neighbors(const std::string& id, std::uint64_t seed, const NeighborQuery& query,
                                   const CallControl& control);
  // From a holding: approximate modes need the whole set's (hold(id, seed, false)).
  Result<NeighborAnswer> neighbors(const Holding& held, const NeighborQuery& query, const CallControl& control);
  // The cell, clipped when `domain` is not empty. INVALID_ARGUMENT for a malformed
  // domain (naming the field) or a seed outside it.
  // A domain of any shape from a file's bytes (format: off, obj, stl, rings, geojson),
  // parsed and validated (INVALID_ARGUMENT naming the fault), kept among the last few.
  Result<std::shared_ptr<const ShapeDomain>> parse_shape(const std::string& format, const std::string& data);
  Result<VoronoiCell> cell(const std::string& id, std::uint64_t seed, const DomainSpec& domain,
                           const CallControl& control);
  Result<VoronoiCell> cell(const Holding& held, const DomainSpec& domain, const CallControl& control);

  // Calls `emit` with consecutive batches of at most batch_size simplices owned by the
  // shard's seeds, in sweep order, on the calling thread. Shard k of S holds the seeds
  // at sweep positions (SpaceSplit order) stream_part(n, k, S), so the shards in
  // order concatenate to the whole mesh as mesh_seeds writes it. A non-OK status from emit stops the
  // run (and is returned). Only a bounded window is computed ahead of emit.
  //
  // A periodic set's shard k holds the seeds [floor(k N / n), floor((k + 1) N / n)) in
  // index order instead, each seed's simplices being the rows of its star whose first
  // vertex is the seed at offset 0, in the star's (canonical) order; `offsets` then
  // carries (d + 1) d image offsets per simplex (empty for other sets).
  using BatchSink = std::function<Status(std::span<const std::uint32_t> simplices,
                                         std::span<const std::int32_t> offsets, std::uint64_t seeds_done)>;
  Status stream_simplices(const std::string& id, std::uint32_t shard_index, std::uint32_t shard_count,
                          std::uint32_t batch_size, const CallControl& control, const BatchSink& emit,
                          StreamPart* range = nullptr, int* dimension = nullptr);

  // The cells of the shard's seeds in order, in batches of at most batch_size (0 =
  // defaults::kCellBatchSize), clipped to `domain` (empty: the set's bounding box); with
  // measures_only, without vertices. Streamed as stream_simplices is.
  using CellBatchSink = std::function<Status(std::span<const VoronoiCell> cells, std::uint64_t seeds_done)>;
  // Many seeds in one call: each answer is the single call's (star, neighbors with
  // `query`, cell with `domain`), computed by worker threads and handed to `emit` in
  // request order, a bounded round at a time. INVALID_ARGUMENT for more than
  // defaults::kMaxBatchSeeds seeds or none; OUT_OF_RANGE naming the first seed >= count.
  // encode (optional): called on the worker that computed each answer, so that the
  // transport's encoding runs on the workers too (it sets BatchAnswer::encoded, and
  // may drop what it no longer needs); it must be safe to call concurrently.
  using AnswerSink = std::function<Status(std::span<const BatchAnswer> answers, std::uint64_t done)>;
  using AnswerEncoder = std::function<void(BatchAnswer& answer)>;
  Status batch(const std::string& id, const std::vector<std::uint64_t>& seeds, BatchKind kind,
               const NeighborQuery& query, const DomainSpec& domain, const CallControl& control, const AnswerSink& emit,
               const AnswerEncoder& encode = {});
  // Values for the points of set `id` (count * width, row-major; each finite), kept
  // durably in the data directory (values/<id>/<values_id>) until the set is deleted.
  // values_id: the SHA-256 of the set's id, the width and the values, so putting the
  // same values again does no work (already_existed). INVALID_ARGUMENT naming the
  // field; NOT_FOUND for an unknown set.
  Result<ValuesInfo> put_values(const std::string& id, std::span<const double> values, std::uint32_t width);
  // Values kept for set `id`, from memory (the last few read are kept, charged to the
  // budget) or read and verified from their file: NOT_FOUND naming values_id when the
  // set has none by that id.
  Result<std::shared_ptr<const KeptValues>> kept_values(const std::string& id, const std::string& values_id);
  // Answers at query points (`queries`: d coordinates each, row-major), handed to `emit`
  // in request order a bounded round at a time (encode as batch()'s). The set's
  // triangulation as arrays is made on the first call and kept (StoredSet::located).
  // Errors, each naming the field: INVALID_ARGUMENT for no queries, more than
  // defaults::kMaxBatchSeeds, coordinates that are not whole points or not finite
  // ("queries[i][c]"), values of another shape or not finite ("values[i]"), natural
  // neighbours outside 2-d and 3-d; FAILED_PRECONDITION for a periodic or weighted set;
  // NOT_FOUND; RESOURCE_EXHAUSTED when the arrays do not fit the budget. A set kept as
  // pieces on a sharded replica: points_from_pieces (the same answers).
  using PointSink = std::function<Status(std::span<const PointResult> answers, std::uint64_t done)>;
  using PointEncoder = std::function<void(PointResult& answer)>;
  Status points(const std::string& id, std::span<const double> queries, const PointQuery& query,
                const CallControl& control, const PointSink& emit, const PointEncoder& encode = {});
  Status stream_cells(const std::string& id, std::uint32_t shard_index, std::uint32_t shard_count,
                      std::uint32_t batch_size, const DomainSpec& domain, bool measures_only,
                      const CallControl& control, const CellBatchSink& emit, StreamPart* range = nullptr);

 private:
  // Whether this replica's shard serves the piece (every piece when not sharded).
  bool is_own_piece(std::uint32_t piece, std::uint32_t pieces) const;
  // Streams of a set kept as pieces: simplices piece by piece in sweep order (each
  // piece swept over its own points), cells seed by seed as their single calls.
  Status stream_simplices_from_pieces(const std::string& id, const PieceManifest& manifest, StreamPart range,
                                      std::uint32_t batch_size, const CallControl& control, const BatchSink& emit);
  Status stream_cells_from_pieces(const std::string& id, StreamPart range, std::uint32_t batch_size,
                                  const DomainSpec& spec, bool measures_only, const CallControl& control,
                                  const CellBatchSink& emit);
  // Point queries on a set kept as pieces: each answered from the piece whose box is
  // nearest it (loaded here if need be) where the piece holds everything the answer
  // rests on (answer_support: every ball within the set's box inside the held box, every
  // hull facet with nothing unheld beyond), the rest from the set's own file.
  Status points_from_pieces(const std::string& id, const PieceLayout& layout, std::span<const double> queries,
                            const PointQuery& query, const CallControl& control, const PointSink& emit,
                            const PointEncoder& encode);
  // The simplex of each of `count` query points (row-major) in the set's arrays
  // (located_index), -1 outside: in Morton order, each walked from the one before.
  Status locate_points(const StoredSet& set, const double* queries, std::size_t count, const CallControl& control,
                       std::shared_ptr<const DelaunayIndex>& index, std::vector<std::int32_t>& located);
  // The set's triangulation as arrays for point queries: kept, or made now and kept.
  Result<std::shared_ptr<const DelaunayIndex>> located_index(const StoredSet& set, const CallControl& control);
  // A batch on a set kept as pieces: seed by seed, each from the piece holding it.
  Status batch_from_pieces(const std::string& id, std::uint64_t count, const std::vector<std::uint64_t>& seeds,
                           BatchKind kind, const NeighborQuery& query, const DomainSpec& spec,
                           const CallControl& control, const AnswerSink& emit, const AnswerEncoder& encode);
  // Cuts a stored set into pieces when its shape and size call for it (ShardSettings)
  // and it has none yet; `points` null: loaded from the store.
  Status ensure_pieces(const PointSetInfo& info, const PointSet* points);
  // A clipped cell of a piece's seed whose reach (squared) the piece does not hold:
  // rebuilt from the seed's neighbours and every point inside a box around the reach
  // (read from the pieces whose boxes meet it), the box doubled until it holds the
  // reach of the cell built.
  Result<VoronoiCell> complete_cell(const StoredSet& piece, std::uint32_t seed, double reach2, const Domain& domain,
                                    const CallControl& control);
  Result<Star> compute_star(const StoredSet& set, std::uint32_t seed, const CallControl& control);
  // A seed of `set` by its index in the whole point set, as answers and errors name it
  // (a piece's seeds are its own indices inside).
  static std::uint64_t global_seed(const StoredSet& set, std::uint32_t seed) {
    return set.piece ? set.piece->ids[seed] : seed;
  }
  // A periodic set's star (and cell, when asked) of one seed.
  static Result<PeriodicStar> periodic_star_of(const StoredSet& set, std::uint32_t seed, const CallControl& control,
                                               VoronoiCell* cell, bool centres);
  static StarAnswer periodic_star_answer(const StoredSet& set, PeriodicStar star);
  static NeighborAnswer periodic_neighbor_answer(const StoredSet& set, const PeriodicStar& star);
  // A star with its circumcentres, as GetStar answers it (single and batched).
  static StarAnswer star_answer(const StoredSet& set, Star star);
  // A periodic set's whole-mesh and cell streams: seed by seed (see BatchSink).
  Status stream_periodic_simplices(const StoredSet& set, StreamPart range, std::uint32_t batch_size,
                                   const CallControl& control, const BatchSink& emit);
  Status stream_periodic_cells(const StoredSet& set, StreamPart range, std::uint32_t batch_size, bool measures_only,
                               const CallControl& control, const CellBatchSink& emit);
  // INVALID_ARGUMENT for a domain or an approximate mode on a periodic set, or an
  // approximate mode on a weighted one.
  static Status check_query(const StoredSet& set, const DomainSpec* domain, const NeighborQuery* query);
  Result<VoronoiCell> cell_of(const StoredSet& set, std::uint32_t seed, const Domain* domain,
                              const CallControl& control, const ShapeDomain* shape = nullptr);
  // The Domain a spec names for this set (nullopt: none), or INVALID_ARGUMENT. With a
  // domain of any shape (`shape`, from shape_for), the box its cells are first clipped to.
  static Result<std::optional<Domain>> resolve_domain(const StoredSet& set, const DomainSpec& spec, bool default_box,
                                                      const ShapeDomain* shape = nullptr);
  // The spec's domain of any shape (nullptr: none), parsed and validated, for this set
  // (2-d or 3-d, unweighted, not periodic, held whole): INVALID_ARGUMENT naming the
  // fault, FAILED_PRECONDITION for a set it does not apply to. The last few parsed are
  // kept (by the SHA-256 of format and bytes), charged to the budget.
  Result<std::shared_ptr<const ShapeDomain>> shape_for(const StoredSet& set, const DomainSpec& spec);
  // The facet cache a stream may have within the budget: its cap (0: none) and charge.
  std::size_t charge_stream_cache(int dimension, std::uint32_t n, MemoryBudget::Charge& charge);
  // The same for a whole-mesh stream's sweep: charges its memo (the front's mail and
  // the workers' tables) and returns the mail cap to run with (0: no memo).
  std::size_t charge_sweep_memo(int dimension, std::uint32_t n, unsigned threads, MemoryBudget::Charge& charge);
  // Gives a run by local triangulations the set's kept triangulation of every point,
  // and has it keep the one the run builds (charged to the budget while the set lives;
  // not kept when it does not fit). `set` must outlive the run.
  void share_whole_triangulation(const StoredSet& set, MeshOptions& options);
  // RESOURCE_EXHAUSTED for exact work on a set above the exact dimension limit.
  static Status exact_allowed(const StoredSet& set, const char* what);
  // Asks, once per set, for its triangulation of every point to be built in the
  // background and kept with it (2-d and 3-d, unweighted, not periodic; held whole or a
  // piece), charged to the budget while the set lives; refused: its stars are walked,
  // the same bytes. Per-seed requests, batches and streams read it once it is there
  // (StoredSet::kept_whole).
  void keep_triangulation(const std::shared_ptr<const StoredSet>& set);
  // The cell of `seed` in a box, by a builder that reads the kept triangulation's stars.
  static Result<VoronoiCell> clipped_cell(const StoredSet& set, std::uint32_t seed, const Domain& domain,
                                          const StarOptions& options, ClippedCellBuilder& builder);

  std::unique_ptr<PointSetStore> store_;
  Limits limits_;
  ShardSettings shards_;
  struct KeptShape {
    std::string key;  // SHA-256 of format, NUL, bytes
    std::shared_ptr<const ShapeDomain> shape;
    MemoryBudget::Charge charge;
  };
  struct LoadedValues {
    std::string key;  // set id / values id
    std::shared_ptr<const KeptValues> values;
    MemoryBudget::Charge charge;
  };
  std::mutex values_mutex_;
  std::vector<LoadedValues> values_;  // most recently used last, at most kValuesKept
  static constexpr std::size_t kValuesKept = 4;
  // Point queries on a set kept as pieces answered from its own file (no piece held
  // what they rest on), for /metrics and tests.
  std::atomic<std::uint64_t> completed_from_whole_{0};
  std::mutex shapes_mutex_;
  std::vector<KeptShape> shapes_;  // most recently used last
  // Builds the sets' triangulations of every point, one at a time, on its own thread
  // (stopped and joined first when the engine goes).
  class TriangulationKeeper;
  std::unique_ptr<TriangulationKeeper, void (*)(TriangulationKeeper*)> keeper_;
  // Sets made by an append whose parent held its triangulation then: the child's is
  // built from the parent's (extend_whole: copied, the new points inserted) if the
  // parent still holds it when the child's is asked for. Weakly held, at most
  // kAppendsRemembered (the oldest forgotten first).
  static constexpr std::size_t kAppendsRemembered = 64;
  std::mutex appended_mu_;
  std::vector<std::pair<std::string, std::weak_ptr<const StoredSet>>> appended_from_;
};

}  // namespace spokemesh::service
