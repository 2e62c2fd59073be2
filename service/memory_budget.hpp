// MemoryBudget: the one budget (--max-memory) that every byte the server holds on a
// request's behalf draws from.
//
// Charged: loaded point sets with their k-d trees (while loaded, released when the
// last request using an evicted set ends), streamed shards' facet caches and output
// windows, upload buffers as their bytes arrive (REST bodies from their Content-Length,
// gRPC chunks as they come), JSON coordinates being parsed. A charge that does not fit
// first asks the reclaimer (the store drops its least recently used sets nobody is
// using) and then fails: the request gets RESOURCE_EXHAUSTED with reason OVER_BUDGET
// (HTTP 503 with Retry-After), never the OOM killer.
//
// Not charged: the process's fixed cost (code, gRPC and Asio machinery, thread
// stacks) and small per-request answers (a star, a cell). docs/service.md states the
// allowance.
//
// Thread safety: all methods are safe to call concurrently (an atomic counter; the
// reclaimer must be thread-safe itself).
#pragma once

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>

#include "spokemesh/status.hpp"

namespace spokemesh::service {

class MemoryBudget {
 public:
  // Frees what it can towards `bytes` (e.g. evicts cached sets); returns nothing.
  using Reclaimer = std::function<void(std::uint64_t bytes)>;

  explicit MemoryBudget(std::uint64_t limit) : limit_(limit) {}
  MemoryBudget(const MemoryBudget&) = delete;
  MemoryBudget& operator=(const MemoryBudget&) = delete;

  void set_reclaimer(Reclaimer reclaimer) { reclaimer_ = std::move(reclaimer); }

  // Bytes held against the budget, released when destroyed (or moved from and reset).
  class Charge {
   public:
    Charge() = default;
    Charge(Charge&& o) noexcept : budget_(std::exchange(o.budget_, nullptr)), bytes_(std::exchange(o.bytes_, 0)) {}
    Charge& operator=(Charge&& o) noexcept {
      if (this != &o) {
        reset();
        budget_ = std::exchange(o.budget_, nullptr);
        bytes_ = std::exchange(o.bytes_, 0);
      }
      return *this;
    }
    ~Charge() { reset(); }
    std::uint64_t bytes() const { return bytes_; }
    // Grows the charge by `more`; false (unchanged) when it does not fit.
    bool grow(std::uint64_t more) {
      if (budget_ == nullptr || !budget_->take(more)) return false;
      bytes_ += more;
      return true;
    }
    void reset() {
      if (budget_ != nullptr && bytes_ != 0) budget_->give_back(bytes_);
      bytes_ = 0;
    }

   private:
    friend class MemoryBudget;
    Charge(MemoryBudget* budget, std::uint64_t bytes) : budget_(budget), bytes_(bytes) {}
    MemoryBudget* budget_ = nullptr;
    std::uint64_t bytes_ = 0;
  };

  // `bytes` against the budget, or nothing when they do not fit (after asking the
  // reclaimer, unless `reclaim` is false).
  std::optional<Charge> try_charge(std::uint64_t bytes, bool reclaim = true) {
    if (!(reclaim ? take(bytes) : try_take(bytes))) return std::nullopt;
    return Charge(this, bytes);
  }
  // An empty charge that grow() adds to.
  Charge empty_charge() { return Charge(this, 0); }
  // As much of `want` as fits, if at least `least` does (e.g. a cache that works at
  // any size, or not at all); nothing otherwise.
  std::optional<Charge> charge_up_to(std::uint64_t want, std::uint64_t least) {
    for (std::uint64_t b = want;; b = std::max(least, b / 2)) {
      if (auto c = try_charge(b)) return c;
      if (b <= least) return std::nullopt;
    }
  }

  std::uint64_t used() const { return used_.load(std::memory_order_relaxed); }
  // Bytes given back since start (monotonic): how much memory has churned, which is
  // what HeapTrimmer watches.
  std::uint64_t released() const { return released_.load(std::memory_order_relaxed); }
  std::uint64_t limit() const { return limit_; }

  // The error for a request whose `what` needs `bytes` that do not fit.
  Status over_budget(const std::string& what, std::uint64_t bytes) const {
    return resource_exhausted(what + " needs " + std::to_string(bytes) + " bytes and the server's memory budget (" +
                              std::to_string(limit_) + " bytes, --max-memory) has " +
                              std::to_string(limit_ - std::min(limit_, used())) + " free; retry later")
        .with_reason("OVER_BUDGET");
  }

 private:
  bool take(std::uint64_t bytes) {
    if (try_take(bytes)) return true;
    if (reclaimer_) {
      reclaimer_(bytes);
      return try_take(bytes);
    }
    return false;
  }
  bool try_take(std::uint64_t bytes) {
    std::uint64_t now = used_.load(std::memory_order_relaxed);
    do {
      if (bytes > limit_ || now > limit_ - bytes) return false;
    } while (!used_.compare_exchange_weak(now, now + bytes, std::memory_order_relaxed));
    return true;
  }
  void give_back(std::uint64_t bytes) {
    used_.fetch_sub(bytes, std::memory_order_relaxed);
    released_.fetch_add(bytes, std::memory_order_relaxed);
  }

  const std::uint64_t limit_;
  std::atomic<std::uint64_t> used_{0};
  std::atomic<std::uint64_t> released_{0};
  Reclaimer reclaimer_;
};

// HeapTrimmer: returns the allocator's free pages to the system after memory churns,
// so that RSS follows the budget. Charged buffers of 64 KiB and more are mapped and
// unmapped directly (main.cpp's mallopt), but the many small ones of small point sets
// and requests leave free pages inside glibc's arenas: about 40 MB of a 256 MB budget
// after four minutes of bench/soak.py, which malloc_trim(0) gives back (it madvises
// free pages anywhere in every arena, not only at the top).
//
// A background thread wakes every `period` and trims when at least `churn` bytes have
// been released to the budget since the last trim: at most a few trims a second under
// churn (each takes each arena's lock for about a millisecond per 100 MB of heap),
// none when idle. Stops and joins when destroyed.
//
// Thread safety: construct and destroy on one thread; the budget is only read.
class HeapTrimmer {
 public:
  HeapTrimmer(const MemoryBudget& budget, std::chrono::milliseconds period, std::uint64_t churn);
  ~HeapTrimmer();
  HeapTrimmer(const HeapTrimmer&) = delete;
  HeapTrimmer& operator=(const HeapTrimmer&) = delete;

  std::uint64_t trims() const { return trims_.load(std::memory_order_relaxed); }

 private:
  const MemoryBudget& budget_;
  std::atomic<std::uint64_t> trims_{0};
  std::mutex mutex_;
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread thread_;
};

}  // namespace spokemesh::service
