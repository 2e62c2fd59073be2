// PointSetStore: uploaded point sets, durable on disk, cached in memory with their trees.
//
// On disk (--data-dir), one file per point set, `<id>.points`, holding exactly the
// bytes the id hashes: dimension (uint32 LE), count (uint64 LE), coordinates (float64
// LE, row-major), then for a weighted set 'W' and its count power weights (float64
// LE), then for a periodic set 'P' and its box (2 dimension float64 LE: LO then HI). Verifying a file is recomputing
// its SHA-256, so the id doubles as a checksum. An optional `<id>.name` holds the display name. A file is written to a
// temporary name, fsynced, renamed into place and the directory fsynced before the
// upload is acknowledged. A file that fails verification is moved to quarantine/ with
// a log line; other point sets are unaffected.
//
// Several servers may share one data dir: an id that is not in memory is looked up
// on disk on first use, and a point set deleted through one server disappears from
// the others at their next request for it (each request checks the file still exists).
//
// In memory, loaded point sets (coordinates + k-d tree) are kept up to a byte budget;
// the least recently used are dropped from memory (never from disk). Requests hold a
// shared_ptr, so a set dropped mid-request stays alive until that request ends.
//
// Thread safety: all member functions are safe to call concurrently.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

#include "memory_budget.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/mesh.hpp"
#include "spokemesh/periodic.hpp"
#include "spokemesh/periodic_box.hpp"
#include "spokemesh/periodic_cells.hpp"
#include "spokemesh/pieces.hpp"
#include "spokemesh/point_queries.hpp"
#include "spokemesh/point_set.hpp"
#include "spokemesh/space_split.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::service {

struct PointSetInfo {
  std::string id;
  int dimension = 0;
  std::uint64_t count = 0;
  std::string display_name;
  bool already_existed = false;
  bool weighted = false;             // carries one power weight per point
  std::vector<double> periodic_box;  // LO_1..LO_d, HI_1..HI_d of its torus, or empty
};

// What a StoredSet holding one piece of a set (pieces.hpp) knows of it: its local
// index k is global index ids[k].
struct PieceOf {
  std::uint32_t index = 0;
  std::vector<std::uint64_t> ids;  // ascending
  std::vector<std::uint8_t> own;   // 1: the piece's own point (0: its halo)
  std::uint64_t start = 0;         // its first sweep position in the whole set
  std::vector<double> held_box;    // every point of the set inside is held
  std::vector<double> global_box;  // the whole set's box (the default domain of its cells)
};

// A point set ready for queries. Immutable; shared by concurrent requests.
struct StoredSet {
  PointSetInfo info;
  PointSet points;
  // The whole mesh's sweep order (exact dimensions only; null above kMaxDimension),
  // built before the tree (its transient records are freed before the tree's build).
  std::unique_ptr<SpaceSplit> split;
  std::unique_ptr<KdTree> tree;             // null for a periodic set (its stars walk `periodic`'s cover)
  std::vector<double> weights;              // one power weight per point, or empty
  std::optional<PeriodicBox> box;           // a periodic set's torus
  std::unique_ptr<PeriodicStars> periodic;  // a periodic set's stars (borrows points, box, weights)
  std::vector<double> bounds;               // the points' bounding box (d lows, d highs): cells' default domain
  std::uint64_t memory_bytes = 0;           // estimate: coordinates + ranks + split + tree
  MemoryBudget::Charge charge;              // memory_bytes against the server's budget, while the set lives
  // The triangulation of every point that a batch of this set's stars or a stream of
  // its simplices built (its Delaunay balls reach across the set: closed surfaces),
  // kept for later ones as the tree is kept, charged to the budget (whole_charge) while
  // the set lives; null until one is built. Guarded by whole_mu (the set is otherwise
  // immutable).
  // Sets the triangulations apply to (2-d and 3-d, unweighted, not periodic) also get
  // one built in the background on their first per-seed request, batch or stream
  // (Engine::keep_triangulation; whole_asked: once), which single star, neighbours and
  // cell requests read (whole_skip_doomed: the cells' plan in a box, ClippedCellBuilder).
  mutable std::mutex whole_mu;
  mutable std::shared_ptr<const WholeTriangulation> whole;
  mutable MemoryBudget::Charge whole_charge;
  mutable bool whole_skip_doomed = false;
  mutable std::atomic<bool> whole_asked{false};
  // The kept triangulation, if any (a snapshot: it stays alive while the caller holds it).
  std::shared_ptr<const WholeTriangulation> kept_whole() const {
    std::lock_guard lock(whole_mu);
    return whole;
  }
  // The triangulation as arrays with a point locator, which point queries read
  // (:locate, :interpolate; point_queries.hpp): made by the first (from the kept
  // triangulation when there is one), charged to the budget (located_charge) while the
  // set lives. Guarded by located_mu, which the first holds while it is made.
  mutable std::mutex located_mu;
  mutable std::shared_ptr<const DelaunayIndex> located;
  mutable MemoryBudget::Charge located_charge;
  // Set when this holds one piece of the set (info.count is then the piece's held points).
  std::optional<PieceOf> piece;
  // The key it is cached under: the id, or for a piece "<id>/<piece>".
  std::string cache_key() const { return piece ? info.id + "/" + std::to_string(piece->index) : info.id; }
};

