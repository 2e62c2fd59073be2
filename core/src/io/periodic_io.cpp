// PeriodicMeshWriter (io.hpp): a torus's simplices with their vertices' offsets.
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>

#include <charconv>
#include <map>
#include <vector>

#include "io/npz.hpp"
#include "spokemesh/io.hpp"
#include "spokemesh/periodic_box.hpp"

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

// .vtu: the connectivity goes to a scratch file as the rows come (each image a row
// uses numbered on first sight, after the n points); commit() writes the file whole.
// Memory: one entry per distinct image used, about the points near the box's sides.
class VtuPeriodicWriter final : public PeriodicMeshWriter {
 public:
  VtuPeriodicWriter(std::string path, const PointSet& points, const PeriodicBox& box)
      : path_(std::move(path)), points_(points), box_(box), d_(points.dimension()) {}
  ~VtuPeriodicWriter() override {
    if (cells_ != nullptr) std::fclose(cells_);
  }
  Status restart() override {
    if (cells_ != nullptr) std::fclose(cells_);
    cells_ = nullptr;
    auto scratch = scratch_file(directory_of(path_));
    if (!scratch.is_ok()) return scratch.status();
    cells_ = scratch.value();
    images_.clear();
    image_list_.clear();
    rows_ = 0;
    return Status::ok();
  }
  Status write(std::span<const std::uint32_t> simplices, std::span<const std::int32_t> offsets) override {
    const auto w = static_cast<std::size_t>(d_ + 1), du = static_cast<std::size_t>(d_);
    std::string text;
    std::vector<std::int32_t> key(du + 1);
    for (std::size_t s = 0; s * w < simplices.size(); ++s) {
      for (std::size_t v = 0; v < w; ++v) {
        const std::uint32_t p = simplices[s * w + v];
        const std::int32_t* k = offsets.data() + (s * w + v) * du;
        std::uint64_t index = p;
        if (std::any_of(k, k + du, [](std::int32_t x) { return x != 0; })) {
          key[0] = static_cast<std::int32_t>(p);
          std::copy(k, k + du, key.begin() + 1);
          const auto [it, added] = images_.try_emplace(key, points_.size() + image_list_.size());
          if (added) image_list_.push_back(key);
          index = it->second;
        }
        if (v > 0) text += ' ';
        text += std::to_string(index);
      }
      text += '\n';
      ++rows_;
    }
    return put(cells_, text);
  }
  Status commit() override {
    if (std::fflush(cells_) != 0 || std::ferror(cells_)) return internal_error("writing " + path_ + "'s scratch file");
    static std::atomic<unsigned> counter{0};
    std::string temp = path_;
    temp.append(".partial-").append(std::to_string(::getpid())).append(".").append(std::to_string(counter++));
    std::FILE* out = std::fopen(temp.c_str(), "wb");
    if (out == nullptr) return invalid_argument(path_ + ": cannot open for writing (" + std::strerror(errno) + ")");
    const std::uint64_t n = points_.size(), copies = n + image_list_.size();
    std::string text =
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"0.1\" "
        "byte_order=\"LittleEndian\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"" +
        std::to_string(copies) + "\" NumberOfCells=\"" + std::to_string(rows_) +
        "\">\n<PointData Scalars=\"point_index\">\n"
        "<DataArray type=\"Int64\" Name=\"point_index\" format=\"ascii\">\n";
    Status s = Status::ok();
    auto flush = [&] {
      if (s.is_ok() && text.size() > (1u << 20)) {
        s = put(out, text);
        text.clear();
      }
    };
    for (std::uint64_t i = 0; i < copies; ++i) {
      text += std::to_string(i < n ? i : static_cast<std::uint64_t>(image_list_[i - n][0]));
      text += '\n';
      flush();
    }
    text +=
        "</DataArray>\n</PointData>\n<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" "
        "format=\"ascii\">\n";
    std::vector<double> at(3, 0.0);
    for (std::uint64_t i = 0; i < copies; ++i) {
      const std::uint32_t p = i < n ? static_cast<std::uint32_t>(i) : static_cast<std::uint32_t>(image_list_[i - n][0]);
      for (int c = 0; c < d_; ++c) {
        const auto cu = static_cast<std::size_t>(c);
        const std::int32_t k = i < n ? 0 : image_list_[i - n][cu + 1];
        at[cu] = image_difference(points_.point(p)[c], k, box_.lo()[cu], box_.hi()[cu], 0.0);
      }
      for (int c = 0; c < 3; ++c) {
        char buf[32];
        const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, at[static_cast<std::size_t>(c)]);
        text.append(buf, end);
        text += c == 2 ? '\n' : ' ';
      }
      flush();
    }
    text += "</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n";
    if (s.is_ok()) s = put(out, text);
    text.clear();
    // The connectivity, copied from the scratch file.
    std::rewind(cells_);
    std::vector<char> piece(1 << 20);
    for (std::size_t got; s.is_ok() && (got = std::fread(piece.data(), 1, piece.size(), cells_)) > 0;) {
      if (std::fwrite(piece.data(), 1, got, out) != got) s = internal_error("writing " + path_);
    }
    text += "</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n";
    for (std::uint64_t r = 1; r <= rows_; ++r) {
      text += std::to_string(r * static_cast<std::uint64_t>(d_ + 1));
      text += '\n';
      flush();
    }
    text += "</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n";
    for (std::uint64_t r = 0; r < rows_; ++r) {
      text += d_ == 2 ? "5\n" : "10\n";  // VTK_TRIANGLE, VTK_TETRA
      flush();
    }
    text += "</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n";
    if (s.is_ok()) s = put(out, text);
    if (std::fclose(out) != 0 && s.is_ok()) s = internal_error("writing " + temp + ": " + std::strerror(errno));
    if (s.is_ok() && std::rename(temp.c_str(), path_.c_str()) != 0) {
      s = internal_error("cannot rename " + temp + " to " + path_ + ": " + std::strerror(errno));
    }
    if (!s.is_ok()) std::remove(temp.c_str());  // nothing half-written is left behind
    return s;
  }

 private:
  static Status put(std::FILE* f, const std::string& text) {
    if (!text.empty() && std::fwrite(text.data(), 1, text.size(), f) != text.size()) {
      return internal_error(std::string("writing a mesh file: ") + std::strerror(errno));
    }
    return Status::ok();
  }
  std::string path_;
  const PointSet& points_;
  const PeriodicBox& box_;
  int d_;
  std::FILE* cells_ = nullptr;
  std::map<std::vector<std::int32_t>, std::uint64_t> images_;
  std::vector<std::vector<std::int32_t>> image_list_;
  std::uint64_t rows_ = 0;
};

}  // namespace

