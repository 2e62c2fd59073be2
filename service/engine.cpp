#include "engine.hpp"

#include "geojson_domain.hpp"
#include "spokemesh/cells.hpp"
#include "spokemesh/certify.hpp"
#include "spokemesh/data_dir.hpp"
#include "spokemesh/pieces.hpp"

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <numeric>
#include <unordered_map>

#include "spokemesh/facet_cache.hpp"
#include "spokemesh/front_cache.hpp"
#include "spokemesh/mesh.hpp"

namespace spokemesh::service {

// ---- CallControl and Watchdog ----------------------------------------------------

CallControl::CallControl(Clock::time_point deadline, std::function<bool()> client_gone, std::function<void()> on_stop)
    : deadline_(deadline.time_since_epoch().count()),
      start_(Clock::now()),
      client_gone_(std::move(client_gone)),
      on_stop_(std::move(on_stop)) {
  Watchdog::instance().add(this);
}

CallControl::~CallControl() { Watchdog::instance().remove(this); }

void CallControl::poll(Clock::time_point now) {
  if (stop_.load(std::memory_order_relaxed)) return;
  // The deadline first: a gRPC client whose deadline passed also reads as cancelled.
  if (now >= deadline()) {
    stop_.store(true);
  } else if (client_gone_ && client_gone_()) {
    client_left_.store(true);
    stop_.store(true);
  }
  if (on_stop_ && stop_.load()) on_stop_();
}

Status CallControl::stopped_status(const std::string& what) const {
  if (client_left_.load()) return cancelled(what + " stopped: the client cancelled or disconnected");
  const auto ms = std::chrono::round<std::chrono::milliseconds>(deadline() - start_).count();
  return {Code::kDeadlineExceeded, what + " stopped at the request deadline (" + std::to_string(ms) +
                                       " ms); ask with a longer deadline or raise --default-deadline"};
}

Watchdog& Watchdog::instance() {
  static Watchdog w;
  return w;
}

Watchdog::Watchdog() : thread_([this] { run(); }) {}

Watchdog::~Watchdog() {
  {
    std::lock_guard lock(mutex_);
    quit_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

void Watchdog::add(CallControl* c) {
  std::lock_guard lock(mutex_);
  controls_.push_back(c);
}

void Watchdog::remove(CallControl* c) {
  std::lock_guard lock(mutex_);
  controls_.erase(std::find(controls_.begin(), controls_.end(), c));
}

void Watchdog::run() {
  std::unique_lock lock(mutex_);
  while (!quit_) {
    // 5 ms: the granularity of deadlines and of noticing a cancelled client.
    cv_.wait_for(lock, std::chrono::milliseconds(5));
    const auto now = Clock::now();
    for (CallControl* c : controls_) c->poll(now);
  }
}

// ---- uploads ----------------------------------------------------------------------

Status UploadSession::adopt(std::vector<double>&& coords, MemoryBudget::Charge&& charge) {
  if (received_ != 0 || coords.size() * sizeof(double) != expected_) {
    return append(coords.data(), coords.size() * sizeof(double));
  }
  sha_->update(coords.data(), expected_);
  received_ = expected_;
  coords_ = std::move(coords);
  charge_ = std::move(charge);
  return Status::ok();
}

Status UploadSession::append(const void* data, std::size_t size) {
  if (size == 0) return Status::ok();  // an empty chunk (memcpy of nothing into nothing is UB)
  if (size > expected_ - received_) {
    return invalid_argument("coordinates: more than the " + std::to_string(expected_) + " bytes that dimension " +
                            std::to_string(header_.dimension) + " x count " + std::to_string(header_.count) +
                            " x 8 bytes allow");
  }
  // Memory follows the bytes that arrived, not the count the header claims: a header
  // alone reserves nothing. Doubling (capped at what the header allows) keeps the
  // copies amortised.
  const std::uint64_t needed = received_ + size;
  if (needed > coords_.size() * sizeof(double)) {
    const std::uint64_t grown = std::min<std::uint64_t>(expected_, std::max<std::uint64_t>(needed, 2 * received_));
    const std::uint64_t words = (grown + sizeof(double) - 1) / sizeof(double);
    const std::uint64_t more = (words - coords_.size()) * sizeof(double);
    if (!charge_.grow(more)) return budget_->over_budget("an upload of " + std::to_string(expected_) + " bytes", more);
    coords_.resize(static_cast<std::size_t>(words));
  }
  std::memcpy(reinterpret_cast<char*>(coords_.data()) + received_, data, size);
  sha_->update(data, size);
  received_ += size;
  return Status::ok();
}

Status UploadSession::append_weights(const void* data, std::size_t size) {
  if (size == 0) return Status::ok();
  if (!header_.weighted) {
    return invalid_argument("weights: this upload's header did not say it is weighted (set weighted = true)");
  }
  if (received_ != expected_) {
    return invalid_argument("weights: sent before all the coordinates (" + std::to_string(received_) + " of " +
                            std::to_string(expected_) + " bytes); send every coordinate first");
  }
  const std::uint64_t expected = static_cast<std::uint64_t>(header_.count) * 8;
  if (size > expected - weight_bytes_) {
    return invalid_argument("weights: more than the " + std::to_string(expected) + " bytes that count " +
                            std::to_string(header_.count) + " x 8 bytes allow");
  }
  if (weights_.empty()) {
    if (!charge_.grow(expected)) return budget_->over_budget("the weights of an upload", expected);
    weights_.resize(static_cast<std::size_t>(header_.count));
  }
  std::memcpy(reinterpret_cast<char*>(weights_.data()) + weight_bytes_, data, size);
  weight_bytes_ += size;
  return Status::ok();
}

StreamPart stream_part(std::uint64_t n, std::uint32_t part_index, std::uint32_t part_count) {
  return {static_cast<std::uint32_t>(n * part_index / part_count),
          static_cast<std::uint32_t>(n * (part_index + 1ull) / part_count)};
}

// The background builds of the sets' triangulations of every point (keep_triangulation):
// a queue of sets (weakly held: a set evicted before its turn is skipped) and one
// thread, which a stop flag cancels mid-build.
class Engine::TriangulationKeeper {
 public:
  explicit TriangulationKeeper(MemoryBudget& budget) : budget_(budget), thread_([this] { run(); }) {}
  ~TriangulationKeeper() {
    {
      std::lock_guard lock(mu_);
      stop_.store(true);
    }
    cv_.notify_all();
    thread_.join();
  }
  // Triangulations built from a parent's so far.
  std::uint64_t extended() const { return extended_.load(std::memory_order_relaxed); }
  // `parent`: the set `set` was appended to, whose kept triangulation it extends.
  void ask(std::weak_ptr<const StoredSet> set, std::weak_ptr<const StoredSet> parent = {}) {
    {
      std::lock_guard lock(mu_);
      queue_.push_back({std::move(set), std::move(parent)});
    }
    cv_.notify_one();
  }

 private:
  void run() {
    for (;;) {
      Asked next;
      {
        std::unique_lock lock(mu_);
        cv_.wait(lock, [&] { return stop_.load() || !queue_.empty(); });
        if (stop_.load()) return;
        next = std::move(queue_.front());
        queue_.erase(queue_.begin());
      }
      if (const std::shared_ptr<const StoredSet> set = next.set.lock()) build(*set, next.parent.lock());
    }
  }

  // One set's triangulation, its memory charged as it grows (refused: none is kept),
  // and how its cells in a box should take their stars. From its parent's when it was
  // appended to a set that still holds one (the same triangulation: it is unique).
  void build(const StoredSet& set, const std::shared_ptr<const StoredSet>& parent) {
    MemoryBudget::Charge charge = budget_.empty_charge();
    WholeOptions options;
    options.split = set.split.get();
    options.cancel = &stop_;
    options.reserve_bytes = [&](std::size_t bytes) { return charge.grow(bytes); };
    const std::shared_ptr<const WholeTriangulation> base = parent ? parent->kept_whole() : nullptr;
    auto built = base != nullptr && base->point_set().size() < set.points.size()
                     ? extend_whole(*base, set.points, options)
                     : triangulate_whole(set.points, options);
    if (base != nullptr && !built.is_ok() && built.status().code() == Code::kInvalidArgument) {
      built = triangulate_whole(set.points, options);  // not its parent's points first after all
    } else if (base != nullptr && built.is_ok()) {
      extended_.fetch_add(1, std::memory_order_relaxed);
    }
    if (!built.is_ok()) return;  // refused, cancelled, or flat: the stars are walked
    CellStarPlan plan;
    if (set.tree && set.bounds.size() == 2 * static_cast<std::size_t>(set.info.dimension)) {
      const int d = set.info.dimension;
      auto box = Domain::box(std::vector<double>(set.bounds.begin(), set.bounds.begin() + d),
                             std::vector<double>(set.bounds.begin() + d, set.bounds.end()));
      if (box.is_ok()) {
        std::vector<std::uint32_t> sample;
        const std::size_t n = set.points.size(), step = std::max<std::size_t>(1, n / 64);
        for (std::size_t k = 0; k < n && sample.size() < 64; k += step) sample.push_back(static_cast<std::uint32_t>(k));
        CellsOptions cells;
        cells.stars = MeshEngine::kTriangulations;
        plan = plan_cell_stars(*set.tree, &box.value(), cells, sample, n);
      }
    }
    std::lock_guard lock(set.whole_mu);
    if (set.whole != nullptr) return;  // a batch or stream kept one first
    set.whole = std::move(built).value();
    set.whole_charge = std::move(charge);
    set.whole_skip_doomed = plan.skip_doomed;
  }

  struct Asked {
    std::weak_ptr<const StoredSet> set, parent;
  };
  MemoryBudget& budget_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::vector<Asked> queue_;
  std::atomic<std::uint64_t> extended_{0};
  std::atomic<bool> stop_{false};
  std::thread thread_;  // last: started once the rest is made
};

Engine::Engine(std::unique_ptr<PointSetStore> store, Limits limits, ShardSettings shards)
    : store_(std::move(store)),
      limits_(limits),
      shards_(shards),
      keeper_(new TriangulationKeeper(store_->budget()), [](TriangulationKeeper* k) { delete k; }) {}

std::uint64_t Engine::triangulations_extended() const { return keeper_->extended(); }

void Engine::keep_triangulation(const std::shared_ptr<const StoredSet>& set) {
  const int d = set->info.dimension;
  if (!limits_.keep_triangulations || (d != 2 && d != 3) || set->box || !set->weights.empty() ||
      set->whole_asked.exchange(true)) {
    return;
  }
  std::weak_ptr<const StoredSet> parent;
  if (!set->piece) {
    std::lock_guard lock(appended_mu_);
    const auto it = std::find_if(appended_from_.begin(), appended_from_.end(),
                                 [&](const auto& e) { return e.first == set->info.id; });
    if (it != appended_from_.end()) {
      parent = it->second;
      appended_from_.erase(it);
    }
  }
  keeper_->ask(set, std::move(parent));
}

namespace {

// Whether a set of this shape is cut into pieces (2-d and 3-d plain sets: the exact
// engine's halos and certificates are those dimensions').
bool pieces_apply(const ShardSettings& shards, const PointSetInfo& info) {
  return shards.pieces_above > 0 && info.count >= shards.pieces_above && (info.dimension == 2 || info.dimension == 3) &&
         !info.weighted && info.periodic_box.empty();
}

}  // namespace

Status Engine::ensure_pieces(const PointSetInfo& info, const PointSet* points) {
  if (!pieces_apply(shards_, info)) return Status::ok();
  auto layout = store_->layout(info.id);
  if (!layout.is_ok()) return layout.status();
  if (layout.value()) return Status::ok();
  std::shared_ptr<const StoredSet> loaded;
  if (points == nullptr) {
    auto set = store_->get(info.id);
    if (!set.is_ok()) return set.status();
    loaded = std::move(set).value();
    points = &loaded->points;
  }
  // About: the whole mesh's sweep at its peak (134 bytes a point in 3-d, bench/README.md),
  // the split and the owner map (16), and a piece's copy as it is written.
  const std::uint64_t bytes = info.count * (160 + 24 * static_cast<std::uint64_t>(info.dimension));
  auto charge = store_->budget().try_charge(bytes);
  if (!charge) {
    return store_->budget().over_budget(
        "cutting point set " + info.id + " into pieces (or cut it with mpirun spokemesh-mpi store)", bytes);
  }
  PieceOptions options;
  options.piece_points = shards_.piece_points;
  options.threads = std::max(1u, limits_.stream_threads);
  auto stored = store_->put_pieces(info.id, *points, options);
  if (!stored.is_ok()) {
    return Status{stored.status().code(), "point set " + info.id +
                                              " is stored, but cutting it into pieces failed (upload it again to "
                                              "retry): " +
                                              stored.status().message()};
  }
  return Status::ok();
}

bool Engine::is_own_piece(std::uint32_t piece, std::uint32_t pieces) const {
  return !shards_.sharded() || shard_of_piece(piece, pieces, shards_.count) == shards_.index;
}

SeedRoute Engine::route_seed(const std::string& id, std::uint64_t seed) {
  SeedRoute route;
  if (!shards_.sharded() || !is_valid_id(id)) return route;
  auto layout = store_->layout(id);
  if (!layout.is_ok() || !layout.value() || seed >= layout.value()->manifest().count) return route;
  auto piece = layout.value()->piece_of(seed);
  if (!piece.is_ok()) return route;
  route.piece = piece.value();
  route.shard = shard_of_piece(piece.value(), layout.value()->pieces(), shards_.count);
  route.here = route.shard == shards_.index;
  return route;
}

Result<ShardMap> Engine::shard_map(const std::string& id) {
  if (!is_valid_id(id)) return invalid_argument("point_set_id: \"" + id.substr(0, 80) + "\" is not a point-set id");
  auto info = store_->info(id);
  if (!info.is_ok()) return info.status();
  ShardMap map;
  map.count = info->count;
  if (!shards_.sharded()) return map;
  auto layout = store_->layout(id);
  if (!layout.is_ok()) return layout.status();
  if (!layout.value()) return map;
  const PieceManifest& m = layout.value()->manifest();
  const std::uint32_t pieces = layout.value()->pieces();
  auto charge = store_->budget().try_charge(m.count * 6);
  if (!charge) return store_->budget().over_budget("the shard map of point set " + id, m.count * 6);
  auto owners = layout.value()->owners();
  if (!owners.is_ok()) return owners.status();
  map.sharded = true;
  map.shard_count = shards_.count;
  map.seed_shards.resize(owners->size());
  for (std::size_t i = 0; i < owners->size(); ++i) {
    map.seed_shards[i] = static_cast<std::uint16_t>(shard_of_piece(owners.value()[i], pieces, shards_.count));
  }
  Sha256 sha;
  const std::string text = manifest_text(m) + "\nshards " + std::to_string(shards_.count) + "\n";
  sha.update(text.data(), text.size());
  map.version = sha.hex_digest().substr(0, 16);
  return map;
}

Result<std::unique_ptr<UploadSession>> Engine::begin_upload(const UploadHeader& h) const {
  const std::string d = std::to_string(h.dimension), n = std::to_string(h.count);
  if (h.dimension < 2) return invalid_argument("dimension: " + d + " is not supported; it must be at least 2");
  if (h.dimension > limits_.max_dimension) {
    return resource_exhausted("dimension: " + d +
                              " exceeds this server's limit --max-dimension=" + std::to_string(limits_.max_dimension));
  }
  if (h.count < h.dimension + 1) {
    return invalid_argument("count: " + n + " points cannot span " + d + " dimensions; at least " +
                            std::to_string(h.dimension + 1) + " are needed");
  }
  if (static_cast<std::uint64_t>(h.count) > limits_.max_points) {
    return resource_exhausted("count: " + n +
                              " points exceed this server's limit --max-points=" + std::to_string(limits_.max_points));
  }
  if ((h.weighted || !h.periodic_box.empty()) && h.dimension > kMaxDimension) {
    return invalid_argument(std::string(h.weighted ? "weighted" : "periodic_box") +
                            ": weighted and periodic sets are exact and limited to d <= " +
                            std::to_string(kMaxDimension) + " (the header says " + d + "-d)");
  }
  if (!h.periodic_box.empty() && h.periodic_box.size() != 2 * static_cast<std::size_t>(h.dimension)) {
    return invalid_argument("periodic_box: " + std::to_string(h.periodic_box.size()) + " values; a " + d +
                            "-d box needs " + std::to_string(2 * h.dimension) + " (LO_1..LO_d, HI_1..HI_d)");
  }
  const std::uint64_t memory = estimated_memory(static_cast<std::uint64_t>(h.count), static_cast<int>(h.dimension),
                                                h.weighted, !h.periodic_box.empty());
  if (memory > limits_.max_memory) {
    return resource_exhausted("count: " + n + " points in " + d + " dimensions need about " + std::to_string(memory) +
                              " bytes, more than this server's --max-memory=" + std::to_string(limits_.max_memory));
  }
  if (h.display_name.size() > limits_.max_display_name) {
    return invalid_argument("display_name: " + std::to_string(h.display_name.size()) + " bytes; at most " +
                            std::to_string(limits_.max_display_name) + " are allowed");
  }
  auto s = std::make_unique<UploadSession>();
  s->header_ = h;
  s->charge_ = store_->budget().empty_charge();
  s->budget_ = &store_->budget();
  s->expected_ = static_cast<std::uint64_t>(h.count) * static_cast<std::uint64_t>(h.dimension) * 8;
  s->sha_ = std::make_unique<Sha256>();
  const std::string header =
      point_set_header_bytes(static_cast<std::uint32_t>(h.dimension), static_cast<std::uint64_t>(h.count));
  s->sha_->update(header.data(), header.size());
  return s;
}

Result<std::unique_ptr<UploadSession>> Engine::begin_append(const std::string& parent_id, UploadHeader added,
                                                            const Principal& who) {
  if (Status s = authorize(parent_id, who); !s.is_ok()) return s;
  // The parent's header only: its coordinates are streamed below, not loaded (its
  // tree and split would be built for nothing: queries go to the new set).
  auto parent = store_->info(parent_id);
  if (!parent.is_ok()) return parent.status();
  if (added.weighted || !added.periodic_box.empty()) {
    return failed_precondition(std::string(added.weighted ? "weighted" : "periodic_box") +
                               ": an append adds points only; to store weights or a periodic box, upload the "
                               "whole set with them");
  }
  if (parent->weighted || !parent->periodic_box.empty()) {
    return failed_precondition("point set " + parent_id + " is " + (parent->weighted ? "weighted" : "periodic") +
                               ": appending to it is not supported (the new points would need " +
                               (parent->weighted ? "weights" : "the box") + "); upload the whole set instead");
  }
  const int d = parent->dimension;
  if (added.dimension != 0 && added.dimension != d) {
    return invalid_argument("dimension: " + std::to_string(added.dimension) +
                            "-d points cannot be appended to point set " + parent_id + ", whose points are " +
                            std::to_string(d) + "-d");
  }
  if (added.count < 1) return invalid_argument("count: appending needs at least one point");
  UploadHeader whole = added;
  whole.dimension = d;
  const auto n = static_cast<std::int64_t>(parent->count);
  whole.count = added.count > INT64_MAX - n ? INT64_MAX : n + added.count;
  auto session = begin_upload(whole);
  if (!session.is_ok()) return session.status();
  UploadSession& s = *session.value();
  if (Status st = store_->read_coordinates(parent_id,
                                           [&](const char* bytes, std::size_t size) { return s.append(bytes, size); });
      !st.is_ok()) {
    return st;
  }
  s.parent_id_ = parent_id;
  return session;
}

Result<PointSetInfo> Engine::finish_upload(UploadSession& s, const Principal& who) {
  if (s.received_ != s.expected_) {
    return invalid_argument("coordinates: received " + std::to_string(s.received_) + " bytes, but dimension " +
                            std::to_string(s.header_.dimension) + " x count " + std::to_string(s.header_.count) +
                            " x 8 bytes = " + std::to_string(s.expected_));
  }
  if (s.header_.weighted && s.weight_bytes_ != static_cast<std::uint64_t>(s.header_.count) * 8) {
    return invalid_argument("weights: received " + std::to_string(s.weight_bytes_ / 8) + " weights (" +
                            std::to_string(s.weight_bytes_) + " bytes), but the set has " +
                            std::to_string(s.header_.count) + " points; send one float64 weight per point");
  }
  const std::string extras = point_set_extra_bytes(s.weights_, s.header_.periodic_box);
  s.sha_->update(extras.data(), extras.size());
  PointSetInfo info;
  info.id = s.sha_->hex_digest();
  info.dimension = static_cast<int>(s.header_.dimension);
  info.count = static_cast<std::uint64_t>(s.header_.count);
  info.display_name = s.header_.display_name;
  info.weighted = s.header_.weighted;
  info.periodic_box = s.header_.periodic_box;
  // Same data as a stored set: no work (the id is a function of the bytes), but the
  // caller becomes one of its owners.
  if (auto existing = store_->info(info.id); existing.is_ok()) {
    const bool had = who.tenant.empty() || store_->owned_by(info.id, who.tenant);
    if (Status st = store_->add_owner(info.id, who.tenant); !st.is_ok()) return st;
    // Its pieces, if an earlier upload stored it but could not cut it.
    if (Status st = ensure_pieces(existing.value(), nullptr); !st.is_ok()) return st;
    existing->already_existed = had;
    return existing;
  }
  PointSet points(info.dimension, std::move(s.coords_));
  if (Status st = points.validate("coordinates", limits_.max_dimension, info.dimension <= kMaxDimension); !st.is_ok()) {
    if (st.reason() == "DUPLICATE_POINTS") {
      // The stored set is exactly what was uploaded (its id is its bytes' hash), so the
      // fix is on the client's side.
      return invalid_argument(st.message() +
                              "; point sets are stored as uploaded, so remove duplicates first (numpy: "
                              "np.unique(points, axis=0)), or mesh locally with spokemesh --merge-duplicates")
          .with_reason("DUPLICATE_POINTS");
    }
    return st;
  }
  std::optional<PeriodicBox> box;
  if (Status st = check_extras(points, s.weights_, info.periodic_box, "coordinates", &box); !st.is_ok()) return st;
  if (box) {
    // The images must be told apart in double precision (the cover a query walks).
    auto stars = PeriodicStars::build(points, *box, s.weights_, "coordinates");
    if (!stars.is_ok()) return stars.status();
  }
  // The owner first, then the set (see PointSetStore::add_owner).
  const bool had = !who.tenant.empty() && store_->owned_by(info.id, who.tenant);
  if (Status st = store_->add_owner(info.id, who.tenant); !st.is_ok()) return st;
  auto stored = store_->put(info, points, s.weights_);
  // A concurrent identical upload may have created it first (already_existed): for a
  // tenant, what counts is whether it had the set before.
  if (stored.is_ok() && !who.tenant.empty()) stored->already_existed = had;
  // A large set is also cut into pieces before it is acknowledged (sharded serving).
  if (stored.is_ok()) {
    if (Status st = ensure_pieces(info, &points); !st.is_ok()) return st;
  }
  // An append to a set that holds its triangulation: the new set's will extend it.
  if (stored.is_ok() && !s.parent_id_.empty() && limits_.keep_triangulations) {
    if (auto parent = store_->loaded(s.parent_id_); parent != nullptr && parent->kept_whole() != nullptr) {
      std::lock_guard lock(appended_mu_);
      if (appended_from_.size() >= kAppendsRemembered) appended_from_.erase(appended_from_.begin());
      appended_from_.emplace_back(info.id, parent);
    }
  }
  return stored;
}

Status Engine::authorize(const std::string& id, const Principal& who) {
  if (who.admin || !is_valid_id(id)) return Status::ok();  // a malformed id gets its own error downstream
  if (store_->owned_by(id, who.tenant)) return Status::ok();
  return Status{Code::kNotFound, "point set " + id + " not found"};
}

Result<PointSetInfo> Engine::get_point_set(const std::string& id, const Principal& who) {
  if (Status s = authorize(id, who); !s.is_ok()) return s;
  auto info = store_->info(id);
  if (info.is_ok()) info->already_existed = false;  // an upload's answer only
  return info;
}

Result<std::vector<PointSetInfo>> Engine::list_point_sets(std::uint32_t page_size, const std::string& page_token,
                                                          std::string* next_page_token, const Principal& who) {
  // AIP-158: a page size above the maximum is clamped to it, not refused.
  if (page_size == 0) page_size = defaults::kPageSize;
  page_size = std::min(page_size, defaults::kMaxPageSize);
  if (!page_token.empty() && !is_valid_id(page_token)) {
    return invalid_argument("page_token: \"" + page_token.substr(0, 80) + "\" is not a token from a previous page");
  }
  bool more = false;
  std::function<bool(const std::string&)> visible;
  if (!who.admin) visible = [&](const std::string& id) { return store_->owned_by(id, who.tenant); };
  std::vector<PointSetInfo> page = store_->list(page_token, page_size, &more, visible);
  for (PointSetInfo& info : page) info.already_existed = false;  // an upload's answer only
  if (next_page_token != nullptr) *next_page_token = more ? page.back().id : "";
  return page;
}

Status Engine::delete_point_set(const std::string& id, const Principal& who) {
  Status s = who.admin ? store_->remove(id) : store_->release(id, who.tenant);
  if (s.is_ok() && !store_->info(id).is_ok()) {
    // Gone with its last owner: its kept values go too.
    std::error_code ignored;
    std::filesystem::remove_all(std::filesystem::path(store_->directory()) / "values" / id, ignored);
    std::lock_guard lock(values_mutex_);
    std::erase_if(values_, [&](const LoadedValues& v) { return v.key.compare(0, id.size() + 1, id + "/") == 0; });
  }
  return s;
}

namespace {

// A kept values file: "SMVALUE1", width (u32 LE), count (u64 LE), the values (f64 LE).
std::string values_file_bytes(std::span<const double> values, std::uint32_t width, std::uint64_t count) {
  std::string bytes = "SMVALUE1";
  for (int k = 0; k < 4; ++k) bytes += static_cast<char>((width >> (8 * k)) & 0xff);
  for (int k = 0; k < 8; ++k) bytes += static_cast<char>((count >> (8 * k)) & 0xff);
  bytes.append(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(double));
  return bytes;
}

std::string values_id_of(const std::string& set_id, const std::string& file_bytes) {
  Sha256 sha;
  sha.update(set_id.data(), set_id.size());
  sha.update(file_bytes.data(), file_bytes.size());
  return sha.hex_digest();
}

std::filesystem::path values_path(const std::string& dir, const std::string& set_id, const std::string& values_id) {
  return std::filesystem::path(dir) / "values" / set_id / (values_id + ".values");
}

}  // namespace

Result<ValuesInfo> Engine::put_values(const std::string& id, std::span<const double> values, std::uint32_t width) {
  auto info = store_->info(id);
  if (!info.is_ok()) return info.status();
  if (width == 0) width = 1;
  const std::uint64_t n = info->count;
  if (values.size() != n * width) {
    return invalid_argument("values: expected " + std::to_string(n) + " rows (one per point of the set) of " +
                            std::to_string(width) + " values, got " + std::to_string(values.size()) + " numbers");
  }
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (!std::isfinite(values[i])) {
      return invalid_argument("values[" + std::to_string(i / width) + "][" + std::to_string(i % width) +
                              "]: not a finite number");
    }
  }
  const std::string bytes = values_file_bytes(values, width, n);
  ValuesInfo out{values_id_of(id, bytes), id, width, n, false};
  const std::filesystem::path path = values_path(store_->directory(), id, out.values_id);
  std::error_code ec;
  if (std::filesystem::exists(path, ec)) {
    out.already_existed = true;
    return out;
  }
  std::filesystem::create_directories(path.parent_path(), ec);
  if (ec) return Status{Code::kInternal, "values: cannot make " + path.parent_path().string() + ": " + ec.message()};
  if (Status s = write_file_durably(path.string(), bytes); !s.is_ok()) return s;
  return out;
}

Result<std::shared_ptr<const KeptValues>> Engine::kept_values(const std::string& id, const std::string& values_id) {
  const std::string key = id + "/" + values_id;
  {
    std::lock_guard lock(values_mutex_);
    const auto it = std::find_if(values_.begin(), values_.end(), [&](const LoadedValues& v) { return v.key == key; });
    if (it != values_.end()) {
      std::rotate(it, it + 1, values_.end());
      return values_.back().values;
    }
  }
  auto missing = [&] {
    return Status{Code::kNotFound, "values_id: point set " + id + " has no values " + values_id.substr(0, 64)};
  };
  if (!is_valid_id(values_id)) return missing();
  const std::filesystem::path path = values_path(store_->directory(), id, values_id);
  std::error_code ec;
  const std::uintmax_t size = std::filesystem::file_size(path, ec);
  if (ec || size < 20 || (size - 20) % 8 != 0) return missing();
  MemoryBudget::Charge charge = store_->budget().empty_charge();
  if (!charge.grow(size)) return store_->budget().over_budget("values " + values_id, size);
  std::string bytes(size, '\0');
  {
    FILE* f = std::fopen(path.c_str(), "rb");
    if (f == nullptr) return missing();
    const std::size_t got = std::fread(bytes.data(), 1, size, f);
    std::fclose(f);
    if (got != size) return missing();
  }
  if (bytes.compare(0, 8, "SMVALUE1") != 0 || values_id_of(id, bytes) != values_id) {
    return Status{Code::kUnavailable,
                  "values_id: the file of values " + values_id + " of point set " + id + " does not match its id"};
  }
  auto kept = std::make_shared<KeptValues>();
  for (int k = 0; k < 4; ++k)
    kept->width |= static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[8 + k])) << (8 * k);
  kept->values.resize((size - 20) / 8);
  std::memcpy(kept->values.data(), bytes.data() + 20, kept->values.size() * sizeof(double));
  bytes = {};
  std::lock_guard lock(values_mutex_);
  if (values_.size() >= kValuesKept) values_.erase(values_.begin());
  values_.push_back({key, kept, std::move(charge)});
  return std::shared_ptr<const KeptValues>(kept);
}

