#include "io/npz.hpp"

#include <unistd.h>
#include <zip.h>

#include <cerrno>
#include <cstring>

#include "spokemesh/io.hpp"

namespace spokemesh {

std::string directory_of(const std::string& path) {
  const std::size_t slash = path.rfind('/');
  return slash == std::string::npos ? "." : slash == 0 ? "/" : path.substr(0, slash);
}

// An anonymous scratch file in `dir` (created, then unlinked at once: nothing is left
// behind whatever happens to the process).
Result<std::FILE*> scratch_file(const std::string& dir) {
  std::string name = dir + "/.spokemesh-scratch.XXXXXX";
  const int fd = ::mkstemp(name.data());
  if (fd < 0) return internal_error("cannot create a scratch file in " + dir + ": " + std::strerror(errno));
  ::unlink(name.c_str());
  std::FILE* f = ::fdopen(fd, "w+b");
  if (f == nullptr) {
    ::close(fd);
    return internal_error("cannot open a scratch file in " + dir + ": " + std::strerror(errno));
  }
  return f;
}

NpyColumn::~NpyColumn() {
  if (file_ != nullptr) std::fclose(file_);
}

Status NpyColumn::open(const std::string& dir) {
  if (file_ != nullptr) std::fclose(file_);
  file_ = nullptr;
  rows_ = 0;
  auto f = scratch_file(dir);
  if (!f.is_ok()) return f.status();
  file_ = f.value();
  const char zeros[kNpyHeaderBytes] = {};
  return put(zeros, kNpyHeaderBytes, 0);
}

Result<std::FILE*> NpyColumn::finish() {
  const std::string header =
      !tail_.empty() ? npy_header_of_shape(descr_, std::to_string(rows_) + ", " + tail_)
      : width_ == 1  ? npy_vector_header(descr_, rows_)
                     : npy_header(descr_, rows_, static_cast<std::uint64_t>(width_));
  if (std::fseek(file_, 0, SEEK_SET) != 0 || std::fwrite(header.data(), 1, header.size(), file_) != header.size() ||
      std::fflush(file_) != 0 || std::fseek(file_, 0, SEEK_SET) != 0) {
    return internal_error("writing " + name_ + ": " + std::strerror(errno));
  }
  std::FILE* f = file_;
  file_ = nullptr;
  return f;
}

Status NpyColumn::put(const void* data, std::size_t bytes, std::uint64_t rows) {
  if (bytes != 0 && std::fwrite(data, 1, bytes, file_) != bytes) {
    return internal_error("writing " + name_ + ": " + std::strerror(errno));
  }
  rows_ += rows;
  return Status::ok();
}

Status write_npz(const std::string& path, const std::vector<NpyColumn*>& columns) {
  int error = 0;
  // libzip writes the archive under a temporary name and renames it on zip_close.
  zip_t* zip = zip_open(path.c_str(), ZIP_CREATE | ZIP_TRUNCATE, &error);
  if (zip == nullptr) {
    zip_error_t e;
    zip_error_init_with_code(&e, error);
    Status s = internal_error("cannot create " + path + ": " + zip_error_strerror(&e));
    zip_error_fini(&e);
    return s;
  }
  for (NpyColumn* c : columns) {
    auto file = c->finish();
    if (!file.is_ok()) {
      zip_discard(zip);
      return file.status();
    }
    zip_source_t* source = zip_source_filep(zip, file.value(), 0, -1);  // owns the FILE*
    if (source == nullptr) {
      std::fclose(file.value());
      Status s = internal_error("writing " + path + ": " + zip_strerror(zip));
      zip_discard(zip);
      return s;
    }
    const zip_int64_t index = zip_file_add(zip, c->name().c_str(), source, ZIP_FL_OVERWRITE);
    // A fixed time stamp (1980-01-02, the start of zip's range in any time zone),
    // so that the same arrays make the same bytes.
    if (index < 0 || zip_set_file_compression(zip, static_cast<zip_uint64_t>(index), ZIP_CM_STORE, 0) != 0 ||
        zip_file_set_mtime(zip, static_cast<zip_uint64_t>(index), 315619200, 0) != 0) {
      if (index < 0) zip_source_free(source);
      Status s = internal_error("writing " + path + ": " + zip_strerror(zip));
      zip_discard(zip);
      return s;
    }
  }
  if (zip_close(zip) != 0) {
    Status s = internal_error("writing " + path + ": " + zip_strerror(zip));
    zip_discard(zip);
    return s;
  }
  return Status::ok();
}

}  // namespace spokemesh