Result<std::unique_ptr<PeriodicMeshWriter>> PeriodicMeshWriter::open(const std::string& path, int dimension,
                                                                     const PointSet* points, const PeriodicBox* box) {
  std::unique_ptr<PeriodicMeshWriter> writer;
  if (has_suffix(path, ".vtu")) {
    if (dimension != 2 && dimension != 3) {
      return invalid_argument(path + ": .vtu output is for 2-d and 3-d meshes (this one is " +
                              std::to_string(dimension) + "-d); use .npz or .txt");
    }
    if (points == nullptr || box == nullptr) {
      return invalid_argument(path + ": a periodic .vtu needs the points and the box (write .npz or .txt here)");
    }
    writer = std::make_unique<VtuPeriodicWriter>(path, *points, *box);
  } else if (has_suffix(path, ".npz")) {
    writer = std::make_unique<NpzPeriodicWriter>(path, dimension);
  } else if (has_suffix(path, ".txt") || has_suffix(path, ".simplices")) {
    writer = std::make_unique<TextPeriodicWriter>(path, dimension);
  } else {
    return invalid_argument(path +
                            ": a periodic mesh is written as .npz (simplices and offsets), as text "
                            "(.txt, .simplices: indices then offsets on each line) or as .vtu (2-d, 3-d: the "
                            "simplices whole, with copies of the images they use)");
  }
  if (Status s = writer->restart(); !s.is_ok()) return s;
  return writer;
}

}  // namespace spokemesh
