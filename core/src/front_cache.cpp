#include "spokemesh/front_cache.hpp"

#include <algorithm>
#include <array>

#include "mixing.hpp"

namespace spokemesh {

FrontMail::FrontMail(int d, const BlockDecomposition& blocks, std::size_t max_bytes)
    : entry_words_(static_cast<std::size_t>(d) + 2), max_bytes_(max_bytes), boxes_(blocks.size()) {}

void FrontMail::post_all(std::span<const std::uint32_t> records) {
  const std::size_t stride = 1 + entry_words_;
  std::lock_guard lock(mu_);
  std::size_t held = held_.load(std::memory_order_relaxed);
  for (std::size_t at = 0; at + stride <= records.size(); at += stride) {
    Mailbox& box = boxes_[records[at]];
    if (box.begun) continue;  // its stars are being computed: too late to help
    if (held + entry_words_ * sizeof(std::uint32_t) > max_bytes_) continue;
    const std::size_t before = box.words.capacity();
    box.words.insert(box.words.end(), records.begin() + static_cast<std::ptrdiff_t>(at + 1),
                     records.begin() + static_cast<std::ptrdiff_t>(at + stride));
    held += (box.words.capacity() - before) * sizeof(std::uint32_t);
  }
  held_.store(held, std::memory_order_relaxed);
  if (held > peak_.load(std::memory_order_relaxed)) peak_.store(held, std::memory_order_relaxed);
}

void FrontMail::take(std::uint32_t b, std::vector<std::uint32_t>& out) {
  std::vector<std::uint32_t> spare;  // out's old buffer, freed outside the lock
  std::lock_guard lock(mu_);
  Mailbox& box = boxes_[b];
  box.begun = true;
  out.clear();
  out.swap(box.words);
  spare.swap(box.words);
  held_.fetch_sub(out.capacity() * sizeof(std::uint32_t), std::memory_order_relaxed);
}

FrontCache::FrontCache(int d, const BlockDecomposition& blocks, FrontMail& mail, const RunOrder& seeds)
    : FacetMemo(d),
      blocks_(blocks),
      tree_(blocks.tree()),
      mail_(mail),
      seeds_(seeds),
      entry_words_(static_cast<std::size_t>(d) + 2),
      slots_(std::size_t{1} << 12, 0) {}

void FrontCache::begin_block(std::uint32_t b) {
  ++generation_;  // every slot of the last block reads empty now
  count_ = 0;
  entries_.clear();
  block_ = b;
  lo_ = blocks_.begin(b);
  hi_ = blocks_.end(b);
  starts_.assign(hi_ - lo_, 0);
  mail_.take(b, incoming_);
  for (std::size_t at = 0; at + entry_words_ <= incoming_.size(); at += entry_words_) {
    const std::uint32_t* facet = &incoming_[at];
    add(facet, hash(facet), facet[d_], facet[d_ + 1]);
  }
  incoming_.clear();
}

void FrontCache::end_block() {
  mail_.post_all(outgoing_);
  outgoing_.clear();
}

std::size_t FrontCache::held_bytes() const {
  return (entries_.capacity() + starts_.capacity() + outgoing_.capacity() + incoming_.capacity()) *
             sizeof(std::uint32_t) +
         slots_.capacity() * sizeof(std::uint64_t);
}

std::int64_t FrontCache::find(const std::uint32_t* facet, std::uint64_t hash) const {
  const std::size_t mask = slots_.size() - 1;
  for (std::size_t s = hash & mask;; s = (s + 1) & mask) {
    const std::uint64_t slot = slots_[s];
    if ((slot >> 32) != generation_) return -1;  // the load stays below 1/2: an empty slot ends every probe
    const std::size_t e = (slot & 0xFFFFFFFFu) - 1;
    if (detail::same_indices(facet, &entries_[e * entry_words_], static_cast<std::size_t>(d_))) {
      return static_cast<std::int64_t>(e);
    }
  }
}

bool FrontCache::add(const std::uint32_t* facet, std::uint64_t hash, std::uint32_t a, std::uint32_t b) {
  if (find(facet, hash) >= 0) return false;
  const std::size_t e = entries_.size() / entry_words_;
  entries_.insert(entries_.end(), facet, facet + d_);
  entries_.push_back(a);
  entries_.push_back(b);
  const std::size_t mask = slots_.size() - 1;
  std::size_t s = hash & mask;
  while ((slots_[s] >> 32) == generation_) s = (s + 1) & mask;
  slots_[s] = generation_ << 32 | (e + 1);
  if (++count_ * 2 > slots_.size()) grow();
  for (int i = 0; i < d_; ++i) {
    const std::uint32_t r = seed_rank(facet[i]);
    if (r >= lo_ && r < hi_ && starts_[r - lo_] == 0) starts_[r - lo_] = static_cast<std::uint32_t>(e + 1);
  }
  return true;
}

void FrontCache::grow() {
  slots_.assign(slots_.size() * 2, 0);
  const std::size_t mask = slots_.size() - 1;
  for (std::size_t e = 0; e < count_; ++e) {
    std::size_t s = hash(&entries_[e * entry_words_]) & mask;
    while ((slots_[s] >> 32) == generation_) s = (s + 1) & mask;
    slots_[s] = generation_ << 32 | (e + 1);
  }
}

void FrontCache::prefetch(std::uint64_t hash) const { __builtin_prefetch(&slots_[hash & (slots_.size() - 1)]); }

bool FrontCache::lookup(std::uint32_t, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t from,
                        std::uint32_t& across) const {
  const std::int64_t e = find(facet, hash);
  if (e < 0) return false;
  const std::uint32_t* w = &entries_[static_cast<std::size_t>(e) * entry_words_];
  const std::uint32_t a = w[d_], b = w[d_ + 1];
  if (from == a) {
    across = b;
    return true;
  }
  if (from == b) {
    across = a;
    return true;
  }
  return false;  // cannot happen for exact answers; compute rather than trust it
}

bool FrontCache::wanted(std::uint32_t x, const std::uint32_t* facet) const {
  const std::uint32_t rx = tree_.leaf_rank(x);
  for (int i = 0; i < d_; ++i) {
    const std::uint32_t r = seed_rank(facet[i]);
    if (facet[i] != x && r != kNotSeed && r > rx) return true;
  }
  return false;
}

void FrontCache::insert(std::uint32_t x, const std::uint32_t* facet, std::uint64_t hash, std::uint32_t a,
                        std::uint32_t b) {
  // Who still wants it: later seeds of this block (the table) and later blocks (one
  // record per block, however many of the facet's vertices it holds).
  const std::uint32_t rx = tree_.leaf_rank(x);
  bool here = false;
  std::array<std::uint32_t, kMaxDimension> later{};
  int count = 0;
  for (int i = 0; i < d_; ++i) {
    const std::uint32_t r = seed_rank(facet[i]);
    if (facet[i] == x || r == kNotSeed || r <= rx) continue;
    if (r < hi_) {
      here = true;
      continue;
    }
    const std::uint32_t block = blocks_.block_of_rank(r);
    if (std::find(later.begin(), later.begin() + count, block) == later.begin() + count) later[count++] = block;
  }
  // Already in the table: recorded, and posted, by an earlier star.
  if (here && !add(facet, hash, a, b)) return;
  for (int k = 0; k < count; ++k) {
    outgoing_.push_back(later[static_cast<std::size_t>(k)]);
    outgoing_.insert(outgoing_.end(), facet, facet + d_);
    outgoing_.push_back(a);
    outgoing_.push_back(b);
  }
}

bool FrontCache::start(std::uint32_t x, std::uint32_t* facet, std::uint32_t& a, std::uint32_t& b) const {
  const std::uint32_t r = tree_.leaf_rank(x);
  if (r < lo_ || r >= hi_) return false;
  const std::uint32_t e1 = starts_[r - lo_];
  if (e1 == 0) return false;
  const std::uint32_t* w = &entries_[std::size_t{e1 - 1} * entry_words_];
  std::copy(w, w + d_, facet);
  a = w[d_];
  b = w[d_ + 1];
  return true;
}

}  // namespace spokemesh
