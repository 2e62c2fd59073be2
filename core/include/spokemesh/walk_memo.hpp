// What a star walk may take from the stars its run computed before it: the memo
// interfaces the walker (star.hpp) reads and writes. A memo only saves work: a walk
// that finds nothing computes the wrap itself, and every star is the same.
//
// FacetMemo is the per-facet interface (d >= 3), implemented by the run-wide
// FacetCache (facet_cache.hpp) and the sweep's per-worker FrontCache
// (front_cache.hpp); EdgeCache is the 2-d ring walk's per-point posts. RunOrder says
// which seeds of a run may come before or after which, for both.
//
// Thread safety: RunOrder is an immutable value; FacetMemo's implementations are safe
// to call concurrently (each says how); EdgeCache as stated on it.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "spokemesh/space_split.hpp"

namespace spokemesh {

// Words mapped from the OS by the caches (see allocate_zeroed in walks/walk_memo.cpp),
// unmapped when released.
struct UnmapWords {
  std::size_t bytes = 0;  // of the mapping
  void operator()(std::uint32_t* p) const;
};
using MappedWords = std::unique_ptr<std::uint32_t[], UnmapWords>;

// Expected Delaunay facets per point for uniform points in dimension d (2..8), as
// meshed here: for sizing tables. An underestimate only fills a table sooner.
double expected_facets_per_point(int d);

// Bytes mapped by all FacetCaches and EdgeCaches alive in this process (0 once every
// cache is destroyed). For tests and the server's memory accounting.
// Thread safety: safe to call concurrently.
std::size_t mapped_cache_bytes();

// The order of a run's seeds as the caches see it: seeds [begin, end) in blocks of
// `block` consecutive indices, blocks in order, a block's seeds in any order; or, for
// a sweep (`sweep` set), the seeds among them at sweep positions [rank_begin,
// rank_end), in the SpaceSplit's order, several blocks of it at once.
struct RunOrder {
  std::uint32_t begin = 0, end = 0, block = 1;
  const SpaceSplit* sweep = nullptr;
  std::uint32_t rank_begin = 0, rank_end = 0xFFFFFFFFu;
  static constexpr std::uint32_t kNotSeed = 0xFFFFFFFFu;
  // For a sweep: v's sweep position if v is a seed of the run, else kNotSeed.
  std::uint32_t sweep_rank(std::uint32_t v) const {
    if (v < begin || v >= end) return kNotSeed;
    const std::uint32_t r = sweep->position_of(v);
    return r >= rank_begin && r < rank_end ? r : kNotSeed;
  }
  bool is_seed(std::uint32_t v) const { return sweep != nullptr ? sweep_rank(v) != kNotSeed : v >= begin && v < end; }
  // Seeds v != x of this run that may be meshed before (after) x.
  bool maybe_before(std::uint32_t v, std::uint32_t x) const {
    if (v == x || !is_seed(v)) return false;
    if (sweep != nullptr) return sweep->position_of(v) < sweep->position_of(x);
    return v < x || (v - begin) / block == (x - begin) / block;
  }
  bool maybe_after(std::uint32_t v, std::uint32_t x) const {
    if (v == x || !is_seed(v)) return false;
    if (sweep != nullptr) return sweep->position_of(v) > sweep->position_of(x);
    return v > x || (v - begin) / block == (x - begin) / block;
  }
};

// What a star walk asks of the wraps other stars of its run found (FacetCache below,
// shared by a run's workers; FrontCache in front_cache.hpp, one per worker of a
// sweep). Facets are d ascending indices, the walking seed x among them; a memo only
// saves work: a walk that finds nothing computes the wrap, and every star is the same.
class FacetMemo {
 public:
  // The apex of a hull facet's missing side.
  static constexpr std::uint32_t kHull = 0xFFFFFFFFu;

  explicit FacetMemo(int d) : d_(d) {}
  virtual ~FacetMemo() = default;
  FacetMemo(const FacetMemo&) = delete;
  FacetMemo& operator=(const FacetMemo&) = delete;

  int dimension() const { return d_; }
  // A facet's hash (d ascending indices), for the calls below.
  std::uint64_t hash(const std::uint32_t* facet) const;
  // The same hashes for the d facets through x of the simplex x + others (d indices,
  // any order, x not among them): out[k] is the hash of the facet without others[k].
  // O(d) for all d (a set hash: a member is dropped by one subtraction).
  void facet_hashes(std::uint32_t x, const std::uint32_t* others, std::uint64_t* out) const;

  // Starts loading the facet's first slot into the CPU cache: a walker announces a
  // simplex's facets before it looks them up, so their memory latencies overlap.
  virtual void prefetch(std::uint64_t hash) const = 0;
  // Starts loading point v's start (insert() may set it, start() reads it). A hint.
  virtual void prefetch_start(std::uint32_t v) const = 0;
  // The apex across `facet` (x among it) from apex `from`, as found by an earlier
  // star; kHull when the facet is on the convex hull. False when unknown (then the
  // caller wraps and records the answer).
  virtual bool lookup(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t from,
                      std::uint32_t& across) const = 0;
  // Reserves up to `count` entries for the caller's inserts (fewer, or none, once
  // full). Callers reserve in batches so that threads do not contend on every insert.
  virtual std::size_t reserve(std::size_t count) = 0;
  // Whether the wrap from x's star across `facet` is worth recording: some other
  // vertex of the facet is a seed that may come later in this run.
  virtual bool wanted(std::uint32_t x, const std::uint32_t* facet) const = 0;
  // Records that wrap: across `facet`, apexes a and b (b may be kHull). Uses one
  // reserved entry; only call it when wanted().
  virtual void insert(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t a,
                      std::uint32_t b) = 0;
  // A facet recorded by another star that contains x, with its two apexes: the
  // simplices facet + a and facet + b (unless b is kHull) are in x's star.
  virtual bool start(std::uint32_t x, std::uint32_t* facet, std::uint32_t& a, std::uint32_t& b) const = 0;