Result<Holding> Engine::hold(const std::string& id, std::uint64_t seed, bool pieces) {
  if (pieces && shards_.sharded()) {
    auto layout = store_->layout(id);
    if (!layout.is_ok()) return layout.status();
    if (layout.value()) {
      const std::uint64_t n = layout.value()->manifest().count;
      if (seed >= n) {
        return out_of_range("seed: " + std::to_string(seed) + " is out of range; point set " + id + " has " +
                            std::to_string(n) + " points (seeds 0.." + std::to_string(n - 1) + ")");
      }
      auto piece = layout.value()->piece_of(seed);
      if (!piece.is_ok()) return piece.status();
      auto set = store_->get_piece(id, piece.value());
      if (!set.is_ok()) return set.status();
      const std::uint32_t local = local_index(set.value()->piece->ids, seed);
      if (local == kNotHeld)
        return internal_error("point set " + id + ": piece " + std::to_string(piece.value()) +
                              " does not hold its point " + std::to_string(seed));
      keep_triangulation(set.value());
      return Holding{std::move(set).value(), local};
    }
  }
  auto set = store_->get(id);
  if (!set.is_ok()) return set.status();
  const std::uint64_t n = set.value()->info.count;
  if (seed >= n) {
    return out_of_range("seed: " + std::to_string(seed) + " is out of range; point set " + id + " has " +
                        std::to_string(n) + " points (seeds 0.." + std::to_string(n - 1) + ")");
  }
  keep_triangulation(set.value());
  return Holding{std::move(set).value(), static_cast<std::uint32_t>(seed)};
}

