// The memo of a sweep: what a whole mesh's stars share when its seeds run block by
// block along a SpaceSplit's blocks, held only for the front.
//
// A wrap across facet F, found in the star of one vertex of F, answers the same wrap
// in the stars of F's other vertices (see FacetMemo). In a sweep the vertices that
// still need it are the seeds of F at a later sweep position: in the same block, met by
// the same worker a few stars later, or in a later block. So each worker keeps one
// small table for the block it is meshing (FrontCache), and answers meant for later
// blocks go to the mailbox (FrontMail) of the first of them, read once when that block
// begins, which passes each on to the next block that wants it. A recorded facet
// therefore waits in one mailbox at a time, until the last block that wants it
// begins: memory follows the front between the blocks done and the blocks to come
// (O(n^((d-1)/d)) facets), not the mesh.
//
// Blocks run concurrently (one per worker): a post to a block that has already begun
// is dropped, and that block's stars compute the wrap themselves. Every star, and so
// the mesh, is the same with or without any memo.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <span>
#include <vector>

#include "spokemesh/facet_cache.hpp"
#include "spokemesh/space_split.hpp"

namespace spokemesh {

// The mailboxes of a sweep's blocks: facets recorded for blocks not yet begun.
// Memory: d + 2 words per held entry (what a block's mailbox holds is dropped when the
// block begins); at most max_bytes, beyond which posts are dropped.
// Thread safety: all methods are safe to call concurrently (one mutex, taken once per
// block by each of post_all() and take()).
class FrontMail {
 public:
  // d: dimension (>= 3); one mailbox per block of `blocks` (borrowed).
  FrontMail(int d, const SpaceSplit& blocks, std::size_t max_bytes);

  // A generous estimate of what a sweep of n uniform points in dimension d holds at
  // most: its mail (the front, O(n^((d-1)/d)) facets) and `threads` workers' tables
  // for blocks of `block_points`. For charging a memory budget before a run; the mail
  // can be capped at the estimate's mail part (MeshOptions::facet_cache_bytes), so
  // that a run never holds more.
  struct Estimate {
    std::size_t mail = 0, tables = 0;
  };
  static Estimate estimate(int d, std::uint64_t n, unsigned threads, std::uint32_t block_points);

  // Appends each record (a block index, then an entry of d + 2 words: the facet's d
  // ascending indices and its two apexes) to that block's mailbox, unless the block has
  // begun or the cap is reached.
  void post_all(std::span<const std::uint32_t> records);
  // Marks block b begun and moves its mailbox's entries (d + 2 words each) into `out`.
  void take(std::uint32_t b, std::vector<std::uint32_t>& out);

  // Bytes of entries held now, and the most ever held at once.
  std::size_t held_bytes() const { return held_.load(std::memory_order_relaxed); }
  std::size_t peak_bytes() const { return peak_.load(std::memory_order_relaxed); }

 private:
  struct Mailbox {
    bool begun = false;
    std::vector<std::uint32_t> words;
  };
  std::size_t entry_words_;
  std::size_t max_bytes_;
  std::mutex mu_;
  std::vector<Mailbox> boxes_;
  std::atomic<std::size_t> held_{0}, peak_{0};
};

// One worker's memo in a sweep: the facets wanted by seeds of the block it is
// meshing, in a table of its own (no atomics), and the records for later blocks, which
// end_block() posts. `seeds` says which points are seeds of the run (its `sweep` is
// the same SpaceSplit); within a block they must be computed in sweep order.
// Memory: the table grows to a block's facets and is reused block after block.
// Ownership: borrows the decomposition and the mail. Thread safety: NOT thread-safe;
// one per worker.
class FrontCache final : public FacetMemo {
 public:
  FrontCache(int d, const SpaceSplit& blocks, FrontMail& mail, const RunOrder& seeds);

  // Starts block b: forgets the last block's table and loads b's mailbox.
  void begin_block(std::uint32_t b);
  // Posts what this block recorded for later blocks.
  void end_block();
  // Bytes of the table and its buffers (capacity), for the run's statistics.
  std::size_t held_bytes() const;

  void prefetch(std::uint64_t hash) const override;
  void prefetch_start(std::uint32_t) const override {}  // a block's starts are few and hot
  bool lookup(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t from,
              std::uint32_t& across) const override;
  std::size_t reserve(std::size_t count) override { return count; }  // bounded by the block
  bool wanted(std::uint32_t x, const std::uint32_t* facet) const override;
  void insert(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t a,
              std::uint32_t b) override;
  bool start(std::uint32_t x, std::uint32_t* facet, std::uint32_t& a, std::uint32_t& b) const override;

 private:
  static constexpr std::uint32_t kNotSeed = RunOrder::kNotSeed;
  // v's sweep position if v is a seed of the run, else kNotSeed.
  std::uint32_t seed_rank(std::uint32_t v) const { return seeds_.sweep_rank(v); }
  // The slot holding `facet`, or -1; `empty` gets the empty slot that ended the probe.
  std::int64_t find(const std::uint32_t* facet, std::uint64_t hash, std::size_t& empty) const;
  // Adds (facet, a, b) to the table unless present; sets the starts of its seeds in
  // this block that have none. Returns false if it was present.
  bool add(const std::uint32_t* facet, std::uint64_t hash, std::uint32_t a, std::uint32_t b);
  void grow();
  // Posts (facet, a, b) to the first block holding one of its seeds at position
  // `after` or later, if any.
  void post_next(const std::uint32_t* facet, std::uint32_t after, std::uint32_t a, std::uint32_t b);
  std::uint32_t* slot(std::size_t s) { return &table_[s * stride_]; }
  const std::uint32_t* slot(std::size_t s) const { return &table_[s * stride_]; }

  const SpaceSplit& blocks_;
  FrontMail& mail_;
  RunOrder seeds_;
  std::size_t stride_;             // words per slot: generation, d ids, apexes a and b
  std::uint32_t lo_ = 0, hi_ = 0;  // the block's range of sweep positions
  // Open addressing, the entry in its slot (one cache line holds a probe). A slot of
  // another generation is empty, so a new block forgets the table without clearing it.
  std::vector<std::uint32_t> table_;
  std::size_t capacity_ = 0;  // slots, a power of two
  std::uint32_t generation_ = 0;
  std::size_t count_ = 0;
  std::vector<std::uint32_t> starts_;    // per leaf position in the block: slot + 1, or 0
  std::vector<std::uint32_t> outgoing_;  // records for later blocks (see FrontMail::post_all)
  std::vector<std::uint32_t> incoming_;
};

}  // namespace spokemesh