 protected:
  // A lookup's answer from an entry's apexes a and b: the one across from `from`.
  // False when `from` is neither, which exact answers never give: the caller then
  // computes the wrap rather than trust the entry.
  static bool across_from(std::uint32_t a, std::uint32_t b, std::uint32_t from, std::uint32_t& across) {
    if (from != a && from != b) return false;
    across = from == a ? b : a;
    return true;
  }
  int d_;
};

// EdgeCache: what a 2-d run's stars share, kept per point instead of per facet.
//
// In 2-d a facet through x is an edge xt and x's star is a ring of triangles about x
// (a path when x is on the convex hull). When x's ring is done, x posts to each
// neighbour t that may come later in the run the two triangles on the edge xt: (x, a,
// b), with a and b the neighbours of t in x's ring (kHull for a side on the hull).
// Those are consecutive triangles of t's own ring, so when t's turn comes, it reads
// every post at once and wraps only across the gaps between them. One read per seed,
// from one cache line that the caller can prefetch seeds ahead, takes the place of
// the FacetCache's chains of lookups at random in a large table, each waiting for the
// one before. Posts only save work: every star is the same with or without them.
//
// Memory: 64 bytes per point (a count and kPostsPerPoint posts), mapped from the OS
// and committed on first touch; the cache is disabled when that exceeds max_bytes.
// A point with more earlier neighbours than fit keeps the first posts; its walk
// computes the rest.
// Thread safety: post() and read() are safe to call concurrently and lock-free: a
// post claims its place with an atomic increment, fills it, then publishes it with a
// release store of its sender; a reader sees only whole posts, and may miss one
// being written (the walk then computes that wrap itself).
class EdgeCache {
 public:
  static constexpr std::uint32_t kHull = FacetMemo::kHull;
  static constexpr int kPostsPerPoint = 5;
  struct Post {
    std::uint32_t from;  // the earlier star's seed
    std::uint32_t a, b;  // the triangles (to, from, a) and (to, from, b); kHull: none
  };

  // n: point count; the run meshes seeds [begin, end) in blocks of `block` seeds (see
  // RunOrder); max_bytes caps the memory (too small a cap disables the cache).
  EdgeCache(std::uint32_t n, std::uint32_t begin, std::uint32_t end, std::size_t max_bytes, std::uint32_t block = 1)
      : EdgeCache(n, RunOrder{begin, end, std::max(block, 1u)}, max_bytes) {}
  // The same for any order of the run's seeds (a sweep's, for one).
  EdgeCache(std::uint32_t n, RunOrder order, std::size_t max_bytes);

  bool enabled() const { return static_cast<bool>(boxes_); }
  // What a cache for n points would reserve within max_bytes (0: disabled).
  static std::size_t bytes_for(std::uint32_t n, std::size_t max_bytes);
  std::size_t reserved_bytes() const { return enabled() ? std::size_t{n_} * kBoxWords * sizeof(std::uint32_t) : 0; }
  // A sweep's boxes are kept in sweep order: every seed at a position below `rank`
  // is done, so their boxes are given back to the OS (a single caller, the run's
  // writer; posts and reads only touch later positions). Also samples the boxes'
  // resident bytes. Nothing for a run in seed order.
  void release_before(std::uint32_t rank);
  // The most the boxes held resident at a sample of release_before (0 when never
  // sampled): what a sweep's 2-d memo costs, the boxes near the sweep and the posts
  // ahead of it.
  std::size_t resident_peak_bytes() const { return resident_peak_; }

  // Whether a post from x's star to its neighbour t may be read: t may come later.
  bool wanted(std::uint32_t x, std::uint32_t t) const { return enabled() && order_.maybe_after(t, x); }
  // Posts (x, a, b) to t (see above); dropped when t's posts are full.
  void post(std::uint32_t t, const Post& p);
  // t's posts, at most kPostsPerPoint, into `out`; returns their number.
  int read(std::uint32_t t, Post* out) const;
  // Start loading t's posts into the CPU cache, to read them or (for_post) to add one.
  void prefetch(std::uint32_t t, bool for_post = false) const {
    if (!enabled() || t >= n_) return;
    if (for_post) {
      __builtin_prefetch(box(t), 1);
    } else {
      __builtin_prefetch(box(t), 0);
    }
  }

 private:
  // Per point: word 0 counts the posts claimed, then 3 words per post (from + 1,
  // published last; a, b).
  static constexpr std::size_t kBoxWords = 16;
  static_assert(1 + 3 * kPostsPerPoint <= kBoxWords);
  // Point t's box: at its sweep position (so that the boxes behind the sweep
  // form one range to release), at its index otherwise.
  std::uint32_t* box(std::uint32_t t) const {
    const std::uint32_t at = order_.sweep != nullptr ? order_.sweep->position_of(t) : t;
    return boxes_.get() + std::size_t{at} * kBoxWords;
  }

  std::uint32_t n_;
  RunOrder order_;
  MappedWords boxes_;
  std::size_t released_ = 0;              // bytes from the start given back (whole pages)
  std::size_t resident_peak_ = 0;         // see resident_peak_bytes()
  std::vector<unsigned char> residency_;  // mincore's answer, kept between samples
};

}  // namespace spokemesh