std::optional<Holding> Engine::hold_at_hand(const std::string& id, std::uint64_t seed) {
  if (!is_valid_id(id)) return std::nullopt;
  std::shared_ptr<const StoredSet> set;
  std::uint32_t index = 0;
  if (shards_.sharded()) {
    auto layout = store_->layout(id);
    if (!layout.is_ok()) return std::nullopt;
    if (layout.value()) {
      if (seed >= layout.value()->manifest().count) return std::nullopt;
      auto piece = layout.value()->piece_of(seed);
      // Another shard's seed is relayed, which waits on a peer: not at hand.
      if (!piece.is_ok() || !is_own_piece(piece.value(), layout.value()->pieces())) return std::nullopt;
      set = store_->get_piece_in_memory(id, piece.value());
      if (!set) return std::nullopt;
      index = local_index(set->piece->ids, seed);
      if (index == kNotHeld) return std::nullopt;
    }
  }
  if (!set) {
    set = store_->get_in_memory(id);
    if (!set || seed >= set->info.count) return std::nullopt;
    index = static_cast<std::uint32_t>(seed);
  }
  if (!set->kept_whole()) return std::nullopt;
  return Holding{std::move(set), index};
}

Status Engine::exact_allowed(const StoredSet& set, const char* what) {
  if (set.info.dimension <= kMaxDimension) return Status::ok();
  return resource_exhausted(std::string(what) + " is exact and limited to d <= " + std::to_string(kMaxDimension) +
                            " (point set " + set.info.id + " is " + std::to_string(set.info.dimension) +
                            "-d, where exact Delaunay work is unbounded); ask GetNeighbors with mode APPROXIMATE "
                            "(REST: /neighbors?mode=approximate) for certified neighbours");
}

Result<Star> Engine::compute_star(const StoredSet& set, std::uint32_t seed, const CallControl& control) {
  if (Status s = exact_allowed(set, "this request"); !s.is_ok()) return s;
  Star star;
  // Read from the kept triangulation when there is one: the walk's star, byte for byte.
  if (const auto whole = set.kept_whole()) {
    WholeStarReader reader(*whole);
    if (Status s = reader.star(seed, star); !s.is_ok()) return s;
    return star;
  }
  StarOptions options;
  options.cancel = control.stop_flag();
  options.weights = set.weights;
  StarWalker walker(*set.tree, options);
  Status s = walker.compute(seed, star);
  if (s.code() == Code::kCancelled) {
    return control.stopped_status("the star of seed " + std::to_string(global_seed(set, seed)));
  }
  if (!s.is_ok()) return s;
  return star;
}

Result<PeriodicStar> Engine::periodic_star_of(const StoredSet& set, std::uint32_t seed, const CallControl& control,
                                              VoronoiCell* cell, bool centres) {
  StarOptions options;
  options.cancel = control.stop_flag();
  auto star = set.periodic->star(seed, options, cell, centres);
  if (star.status().code() == Code::kCancelled)
    return control.stopped_status("the star of seed " + std::to_string(seed));
  return star;
}

StarAnswer Engine::periodic_star_answer(const StoredSet& set, PeriodicStar star) {
  StarAnswer answer;
  answer.star.seed = star.seed;
  answer.star.dimension = set.info.dimension;
  answer.star.hidden = star.hidden;
  answer.star.simplices = std::move(star.simplices);
  answer.offsets = std::move(star.offsets);
  answer.circumcentres = std::move(star.centres);
  return answer;
}

NeighborAnswer Engine::periodic_neighbor_answer(const StoredSet& set, const PeriodicStar& star) {
  NeighborAnswer answer;
  periodic_neighbors(star, set.info.dimension, answer.neighbors, answer.offsets);
  return answer;
}

Status Engine::check_query(const StoredSet& set, const DomainSpec* domain, const NeighborQuery* query) {
  if (set.box && domain != nullptr && !domain->empty()) {
    return invalid_argument("domain: point set " + set.info.id +
                            " is periodic: its cells fill the torus, so box, "
                            "halfspaces and bounding_box do not apply");
  }
  if (query != nullptr && query->mode != NeighborQuery::Mode::kExact && (set.box || !set.weights.empty())) {
    return invalid_argument(std::string("mode: point set ") + set.info.id + " is " +
                            (set.box ? "periodic" : "weighted") +
                            ": its neighbours come from the exact engine only; ask mode EXACT");
  }
  return Status::ok();
}

Result<StarAnswer> Engine::star(const std::string& id, std::uint64_t seed, const CallControl& control) {
  auto held = hold(id, seed);
  if (!held.is_ok()) return held.status();
  return star(held.value(), control);
}

Result<StarAnswer> Engine::star(const Holding& held, const CallControl& control) {
  const auto& set = held.set;
  const std::uint32_t s = held.index;
  if (set->periodic) {
    auto star = periodic_star_of(*set, s, control, nullptr, true);
    if (!star.is_ok()) return star.status();
    return periodic_star_answer(*set, std::move(star).value());
  }
  auto star = compute_star(*set, s, control);
  if (!star.is_ok()) return star.status();
  StarAnswer answer = star_answer(*set, std::move(star).value());
  if (set->piece) to_global(answer.star, set->piece->ids);
  return answer;
}

StarAnswer Engine::star_answer(const StoredSet& set, Star star) {
  StarAnswer answer;
  answer.star = std::move(star);
  const PointSet& points = set.points;
  const int d = points.dimension();
  const double* weights = set.weights.empty() ? nullptr : set.weights.data();
  answer.circumcentres.resize(answer.star.size() * d);
  for (std::size_t i = 0; i < answer.star.size(); ++i) {
    circumcentre(points, answer.star.simplex(i), d + 1, weights, answer.circumcentres.data() + i * d);
  }
  return answer;
}

Result<NeighborAnswer> Engine::neighbors(const std::string& id, std::uint64_t seed, const NeighborQuery& query,
                                         const CallControl& control) {
  // Approximate walks are answered from the whole set: their answer depends on it.
  auto held = hold(id, seed, query.mode == NeighborQuery::Mode::kExact);
  if (!held.is_ok()) return held.status();
  return neighbors(held.value(), query, control);
}

Result<NeighborAnswer> Engine::neighbors(const Holding& held, const NeighborQuery& query, const CallControl& control) {
  const StoredSet& set = *held.set;
  if (set.piece && query.mode != NeighborQuery::Mode::kExact) {
    return internal_error("approximate neighbours are walked over the whole set, not a piece");
  }
  const std::uint64_t seed = global_seed(set, held.index);
  if (Status s = check_query(set, nullptr, &query); !s.is_ok()) return s;
  NeighborAnswer answer;
  if (set.periodic) {
    auto star = periodic_star_of(set, held.index, control, nullptr, false);
    if (!star.is_ok()) return star.status();
    return periodic_neighbor_answer(set, star.value());
  }
  if (query.mode == NeighborQuery::Mode::kExact) {
    if (Status s = exact_allowed(set, "GetNeighbors with mode EXACT"); !s.is_ok()) return s;
    auto star = compute_star(set, held.index, control);
    if (!star.is_ok()) return star.status();
    if (set.piece) to_global(star.value(), set.piece->ids);
    answer.neighbors = star_neighbors(star.value());
    return answer;
  }
  ApproxOptions options;
  options.mode = approx_walk(query.mode);
  options.max_misses = query.max_consecutive_misses == 0 ? kDefaultMaxMisses : query.max_consecutive_misses;
  options.max_vertices = query.max_vertices == 0 ? kDefaultMaxVertices : query.max_vertices;
  options.cancel = control.stop_flag();
  ApproxWalker walker(*set.tree, options);
  Status s = walker.compute(held.index, answer.walk);
  if (s.code() == Code::kCancelled) return control.stopped_status("the neighbour walk of seed " + std::to_string(seed));
  if (!s.is_ok()) return s;
  answer.exact = false;
  answer.neighbors = answer.walk.neighbors;
  return answer;
}

namespace {
std::string shape_needs_whole(const std::string& id) {
  return "domain.shape: point set " + id + " is kept as pieces (sharded); a domain of any shape needs it held whole";
}
}  // namespace

Result<std::shared_ptr<const ShapeDomain>> Engine::shape_for(const StoredSet& set, const DomainSpec& spec) {
  if (spec.shape_format.empty()) return std::shared_ptr<const ShapeDomain>();
  // (Periodic sets never get here: every caller's check_query refuses any domain on them.)
  if (!set.weights.empty()) {
    return failed_precondition("domain.shape: cells of weighted points in a domain of any shape are not supported yet");
  }
  if (set.piece) return failed_precondition(shape_needs_whole(set.info.id));
  auto shape = parse_shape(spec.shape_format, spec.shape_data);
  if (!shape.is_ok()) return shape.status();
  if (shape.value()->dimension() != set.points.dimension()) {
    return invalid_argument("domain.shape: a " + std::to_string(shape.value()->dimension()) + "-d domain (" +
                            shape.value()->describe() + "); point set " + set.info.id + " is " +
                            std::to_string(set.points.dimension()) + "-d");
  }
  return shape;
}

Result<std::shared_ptr<const ShapeDomain>> Engine::parse_shape(const std::string& format, const std::string& data) {
  static const char* const kFormats[] = {"off", "obj", "stl", "rings", "geojson"};
  if (std::find_if(std::begin(kFormats), std::end(kFormats), [&](const char* f) { return format == f; }) ==
      std::end(kFormats)) {
    return invalid_argument("domain.shape.format: '" + format.substr(0, 40) +
                            "' is not one of off, obj, stl, rings, geojson");
  }
  std::string key;
  {
    Sha256 hash;
    hash.update(format.data(), format.size() + 1);  // with its NUL
    hash.update(data.data(), data.size());
    key = hash.hex_digest();
  }
  {
    std::lock_guard<std::mutex> lock(shapes_mutex_);
    for (std::size_t i = 0; i < shapes_.size(); ++i) {
      if (shapes_[i].key != key) continue;
      std::rotate(shapes_.begin() + static_cast<std::ptrdiff_t>(i),
                  shapes_.begin() + static_cast<std::ptrdiff_t>(i) + 1, shapes_.end());
      return shapes_.back().shape;
    }
  }
  auto parsed = parse_domain_bytes(data, "domain." + format);
  if (!parsed.is_ok()) return parsed.status();
  auto shape = std::make_shared<const ShapeDomain>(std::move(parsed).value());
  const std::size_t bytes = shape->memory_bytes();
  auto charge = store_->budget().try_charge(bytes);
  if (!charge) return store_->budget().over_budget("a domain of any shape", bytes);
  std::lock_guard<std::mutex> lock(shapes_mutex_);
  shapes_.push_back({std::move(key), shape, std::move(*charge)});
  if (shapes_.size() > defaults::kKeptShapes) shapes_.erase(shapes_.begin());
  return std::shared_ptr<const ShapeDomain>(shape);
}