// A set kept as pieces (pieces.hpp): its manifest, and its owner map open for lookups.
class PieceLayout {
 public:
  // owners_fd: the owner map, manifest.count 4-byte entries (checked by the caller);
  // owned, and mapped read-only here (every sharded request looks a seed up in it: a
  // memory read instead of a pread; its pages are the kernel's file cache, reclaimable,
  // not the server's memory budget). The map's file is never rewritten in place (the
  // data directory's commit rule), so the mapping stays valid while it is held.
  PieceLayout(PieceManifest manifest, int owners_fd);
  ~PieceLayout();
  PieceLayout(const PieceLayout&) = delete;
  PieceLayout& operator=(const PieceLayout&) = delete;
  const PieceManifest& manifest() const { return manifest_; }
  std::uint32_t pieces() const { return static_cast<std::uint32_t>(manifest_.pieces.size()); }
  // The piece holding point `seed` (< manifest().count): one entry of the owner map.
  Result<std::uint32_t> piece_of(std::uint64_t seed) const;
  // The piece of every point (the whole owner map, manifest().count entries, each checked).
  Result<std::vector<std::uint32_t>> owners() const;

 private:
  PieceManifest manifest_;
  int owners_fd_;
  const std::uint32_t* owners_ = nullptr;  // the mapping (null: not mapped, pread instead)
  std::size_t mapped_bytes_ = 0;
};

// Incremental SHA-256 (OpenSSL EVP).
class Sha256 {
 public:
  Sha256();
  ~Sha256();
  Sha256(const Sha256&) = delete;
  Sha256& operator=(const Sha256&) = delete;
  void update(const void* data, std::size_t size);
  std::string hex_digest();  // lowercase; ends the computation

 private:
  void* ctx_;  // EVP_MD_CTX
};

// Bytes of the hashed header: dimension (uint32 LE) + count (uint64 LE).
std::string point_set_header_bytes(std::uint32_t dimension, std::uint64_t count);
// Bytes hashed (and stored) after the coordinates: 'W' and the weights when there are
// any, then 'P' and the box when there is one; nothing for a plain set, whose id is
// therefore what it always was.
std::string point_set_extra_bytes(std::span<const double> weights, std::span<const double> periodic_box);

