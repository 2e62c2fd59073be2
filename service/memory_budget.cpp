#include "memory_budget.hpp"

#include <malloc.h>

namespace spokemesh::service {

HeapTrimmer::HeapTrimmer(const MemoryBudget& budget, std::chrono::milliseconds period, std::uint64_t churn)
    : budget_(budget) {
  thread_ = std::thread([this, period, churn] {
    std::uint64_t trimmed_at = budget_.released();
    std::unique_lock lock(mutex_);
    while (!wake_.wait_for(lock, period, [this] { return stopping_; })) {
      const std::uint64_t released = budget_.released();
      if (released - trimmed_at < churn) continue;
      trimmed_at = released;
      lock.unlock();
      ::malloc_trim(0);
      trims_.fetch_add(1, std::memory_order_relaxed);
      lock.lock();
    }
  });
}

HeapTrimmer::~HeapTrimmer() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  thread_.join();
}

}  // namespace spokemesh::service
