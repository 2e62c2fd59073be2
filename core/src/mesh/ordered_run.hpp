// run_in_order: units of work computed by a pool of threads and handed on in order.
//
// Units 0 .. count - 1 are taken in order by `threads` workers; at most `window` units
// beyond the next one to hand on are in flight (so a slow consumer bounds what is
// buffered). Each finished unit goes to `sink` on the calling thread, in unit order.
// The first non-OK status (from a worker or from the sink) stops the run: units not
// yet begun are not computed, and that status is returned.
//
// Each worker builds its own state by calling make_worker() on its thread (a
// StarWalker, a triangulation: a std::unique_ptr, as such state does not move), then
// calls it for each unit it takes: (*worker)(unit, out) -> Status, with `out` a
// default-constructed or recycled Out; finally worker->finish() once, under the run's
// lock (to merge its counters).
//
// Thread safety: make_worker and the workers run concurrently; sink runs on the
// calling thread only.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <thread>
#include <vector>

#include "spokemesh/status.hpp"

namespace spokemesh::detail {

template <class Out, class MakeWorker, class Sink>
Status run_in_order(std::uint64_t count, unsigned threads, std::uint64_t window, MakeWorker&& make_worker,
                    Sink&& sink) {
  struct Slot {
    bool done = false;
    Status status;
    Out out;
  };
  std::mutex mu;
  std::condition_variable worker_cv, writer_cv;
  std::deque<Slot> ring;  // ring[i] is unit (written + i)
  std::uint64_t written = 0, next = 0;
  bool stop = false;

  auto body = [&] {
    auto worker = make_worker();
    Out out{};
    for (;;) {
      std::uint64_t unit;
      {
        std::unique_lock lock(mu);
        worker_cv.wait(lock, [&] { return stop || next >= count || next < written + window; });
        if (stop || next >= count) break;
        unit = next++;
        if (ring.size() <= unit - written) ring.resize(unit - written + 1);
      }
      Status status = (*worker)(unit, out);
      std::lock_guard lock(mu);
      Slot& slot = ring[unit - written];
      slot.done = true;
      slot.status = std::move(status);
      std::swap(slot.out, out);
      writer_cv.notify_one();
    }
    std::lock_guard lock(mu);
    worker->finish();
  };

  std::vector<std::thread> pool;
  pool.reserve(threads);
  for (unsigned t = 0; t < threads; ++t) pool.emplace_back(body);

  Status failure;
  Out current{};
  while (written < count) {
    {
      std::unique_lock lock(mu);
      writer_cv.wait(lock, [&] { return !ring.empty() && ring.front().done; });
      std::swap(current, ring.front().out);
      failure = std::move(ring.front().status);
      ring.pop_front();
      ++written;
      worker_cv.notify_all();
    }
    if (failure.is_ok()) failure = sink(current);
    if (!failure.is_ok()) {
      std::lock_guard lock(mu);
      stop = true;
      worker_cv.notify_all();
      break;
    }
  }
  for (auto& t : pool) t.join();
  return failure;
}

}  // namespace spokemesh::detail