// Checks what a set carries besides its coordinates (validated points): `weights`
// empty or one finite power weight per point (|w| <= kMaxWeight); `periodic_box` empty
// or 2 d values LO_1..LO_d, HI_1..HI_d with LO < HI and every point in [LO, HI); both
// only where answers are exact (d <= kMaxDimension). INVALID_ARGUMENT naming the field
// ("weights", "periodic_box", or `what` for the points) and the index; sets *box.
Status check_extras(const PointSet& points, std::span<const double> weights, std::span<const double> periodic_box,
                    const std::string& what, std::optional<PeriodicBox>* box);

// True for 64 lowercase hex digits.
bool is_valid_id(const std::string& id);

// Estimated resident bytes of a loaded set of n points in d dimensions (weighted,
// periodic: as the set is).
std::uint64_t estimated_memory(std::uint64_t n, int d, bool weighted = false, bool periodic = false);

using LogFn = std::function<void(const std::string& level, const std::string& message)>;

class PointSetStore {
 public:
  ~PointSetStore();
  // Creates data_dir (and quarantine/) if needed. memory_budget: the server's one
  // budget (--max-memory), owned here (budget()): loaded sets draw from it, and when a
  // charge does not fit the store drops its least recently used sets nobody is using.
  static Result<std::unique_ptr<PointSetStore>> open(const std::string& data_dir, std::uint64_t memory_budget,
                                                     LogFn log);

  // Stores a validated point set whose id is `info.id` (computed by the caller from
  // the same bytes), with its weights (info.weighted) and box (info.periodic_box).
  // Durable when this returns OK. If the file exists already, nothing is written and
  // info.already_existed is set.
  Result<PointSetInfo> put(PointSetInfo info, const PointSet& points, std::span<const double> weights = {});

  // The loaded set, from memory or from disk. NOT_FOUND if unknown;
  // INVALID_ARGUMENT for a malformed id.
  Result<std::shared_ptr<const StoredSet>> get(const std::string& id);

  // The set if it is loaded in memory now (whole, not a piece), else null: nothing is
  // read (an append asks whether its parent's triangulation is at hand).
  std::shared_ptr<const StoredSet> loaded(const std::string& id) const;

  // Pieces (pieces.hpp): the layout of a set kept as pieces, cached (null when the set
  // has none); one piece loaded with its tree, cached and charged like a set (least
  // recently used first out); and writing a set's pieces (the set must be stored).
  Result<std::shared_ptr<const PieceLayout>> layout(const std::string& id);
  Result<std::shared_ptr<const StoredSet>> get_piece(const std::string& id, std::uint32_t piece);
  // get() and get_piece() when the set or piece is in memory and still stored, else null
  // (never read from disk: for answers given without a thread of their own).
  std::shared_ptr<const StoredSet> get_in_memory(const std::string& id);
  std::shared_ptr<const StoredSet> get_piece_in_memory(const std::string& id, std::uint32_t piece);
  // The pieces of set `id` held in memory now, and dropping one from memory (requests
  // holding it keep it until they end): a sharded replica's streams read other shards'
  // pieces and give them back when done.
  std::vector<std::uint32_t> pieces_held(const std::string& id) const;
  void drop_piece(const std::string& id, std::uint32_t piece);
  Result<PieceManifest> put_pieces(const std::string& id, const PointSet& points, const PieceOptions& options);
  // Pieces loaded now, and their bytes (for /metrics).
  std::pair<std::size_t, std::uint64_t> pieces_in_memory() const;
  const std::string& directory() const { return dir_; }

  // Metadata only (reads the 12-byte header and the extras' tags and box, does not load
  // or verify coordinates).
  Result<PointSetInfo> info(const std::string& id);

  // The set's coordinates in order (little-endian float64, as uploaded), handed to
  // `sink` in pieces of at most defaults::kDownloadChunkBytes; a non-OK status from the
  // sink stops the read and is returned. From memory when the set is loaded; otherwise
  // read from its file without loading it (no tree, no split, no charge against the
  // memory budget beyond one piece) and verified against its id as the bytes pass: a
  // mismatch quarantines the file and returns NOT_FOUND after the sink has seen the
  // bytes, so a caller must not act on them until this returns OK. For appends, whose
  // parent need not be queried.
  using CoordinateSink = std::function<Status(const char* bytes, std::size_t size)>;
  Status read_coordinates(const std::string& id, const CoordinateSink& sink);

