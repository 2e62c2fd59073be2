// Internal: NumPy .npy arrays streamed to scratch files and assembled into .npz
// archives (spokemesh/zip_layout.hpp), for the cell and periodic mesh writers.
//
// Thread safety: an NpyColumn is used by one thread.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "spokemesh/status.hpp"

namespace spokemesh {

// The directory part of a path ("." for a bare name).
std::string directory_of(const std::string& path);

// An anonymous scratch file in `dir` (created, then unlinked at once: nothing is left
// behind whatever happens to the process).
Result<std::FILE*> scratch_file(const std::string& dir);

// One .npy array written row by row to a scratch file; the 128-byte header, which
// holds the row count, is written last. Rows are `width` values; `tail` (for example
// "3, 2") gives a row's shape when it is not a vector of width values.
class NpyColumn {
 public:
  NpyColumn(std::string name, std::string descr, int width, std::string tail = "")
      : name_(std::move(name)), descr_(std::move(descr)), width_(width), tail_(std::move(tail)) {}
  ~NpyColumn();
  NpyColumn(const NpyColumn&) = delete;
  NpyColumn& operator=(const NpyColumn&) = delete;

  // Opens (or, open again, empties) the scratch file in `dir`.
  Status open(const std::string& dir);
  template <class T>
  Status append(const T* values, std::size_t count) {
    return put(values, sizeof(T) * count, count / static_cast<std::size_t>(width_));
  }
  // Writes the header; the file then holds the whole .npy, and is handed over.
  Result<std::FILE*> finish();
  const std::string& name() const { return name_; }

 private:
  Status put(const void* data, std::size_t bytes, std::uint64_t rows);
  std::string name_, descr_;
  int width_;
  std::string tail_;
  std::FILE* file_ = nullptr;
  std::uint64_t rows_ = 0;
};

// Assembles the columns (finished here) into the .npz `path`, uncompressed, with fixed
// time stamps so that the same arrays make the same bytes; written under a temporary
// name and renamed into place.
Status write_npz(const std::string& path, const std::vector<NpyColumn*>& columns);

}  // namespace spokemesh