Result<std::optional<Domain>> Engine::resolve_domain(const StoredSet& set, const DomainSpec& spec, bool default_box,
                                                     const ShapeDomain* shape) {
  const int d = set.points.dimension();
  const int given = (spec.box.empty() ? 0 : 1) + (spec.halfspaces.empty() ? 0 : 1) + (spec.bounding_box ? 1 : 0) +
                    (spec.shape_format.empty() ? 0 : 1);
  if (given > 1) return invalid_argument("domain: give one of box, halfspaces, bounding_box and shape");
  if (shape != nullptr) {
    // The box the convex cells are clipped to before the shape: from the set's box.
    std::vector<double> lo(static_cast<std::size_t>(d)), hi(static_cast<std::size_t>(d));
    if (!set.bounds.empty()) {
      lo.assign(set.bounds.begin(), set.bounds.begin() + d);
      hi.assign(set.bounds.begin() + d, set.bounds.end());
      auto box = ShapeClipper::box(std::move(lo), std::move(hi), *shape);
      if (!box.is_ok()) return box.status();
      return std::optional<Domain>(std::move(box).value());
    }
    auto box = ShapeClipper::box(set.points, *shape);
    if (!box.is_ok()) return box.status();
    return std::optional<Domain>(std::move(box).value());
  }
  if (!spec.box.empty()) {
    if (spec.box.size() != 2 * static_cast<std::size_t>(d)) {
      return invalid_argument("domain.box: " + std::to_string(spec.box.size()) + " values; a box around " +
                              std::to_string(d) + "-d points needs " + std::to_string(2 * d) +
                              " (LO_1..LO_d, HI_1..HI_d)");
    }
    auto box = Domain::box({spec.box.begin(), spec.box.begin() + d}, {spec.box.begin() + d, spec.box.end()});
    if (!box.is_ok()) return invalid_argument("domain." + box.status().message());
    return std::optional<Domain>(std::move(box).value());
  }
  if (!spec.halfspaces.empty()) {
    const std::size_t w = static_cast<std::size_t>(d) + 1;
    if (spec.halfspaces.size() % w != 0) {
      return invalid_argument("domain.halfspaces: " + std::to_string(spec.halfspaces.size()) +
                              " values are not a whole number of walls of " + std::to_string(w) +
                              " (a_1 .. a_d b for a . x <= b)");
    }
    std::vector<double> normals, offsets;
    for (std::size_t k = 0; k < spec.halfspaces.size(); k += w) {
      normals.insert(normals.end(), spec.halfspaces.begin() + static_cast<std::ptrdiff_t>(k),
                     spec.halfspaces.begin() + static_cast<std::ptrdiff_t>(k + w - 1));
      offsets.push_back(spec.halfspaces[k + w - 1]);
    }
    auto h = Domain::halfspaces(d, std::move(normals), std::move(offsets));
    if (!h.is_ok()) return invalid_argument("domain." + h.status().message());
    return std::optional<Domain>(std::move(h).value());
  }
  if ((spec.bounding_box || default_box) && (set.piece || !set.bounds.empty())) {
    // The whole set's box, kept with it (Domain::bounding_box of the points is this box).
    const auto& g = set.piece ? set.piece->global_box : set.bounds;
    auto box = Domain::box({g.begin(), g.begin() + d}, {g.begin() + d, g.end()});
    if (!box.is_ok()) return box.status();
    return std::optional<Domain>(std::move(box).value());
  }
  if (spec.bounding_box || default_box) return std::optional<Domain>(Domain::bounding_box(set.points));
  return std::optional<Domain>();
}

Result<VoronoiCell> Engine::cell(const std::string& id, std::uint64_t seed, const DomainSpec& spec,
                                 const CallControl& control) {
  auto held = hold(id, seed);
  if (!held.is_ok()) return held.status();
  return cell(held.value(), spec, control);
}

Result<VoronoiCell> Engine::cell(const Holding& held, const DomainSpec& spec, const CallControl& control) {
  const StoredSet& set = *held.set;
  if (Status s = exact_allowed(set, "GetVoronoiCell"); !s.is_ok()) return s;
  if (Status s = check_query(set, &spec, nullptr); !s.is_ok()) return s;
  auto shape = shape_for(set, spec);
  if (!shape.is_ok()) return shape.status();
  auto domain = resolve_domain(set, spec, false, shape.value().get());
  if (!domain.is_ok()) return domain.status();
  return cell_of(set, held.index, domain.value() ? &*domain.value() : nullptr, control, shape.value().get());
}

Result<VoronoiCell> Engine::cell_of(const StoredSet& set, std::uint32_t seed, const Domain* domain,
                                    const CallControl& control, const ShapeDomain* shape) {
  if (set.periodic) {
    VoronoiCell cell;
    auto star = periodic_star_of(set, seed, control, &cell, false);
    if (!star.is_ok()) return star.status();
    return cell;
  }
  if (domain == nullptr) {
    auto star = compute_star(set, seed, control);
    if (!star.is_ok()) return star.status();
    VoronoiCell cell = voronoi_cell(set.points, star.value(), set.weights);
    if (set.piece) to_global(cell, set.piece->ids);
    return cell;
  }
  // Clipped: the same builder as StreamCells and `spokemesh cells`, so every route
  // gives the same bytes.
  if (Status s = exact_allowed(set, "this request"); !s.is_ok()) return s;
  StarOptions options;
  options.cancel = control.stop_flag();
  options.weights = set.weights;
  if (shape != nullptr) {
    // A domain of any shape (sets held whole only: shape_for).
    VoronoiCell cell;
    const auto whole = set.kept_whole();
    std::optional<WholeStarReader> reader;
    if (whole) reader.emplace(*whole);
    if (Status s = shape_cell(*set.tree, *shape, *domain, seed, cell, options, reader ? &*reader : nullptr);
        !s.is_ok()) {
      if (s.code() == Code::kCancelled) return control.stopped_status("the cell of seed " + std::to_string(seed));
      return s;
    }
    return cell;
  }
  // A piece's seed outside the domain is named as the whole set names it.
  if (set.piece) {
    if (Status s = check_seed_in_domain(set.points.point(seed), global_seed(set, seed), *domain); !s.is_ok()) return s;
  }
  ClippedCellBuilder builder(*set.tree, *domain, options);
  auto cell = clipped_cell(set, seed, *domain, options, builder);
  if (cell.status().code() == Code::kCancelled)
    return control.stopped_status("the cell of seed " + std::to_string(global_seed(set, seed)));
  if (cell.is_ok() && set.piece) {
    // A piece's cell is the whole set's when the points within the reach that decided
    // it are all held (as spokemesh-mpi certifies its cells); otherwise completed.
    const double reach2 = builder.last_reach2();
    const StarCertifier certifier(set.points, set.piece->global_box);
    if (reach2 > 0 && !certifier.ball_is_held(seed, reach2 * (1 + 4 * kDistanceMargin), set.piece->held_box, {},
                                              set.piece->global_box)) {
      return complete_cell(set, seed, reach2 * (1 + 4 * kDistanceMargin), *domain, control);
    }
    to_global(cell.value(), set.piece->ids);
  }
  return cell;
}

Result<VoronoiCell> Engine::clipped_cell(const StoredSet& set, std::uint32_t seed, const Domain& /*domain*/,
                                         const StarOptions& /*options*/, ClippedCellBuilder& builder) {
  const auto whole = set.kept_whole();
  std::optional<WholeStarReader> reader;
  if (whole) {
    reader.emplace(*whole);
    bool skip_doomed = false;
    {
      std::lock_guard lock(set.whole_mu);
      skip_doomed = set.whole_skip_doomed;
    }
    builder.set_stars(&*reader, skip_doomed);
  }
  VoronoiCell cell;
  Status s = builder.cell(seed, cell);
  builder.set_stars(nullptr);
  if (!s.is_ok()) return s;
  return cell;
}

