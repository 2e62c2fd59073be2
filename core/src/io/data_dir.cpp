#include "spokemesh/data_dir.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <random>

namespace spokemesh::data_dir {
namespace {

std::string parent_of(const std::string& path) {
  const std::size_t slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  return slash == 0 ? "/" : path.substr(0, slash);
}

}  // namespace

bool is_set_id(std::string_view id) {
  if (id.size() != 64) return false;
  for (const char c : id) {
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  }
  return true;
}

std::string set_file_name(const std::string& id) { return id + ".points"; }
std::string set_file(const std::string& dir, const std::string& id) { return dir + "/" + set_file_name(id); }

std::string set_id_of_file_name(std::string_view name) {
  constexpr std::string_view kSuffix = ".points";
  if (name.size() != 64 + kSuffix.size() || name.substr(64) != kSuffix || !is_set_id(name.substr(0, 64))) return "";
  return std::string(name.substr(0, 64));
}

std::string name_file(const std::string& dir, const std::string& id) { return dir + "/" + id + ".name"; }

std::string owner_file(const std::string& dir, const std::string& id, std::string_view tenant) {
  // The tenant in hex: any name is a safe file name.
  static constexpr char kHex[] = "0123456789abcdef";
  std::string path = dir + "/" + id + ".owner-";
  for (const unsigned char ch : tenant) {
    path += kHex[ch >> 4];
    path += kHex[ch & 15];
  }
  return path;
}

std::string pieces_dir(const std::string& dir, const std::string& id) { return dir + "/pieces/" + id; }
std::string manifest_file(const std::string& layout_dir) { return layout_dir + "/manifest"; }
std::string owners_file(const std::string& layout_dir) { return layout_dir + "/owners"; }
std::string piece_file(const std::string& layout_dir, std::uint32_t piece) {
  return layout_dir + "/" + std::to_string(piece) + ".piece";
}

std::string temp_name(const std::string& dir, std::string_view tag) {
  static std::atomic<std::uint64_t> counter{0};
  thread_local std::mt19937_64 rng{std::random_device{}()};
  char buf[96];
  std::snprintf(buf, sizeof buf, "/.tmp-%.*s-%d-%llu-%016llx", static_cast<int>(std::min<std::size_t>(tag.size(), 16)),
                tag.data(), static_cast<int>(::getpid()), static_cast<unsigned long long>(counter.fetch_add(1)),
                static_cast<unsigned long long>(rng()));
  return dir + buf;
}

void remove_stale_temporaries(const std::string& dir, long seconds) {
  namespace fs = std::filesystem;
  const auto now = fs::file_time_type::clock::now();
  for (const std::string& where : {dir, dir + "/pieces"}) {
    std::error_code ec;
    for (fs::directory_iterator it(where, ec), end; !ec && it != end; it.increment(ec)) {
      if (it->path().filename().string().rfind(".tmp-", 0) != 0) continue;
      std::error_code ignored;
      const auto modified = fs::last_write_time(it->path(), ignored);
      if (!ignored && now - modified > std::chrono::seconds(seconds)) fs::remove_all(it->path(), ignored);
    }
  }
}

int sync(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return errno;
  const int error = ::fsync(fd) == 0 ? 0 : errno;
  ::close(fd);
  return error;
}

int write_all(int fd, const char* bytes, std::size_t size) {
  while (size > 0) {
    const ssize_t w = ::write(fd, bytes, size);
    if (w < 0) {
      if (errno == EINTR) continue;
      return errno;
    }
    bytes += w;
    size -= static_cast<std::size_t>(w);
  }
  return 0;
}

int commit_file(const std::string& temp, const std::string& final_path, Move move) {
  int error = 0;
  if (move == Move::kExclusive) {
    // link() fails on an existing name, atomically, where rename() would replace it.
    if (::link(temp.c_str(), final_path.c_str()) != 0) error = errno;
    ::unlink(temp.c_str());
  } else if (::rename(temp.c_str(), final_path.c_str()) != 0) {
    error = errno;
    ::unlink(temp.c_str());
  }
  if (error != 0) return error;
  return sync(parent_of(final_path));
}

int commit_directory(const std::string& temp_dir, const std::string& final_dir) {
  if (const int error = sync(temp_dir); error != 0) return error;
  if (::rename(temp_dir.c_str(), final_dir.c_str()) != 0) return errno == ENOTEMPTY ? EEXIST : errno;
  return sync(parent_of(final_dir));
}

int write_file(const std::string& path, std::string_view bytes, Move move) {
  const std::string temp = temp_name(parent_of(path));
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) return errno;
  int error = write_all(fd, bytes.data(), bytes.size());
  if (error == 0 && ::fsync(fd) != 0) error = errno;
  if (::close(fd) != 0 && error == 0) error = errno;
  if (error != 0) {
    ::unlink(temp.c_str());
    return error;
  }
  return commit_file(temp, path, move);
}

}  // namespace spokemesh::data_dir
