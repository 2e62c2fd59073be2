#include "io/npz.hpp"

#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <memory>

#include "spokemesh/io.hpp"
#include "spokemesh/zip_layout.hpp"

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
  const std::string header = !tail_.empty() ? npy_header_of_shape(descr_, std::to_string(rows_) + ", " + tail_)
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
  // Written under a temporary name beside the target and renamed into place, so a
  // reader sees the old file or the whole new one, and a failure leaves nothing behind.
  std::string temp = path + ".XXXXXX";
  const int fd = ::mkstemp(temp.data());
  if (fd < 0) return internal_error("cannot create " + path + ": " + std::strerror(errno));
  // mkstemp makes the file 0600: give it the mode a plain create would (0666 less the
  // umask, which can only be read by setting it).
  const mode_t mask = ::umask(0);
  ::umask(mask);
  ::fchmod(fd, 0666 & ~mask);
  std::FILE* out = ::fdopen(fd, "wb");
  if (out == nullptr) {
    ::close(fd);
    ::unlink(temp.c_str());
    return internal_error("cannot open " + path + ": " + std::strerror(errno));
  }
  auto fail = [&](const std::string& what) {
    Status s = internal_error("writing " + path + ": " + what);
    std::fclose(out);
    ::unlink(temp.c_str());
    return s;
  };
  std::vector<ZipMember> members;
  std::uint64_t at = 0;
  std::vector<char> buffer(1 << 20);
  for (NpyColumn* c : columns) {
    auto file = c->finish();
    if (!file.is_ok()) {
      std::fclose(out);
      ::unlink(temp.c_str());
      return file.status();
    }
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> in(file.value(), &std::fclose);
    if (::fseeko(in.get(), 0, SEEK_END) != 0) return fail(std::strerror(errno));
    ZipMember m{c->name(), static_cast<std::uint64_t>(::ftello(in.get())), 0, at};
    std::rewind(in.get());
    // The member's bytes after room for its header, whose CRC is known only after them.
    const std::uint64_t header = zip_local_header_size(m.name, m.size);
    if (::fseeko(out, static_cast<off_t>(at + header), SEEK_SET) != 0) return fail(std::strerror(errno));
    uLong crc = ::crc32(0L, Z_NULL, 0);
    for (std::uint64_t left = m.size; left > 0;) {
      const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(left, buffer.size()));
      if (std::fread(buffer.data(), 1, want, in.get()) != want) return fail("reading a scratch file back");
      crc = ::crc32(crc, reinterpret_cast<const Bytef*>(buffer.data()), static_cast<uInt>(want));
      if (std::fwrite(buffer.data(), 1, want, out) != want) return fail(std::strerror(errno));
      left -= want;
    }
    m.crc = static_cast<std::uint32_t>(crc);
    const std::string local = zip_local_header(m);
    if (::fseeko(out, static_cast<off_t>(at), SEEK_SET) != 0 ||
        std::fwrite(local.data(), 1, local.size(), out) != local.size()) {
      return fail(std::strerror(errno));
    }
    at += header + m.size;
    members.push_back(std::move(m));
  }
  const std::string directory = zip_central_directory(members, at);
  if (::fseeko(out, static_cast<off_t>(at), SEEK_SET) != 0 ||
      std::fwrite(directory.data(), 1, directory.size(), out) != directory.size() || std::fflush(out) != 0) {
    return fail(std::strerror(errno));
  }
  if (std::fclose(out) != 0) {
    ::unlink(temp.c_str());
    return internal_error("writing " + path + ": " + std::strerror(errno));
  }
  if (std::rename(temp.c_str(), path.c_str()) != 0) {
    Status s = internal_error("cannot rename " + temp + " to " + path + ": " + std::strerror(errno));
    ::unlink(temp.c_str());
    return s;
  }
  return Status::ok();
}

}  // namespace spokemesh