Result<VoronoiCell> Engine::complete_cell(const StoredSet& piece, std::uint32_t seed, double reach2,
                                          const Domain& domain, const CallControl& control) {
  const int d = piece.info.dimension;
  const auto dd = static_cast<std::size_t>(d);
  const PieceOf& of = *piece.piece;
  const std::uint64_t global_seed = of.ids[seed];
  auto layout = store_->layout(piece.info.id);
  if (!layout.is_ok()) return layout.status();
  const PieceManifest& m = layout.value()->manifest();
  const std::vector<double>& g = m.global_box;
  const double* x = piece.points.point(seed);
  // The seed's neighbours (its piece holds them, and so its whole star), which the
  // builder's star route needs besides the points within the reach.
  auto star = compute_star(piece, seed, control);
  if (!star.is_ok()) return star.status();
  std::vector<std::uint32_t> ring = star->simplices;
  std::sort(ring.begin(), ring.end());
  ring.erase(std::unique(ring.begin(), ring.end()), ring.end());
  // A box around the ball that decided the cell, doubled until it holds the reach of
  // the cell built from every point inside it.
  double radius = std::sqrt(reach2) * (1 + 1e-6);
  for (;;) {
    std::vector<double> around(2 * dd);
    bool everything = true;
    for (std::size_t c = 0; c < dd; ++c) {
      around[c] = std::max(g[c], x[c] - radius);
      around[dd + c] = std::min(g[dd + c], x[c] + radius);
      everything = everything && around[c] <= g[c] && around[dd + c] >= g[dd + c];
    }
    // Every point of the set inside `around` is one of the own points of a piece whose
    // box meets it: read from that piece's file (this piece's from memory).
    std::vector<std::pair<std::uint64_t, std::vector<double>>> held;
    for (const std::uint32_t v : ring)
      held.emplace_back(of.ids[v], std::vector<double>(piece.points.point(v), piece.points.point(v) + dd));
    for (std::uint32_t p = 0; p < m.pieces.size(); ++p) {
      const std::vector<double>& b = m.pieces[p].box;
      bool meets = true;
      for (std::size_t c = 0; c < dd && meets; ++c) meets = b[c] <= around[dd + c] && b[dd + c] >= around[c];
      if (!meets) continue;
      if (p == of.index) {
        for (std::size_t k = 0; k < of.ids.size(); ++k) {
          if (of.own[k] != 0 && in_box(around, piece.points.point(k))) {
            held.emplace_back(of.ids[k], std::vector<double>(piece.points.point(k), piece.points.point(k) + dd));
          }
        }
        continue;
      }
      auto other = read_piece(data_dir::piece_file(data_dir::pieces_dir(store_->directory(), piece.info.id), p), m, p);
      if (!other.is_ok()) {
        return Status{Code::kUnavailable, "point set " + piece.info.id + ": piece " + std::to_string(p) +
                                              " cannot be read: " + other.status().message()};
      }
      for (std::size_t k = 0; k < other->ids.size(); ++k) {
        const double* q = other->coords.data() + k * dd;
        if (other->own[k] != 0 && in_box(around, q)) held.emplace_back(other->ids[k], std::vector<double>(q, q + dd));
      }
    }
    std::sort(held.begin(), held.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    held.erase(std::unique(held.begin(), held.end(), [](const auto& a, const auto& b) { return a.first == b.first; }),
               held.end());
    std::vector<double> coords;
    std::vector<std::uint64_t> ids;
    coords.reserve(held.size() * dd);
    for (const auto& [id, p] : held) {
      ids.push_back(id);
      coords.insert(coords.end(), p.begin(), p.end());
    }
    held = {};
    PointSet points(d, std::move(coords));
    if (Status s = points.validate("point set " + piece.info.id); !s.is_ok()) return s;
    const KdTree tree(points);
    StarOptions options;
    options.cancel = control.stop_flag();
    ClippedCellBuilder builder(tree, domain, options);
    const std::uint32_t local = local_index(ids, global_seed);
    auto cell = builder.cell(local);
    if (cell.status().code() == Code::kCancelled) {
      return control.stopped_status("the cell of seed " + std::to_string(global_seed));
    }
    if (!cell.is_ok()) return cell.status();
    const double reach = builder.last_reach2();
    const StarCertifier certifier(points, g);
    if (everything || reach <= 0 || certifier.ball_is_held(local, reach * (1 + 4 * kDistanceMargin), around, {}, g)) {
      to_global(cell.value(), ids);
      return cell;
    }
    radius = std::max(2 * radius, std::sqrt(reach) * (1 + 1e-6));
  }
}

namespace {

// A cell's size in a message, about. Batches of cells also end at
// defaults::kMessagePayloadBytes, well within gRPC's default 4 MiB message limit,
// whatever the cells' size (high-d cells have many vertices).
std::size_t payload_bytes(const VoronoiCell& c) {
  std::size_t bytes =
      8 * (c.vertices.size() + c.centroid.size()) + 4 * (c.vertex_simplices.size() + c.facet_offsets.size()) + 64;
  for (const VoronoiFacet& f : c.facets) bytes += 8 * f.normal.size() + 4 * f.vertices.size() + 24;
  return bytes;
}

// Cells gathered into batches of at most batch_size cells and about
// kMessagePayloadBytes, each handed to `emit` when full; finish() sends the rest (or
// one empty batch, so that a stream always says where its shard lies).
class CellBatcher {
 public:
  CellBatcher(std::uint32_t batch_size, const Engine::CellBatchSink& emit) : batch_size_(batch_size), emit_(emit) {
    pending_.reserve(batch_size);
  }
  Status add(std::span<const VoronoiCell> cells, std::uint64_t done) {
    for (const VoronoiCell& c : cells) {
      pending_.push_back(c);
      bytes_ += payload_bytes(c);
      if (pending_.size() == batch_size_ || bytes_ > defaults::kMessagePayloadBytes) {
        bytes_ = 0;
        emitted_ = true;
        if (Status st = emit_(pending_, done); !st.is_ok()) return st;
        pending_.clear();
      }
    }
    return Status::ok();
  }
  Status finish(std::uint64_t done) {
    if (!pending_.empty() || !emitted_) return emit_(pending_, done);
    return Status::ok();
  }

 private:
  std::uint32_t batch_size_;
  const Engine::CellBatchSink& emit_;
  std::vector<VoronoiCell> pending_;
  std::size_t bytes_ = 0;
  bool emitted_ = false;
};

// Answers items 0..count-1 with `threads` workers, a round of round_size consecutive
// items at a time: the workers take the round's items one at a time from a shared
// counter, while the calling thread emits the round before (in order), so encoding and
// the client's reading overlap the work. (Rounds of 32 with the emission in between
// kept 2 workers 1 core busy on average.) compute(t, i, answer) runs on worker t;
// emit(answers, done) on the caller, done = items answered so far. The failure of the
// lowest item is returned (so the error is the same whatever the threads); the workers
// stop taking items after any.
template <class Answer, class Compute, class Emit>
Status in_rounds(std::size_t count, unsigned threads, std::size_t round_size, const CallControl& control,
                 const std::string& what, Compute&& compute, Emit&& emit) {
  std::vector<Answer> round, previous;
  std::mutex failure_mutex;
  std::size_t failed_at = count;
  Status failure;
  std::atomic<bool> failed{false};
  std::size_t previous_end = 0;
  for (std::size_t at = 0; at < count; at = previous_end) {
    const std::size_t end = std::min(count, at + round_size);
    round.assign(end - at, Answer{});
    std::atomic<std::size_t> next{at};
    auto work = [&](unsigned t) {
      for (std::size_t i; !failed.load(std::memory_order_relaxed) && (i = next.fetch_add(1)) < end;) {
        Status s = compute(t, i, round[i - at]);
        if (s.is_ok()) continue;
        if (s.code() == Code::kCancelled) s = control.stopped_status(what);
        const std::lock_guard<std::mutex> lock(failure_mutex);
        if (i < failed_at) {
          failed_at = i;
          failure = std::move(s);
        }
        failed = true;
      }
    };
    std::vector<std::thread> pool;
    for (unsigned t = 0; t < threads; ++t) pool.emplace_back(work, t);
    const Status emitted = previous.empty() ? Status::ok() : emit(std::span<const Answer>(previous), previous_end);
    for (std::thread& th : pool) th.join();
    if (!failure.is_ok()) return failure;
    if (!emitted.is_ok()) return emitted;
    std::swap(previous, round);
    previous_end = end;
  }
  return emit(std::span<const Answer>(previous), previous_end);
}

// A batch's compute step followed, on the same worker, by the transport's encoder.
template <class Compute>
auto encoded(Compute& compute, const Engine::AnswerEncoder& encode) {
  return [&compute, &encode](unsigned t, std::size_t i, BatchAnswer& a) -> Status {
    Status s = compute(t, i, a);
    if (s.is_ok() && encode) encode(a);
    return s;
  };
}

}  // namespace

void Engine::share_whole_triangulation(const StoredSet& set, MeshOptions& options) {
  {
    std::lock_guard lock(set.whole_mu);
    options.whole = set.whole;
  }
  options.keep_whole = [this, &set](std::shared_ptr<const WholeTriangulation> whole) {
    MemoryBudget::Charge charge = store_->budget().empty_charge();
    if (!charge.grow(whole->bytes())) return;  // not kept: later runs build their own
    std::lock_guard lock(set.whole_mu);
    if (set.whole != nullptr) return;  // a concurrent run kept one first
    set.whole = std::move(whole);
    set.whole_charge = std::move(charge);
  };
}

namespace {

// The errors of a batch's seeds (every transport's, and relayed batches'): none, too
// many, or the first one out of range.
Status check_batch_seeds(const std::vector<std::uint64_t>& seeds, std::uint64_t count) {
  if (seeds.empty()) return invalid_argument("seeds: none given");
  if (seeds.size() > defaults::kMaxBatchSeeds) {
    return invalid_argument("seeds: " + std::to_string(seeds.size()) + " exceed the limit of " +
                            std::to_string(defaults::kMaxBatchSeeds) + " per call");
  }
  for (std::size_t i = 0; i < seeds.size(); ++i) {
    if (seeds[i] >= count) {
      return out_of_range("seeds[" + std::to_string(i) + "]: seed " + std::to_string(seeds[i]) +
                          " is out of range (the point set has " + std::to_string(count) + " points)");
    }
  }
  return Status::ok();
}

}  // namespace

Result<std::vector<std::uint32_t>> Engine::batch_routes(const std::string& id,
                                                        const std::vector<std::uint64_t>& seeds) {
  std::vector<std::uint32_t> routes;
  if (!shards_.sharded()) return routes;
  auto layout = store_->layout(id);
  if (!layout.is_ok()) return layout.status();
  if (!layout.value()) return routes;
  if (Status s = check_batch_seeds(seeds, layout.value()->manifest().count); !s.is_ok()) return s;
  routes.reserve(seeds.size());
  for (const std::uint64_t seed : seeds) {
    auto piece = layout.value()->piece_of(seed);
    if (!piece.is_ok()) return piece.status();
    routes.push_back(shard_of_piece(piece.value(), layout.value()->pieces(), shards_.count));
  }
  return routes;
}

Status Engine::batch(const std::string& id, const std::vector<std::uint64_t>& seeds, BatchKind kind,
                     const NeighborQuery& query, const DomainSpec& spec, const CallControl& control,
                     const AnswerSink& emit, const AnswerEncoder& encode) {
  // None or too many, before the set is loaded; the range once its count is known.
  if (Status s = check_batch_seeds(seeds, ~std::uint64_t{0}); !s.is_ok()) return s;
  if (shards_.sharded()) {
    auto layout = store_->layout(id);
    if (!layout.is_ok()) return layout.status();
    if (layout.value()) {
      if (!spec.shape_format.empty()) return failed_precondition(shape_needs_whole(id));
      return batch_from_pieces(id, layout.value()->manifest().count, seeds, kind, query, spec, control, emit, encode);
    }
  }
  auto set_or = store_->get(id);
  if (!set_or.is_ok()) return set_or.status();
  const std::shared_ptr<const StoredSet> set = set_or.value();
  if (Status s = check_batch_seeds(seeds, set->info.count); !s.is_ok()) return s;
  keep_triangulation(set);
  // The set's kept triangulation, when there is one: every star is read from it.
  const std::shared_ptr<const WholeTriangulation> kept = set->kept_whole();
  std::optional<Domain> domain;
  std::shared_ptr<const ShapeDomain> shape;
  if (kind == BatchKind::kCells) {
    if (Status s = exact_allowed(*set, "a batch of cells"); !s.is_ok()) return s;
    if (Status s = check_query(*set, &spec, nullptr); !s.is_ok()) return s;
    auto sh = shape_for(*set, spec);
    if (!sh.is_ok()) return sh.status();
    shape = std::move(sh).value();
    auto d = resolve_domain(*set, spec, false, shape.get());
    if (!d.is_ok()) return d.status();
    domain = std::move(d).value();
  }
  // Memory: two rounds of answers (in_rounds), charged like a stream's window; rounds
  // shrink with the dimension, where one star can hold many simplices.
  auto window = store_->budget().try_charge(kStreamWindowBytes);
  if (!window) return store_->budget().over_budget("a batch of seeds", kStreamWindowBytes);
  const unsigned threads = std::max(1u, limits_.stream_threads);
  const int dimension = set->points.dimension();
  const bool exact = kind != BatchKind::kNeighbors || query.mode == NeighborQuery::Mode::kExact;
  if (exact) {
    if (Status s = exact_allowed(*set, "this batch"); !s.is_ok()) return s;
  }
  if (Status s = check_query(*set, kind == BatchKind::kCells ? &spec : nullptr,
                             kind == BatchKind::kNeighbors ? &query : nullptr);
      !s.is_ok()) {
    return s;
  }
  StarOptions star_options;
  star_options.cancel = control.stop_flag();
  star_options.weights = set->weights;
  std::vector<std::unique_ptr<StarWalker>> walkers;
  std::vector<std::unique_ptr<WholeStarReader>> readers;
  std::vector<Star> scratch(threads);
  if (kept) {
    for (unsigned t = 0; t < threads; ++t) readers.push_back(std::make_unique<WholeStarReader>(*kept));
  } else if (set->tree) {
    for (unsigned t = 0; t < threads; ++t) walkers.push_back(std::make_unique<StarWalker>(*set->tree, star_options));
  }
  // Clipped cells come from one ClippedCellBuilder per thread, as in StreamCells.
  std::vector<std::unique_ptr<ClippedCellBuilder>> builders(threads);
  std::vector<std::unique_ptr<ShapeClipper>> clippers(threads);
  if (kind == BatchKind::kCells && domain) {
    bool skip_doomed = false;
    if (kept) {
      std::lock_guard lock(set->whole_mu);
      skip_doomed = set->whole_skip_doomed;
    }
    for (unsigned t = 0; t < threads; ++t) {
      builders[t] = std::make_unique<ClippedCellBuilder>(*set->tree, *domain, star_options);
      if (kept) builders[t]->set_stars(readers[t].get(), skip_doomed);
    }
    if (shape) {
      for (auto& c : clippers) {
        c = std::make_unique<ShapeClipper>(set->points, *shape);
        c->set_geometry(true);
      }
    }
  }
  // Exact stars of many seeds of a 2-d or 3-d set: computed together first, as a whole
  // mesh restricted to them computes them (local triangulations of the regions holding
  // them, certified: no sphere query per simplex, so a seed on a scan line or a
  // surface costs what a uniform seed does), kept in memory charged to the budget, then
  // answered in the request's order. A star the budget could not keep is walked below.
  std::unordered_map<std::uint32_t, Star> batched;
  MemoryBudget::Charge batched_charge = store_->budget().empty_charge();
  const bool from_stars =
      kind == BatchKind::kStars || (kind == BatchKind::kNeighbors && exact) || (kind == BatchKind::kCells && !domain);
  if (from_stars && !kept && !set->periodic && set->tree && set->split &&
      seeds.size() >= defaults::kBatchTogetherAtLeast) {
    std::vector<std::uint32_t> wanted(seeds.begin(), seeds.end());
    std::sort(wanted.begin(), wanted.end());
    wanted.erase(std::unique(wanted.begin(), wanted.end()), wanted.end());
    MeshOptions options;
    options.threads = threads;
    options.split = set->split.get();
    options.star = star_options;
    options.seeds = wanted;
    options.engine = engine_for(set->points, *set->split, options);
    if (options.engine == MeshEngine::kTriangulations) {
      MemoryBudget::Charge tri_charge = store_->budget().empty_charge();
      options.reserve_bytes = [&tri_charge, cap = limits_.stream_cache_bytes](std::size_t bytes) {
        return tri_charge.bytes() + bytes <= cap && tri_charge.grow(bytes);
      };
      options.accept_part = StarPart::kAll;
      share_whole_triangulation(*set, options);
      std::mutex mu;
      options.accept = [&](const Star& star) {
        const std::size_t bytes = star.simplices.size() * sizeof(std::uint32_t) + sizeof(Star) + 32;
        std::lock_guard lock(mu);
        if (batched_charge.grow(bytes)) batched.emplace(star.seed, star);
        return false;  // the stars are the answer, not rows
      };
      batched.reserve(wanted.size());
      auto run =
          mesh_seeds(*set->tree, options, [](std::span<const std::uint32_t>, std::uint64_t) { return Status::ok(); });
      if (!run.is_ok()) {
        if (run.status().code() == Code::kCancelled) return control.stopped_status("a batch of seeds");
        return run.status();
      }
    }
  }
  auto answer = [&](unsigned t, std::size_t i, BatchAnswer& a) -> Status {
    a.seed = seeds[i];
    const auto seed = static_cast<std::uint32_t>(seeds[i]);
    if (const auto found = batched.find(seed); found != batched.end()) {
      const Star& star = found->second;
      if (kind == BatchKind::kStars) {
        a.star = star_answer(*set, star);
      } else if (kind == BatchKind::kNeighbors) {
        a.neighbors.neighbors = star_neighbors(star);
      } else {
        a.cell = voronoi_cell(set->points, star, set->weights);
      }
      return Status::ok();
    }
    if (set->periodic) {
      VoronoiCell* cell = kind == BatchKind::kCells ? &a.cell : nullptr;
      auto star = periodic_star_of(*set, seed, control, cell, kind == BatchKind::kStars);
      if (!star.is_ok()) return star.status();
      if (kind == BatchKind::kStars) a.star = periodic_star_answer(*set, std::move(star).value());
      if (kind == BatchKind::kNeighbors) a.neighbors = periodic_neighbor_answer(*set, star.value());
      return Status::ok();
    }
    if (kind == BatchKind::kNeighbors && query.mode != NeighborQuery::Mode::kExact) {
      auto r = neighbors(id, seeds[i], query, control);
      if (r.is_ok()) a.neighbors = std::move(r).value();
      return r.status();
    }
    if (builders[t]) {
      auto r = builders[t]->cell(seed);
      if (!r.is_ok()) return r.status();
      a.cell = std::move(r).value();
      if (clippers[t]) clippers[t]->clip(seed, a.cell);
      return Status::ok();
    }
    // The exact answers from one walker per thread, kept across the batch (the star is
    // the same from any walker; reuse saves its set-up per seed).
    if (Status s = kept ? readers[t]->star(seed, scratch[t]) : walkers[t]->compute(seed, scratch[t]); !s.is_ok())
      return s;
    if (kind == BatchKind::kStars) {
      a.star = star_answer(*set, scratch[t]);
    } else if (kind == BatchKind::kNeighbors) {
      a.neighbors.neighbors = star_neighbors(scratch[t]);
    } else if (!domain) {
      a.cell = voronoi_cell(set->points, scratch[t], set->weights);
    } else {
      auto r = voronoi_cell(set->points, scratch[t], *domain, set->weights);
      if (!r.is_ok()) return r.status();
      a.cell = std::move(r).value();
    }
    return Status::ok();
  };
  const std::size_t per_thread = dimension <= 3 ? 128 : dimension == 4 ? 32 : 16;
  return in_rounds<BatchAnswer>(seeds.size(), threads, per_thread * threads, control, "a batch of seeds",
                                encoded(answer, encode), emit);
}

Status Engine::locate_points(const StoredSet& set, const double* queries, std::size_t count, const CallControl& control,
                             std::shared_ptr<const DelaunayIndex>& index, std::vector<std::int32_t>& located) {
  auto made = located_index(set, control);
  if (!made.is_ok()) return made.status();
  index = std::move(made).value();
  located.assign(count, -1);
  index->locator().locate_many(queries, count, std::max(1u, limits_.stream_threads),
                               [&](std::size_t, std::size_t i, std::int32_t s) { located[i] = s; });
  return Status::ok();
}

Result<std::shared_ptr<const DelaunayIndex>> Engine::located_index(const StoredSet& set, const CallControl& control) {
  std::lock_guard lock(set.located_mu);
  if (set.located) return set.located;
  MeshOptions options;
  options.threads = std::max(1u, limits_.stream_threads);
  options.split = set.split.get();
  options.star.cancel = control.stop_flag();
  // The kept triangulation's rows when there is one; a run that builds the
  // triangulation of every point (balls across the set) hands it over to be kept.
  share_whole_triangulation(set, options);
  MemoryBudget::Charge regions = store_->budget().empty_charge();
  options.reserve_bytes = [&regions, cap = limits_.stream_cache_bytes](std::size_t bytes) {
    return regions.bytes() + bytes <= cap && regions.grow(bytes);
  };
  MemoryBudget::Charge charge = store_->budget().empty_charge();
  std::size_t asked = 0;
  auto built = DelaunayIndex::build(*set.tree, options, [&](std::size_t bytes) {
    asked += bytes;
    return charge.grow(bytes);
  });
  if (!built.is_ok()) {
    if (built.status().code() == Code::kCancelled) return control.stopped_status("the point set's triangulation");
    if (built.status().code() == Code::kResourceExhausted) {
      return store_->budget().over_budget("the triangulation of point set " + set.info.id + " as arrays", asked);
    }
    return built.status();
  }
  set.located = std::move(built).value();
  set.located_charge = std::move(charge);
  return set.located;
}

namespace {

const char* point_method_name(PointMethod m) {
  switch (m) {
    case PointMethod::kLocate:
      return "locate";
    case PointMethod::kLinear:
      return "linear";
    case PointMethod::kNatural:
      return "natural";
    case PointMethod::kNearest:
      return "nearest";
  }
  return "?";
}

}  // namespace

namespace {

// The checks of a point query that need only the set's description: each error names
// its field (Engine::points).
Status check_point_query(const PointSetInfo& info, std::span<const double> queries, const PointQuery& query) {
  const std::string& id = info.id;
  const int d = info.dimension;
  const auto dd = static_cast<std::size_t>(d);
  if (queries.size() % dd != 0) {
    return invalid_argument("queries: " + std::to_string(queries.size()) + " numbers are not whole " +
                            std::to_string(d) + "-d points");
  }
  const std::size_t m = queries.size() / dd;
  if (m > defaults::kMaxBatchSeeds) {
    return invalid_argument("queries: " + std::to_string(m) + " points exceed the limit of " +
                            std::to_string(defaults::kMaxBatchSeeds) + " per call");
  }
  for (std::size_t i = 0; i < queries.size(); ++i) {
    if (!std::isfinite(queries[i])) {
      return invalid_argument("queries[" + std::to_string(i / dd) + "][" + std::to_string(i % dd) +
                              "]: not a finite number");
    }
  }
  if (!info.periodic_box.empty()) {
    return failed_precondition("point set " + id +
                               " is periodic: answers at other points are not computed on a "
                               "torus yet");
  }
  if (info.weighted) {
    return failed_precondition("point set " + id +
                               " is weighted: answers at other points are computed from the "
                               "Delaunay triangulation of unweighted sets only");
  }
  if (d > kMaxDimension) {
    return resource_exhausted("answers at other points are exact and limited to d <= " + std::to_string(kMaxDimension) +
                              " (point set " + id + " is " + std::to_string(d) + "-d)");
  }
  if (query.method == PointMethod::kNatural && d != 2 && d != 3) {
    return invalid_argument("method: natural-neighbour interpolation is computed in 2-d and 3-d, and point set " + id +
                            " is " + std::to_string(d) + "-d (linear and nearest work in any dimension)");
  }
  if (query.method != PointMethod::kLocate) {
    const std::uint64_t n = info.count;
    if (query.width == 0 || query.values.size() != n * query.width) {
      return invalid_argument(
          "values: expected " + std::to_string(n) + " rows (one per point of the set) of " +
          (query.width == 0 ? std::string("at least one value") : std::to_string(query.width) + " values") + ", got " +
          std::to_string(query.values.size()) + " numbers");
    }
    for (std::size_t i = 0; i < query.values.size(); ++i) {
      if (!std::isfinite(query.values[i])) {
        return invalid_argument("values[" + std::to_string(i / query.width) + "][" + std::to_string(i % query.width) +
                                "]: not a finite number");
      }
    }
  }
  return Status::ok();
}

// One query's answer from a triangulation (`ids`, when given, maps its point ids to the
// set's: a piece's), the located simplex given; values by the set's ids.
Status answer_query(const DelaunayArrays& tri, const std::vector<std::uint64_t>* ids, std::int32_t located,
                    const double* q, const PointQuery& query, bool natural, PointResult& r) {
  if (Status s = answer_point(tri, located, q, natural, r.answer); !s.is_ok()) return s;
  if (ids != nullptr) {
    for (int j = 0; j < r.answer.vertex_count; ++j) {
      r.answer.simplex[static_cast<std::size_t>(j)] =
          static_cast<std::uint32_t>((*ids)[r.answer.simplex[static_cast<std::size_t>(j)]]);
    }
    for (std::uint32_t& v : r.answer.natural.neighbors) v = static_cast<std::uint32_t>((*ids)[v]);
  }
  if (query.method == PointMethod::kLocate) return Status::ok();
  const std::size_t width = query.width;
  r.values.resize(width);
  r.has_values = query.method == PointMethod::kLinear
                     ? interpolate_linear(r.answer, query.values, width, r.values.data())
                     : interpolate_natural(r.answer, query.values, width, r.values.data());
  if (!r.has_values && query.fill) {
    std::fill(r.values.begin(), r.values.end(), *query.fill);
    r.has_values = true;
  }
  if (!r.has_values) r.values.clear();
  return Status::ok();
}

// Whether the answers need Sibson's coordinates.
bool wants_natural(const PointQuery& query, int d) {
  return query.method == PointMethod::kNatural ||
         (query.method == PointMethod::kLocate && query.natural && (d == 2 || d == 3));
}

// The nearest point's values.
void answer_nearest(std::uint32_t p, const PointQuery& query, PointResult& r) {
  r.nearest = p;
  r.has_values = true;
  r.values.assign(query.values.begin() + static_cast<std::ptrdiff_t>(p * query.width),
                  query.values.begin() + static_cast<std::ptrdiff_t>((p + 1) * query.width));
}

}  // namespace

Status Engine::points(const std::string& id, std::span<const double> queries, const PointQuery& query,
                      const CallControl& control, const PointSink& emit, const PointEncoder& encode) {
  if (queries.empty()) return invalid_argument("queries: none given");
  if (shards_.sharded()) {
    auto layout = store_->layout(id);
    if (!layout.is_ok()) return layout.status();
    if (layout.value()) {
      auto info = store_->info(id);
      if (!info.is_ok()) return info.status();
      if (Status s = check_point_query(info.value(), queries, query); !s.is_ok()) return s;
      return points_from_pieces(id, *layout.value(), queries, query, control, emit, encode);
    }
  }
  auto set_or = store_->get(id);
  if (!set_or.is_ok()) return set_or.status();
  const std::shared_ptr<const StoredSet> held = set_or.value();
  const StoredSet& set = *held;
  if (Status s = check_point_query(set.info, queries, query); !s.is_ok()) return s;
  const int d = set.info.dimension;
  const auto dd = static_cast<std::size_t>(d);
  const std::size_t m = queries.size() / dd;
  const bool natural = wants_natural(query, d);
  auto window = store_->budget().try_charge(kStreamWindowBytes);
  if (!window) return store_->budget().over_budget("point queries", kStreamWindowBytes);
  const unsigned threads = std::max(1u, limits_.stream_threads);
  // The simplex of every query first (Morton order, each walked from the one before),
  // then the answers in rounds, in request order.
  std::shared_ptr<const DelaunayIndex> index;
  std::vector<std::int32_t> located;
  if (query.method != PointMethod::kNearest) {
    if (Status s = locate_points(set, queries.data(), m, control, index, located); !s.is_ok()) return s;
  }
  const std::string what = std::string("point queries (") + point_method_name(query.method) + ")";
  auto answer = [&](unsigned, std::size_t i, PointResult& r) -> Status {
    if (control.stopped()) return cancelled(what);
    r.index = i;
    const double* q = queries.data() + i * dd;
    if (query.method == PointMethod::kNearest) {
      answer_nearest(nearest_point(*set.tree, q), query, r);
    } else if (Status s = answer_query(index->arrays(), nullptr, located[i], q, query, natural, r); !s.is_ok()) {
      return Status{s.code(), "queries[" + std::to_string(i) + "]: " + s.message()};
    }
    if (encode) encode(r);
    return Status::ok();
  };
  return in_rounds<PointResult>(m, threads, 512 * threads, control, what, answer, emit);
}

namespace {

// Boxes covering every point of the set outside a piece's held box (inside it every
// point is held): slabs of the set's box beyond each of the held box's sides.
std::vector<double> unheld_slabs(std::span<const double> global, std::span<const double> held) {
  const std::size_t d = global.size() / 2;
  std::vector<double> out;
  for (std::size_t k = 0; k < d; ++k) {
    if (held[k] > global[k]) {
      out.insert(out.end(), global.begin(), global.end());
      out[out.size() - d + k] = held[k];
    }
    if (held[d + k] < global[d + k]) {
      out.insert(out.end(), global.begin(), global.end());
      out[out.size() - 2 * d + k] = held[d + k];
    }
  }
  return out;
}

// Whether a piece holds everything an answer rests on (point_queries.hpp,
// answer_support): each simplex's ball is certified against the unheld slabs, and
// nothing unheld may lie beyond a hull facet.
bool support_held(const DelaunayArrays& tri, const AnswerSupport& support, const StarCertifier& certifier,
                  std::span<const double> held, std::span<const double> unheld) {
  if (unheld.empty()) return true;
  const int d = tri.points->dimension();
  const auto w = static_cast<std::size_t>(d + 1);
  Star star;
  star.dimension = d;
  for (const std::int32_t s : support.simplices) {
    const std::uint32_t* row = &tri.simplices[static_cast<std::size_t>(s) * w];
    star.seed = row[0];
    star.simplices.assign(row, row + w);
    if (!certifier.certify(star, held, {}, unheld, [](std::span<const std::uint32_t>) { return false; }).certified) {
      return false;
    }
  }
  for (const auto& [s, k] : support.hull_facets) {
    const std::uint32_t* row = &tri.simplices[static_cast<std::size_t>(s) * w];
    std::array<const double*, kMaxDimension> facet{};
    for (std::size_t j = 0, at = 0; j < w; ++j) {
      if (static_cast<int>(j) != k) facet[at++] = tri.points->point(row[j]);
    }
    const double* inner = tri.points->point(row[static_cast<std::size_t>(k)]);
    for (std::size_t b = 0; b + 2 * static_cast<std::size_t>(d) <= unheld.size();
         b += 2 * static_cast<std::size_t>(d)) {
      if (StarCertifier::may_be_beyond(d, facet.data(), inner, unheld.data() + b)) return false;
    }
  }
  return true;
}

}  // namespace

Status Engine::points_from_pieces(const std::string& id, const PieceLayout& layout, std::span<const double> queries,
                                  const PointQuery& query, const CallControl& control, const PointSink& emit,
                                  const PointEncoder& encode) {
  const PieceManifest& m = layout.manifest();
  const int d = m.dimension;
  const auto dd = static_cast<std::size_t>(d);
  const std::size_t count = queries.size() / dd;
  const bool natural = wants_natural(query, d);
  auto window = store_->budget().try_charge(kStreamWindowBytes);
  if (!window) return store_->budget().over_budget("point queries", kStreamWindowBytes);
  const unsigned threads = std::max(1u, limits_.stream_threads);
  const std::string what = std::string("point queries (") + point_method_name(query.method) + ")";
  const std::vector<double>& g = m.global_box;
  // Each query's piece: the one whose own box is nearest (0 inside), the first of equals.
  std::vector<std::uint32_t> piece_of(count, 0);
  for (std::size_t i = 0; i < count; ++i) {
    const double* q = queries.data() + i * dd;
    double best = std::numeric_limits<double>::infinity();
    for (std::uint32_t p = 0; p < m.pieces.size(); ++p) {
      const std::vector<double>& b = m.pieces[p].box;
      double d2 = 0;
      for (std::size_t k = 0; k < dd; ++k) {
        const double gap = std::max({b[k] - q[k], q[k] - b[dd + k], 0.0});
        d2 += gap * gap;
      }
      if (d2 < best) {
        best = d2;
        piece_of[i] = p;
      }
    }
  }
  std::vector<std::uint32_t> order(count);
  std::iota(order.begin(), order.end(), 0u);
  std::stable_sort(order.begin(), order.end(),
                   [&](std::uint32_t a, std::uint32_t b) { return piece_of[a] < piece_of[b]; });
  std::vector<PointResult> results(count);
  std::vector<std::uint8_t> settled(count, 0);
  auto outside_set_box = [&](const double* q) {
    for (std::size_t k = 0; k < dd; ++k) {
      if (q[k] < g[k] || q[k] > g[dd + k]) return true;
    }
    return false;
  };
  // Runs `fn(j)` for j in [0, n) on the stream threads; the lowest failure is returned.
  auto parallel = [&](std::size_t n, const std::function<Status(std::size_t)>& fn) {
    std::atomic<std::size_t> next{0};
    std::mutex mu;
    std::size_t failed_at = n;
    Status failure;
    auto work = [&] {
      for (std::size_t j; (j = next.fetch_add(1)) < n;) {
        Status s = control.stopped() ? cancelled(what) : fn(j);
        if (s.is_ok()) continue;
        std::lock_guard lock(mu);
        if (j < failed_at) {
          failed_at = j;
          failure = std::move(s);
        }
        next = n;
      }
    };
    std::vector<std::thread> pool;
    for (unsigned t = 1; t < threads && n > 64; ++t) pool.emplace_back(work);
    work();
    for (std::thread& th : pool) th.join();
    if (failure.code() == Code::kCancelled) return control.stopped_status(what);
    return failure;
  };
  for (std::size_t at = 0; at < count;) {
    const std::uint32_t p = piece_of[order[at]];
    std::size_t end = at;
    while (end < count && piece_of[order[end]] == p) ++end;
    auto piece_or = store_->get_piece(id, p);
    if (!piece_or.is_ok()) return piece_or.status();
    const std::shared_ptr<const StoredSet> piece = piece_or.value();
    const PieceOf& of = *piece->piece;
    const std::vector<double> unheld = unheld_slabs(g, of.held_box);
    const StarCertifier certifier(piece->points, g);
    const std::size_t n = end - at;
    std::vector<double> group(n * dd);
    for (std::size_t j = 0; j < n; ++j) {
      std::copy_n(queries.data() + order[at + j] * dd, dd, group.data() + j * dd);
    }
    std::shared_ptr<const DelaunayIndex> index;
    std::vector<std::int32_t> located;
    if (query.method != PointMethod::kNearest) {
      if (Status s = locate_points(*piece, group.data(), n, control, index, located); !s.is_ok()) return s;
    }
    Status s = parallel(n, [&](std::size_t j) -> Status {
      const std::uint32_t i = order[at + j];
      const double* q = group.data() + j * dd;
      PointResult& r = results[i];
      if (query.method == PointMethod::kNearest) {
        const std::uint32_t local = nearest_point(*piece->tree, q);
        const double* x = piece->points.point(local);
        double d2 = 0;
        for (std::size_t k = 0; k < dd; ++k) d2 += (x[k] - q[k]) * (x[k] - q[k]);
        // Held when the ball around q through it, within the set's box, lies in the held box.
        const double reach = std::sqrt(d2) * (1 + 1e-9) + 1e-300;
        bool held = true;
        for (std::size_t k = 0; k < dd && held; ++k) {
          held = std::max(q[k] - reach, g[k]) >= of.held_box[k] &&
                 std::min(q[k] + reach, g[dd + k]) <= of.held_box[dd + k];
        }
        if (!held) return Status::ok();
        answer_nearest(static_cast<std::uint32_t>(of.ids[local]), query, r);
        settled[i] = 1;
        return Status::ok();
      }
      const DelaunayArrays arrays = index->arrays();
      thread_local AnswerSupport support;
      answer_support(arrays, located[j], q, natural, support);
      const bool held =
          support.outside ? outside_set_box(q) : support_held(arrays, support, certifier, of.held_box, unheld);
      if (!held) return Status::ok();
      if (Status st = answer_query(arrays, &of.ids, located[j], q, query, natural, r); !st.is_ok()) {
        return Status{st.code(), "queries[" + std::to_string(i) + "]: " + st.message()};
      }
      settled[i] = 1;
      return Status::ok();
    });
    if (!s.is_ok()) return s;
    at = end;
  }
  // What no piece held: from the set's own file, as a replica holding it whole answers.
  std::vector<std::uint32_t> rest;
  for (std::uint32_t i = 0; i < count; ++i) {
    if (settled[i] == 0) rest.push_back(i);
  }
  if (!rest.empty()) {
    auto whole_or = store_->get(id);
    if (!whole_or.is_ok()) return whole_or.status();
    const std::shared_ptr<const StoredSet> whole = whole_or.value();
    std::vector<double> group(rest.size() * dd);
    for (std::size_t j = 0; j < rest.size(); ++j) std::copy_n(queries.data() + rest[j] * dd, dd, group.data() + j * dd);
    std::shared_ptr<const DelaunayIndex> index;
    std::vector<std::int32_t> located;
    if (query.method != PointMethod::kNearest) {
      if (Status s = locate_points(*whole, group.data(), rest.size(), control, index, located); !s.is_ok()) return s;
    }
    Status s = parallel(rest.size(), [&](std::size_t j) -> Status {
      const std::uint32_t i = rest[j];
      const double* q = group.data() + j * dd;
      if (query.method == PointMethod::kNearest) {
        answer_nearest(nearest_point(*whole->tree, q), query, results[i]);
        return Status::ok();
      }
      if (Status st = answer_query(index->arrays(), nullptr, located[j], q, query, natural, results[i]); !st.is_ok()) {
        return Status{st.code(), "queries[" + std::to_string(i) + "]: " + st.message()};
      }
      return Status::ok();
    });
    if (!s.is_ok()) return s;
  }
  completed_from_whole_.fetch_add(rest.size(), std::memory_order_relaxed);
  // In request order, encoded, a round at a time.
  constexpr std::size_t kRound = 1024;
  for (std::size_t at = 0; at < count; at += kRound) {
    const std::size_t end = std::min(count, at + kRound);
    for (std::size_t i = at; i < end; ++i) {
      results[i].index = i;
      if (encode) encode(results[i]);
    }
    if (Status s = emit(std::span<const PointResult>(results.data() + at, end - at), end); !s.is_ok()) return s;
  }
  return Status::ok();
}

Status Engine::batch_from_pieces(const std::string& id, std::uint64_t count, const std::vector<std::uint64_t>& seeds,
                                 BatchKind kind, const NeighborQuery& query, const DomainSpec& spec,
                                 const CallControl& control, const AnswerSink& emit, const AnswerEncoder& encode) {
  if (Status s = check_batch_seeds(seeds, count); !s.is_ok()) return s;
  auto window = store_->budget().try_charge(kStreamWindowBytes);
  if (!window) return store_->budget().over_budget("a batch of seeds", kStreamWindowBytes);
  const unsigned threads = std::max(1u, limits_.stream_threads);
  // Each seed as its single call answers it, from the piece holding it.
  auto answer = [&](unsigned, std::size_t i, BatchAnswer& a) -> Status {
    a.seed = seeds[i];
    if (kind == BatchKind::kStars) {
      auto r = star(id, seeds[i], control);
      if (r.is_ok()) a.star = std::move(r).value();
      return r.status();
    }
    if (kind == BatchKind::kNeighbors) {
      auto r = neighbors(id, seeds[i], query, control);
      if (r.is_ok()) a.neighbors = std::move(r).value();
      return r.status();
    }
    auto r = cell(id, seeds[i], spec, control);
    if (r.is_ok()) a.cell = std::move(r).value();
    return r.status();
  };
  return in_rounds<BatchAnswer>(seeds.size(), threads, 128 * threads, control, "a batch of seeds",
                                encoded(answer, encode), emit);
}

Status Engine::stream_simplices_from_pieces(const std::string& id, const PieceManifest& m, StreamPart range,
                                            std::uint32_t batch_size, const CallControl& control,
                                            const BatchSink& emit) {
  const std::size_t width = static_cast<std::size_t>(m.dimension) + 1;
  MemoryBudget& budget = store_->budget();
  auto window = budget.try_charge(kStreamWindowBytes);
  if (!window) return budget.over_budget("a streamed shard", kStreamWindowBytes);
  std::vector<std::uint32_t> pending;  // less than one batch, carried between blocks and pieces
  pending.reserve(batch_size * width);
  bool emitted = false;
  std::uint64_t done = 0, done_before = 0;
  const std::vector<std::uint32_t> held_before = store_->pieces_held(id);
  // The pieces overlapping the range in sweep order, each swept over its own points
  // as the whole set's sweep takes them (its halo holds every neighbour: the same rows).
  for (std::uint32_t p = 0; p < m.pieces.size(); ++p) {
    const std::uint64_t first = m.pieces[p].start, last = first + m.pieces[p].count;
    if (last <= range.begin || first >= range.end) continue;
    // Another shard's piece this stream loads is given back once swept.
    struct GiveBack {
      PointSetStore& store;
      const std::string& id;
      std::uint32_t piece;
      bool give;
      ~GiveBack() {
        if (give) store.drop_piece(id, piece);
      }
    } give_back{*store_, id, p,
                !is_own_piece(p, static_cast<std::uint32_t>(m.pieces.size())) &&
                    std::find(held_before.begin(), held_before.end(), p) == held_before.end()};
    auto loaded = store_->get_piece(id, p);
    if (!loaded.is_ok()) return loaded.status();
    const StoredSet& s = *loaded.value();
    const PieceOf& piece = *s.piece;
    std::vector<std::uint32_t> members;
    members.reserve(m.pieces[p].count);
    for (std::uint32_t k = 0; k < piece.own.size(); ++k) {
      if (piece.own[k] != 0) members.push_back(k);
    }
    const std::uint32_t ends[1] = {static_cast<std::uint32_t>(members.size())};
    const SpaceSplit split(s.points, members, ends, SpaceSplit::default_block_points(m.dimension, m.count));
    MemoryBudget::Charge cache_charge;
    MeshOptions options;
    options.threads = std::max(1u, limits_.stream_threads);
    options.sweep_begin = static_cast<std::uint32_t>(std::max<std::uint64_t>(range.begin, first) - first);
    options.sweep_end = static_cast<std::uint32_t>(std::min<std::uint64_t>(range.end, last) - first);
    options.star.cancel = control.stop_flag();
    options.split = &split;
    options.engine = engine_for(s.points, split, options);
    if (options.engine == MeshEngine::kTriangulations) {
      cache_charge = budget.empty_charge();
      options.facet_cache_bytes = 0;
      options.reserve_bytes = [&cache_charge, cap = limits_.stream_cache_bytes](std::size_t bytes) {
        return cache_charge.bytes() + bytes <= cap && cache_charge.grow(bytes);
      };
    } else {
      options.facet_cache_bytes =
          charge_sweep_memo(m.dimension, static_cast<std::uint32_t>(s.info.count), options.threads, cache_charge);
    }
    auto sink = [&](std::span<const std::uint32_t> block, std::uint64_t seeds_done) -> Status {
      done = done_before + seeds_done;
      for (const std::uint32_t v : block) {
        pending.push_back(static_cast<std::uint32_t>(piece.ids[v]));
        if (pending.size() == batch_size * width) {
          emitted = true;
          if (Status st = emit(pending, {}, done); !st.is_ok()) return st;
          pending.clear();
        }
      }
      return Status::ok();
    };
    auto result = mesh_seeds(*s.tree, options, sink);
    if (!result.is_ok()) {
      if (result.status().code() == Code::kCancelled && control.stopped()) {
        return control.stopped_status("streaming the simplices of point set " + id);
      }
      return result.status();
    }
    done_before += options.sweep_end - options.sweep_begin;
    done = done_before;
  }
  if (!pending.empty() || !emitted) return emit(pending, {}, done);
  return Status::ok();
}

Status Engine::stream_cells_from_pieces(const std::string& id, StreamPart range, std::uint32_t batch_size,
                                        const DomainSpec& spec, bool measures_only, const CallControl& control,
                                        const CellBatchSink& emit) {
  auto window = store_->budget().try_charge(kStreamWindowBytes);
  if (!window) return store_->budget().over_budget("a streamed shard of cells", kStreamWindowBytes);
  // Each seed's cell as its single call answers it (from its piece), clipped to the
  // set's bounding box unless the request names a domain, as a whole set's stream.
  DomainSpec clip = spec;
  if (clip.empty()) clip.bounding_box = true;
  CellBatcher batches(batch_size, emit);
  auto answer = [&](unsigned, std::size_t i, VoronoiCell& c) -> Status {
    auto r = cell(id, range.begin + i, clip, control);
    if (!r.is_ok()) return r.status();
    c = std::move(r).value();
    if (measures_only) keep_measures_only(c);
    return Status::ok();
  };
  std::uint64_t done = 0;
  auto forward = [&](std::span<const VoronoiCell> cells, std::uint64_t so_far) -> Status {
    done = so_far;
    return batches.add(cells, done);
  };
  // Other shards' pieces this stream loads are given back when it ends.
  const std::vector<std::uint32_t> held_before = store_->pieces_held(id);
  const unsigned threads = std::max(1u, limits_.stream_threads);
  Status s = in_rounds<VoronoiCell>(range.end - range.begin, threads, 64 * threads, control,
                                    "streaming the cells of point set " + id, answer, forward);
  if (auto layout = store_->layout(id); layout.is_ok() && layout.value()) {
    for (const std::uint32_t p : store_->pieces_held(id)) {
      if (!is_own_piece(p, layout.value()->pieces()) &&
          std::find(held_before.begin(), held_before.end(), p) == held_before.end()) {
        store_->drop_piece(id, p);
      }
    }
  }
  if (!s.is_ok()) return s;
  return batches.finish(done);
}

std::size_t Engine::charge_stream_cache(int dimension, std::uint32_t n, MemoryBudget::Charge& charge) {
  // A smaller cache, or none, gives the same answers, only slower.
  MemoryBudget& budget = store_->budget();
  for (std::size_t cap = limits_.stream_cache_bytes; cap >= defaults::kMinStreamCacheBytes; cap /= 2) {
    const std::size_t need = RunCache::bytes_for(dimension, n, cap);
    if (need == 0) continue;
    if (auto c = budget.try_charge(need)) {
      charge = std::move(*c);
      return cap;
    }
  }
  return 0;
}

std::size_t Engine::charge_sweep_memo(int dimension, std::uint32_t n, unsigned threads, MemoryBudget::Charge& charge) {
  if (RunCache::uses_edges(dimension)) return charge_stream_cache(dimension, n, charge);  // as for cells
  // The front's mail, capped at the estimate's mail part so that the charge bounds it,
  // plus the workers' block tables. Less mail, or none, gives the same simplices.
  const FrontMail::Estimate estimate =
      FrontMail::estimate(dimension, n, threads, SpaceSplit::default_block_points(dimension, n));
  MemoryBudget& budget = store_->budget();
  // A small set's whole estimate (under kMinStreamCacheBytes) is tried as it is; a
  // larger one is halved down to that while the budget is short.
  for (std::size_t mail = std::min(limits_.stream_cache_bytes, estimate.mail); mail != 0; mail /= 2) {
    if (auto c = budget.try_charge(mail + estimate.tables)) {
      charge = std::move(*c);
      return mail;
    }
    if (mail / 2 < defaults::kMinStreamCacheBytes) break;
  }
  return 0;
}

Status Engine::stream_cells(const std::string& id, std::uint32_t shard_index, std::uint32_t shard_count,
                            std::uint32_t batch_size, const DomainSpec& spec, bool measures_only,
                            const CallControl& control, const CellBatchSink& emit, StreamPart* range_out) {
  if (shard_count == 0) shard_count = 1;
  if (shard_index >= shard_count) {
    return invalid_argument("shard_index: " + std::to_string(shard_index) + " must be below shard_count " +
                            std::to_string(shard_count));
  }
  if (batch_size == 0) batch_size = defaults::kCellBatchSize;
  if (batch_size > defaults::kMaxCellBatchSize) {
    return invalid_argument("batch_size: " + std::to_string(batch_size) + " is above the maximum " +
                            std::to_string(defaults::kMaxCellBatchSize) + " cells");
  }
  if (shards_.sharded()) {
    auto layout = store_->layout(id);
    if (!layout.is_ok()) return layout.status();
    if (layout.value()) {
      if (!spec.shape_format.empty()) return failed_precondition(shape_needs_whole(id));
      const StreamPart range = stream_part(layout.value()->manifest().count, shard_index, shard_count);
      if (range_out != nullptr) *range_out = range;
      return stream_cells_from_pieces(id, range, batch_size, spec, measures_only, control, emit);
    }
  }
  auto set = store_->get(id);
  if (!set.is_ok()) return set.status();
  const StoredSet& s = *set.value();
  if (Status allowed = exact_allowed(s, "StreamCells"); !allowed.is_ok()) return allowed;
  if (Status st = check_query(s, &spec, nullptr); !st.is_ok()) return st;
  const StreamPart range = stream_part(s.info.count, shard_index, shard_count);
  if (range_out != nullptr) *range_out = range;
  if (s.periodic) return stream_periodic_cells(s, range, batch_size, measures_only, control, emit);
  auto shape = shape_for(s, spec);
  if (!shape.is_ok()) return shape.status();
  auto domain = resolve_domain(s, spec, true, shape.value().get());
  if (!domain.is_ok()) return domain.status();
  // Memory: one round of cells (threads x block) and a batch, within the stream window,
  // and the facet cache as for simplices.
  MemoryBudget& budget = store_->budget();
  auto window = budget.try_charge(kStreamWindowBytes);
  if (!window) return budget.over_budget("a streamed shard of cells", kStreamWindowBytes);
  MemoryBudget::Charge cache_charge;
  CellsOptions options;
  options.threads = std::max(1u, limits_.stream_threads);
  options.facet_cache_bytes =
      charge_stream_cache(s.info.dimension, static_cast<std::uint32_t>(s.info.count), cache_charge);
  options.seed_begin = range.begin;
  options.seed_end = range.end;
  options.block_size = 64;
  options.measures_only = measures_only;
  options.star.cancel = control.stop_flag();
  options.star.weights = s.weights;
  options.shape = shape.value().get();
  // Stars from the set's kept triangulation, or one this run builds and keeps (charged
  // to the budget while the set lives; a stream's triangulation within --stream-cache).
  keep_triangulation(set.value());
  options.whole = s.kept_whole();
  MemoryBudget::Charge tri_charge = budget.empty_charge();
  options.reserve_bytes = [&tri_charge, cap = limits_.stream_cache_bytes](std::size_t bytes) {
    return tri_charge.bytes() + bytes <= cap && tri_charge.grow(bytes);
  };
  options.keep_whole = [&s, &tri_charge](std::shared_ptr<const WholeTriangulation> whole) {
    std::lock_guard lock(s.whole_mu);
    if (s.whole != nullptr) return;
    s.whole = std::move(whole);
    s.whole_charge = std::move(tri_charge);
  };
  CellBatcher batches(batch_size, emit);
  std::uint64_t done = 0;
  auto sink = [&](std::span<const VoronoiCell> cells, std::uint64_t seeds_done) -> Status {
    done = seeds_done;
    return batches.add(cells, done);
  };
  Status result = compute_cells(*s.tree, &*domain.value(), options, sink);
  if (!result.is_ok()) {
    if (result.code() == Code::kCancelled && control.stopped()) {
      return control.stopped_status("streaming cells of shard " + std::to_string(shard_index) + " of " +
                                    std::to_string(shard_count));
    }
    return result;
  }
  return batches.finish(done);
}

Status Engine::stream_simplices(const std::string& id, std::uint32_t shard_index, std::uint32_t shard_count,
                                std::uint32_t batch_size, const CallControl& control, const BatchSink& emit,
                                StreamPart* range_out, int* dimension_out) {
  if (shard_count == 0) shard_count = 1;
  if (shard_index >= shard_count) {
    return invalid_argument("shard_index: " + std::to_string(shard_index) + " must be below shard_count " +
                            std::to_string(shard_count));
  }
  if (batch_size == 0) batch_size = defaults::kBatchSize;
  if (batch_size > defaults::kMaxBatchSize) {
    return invalid_argument("batch_size: " + std::to_string(batch_size) + " is above the maximum " +
                            std::to_string(defaults::kMaxBatchSize));
  }
  if (shards_.sharded()) {
    auto layout = store_->layout(id);
    if (!layout.is_ok()) return layout.status();
    if (layout.value()) {
      const PieceManifest& m = layout.value()->manifest();
      const StreamPart range = stream_part(m.count, shard_index, shard_count);
      if (range_out != nullptr) *range_out = range;
      if (dimension_out != nullptr) *dimension_out = m.dimension;
      return stream_simplices_from_pieces(id, m, range, batch_size, control, emit);
    }
  }
  auto set = store_->get(id);
  if (!set.is_ok()) return set.status();
  const StoredSet& s = *set.value();
  if (Status allowed = exact_allowed(s, "StreamSimplices"); !allowed.is_ok()) return allowed;
  const StreamPart range = stream_part(s.info.count, shard_index, shard_count);
  if (range_out != nullptr) *range_out = range;
  if (dimension_out != nullptr) *dimension_out = s.info.dimension;
  if (s.periodic) return stream_periodic_simplices(s, range, batch_size, control, emit);
  const std::size_t width = static_cast<std::size_t>(s.info.dimension) + 1;

  // The stream's memory against the budget: its output window (a bounded number of
  // blocks of simplices and one batch: kStreamWindowBytes covers both), and either its
  // local triangulations as they grow, or (star walks) its facet cache at the size it
  // would take, or smaller (a smaller cache, or none, gives the same simplices, only
  // slower) when the budget is short.
  MemoryBudget& budget = store_->budget();
  const auto n32 = static_cast<std::uint32_t>(s.info.count);
  auto window = budget.try_charge(kStreamWindowBytes);
  if (!window) return budget.over_budget("a streamed shard", kStreamWindowBytes);
  MemoryBudget::Charge cache_charge;
  MeshOptions options;
  options.threads = std::max(1u, limits_.stream_threads);
  options.sweep_begin = range.begin;  // shards of simplices are parts of the sweep
  options.sweep_end = range.end;
  options.star.cancel = control.stop_flag();
  options.star.weights = s.weights;
  options.split = s.split.get();
  options.engine = engine_for(s.points, *s.split, options);
  if (options.engine == MeshEngine::kTriangulations) {
    // Local triangulations: their memory is charged as it grows (a region per worker,
    // and the whole set's triangulation when balls reach across it), up to the stream
    // cache; what that or the budget refuses is meshed by star walks instead, the same
    // rows.
    cache_charge = budget.empty_charge();
    options.facet_cache_bytes = 0;
    options.reserve_bytes = [&cache_charge, cap = limits_.stream_cache_bytes](std::size_t bytes) {
      return cache_charge.bytes() + bytes <= cap && cache_charge.grow(bytes);
    };
    share_whole_triangulation(s, options);
  } else {
    options.facet_cache_bytes = charge_sweep_memo(s.info.dimension, n32, options.threads, cache_charge);
  }

  std::vector<std::uint32_t> pending;  // less than one batch, carried between blocks
  pending.reserve(batch_size * width);
  bool emitted = false;
  std::uint64_t done = 0;
  auto flush = [&](std::span<const std::uint32_t> batch) -> Status {
    emitted = true;
    return emit(batch, {}, done);
  };
  auto sink = [&](std::span<const std::uint32_t> block, std::uint64_t seeds_done) -> Status {
    done = seeds_done;
    while (!block.empty()) {
      const std::size_t take = std::min(block.size(), batch_size * width - pending.size());
      pending.insert(pending.end(), block.begin(), block.begin() + static_cast<std::ptrdiff_t>(take));
      block = block.subspan(take);
      if (pending.size() == batch_size * width) {
        if (Status st = flush(pending); !st.is_ok()) return st;
        pending.clear();
      }
    }
    return Status::ok();
  };
  auto result = mesh_seeds(*s.tree, options, sink);
  if (!result.is_ok()) {
    if (result.status().code() == Code::kCancelled && control.stopped()) {
      return control.stopped_status("streaming shard " + std::to_string(shard_index) + " of " +
                                    std::to_string(shard_count));
    }
    return result.status();
  }
  if (!pending.empty() || !emitted) return flush(pending);
  return Status::ok();
}

Status Engine::stream_periodic_simplices(const StoredSet& set, StreamPart range, std::uint32_t batch_size,
                                         const CallControl& control, const BatchSink& emit) {
  // Seed by seed (each star whole, from the set's cover), in index order: a periodic
  // set has no sweep; the rows of a seed are the same whoever asks (PeriodicStars).
  auto window = store_->budget().try_charge(kStreamWindowBytes);
  if (!window) return store_->budget().over_budget("a streamed shard", kStreamWindowBytes);
  const auto d = static_cast<std::size_t>(set.info.dimension), width = d + 1;
  const unsigned threads = std::max(1u, limits_.stream_threads);
  std::vector<std::uint32_t> pending;
  std::vector<std::int32_t> pending_offsets;
  bool emitted = false;
  auto compute = [&](unsigned, std::size_t i, PeriodicStar& star) -> Status {
    auto r = periodic_star_of(set, static_cast<std::uint32_t>(range.begin + i), control, nullptr, false);
    if (!r.is_ok()) return r.status();
    star = std::move(r).value();
    return Status::ok();
  };
  auto take = [&](std::span<const PeriodicStar> stars, std::size_t done) -> Status {
    for (const PeriodicStar& star : stars) {
      for (std::size_t r = 0; r < star.size(static_cast<int>(d)); ++r) {
        // The seed's own rows: it is their first vertex, at offset 0.
        const std::int32_t* k = star.offsets.data() + r * width * d;
        if (star.simplices[r * width] != star.seed || std::any_of(k, k + d, [](std::int32_t v) { return v != 0; })) {
          continue;
        }
        pending.insert(pending.end(), star.simplices.begin() + static_cast<std::ptrdiff_t>(r * width),
                       star.simplices.begin() + static_cast<std::ptrdiff_t>((r + 1) * width));
        pending_offsets.insert(pending_offsets.end(), k, k + width * d);
        if (pending.size() == batch_size * width) {
          emitted = true;
          if (Status st = emit(pending, pending_offsets, done); !st.is_ok()) return st;
          pending.clear();
          pending_offsets.clear();
        }
      }
    }
    return Status::ok();
  };
  const std::size_t round = (d <= 3 ? 64 : 16) * threads;
  if (Status st = in_rounds<PeriodicStar>(range.end - range.begin, threads, round, control,
                                          "streaming a periodic shard", compute, take);
      !st.is_ok()) {
    return st;
  }
  if (!pending.empty() || !emitted) return emit(pending, pending_offsets, range.end - range.begin);
  return Status::ok();
}

Status Engine::stream_periodic_cells(const StoredSet& set, StreamPart range, std::uint32_t batch_size,
                                     bool measures_only, const CallControl& control, const CellBatchSink& emit) {
  auto window = store_->budget().try_charge(kStreamWindowBytes);
  if (!window) return store_->budget().over_budget("a streamed shard of cells", kStreamWindowBytes);
  const unsigned threads = std::max(1u, limits_.stream_threads);
  CellBatcher batches(batch_size, emit);
  auto compute = [&](unsigned, std::size_t i, VoronoiCell& cell) -> Status {
    auto r = periodic_star_of(set, static_cast<std::uint32_t>(range.begin + i), control, &cell, false);
    if (!r.is_ok()) return r.status();
    if (measures_only) {
      cell.vertices.clear();
      for (VoronoiFacet& f : cell.facets) f.vertices.clear();
    }
    return Status::ok();
  };
  auto take = [&](std::span<const VoronoiCell> cells, std::size_t done) { return batches.add(cells, done); };
  const std::size_t round = (set.info.dimension <= 3 ? 64 : 16) * threads;
  if (Status st = in_rounds<VoronoiCell>(range.end - range.begin, threads, round, control, "streaming periodic cells",
                                         compute, take);
      !st.is_ok()) {
    return st;
  }
  return batches.finish(range.end - range.begin);
}

}  // namespace spokemesh::service