  // Ids on disk in ascending order, strictly after `after`, at most `limit`; with
  // `visible`, only the ids it accepts.
  std::vector<PointSetInfo> list(const std::string& after, std::size_t limit, bool* more,
                                 const std::function<bool(const std::string&)>& visible = {});

  // Tenancy (see auth.hpp): one empty marker file per owning tenant, written durably
  // before the set itself so that a concurrent last-owner delete cannot remove a set
  // just acknowledged to another tenant. The empty tenant (open mode) has no marker.
  Status add_owner(const std::string& id, const std::string& tenant);
  bool owned_by(const std::string& id, const std::string& tenant) const;
  // Removes the tenant's marker; deletes the set when no owner is left. NOT_FOUND if
  // the tenant did not own it.
  Status release(const std::string& id, const std::string& tenant);

  Status remove(const std::string& id);

  // Loads and verifies every point set on disk (start-up), but those `skip` names (a
  // sharded replica's sets kept as pieces, checked piece by piece as they load).
  // Returns how many loaded.
  std::size_t load_all(const std::function<bool(const std::string&)>& skip = {});

  // Bytes of the sets and pieces loaded in memory (their estimates), and how many sets
  // are held whole (pieces: pieces_in_memory).
  std::uint64_t memory_in_use() const;
  std::size_t loaded_count() const;
  MemoryBudget& budget() { return budget_; }

 private:
  PointSetStore(std::string dir, std::uint64_t budget, LogFn log);
  std::string data_path(const std::string& id) const;
  std::string name_path(const std::string& id) const;
  std::string owner_path(const std::string& id, const std::string& tenant) const;
  bool has_owners(const std::string& id) const;
  void remove_owner_markers(const std::string& id);
  Result<std::shared_ptr<const StoredSet>> load_from_disk(const std::string& id, MemoryBudget::Charge charge);
  // Reads a set's file and verifies it: the header's shape against the file's size,
  // then the SHA-256 of header and coordinates against the id; a malformed or corrupt
  // file is quarantined (NOT_FOUND). The coordinates go at once into
  // destination(d, n) (n * d doubles) when it returns a buffer, else through `sink` in
  // pieces of defaults::kDownloadChunkBytes (a non-OK status from it stops the read).
  // The bytes after the coordinates (point_set_extra_bytes) go to *extras when given.
  using Destination = std::function<double*(std::uint32_t d, std::uint64_t n)>;
  Status read_verified(const std::string& id, const Destination& destination, const CoordinateSink& sink,
                       std::string* extras = nullptr);
  // Drops least recently used sets that no request holds, until `bytes` are freed.
  void reclaim(std::uint64_t bytes);
  void quarantine(const std::string& id, const std::string& why);
  std::shared_ptr<const StoredSet> remember(std::shared_ptr<const StoredSet> set);
  void forget(const std::string& id);
  // Whether the set's file is in the data directory (another server sharing it may
  // have deleted it). Asked by every request, so looked up relative to a descriptor of
  // the directory kept open (one name looked up, not every component of the path).
  bool set_file_present(const std::string& id);

  const std::string dir_;
  MemoryBudget budget_;
  LogFn log_;

  mutable std::mutex mutex_;
  // Most recently used first.
  std::list<std::shared_ptr<const StoredSet>> lru_;
  std::unordered_map<std::string, std::list<std::shared_ptr<const StoredSet>>::iterator> index_;
  std::uint64_t in_use_ = 0;
  std::unordered_map<std::string, std::shared_ptr<const PieceLayout>> layouts_;  // guarded by mutex_
  int dir_fd_ = -1;                                                              // dir_, for set_file_present (O_PATH)
};

}  // namespace spokemesh::service
