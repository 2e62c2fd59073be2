// spokemesh-mpi's output: the ranks' parts of a file written at their offsets into a
// temporary file renamed into place only after every rank succeeded, and the spool
// that keeps a rank's rows on disk until then.
//
// Thread safety: write_ordered is collective (main thread); a Spool is used by one
// thread at a time.
#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "comm.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::mpi {

// Writes every rank's part at its offset (after rank 0's `header`; every rank gives
// its size as header_bytes) into a temporary file beside `path`, renamed into place by
// rank 0 once every rank succeeded. A rank's part is `body_bytes` long and produced
// piece by piece by `body`, which hands each piece to the writer it is given (pieces
// of at most a few MB: nothing of the size of the output is held).
using PieceWriter = std::function<Status(std::string_view)>;
// The general form: every rank writes what it likes where it likes (`at` bytes from
// the start) through the writer `body` is given; the file is renamed into place by
// rank 0 once every rank succeeded, else removed. Collective.
using WriteAt = std::function<Status(std::uint64_t at, std::string_view bytes)>;
Status write_file(Comm& comm, const std::string& path, const std::function<Status(const WriteAt&)>& body);
Status write_ordered(Comm& comm, const std::string& path, std::uint64_t header_bytes, const std::string& header,
                     std::uint64_t body_bytes, const std::function<Status(const PieceWriter&)>& body);

// Rows kept on disk until the end (an anonymous temporary file, as the CLI spools
// .vtu): each row's d + 1 indices, then its owner's sweep position.
class Spool {
 public:
  explicit Spool(std::size_t width) : width_(width), file_(std::tmpfile()) {}
  ~Spool() {
    if (file_ != nullptr) std::fclose(file_);
  }
  Spool(const Spool&) = delete;
  Spool& operator=(const Spool&) = delete;
  bool ok() const { return file_ != nullptr && std::ferror(file_) == 0; }
  void append(std::span<const std::uint32_t> words) {
    if (file_ != nullptr) std::fwrite(words.data(), sizeof(std::uint32_t), words.size(), file_);
    rows_ += words.size() / (width_ + 1);
  }
  std::uint64_t rows() const { return rows_; }
  // Calls f(row, position) for every row in order.
  template <class F>
  void for_each(F&& f) {
    if (file_ == nullptr) return;
    std::fflush(file_);
    std::rewind(file_);
    std::vector<std::uint32_t> chunk((width_ + 1) * 65536);
    for (;;) {
      const std::size_t got = std::fread(chunk.data(), sizeof(std::uint32_t), chunk.size(), file_);
      for (std::size_t at = 0; at + width_ + 1 <= got; at += width_ + 1) {
        f(std::span<const std::uint32_t>(chunk.data() + at, width_), chunk[at + width_]);
      }
      if (got < chunk.size()) break;
    }
  }

 private:
  std::size_t width_;
  std::FILE* file_;
  std::uint64_t rows_ = 0;
};

}  // namespace spokemesh::mpi
