// PeriodicMeshWriter (io.hpp): a torus's simplices with their vertices' offsets.
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>

#include "io/npz.hpp"
#include "spokemesh/io.hpp"

namespace spokemesh {

namespace {

bool has_suffix(const std::string& s, const char* suffix) {
  const std::size_t n = std::strlen(suffix);
  return s.size() >= n && s.compare(s.size() - n, n, suffix) == 0;
}

class NpzPeriodicWriter final : public PeriodicMeshWriter {
 public:
  NpzPeriodicWriter(std::string path, int d)
      : path_(std::move(path)),
        d_(d),
        simplices_("simplices.npy", "<i8", d + 1),
        offsets_("offsets.npy", "<i4", (d + 1) * d, std::to_string(d + 1) + ", " + std::to_string(d)) {}

  Status restart() override {
    const std::string dir = directory_of(path_);
    if (Status s = simplices_.open(dir); !s.is_ok()) return s;
    return offsets_.open(dir);
  }
  Status write(std::span<const std::uint32_t> simplices, std::span<const std::int32_t> offsets) override {
    wide_.assign(simplices.begin(), simplices.end());
    if (Status s = simplices_.append(wide_.data(), wide_.size()); !s.is_ok()) return s;
    return offsets_.append(offsets.data(), offsets.size());
  }
  Status commit() override { return write_npz(path_, {&simplices_, &offsets_}); }

 private:
  std::string path_;
  int d_;
  NpyColumn simplices_, offsets_;
  std::vector<std::int64_t> wide_;
};

class TextPeriodicWriter final : public PeriodicMeshWriter {
 public:
  TextPeriodicWriter(std::string path, int d) : path_(std::move(path)), d_(d) {
    static std::atomic<unsigned> counter{0};
    temp_ = path_;
    temp_.append(".partial-").append(std::to_string(::getpid())).append(".").append(std::to_string(counter++));
  }
  ~TextPeriodicWriter() override {
    if (file_ != nullptr) std::fclose(file_);
    if (!committed_) std::remove(temp_.c_str());
  }
  Status restart() override {
    if (file_ != nullptr) std::fclose(file_);
    file_ = std::fopen(temp_.c_str(), "wb");
    if (file_ == nullptr) return invalid_argument(path_ + ": cannot open for writing (" + std::strerror(errno) + ")");
    const std::string head = "# periodic mesh: per line the " + std::to_string(d_ + 1) +
                             " point indices of a simplex, then each vertex's " + std::to_string(d_) +
                             " offsets in box lengths (vertex v at point + offset * (HI - LO))\n";
    return put(head);
  }
  Status write(std::span<const std::uint32_t> simplices, std::span<const std::int32_t> offsets) override {
    const auto w = static_cast<std::size_t>(d_ + 1);
    std::string line;
    for (std::size_t s = 0; s * w < simplices.size(); ++s) {
      line.clear();
      for (std::size_t v = 0; v < w; ++v) {
        if (v > 0) line += ' ';
        line += std::to_string(simplices[s * w + v]);
      }
      for (std::size_t k = 0; k < w * static_cast<std::size_t>(d_); ++k) {
        line += ' ';
        line += std::to_string(offsets[s * w * static_cast<std::size_t>(d_) + k]);
      }
      line += '\n';
      buffer_ += line;
    }
    const std::string out = std::move(buffer_);
    buffer_.clear();
    return put(out);
  }
  Status commit() override {
    const bool failed = std::ferror(file_) != 0;
    const int closed = std::fclose(file_);
    file_ = nullptr;
    if (closed != 0 || failed) return internal_error("writing " + temp_ + ": " + std::strerror(errno));
    if (std::rename(temp_.c_str(), path_.c_str()) != 0) {
      return internal_error("cannot rename " + temp_ + " to " + path_ + ": " + std::strerror(errno));
    }
    committed_ = true;
    return Status::ok();
  }

 private:
  Status put(const std::string& text) {
    if (!text.empty() && std::fwrite(text.data(), 1, text.size(), file_) != text.size()) {
      return internal_error("writing " + temp_ + ": " + std::strerror(errno));
    }
    return Status::ok();
  }
  std::string path_, temp_;
  int d_;
  std::FILE* file_ = nullptr;
  std::string buffer_;
  bool committed_ = false;
};

}  // namespace

Result<std::unique_ptr<PeriodicMeshWriter>> PeriodicMeshWriter::open(const std::string& path, int dimension) {
  std::unique_ptr<PeriodicMeshWriter> writer;
  if (has_suffix(path, ".npz")) {
    writer = std::make_unique<NpzPeriodicWriter>(path, dimension);
  } else if (has_suffix(path, ".txt") || has_suffix(path, ".simplices")) {
    writer = std::make_unique<TextPeriodicWriter>(path, dimension);
  } else {
    return invalid_argument(path + ": a periodic mesh is written as .npz (simplices and offsets) or as text "
                            "(.txt, .simplices: indices then offsets on each line)");
  }
  if (Status s = writer->restart(); !s.is_ok()) return s;
  return writer;
}

}  // namespace spokemesh
