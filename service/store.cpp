#include "store.hpp"

#include "limits.hpp"

#include "spokemesh/approx.hpp"
#include "spokemesh/data_dir.hpp"
#include "spokemesh/io.hpp"

#include <dirent.h>
#include <fcntl.h>
#include <openssl/evp.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cerrno>
#include <cstring>
#include <ctime>
#include <filesystem>

namespace spokemesh::service {
namespace {

static_assert(std::endian::native == std::endian::little,
              "the stored format and the id hash are little-endian; a big-endian port must byte-swap");

constexpr std::size_t kHeaderBytes = 12;

std::string errno_text() { return std::strerror(errno); }

// Reads exactly `size` bytes (false on error or early end of file).
bool read_all(int fd, char* out, std::size_t size) {
  std::size_t done = 0;
  while (done < size) {
    const ssize_t r = ::read(fd, out + done, size - done);
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) return false;
    done += static_cast<std::size_t>(r);
  }
  return true;
}

bool read_file(const std::string& path, std::string& out) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return false;
  struct stat st {};
  bool ok = ::fstat(fd, &st) == 0;
  if (ok) {
    out.resize(static_cast<std::size_t>(st.st_size));
    ok = read_all(fd, out.data(), out.size());
  }
  ::close(fd);
  return ok;
}

// The data directory's fsync (data_dir.hpp), as a yes or no.
bool fsync_dir(const std::string& dir) { return data_dir::sync(dir) == 0; }

// A failed write as clients see it: the operation and the system's reason, never the
// server's paths; a full volume is RESOURCE_EXHAUSTED with reason STORAGE_FULL.
Status storage_error(const char* what, int error) {
  if (error == ENOSPC || error == EDQUOT) {
    return resource_exhausted(std::string("insufficient storage: the server's data volume is full (") + what + ")")
        .with_reason("STORAGE_FULL");
  }
  return internal_error(std::string("storage error: ") + what + ": " + std::strerror(error));
}

// Writes `parts` to `path` by the data directory's commit rule (data_dir.hpp).
// exclusive: `path` must not exist yet; if it does (a concurrent identical upload, on
// this or another replica, won), nothing is written and the status is ALREADY_EXISTS.
Status write_durably(const std::string& dir, const std::string& path,
                     std::initializer_list<std::pair<const char*, std::size_t>> parts, bool exclusive = false) {
  const std::string temp = data_dir::temp_name(dir);
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) return storage_error("cannot create a file", errno);
  int error = 0;
  for (const auto& [data, size] : parts) {
    if (error == 0) error = data_dir::write_all(fd, data, size);
  }
  if (error == 0 && ::fsync(fd) != 0) error = errno;
  if (::close(fd) != 0 && error == 0) error = errno;
  if (error != 0) {
    ::unlink(temp.c_str());
    return storage_error("cannot store the point set", error);
  }
  error = data_dir::commit_file(temp, path, exclusive ? data_dir::Move::kExclusive : data_dir::Move::kReplace);
  if (error == EEXIST && exclusive) return Status{Code::kAlreadyExists, "exists"};
  if (error != 0) return storage_error("cannot store the point set", error);
  return Status::ok();
}

Status not_an_id(const std::string& id) {
  return invalid_argument("point_set_id: \"" + id.substr(0, 80) + "\" is not a point-set id (64 lowercase hex digits)");
}

bool file_exists(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0;
}

}  // namespace

Sha256::Sha256() : ctx_(EVP_MD_CTX_new()) { EVP_DigestInit_ex(static_cast<EVP_MD_CTX*>(ctx_), EVP_sha256(), nullptr); }
Sha256::~Sha256() { EVP_MD_CTX_free(static_cast<EVP_MD_CTX*>(ctx_)); }
void Sha256::update(const void* data, std::size_t size) {
  EVP_DigestUpdate(static_cast<EVP_MD_CTX*>(ctx_), data, size);
}
std::string Sha256::hex_digest() {
  unsigned char md[EVP_MAX_MD_SIZE];
  unsigned int len = 0;
  EVP_DigestFinal_ex(static_cast<EVP_MD_CTX*>(ctx_), md, &len);
  static const char* hex = "0123456789abcdef";
  std::string out(2 * len, '0');
  for (unsigned i = 0; i < len; ++i) {
    out[2 * i] = hex[md[i] >> 4];
    out[2 * i + 1] = hex[md[i] & 15];
  }
  return out;
}

std::string point_set_header_bytes(std::uint32_t dimension, std::uint64_t count) {
  std::string h(kHeaderBytes, '\0');
  std::memcpy(h.data(), &dimension, 4);
  std::memcpy(h.data() + 4, &count, 8);
  return h;
}

std::string point_set_extra_bytes(std::span<const double> weights, std::span<const double> periodic_box) {
  std::string out;
  if (!weights.empty()) {
    out += 'W';
    out.append(reinterpret_cast<const char*>(weights.data()), weights.size_bytes());
  }
  if (!periodic_box.empty()) {
    out += 'P';
    out.append(reinterpret_cast<const char*>(periodic_box.data()), periodic_box.size_bytes());
  }
  return out;
}

namespace {

// The parts of a set's extra bytes (point_set_extra_bytes), or false when they are not
// of that form for n points in d dimensions.
bool parse_extras(const std::string& bytes, std::uint64_t n, std::uint32_t d, std::vector<double>* weights,
                  std::vector<double>* box) {
  std::size_t at = 0;
  auto take = [&](char tag, std::uint64_t values, std::vector<double>* out) {
    if (at >= bytes.size() || bytes[at] != tag) return true;  // absent
    if (bytes.size() - at - 1 < values * 8) return false;
    if (out != nullptr) {
      out->resize(values);
      std::memcpy(out->data(), bytes.data() + at + 1, values * 8);
    }
    at += 1 + values * 8;
    return true;
  };
  return take('W', n, weights) && take('P', 2ull * d, box) && at == bytes.size();
}

}  // namespace

Status check_extras(const PointSet& points, std::span<const double> weights, std::span<const double> periodic_box,
                    const std::string& what, std::optional<PeriodicBox>* box) {
  const int d = points.dimension();
  if ((!weights.empty() || !periodic_box.empty()) && d > kMaxDimension) {
    return invalid_argument(std::string(weights.empty() ? "periodic_box" : "weights") +
                            ": weighted and periodic sets are exact and limited to d <= " +
                            std::to_string(kMaxDimension) + " (these points are " + std::to_string(d) + "-d)");
  }
  if (!weights.empty()) {
    auto checked = weights_from_values(weights, "weights", points.size(), WeightKind::kPowerWeight);
    if (!checked.is_ok()) return checked.status();
  }
  if (!periodic_box.empty()) {
    if (periodic_box.size() != 2 * static_cast<std::size_t>(d)) {
      return invalid_argument("periodic_box: " + std::to_string(periodic_box.size()) + " values; a box around " +
                              std::to_string(d) + "-d points needs " + std::to_string(2 * d) +
                              " (LO_1..LO_d, HI_1..HI_d)");
    }
    const auto du = static_cast<std::ptrdiff_t>(d);
    auto b = PeriodicBox::of({periodic_box.begin(), periodic_box.begin() + du},
                             {periodic_box.begin() + du, periodic_box.end()}, "periodic_box");
    if (!b.is_ok()) return b.status();
    if (Status s = b.value().check_contains(points, what); !s.is_ok()) return s;
    if (box != nullptr) *box = std::move(b).value();
  }
  return Status::ok();
}

bool is_valid_id(const std::string& id) { return data_dir::is_set_id(id); }

std::uint64_t estimated_memory(std::uint64_t n, int d, bool weighted, bool periodic) {
  const auto dd = static_cast<std::uint64_t>(d);
  const std::uint64_t weights = weighted ? 8 * n : 0;
  // A periodic set keeps its coordinates and its cover (PeriodicStars), no tree or
  // sweep of its own; the cover holds the weights again for its images.
  if (periodic) return n * 8 * dd + 2 * weights + PeriodicStars::estimated_bytes(n, d);
  // Per point: the coordinates (8 d), the tree's leaf-ordered copy (8 d) and its box
  // tree (about 0.36 nodes of 2 d floats and 12 bytes: 3 d + 5), lexicographic ranks
  // and the permutations (4 + 4 + 4 + 4), nanoflann's nodes (about 0.36 of 40 bytes),
  // the sweep's order both ways (4 + 4; its records, 8 d + 8 while it is built, are
  // freed before the tree's build copies the coordinates, so they add no peak).
  return n * (8 * dd + 8 * dd + 3 * dd + 5 + 16 + 15 + 8) + weights;
}

PointSetStore::PointSetStore(std::string dir, std::uint64_t budget, LogFn log)
    : dir_(std::move(dir)), budget_(budget), log_(std::move(log)) {
  budget_.set_reclaimer([this](std::uint64_t bytes) { reclaim(bytes); });
  dir_fd_ = ::open(dir_.c_str(), O_PATH | O_DIRECTORY | O_CLOEXEC);  // -1: paths are used instead
}

void PointSetStore::reclaim(std::uint64_t bytes) {
  // Sets are destroyed outside the lock (a large set's memory takes a while to free).
  std::vector<std::shared_ptr<const StoredSet>> dropped;
  {
    std::lock_guard lock(mutex_);
    std::uint64_t freed = 0;
    for (auto it = lru_.end(); it != lru_.begin() && freed < bytes;) {
      --it;
      if (it->use_count() != 1) continue;  // a request is using it: dropping frees nothing now
      freed += (*it)->memory_bytes;
      in_use_ -= (*it)->memory_bytes;
      index_.erase((*it)->cache_key());
      dropped.push_back(std::move(*it));
      it = lru_.erase(it);
    }
  }
}

Result<std::unique_ptr<PointSetStore>> PointSetStore::open(const std::string& data_dir, std::uint64_t memory_budget,
                                                           LogFn log) {
  for (const std::string& d : {data_dir, data_dir + "/quarantine"}) {
    if (::mkdir(d.c_str(), 0755) != 0 && errno != EEXIST) {
      return Status{Code::kFailedPrecondition, "--data-dir: cannot create " + d + ": " + errno_text()};
    }
  }
  if (::access(data_dir.c_str(), W_OK) != 0) {
    return Status{Code::kFailedPrecondition, "--data-dir: " + data_dir + " is not writable"};
  }
  auto store = std::unique_ptr<PointSetStore>(new PointSetStore(data_dir, memory_budget, std::move(log)));
  // Temporary files of uploads that never finished (a crash). With a shared data dir
  // another server may be writing one right now, so only old ones are removed.
  spokemesh::data_dir::remove_stale_temporaries(data_dir, 600);
  return store;
}

std::string PointSetStore::data_path(const std::string& id) const { return data_dir::set_file(dir_, id); }
std::string PointSetStore::name_path(const std::string& id) const { return data_dir::name_file(dir_, id); }

std::string PointSetStore::owner_path(const std::string& id, const std::string& tenant) const {
  return data_dir::owner_file(dir_, id, tenant);
}

Status PointSetStore::add_owner(const std::string& id, const std::string& tenant) {
  if (tenant.empty() || file_exists(owner_path(id, tenant))) return Status::ok();
  return write_durably(dir_, owner_path(id, tenant), {});
}

bool PointSetStore::owned_by(const std::string& id, const std::string& tenant) const {
  return !tenant.empty() && file_exists(owner_path(id, tenant));
}

bool PointSetStore::has_owners(const std::string& id) const {
  const std::string prefix = id + ".owner-";
  bool found = false;
  if (DIR* dir = ::opendir(dir_.c_str())) {
    while (const dirent* e = ::readdir(dir)) {
      if (std::strncmp(e->d_name, prefix.c_str(), prefix.size()) == 0) {
        found = true;
        break;
      }
    }
    ::closedir(dir);
  }
  return found;
}

void PointSetStore::remove_owner_markers(const std::string& id) {
  const std::string prefix = id + ".owner-";
  std::vector<std::string> markers;
  if (DIR* dir = ::opendir(dir_.c_str())) {
    while (const dirent* e = ::readdir(dir)) {
      if (std::strncmp(e->d_name, prefix.c_str(), prefix.size()) == 0) markers.push_back(dir_ + "/" + e->d_name);
    }
    ::closedir(dir);
  }
  for (const std::string& m : markers) ::unlink(m.c_str());
}

Status PointSetStore::release(const std::string& id, const std::string& tenant) {
  if (!is_valid_id(id)) return not_an_id(id);
  if (::unlink(owner_path(id, tenant).c_str()) != 0) {
    return {Code::kNotFound, "point set " + id + " not found"};
  }
  fsync_dir(dir_);
  if (has_owners(id)) return Status::ok();  // still another tenant's
  Status s = remove(id);
  return s.code() == Code::kNotFound ? Status::ok() : s;  // another replica removed it first
}

Result<PointSetInfo> PointSetStore::put(PointSetInfo info, const PointSet& points, std::span<const double> weights) {
  const std::string path = data_path(info.id);
  if (file_exists(path)) {
    auto existing = this->info(info.id);
    if (existing.is_ok()) {
      existing->already_existed = true;
      return existing;
    }
  }
  const std::string header = point_set_header_bytes(static_cast<std::uint32_t>(info.dimension), info.count);
  const auto coords = points.coordinates();
  const std::string extras = point_set_extra_bytes(weights, info.periodic_box);
  // Of concurrent identical uploads (any replica), exactly one creates the set: the
  // others find it existing, and its name is the creator's.
  Status s = write_durably(dir_, path,
                           {{header.data(), header.size()},
                            {reinterpret_cast<const char*>(coords.data()), coords.size_bytes()},
                            {extras.data(), extras.size()}},
                           /*exclusive=*/true);
  if (s.code() == Code::kAlreadyExists) {
    auto existing = this->info(info.id);
    if (existing.is_ok()) existing->already_existed = true;
    return existing;
  }
  if (!s.is_ok()) return s;
  if (!info.display_name.empty()) {
    // After the data: only the creator names the set. (A crash in between leaves the
    // set whole, without its name.)
    if (Status n = write_durably(dir_, name_path(info.id), {{info.display_name.data(), info.display_name.size()}});
        !n.is_ok()) {
      if (log_) log_("error", "point set " + info.id + " stored without its display name: " + n.message());
      info.display_name.clear();
    }
  }
  // Not kept in memory: the first query loads the set and builds its tree (get), so an
  // upload holds no more than its own bytes and a set nobody queries costs no memory.
  return info;
}

Result<PointSetInfo> PointSetStore::info(const std::string& id) {
  if (!is_valid_id(id)) {
    return not_an_id(id);
  }
  {
    std::lock_guard lock(mutex_);
    if (auto it = index_.find(id); it != index_.end() && set_file_present(id)) return (*it->second)->info;
  }
  const int fd = ::open(data_path(id).c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return Status{Code::kNotFound, "point set " + id + " not found"};
  char header[kHeaderBytes];
  const bool ok = ::read(fd, header, kHeaderBytes) == static_cast<ssize_t>(kHeaderBytes);
  PointSetInfo info;
  info.id = id;
  std::uint32_t d = 0;
  if (ok) {
    std::memcpy(&d, header, 4);
    std::memcpy(&info.count, header + 4, 8);
    info.dimension = static_cast<int>(d);
    // The extras' tags and the box (the weights are not read): a weighted set's 'W'
    // follows the coordinates, a periodic set's 'P' follows that.
    const std::uint64_t coords_end = kHeaderBytes + info.count * d * 8;
    char tag = 0;
    std::uint64_t at = coords_end;
    if (d != 0 && info.count < (std::uint64_t{1} << 40) && ::pread(fd, &tag, 1, static_cast<off_t>(at)) == 1) {
      if (tag == 'W') {
        info.weighted = true;
        at += 1 + 8 * info.count;
        if (::pread(fd, &tag, 1, static_cast<off_t>(at)) != 1) tag = 0;
      }
      if (tag == 'P') {
        info.periodic_box.resize(2ull * d);
        const auto bytes = static_cast<ssize_t>(16ull * d);
        if (::pread(fd, info.periodic_box.data(), static_cast<std::size_t>(bytes), static_cast<off_t>(at + 1)) !=
            bytes) {
          info.periodic_box.clear();
        }
      }
    }
  }
  ::close(fd);
  if (!ok) return Status{Code::kNotFound, "point set " + id + " not found (its file is truncated)"};
  std::string name;
  if (read_file(name_path(id), name)) info.display_name = name;
  return info;
}

Status PointSetStore::read_coordinates(const std::string& id, const CoordinateSink& sink) {
  if (!is_valid_id(id)) return not_an_id(id);
  std::shared_ptr<const StoredSet> loaded;
  {
    std::lock_guard lock(mutex_);
    if (auto it = index_.find(id); it != index_.end()) loaded = *it->second;
  }
  if (loaded != nullptr && set_file_present(id)) {
    const std::span<const double> coords = loaded->points.coordinates();
    const auto* bytes = reinterpret_cast<const char*>(coords.data());
    for (std::size_t at = 0; at < coords.size_bytes(); at += defaults::kDownloadChunkBytes) {
      if (Status s = sink(bytes + at, std::min(defaults::kDownloadChunkBytes, coords.size_bytes() - at)); !s.is_ok())
        return s;
    }
    return Status::ok();
  }
  return read_verified(id, nullptr, sink);
}

Status PointSetStore::read_verified(const std::string& id, const Destination& destination, const CoordinateSink& sink,
                                    std::string* extras) {
  const int fd = ::open(data_path(id).c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return Status{Code::kNotFound, "point set " + id + " not found"};
  struct stat st {};
  char header[kHeaderBytes];
  bool ok = ::fstat(fd, &st) == 0 && read_all(fd, header, kHeaderBytes);
  const auto size = static_cast<std::uint64_t>(st.st_size);
  std::uint32_t d = 0;
  std::uint64_t n = 0;
  if (ok) {
    std::memcpy(&d, header, 4);
    std::memcpy(&n, header + 4, 8);
  }
  // The extras (weights, box) are at most 1 + 8 n + 1 + 16 d bytes after the coordinates.
  const bool shaped = ok && d >= 2 && d <= kMaxApproxDimension && n <= (size - kHeaderBytes) / 8 / d &&
                      size >= kHeaderBytes + n * d * 8 && size - kHeaderBytes - n * d * 8 <= 2 + 8 * n + 16 * d;
  if (ok && !shaped) {
    ::close(fd);
    quarantine(id, "its header does not match its size");
    return Status{Code::kNotFound, "point set " + id + " was malformed on disk and has been quarantined"};
  }
  Sha256 sha;
  sha.update(header, kHeaderBytes);
  Status stopped;
  if (double* all = ok && destination ? destination(d, n) : nullptr; all != nullptr) {
    // Straight into the caller's buffer: no second copy of the file in memory.
    ok = read_all(fd, reinterpret_cast<char*>(all), n * d * 8);
    if (ok) sha.update(all, n * d * 8);
  } else {
    std::vector<char> piece(defaults::kDownloadChunkBytes);
    for (std::uint64_t left = ok ? n * d * 8 : 0; left > 0 && ok && stopped.is_ok();) {
      const std::size_t take = static_cast<std::size_t>(std::min<std::uint64_t>(left, piece.size()));
      ok = read_all(fd, piece.data(), take);
      if (!ok) break;
      sha.update(piece.data(), take);
      stopped = sink(piece.data(), take);
      left -= take;
    }
  }
  std::string tail;
  if (ok && stopped.is_ok()) {
    tail.resize(static_cast<std::size_t>(size - kHeaderBytes - n * d * 8));
    ok = read_all(fd, tail.data(), tail.size()) && parse_extras(tail, n, d, nullptr, nullptr);
    if (ok) sha.update(tail.data(), tail.size());
  }
  ::close(fd);
  if (!stopped.is_ok()) return stopped;
  if (extras != nullptr) *extras = std::move(tail);
  if (!ok || sha.hex_digest() != id) {
    quarantine(id, "its SHA-256 does not match its id (corrupt or truncated, " + std::to_string(size) + " bytes)");
    return Status{Code::kNotFound,
                  "point set " + id + " was corrupt on disk and has been quarantined; upload it again"};
  }
  return Status::ok();
}

Result<std::shared_ptr<const StoredSet>> PointSetStore::get(const std::string& id) {
  if (!is_valid_id(id)) {
    return not_an_id(id);
  }
  const bool on_disk = set_file_present(id);
  {
    std::lock_guard lock(mutex_);
    if (auto it = index_.find(id); it != index_.end()) {
      if (on_disk) {
        lru_.splice(lru_.begin(), lru_, it->second);
        return *it->second;
      }
    }
  }
  if (!on_disk) {
    forget(id);  // deleted, possibly through another server sharing the data dir
    return Status{Code::kNotFound, "point set " + id + " not found"};
  }
  // Charged before it is read: the set and its tree must fit the budget.
  auto header = info(id);
  if (!header.is_ok()) return header.status();
  const std::uint64_t bytes =
      estimated_memory(header->count, header->dimension, header->weighted, !header->periodic_box.empty());
  auto charge = budget_.try_charge(bytes);
  if (!charge) return budget_.over_budget("loading point set " + id, bytes);
  auto loaded = load_from_disk(id, std::move(*charge));
  if (!loaded.is_ok()) return loaded.status();
  return remember(std::move(loaded).value());
}

Result<std::shared_ptr<const StoredSet>> PointSetStore::load_from_disk(const std::string& id,
                                                                       MemoryBudget::Charge charge) {
  std::vector<double> coords;
  std::uint32_t d = 0;
  std::uint64_t n = 0;
  std::string extras;
  const Status read = read_verified(
      id,
      [&](std::uint32_t dim, std::uint64_t count) {
        d = dim;
        n = count;
        coords.resize(count * dim);
        return coords.data();
      },
      nullptr, &extras);
  if (!read.is_ok()) return read;
  auto set = std::make_shared<StoredSet>();
  set->points = PointSet(static_cast<int>(d), std::move(coords));
  const std::string what = "point set " + id;
  std::vector<double> box;
  parse_extras(extras, n, d, &set->weights, &box);  // verified by read_verified
  Status valid = set->points.validate(what, kMaxApproxDimension, static_cast<int>(d) <= kMaxDimension);
  if (valid.is_ok()) valid = check_extras(set->points, set->weights, box, what, &set->box);
  if (valid.is_ok() && set->box) {
    auto stars = PeriodicStars::build(set->points, *set->box, set->weights, what);
    if (stars.is_ok()) set->periodic = std::move(stars).value();
    valid = stars.status();
  }
  if (!valid.is_ok()) {
    quarantine(id, valid.message());
    return Status{Code::kNotFound, "point set " + id + " was invalid on disk and has been quarantined"};
  }
  set->info.id = id;
  set->info.dimension = static_cast<int>(d);
  set->info.count = n;
  set->info.weighted = !set->weights.empty();
  set->info.periodic_box = box;
  std::string name;
  if (read_file(name_path(id), name)) set->info.display_name = name;
  if (set->box) {
    // Nothing else: a periodic set's stars walk its cover's tree.
  } else if (d <= static_cast<std::uint64_t>(kMaxDimension)) {
    set->split = std::make_unique<SpaceSplit>(set->points, SpaceSplit::default_block_points(static_cast<int>(d), n));
    set->tree = std::make_unique<KdTree>(set->points);
  } else {
    set->tree = std::make_unique<KdTree>(set->points);
  }
  // Once, not per request (a clipped cell of a 20M set would scan it: 50 ms).
  if (n > 0) {
    set->bounds.assign(set->points.point(0), set->points.point(0) + d);
    set->bounds.insert(set->bounds.end(), set->points.point(0), set->points.point(0) + d);
    for (std::uint64_t i = 1; i < n; ++i) {
      const double* p = set->points.point(i);
      for (std::uint32_t c = 0; c < d; ++c) {
        set->bounds[c] = std::min(set->bounds[c], p[c]);
        set->bounds[d + c] = std::max(set->bounds[d + c], p[c]);
      }
    }
  }
  set->memory_bytes = estimated_memory(n, static_cast<int>(d), set->info.weighted, set->box.has_value());
  set->charge = std::move(charge);
  return std::shared_ptr<const StoredSet>(std::move(set));
}

void PointSetStore::quarantine(const std::string& id, const std::string& why) {
  const std::string target = dir_ + "/quarantine/" + id + ".points." + std::to_string(std::time(nullptr));
  const bool moved = ::rename(data_path(id).c_str(), target.c_str()) == 0;
  if (moved) fsync_dir(dir_);
  forget(id);
  if (log_) {
    log_("error",
         "point set " + id + " quarantined: " + why + (moved ? " (moved to " + target + ")" : " (move failed)"));
  }
}

std::shared_ptr<const StoredSet> PointSetStore::loaded(const std::string& id) const {
  std::lock_guard lock(mutex_);
  const auto it = index_.find(id);
  return it == index_.end() ? nullptr : *it->second;
}

std::shared_ptr<const StoredSet> PointSetStore::get_in_memory(const std::string& id) {
  if (!is_valid_id(id) || !set_file_present(id)) return nullptr;  // deleted: get() says so
  std::lock_guard lock(mutex_);
  const auto it = index_.find(id);
  if (it == index_.end()) return nullptr;
  lru_.splice(lru_.begin(), lru_, it->second);
  return *it->second;
}

std::shared_ptr<const StoredSet> PointSetStore::get_piece_in_memory(const std::string& id, std::uint32_t piece) {
  if (!is_valid_id(id) || !set_file_present(id)) return nullptr;
  std::lock_guard lock(mutex_);
  const auto it = index_.find(id + "/" + std::to_string(piece));
  if (it == index_.end()) return nullptr;
  lru_.splice(lru_.begin(), lru_, it->second);
  return *it->second;
}

std::shared_ptr<const StoredSet> PointSetStore::remember(std::shared_ptr<const StoredSet> set) {
  std::lock_guard lock(mutex_);
  const std::string key = set->cache_key();
  if (auto it = index_.find(key); it != index_.end()) {
    lru_.splice(lru_.begin(), lru_, it->second);
    return *it->second;  // another request loaded it first
  }
  lru_.push_front(set);
  index_[key] = lru_.begin();
  in_use_ += set->memory_bytes;
  return set;  // the budget, not a count, decides when sets leave memory (reclaim)
}

bool PointSetStore::set_file_present(const std::string& id) {
  const std::string name = data_dir::set_file_name(id);
  struct stat st {};
  if (dir_fd_ >= 0) return ::fstatat(dir_fd_, name.c_str(), &st, 0) == 0;
  return file_exists(data_path(id));
}

PointSetStore::~PointSetStore() {
  if (dir_fd_ >= 0) ::close(dir_fd_);
}

void PointSetStore::forget(const std::string& id) {
  std::vector<std::shared_ptr<const StoredSet>> dropped;  // destroyed outside the lock
  std::lock_guard lock(mutex_);
  if (auto it = index_.find(id); it != index_.end()) {
    in_use_ -= (*it->second)->memory_bytes;
    dropped.push_back(std::move(*it->second));
    lru_.erase(it->second);
    index_.erase(it);
  }
  // Its pieces and layout too (a set deleted, possibly through another server).
  if (layouts_.erase(id) != 0) {
    for (auto it = lru_.begin(); it != lru_.end();) {
      if ((*it)->piece && (*it)->info.id == id) {
        in_use_ -= (*it)->memory_bytes;
        index_.erase((*it)->cache_key());
        dropped.push_back(std::move(*it));
        it = lru_.erase(it);
      } else {
        ++it;
      }
    }
  }
}

PieceLayout::PieceLayout(PieceManifest manifest, int owners_fd)
    : manifest_(std::move(manifest)), owners_fd_(owners_fd) {
  const std::size_t bytes = manifest_.count * 4;
  if (owners_fd_ >= 0 && bytes > 0) {
    void* mapped = ::mmap(nullptr, bytes, PROT_READ, MAP_SHARED, owners_fd_, 0);
    if (mapped != MAP_FAILED) {
      owners_ = static_cast<const std::uint32_t*>(mapped);
      mapped_bytes_ = bytes;
    }
  }
}

PieceLayout::~PieceLayout() {
  if (owners_ != nullptr) ::munmap(const_cast<std::uint32_t*>(owners_), mapped_bytes_);
  if (owners_fd_ >= 0) ::close(owners_fd_);
}

Result<std::uint32_t> PieceLayout::piece_of(std::uint64_t seed) const {
  std::uint32_t piece = 0;
  bool read = false;
  if (owners_ != nullptr) {
    read = seed < manifest_.count;
    if (read) piece = owners_[seed];
  } else {
    read = ::pread(owners_fd_, &piece, 4, static_cast<off_t>(seed * 4)) == 4;
  }
  if (!read || piece >= pieces()) {
    return internal_error("point set " + manifest_.set_id + ": its owner map has no valid entry for point " +
                          std::to_string(seed));
  }
  return piece;
}

Result<std::vector<std::uint32_t>> PieceLayout::owners() const {
  std::vector<std::uint32_t> out(manifest_.count);
  if (owners_ != nullptr) {
    std::copy(owners_, owners_ + out.size(), out.begin());
  } else {
    char* bytes = reinterpret_cast<char*>(out.data());
    for (std::size_t done = 0, size = out.size() * 4; done < size;) {
      const ssize_t r = ::pread(owners_fd_, bytes + done, size - done, static_cast<off_t>(done));
      if (r < 0 && errno == EINTR) continue;
      if (r <= 0) return internal_error("point set " + manifest_.set_id + ": its owner map cannot be read");
      done += static_cast<std::size_t>(r);
    }
  }
  for (std::size_t i = 0; i < out.size(); ++i) {
    if (out[i] >= pieces()) {
      return internal_error("point set " + manifest_.set_id + ": its owner map has no valid entry for point " +
                            std::to_string(i));
    }
  }
  return out;
}

Result<std::shared_ptr<const PieceLayout>> PointSetStore::layout(const std::string& id) {
  if (!is_valid_id(id)) return not_an_id(id);
  {
    std::lock_guard lock(mutex_);
    if (auto it = layouts_.find(id); it != layouts_.end()) return it->second;
  }
  auto manifest = read_manifest(dir_, id);
  if (manifest.status().code() == Code::kNotFound) return std::shared_ptr<const PieceLayout>();
  if (!manifest.is_ok()) return manifest.status();
  const std::string owners = data_dir::owners_file(data_dir::pieces_dir(dir_, id));
  const int fd = ::open(owners.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return internal_error(owners + ": cannot open: " + errno_text());
  struct stat st {};
  if (::fstat(fd, &st) != 0 || static_cast<std::uint64_t>(st.st_size) != manifest->count * 4) {
    ::close(fd);
    return internal_error(owners + ": not one 4-byte entry per point of the manifest");
  }
  auto layout = std::make_shared<const PieceLayout>(std::move(manifest).value(), fd);
  std::lock_guard lock(mutex_);
  return layouts_.emplace(id, std::move(layout)).first->second;
}

Result<std::shared_ptr<const StoredSet>> PointSetStore::get_piece(const std::string& id, std::uint32_t piece) {
  if (!set_file_present(id)) {
    forget(id);  // deleted, possibly through another server sharing the data dir
    return Status{Code::kNotFound, "point set " + id + " not found"};
  }
  const std::string key = id + "/" + std::to_string(piece);
  {
    std::lock_guard lock(mutex_);
    if (auto it = index_.find(key); it != index_.end()) {
      lru_.splice(lru_.begin(), lru_, it->second);
      return *it->second;
    }
  }
  auto layout = this->layout(id);
  if (!layout.is_ok()) return layout.status();
  if (!layout.value() || piece >= layout.value()->pieces()) {
    return internal_error("point set " + id + " has no piece " + std::to_string(piece));
  }
  const PieceManifest& m = layout.value()->manifest();
  const PieceEntry& entry = m.pieces[piece];
  // Charged before it is read: its points, ids and tree.
  const std::uint64_t bytes = estimated_memory(entry.held, m.dimension) + 10 * entry.held;
  auto charge = budget_.try_charge(bytes);
  if (!charge) return budget_.over_budget("loading piece " + std::to_string(piece) + " of point set " + id, bytes);
  auto read = read_piece(data_dir::piece_file(data_dir::pieces_dir(dir_, id), piece), m, piece);
  if (!read.is_ok()) {
    log_("error", read.status().message());
    return Status{Code::kUnavailable, "point set " + id + ": piece " + std::to_string(piece) +
                                          " cannot be read: " + read.status().message()};
  }
  auto points = piece_point_set(read.value());
  if (!points.is_ok()) return points.status();
  auto set = std::make_shared<StoredSet>();
  set->points = std::move(points).value();
  set->info.id = id;
  set->info.dimension = m.dimension;
  set->info.count = entry.held;
  PieceOf of;
  of.index = piece;
  of.ids = std::move(read->ids);
  of.own = std::move(read->own);
  of.start = read->start;
  of.held_box = std::move(read->held_box);
  of.global_box = m.global_box;
  set->piece = std::move(of);
  set->tree = std::make_unique<KdTree>(set->points);
  set->memory_bytes = bytes;
  set->charge = std::move(*charge);
  return remember(std::shared_ptr<const StoredSet>(std::move(set)));
}

Result<PieceManifest> PointSetStore::put_pieces(const std::string& id, const PointSet& points,
                                                const PieceOptions& options) {
  return store_pieces(points, id, dir_, options);
}

std::vector<std::uint32_t> PointSetStore::pieces_held(const std::string& id) const {
  std::lock_guard lock(mutex_);
  std::vector<std::uint32_t> out;
  for (const auto& set : lru_) {
    if (set->piece && set->info.id == id) out.push_back(set->piece->index);
  }
  return out;
}

void PointSetStore::drop_piece(const std::string& id, std::uint32_t piece) {
  std::shared_ptr<const StoredSet> dropped;  // destroyed outside the lock
  std::lock_guard lock(mutex_);
  if (auto it = index_.find(id + "/" + std::to_string(piece)); it != index_.end()) {
    in_use_ -= (*it->second)->memory_bytes;
    dropped = std::move(*it->second);
    lru_.erase(it->second);
    index_.erase(it);
  }
}

std::pair<std::size_t, std::uint64_t> PointSetStore::pieces_in_memory() const {
  std::lock_guard lock(mutex_);
  std::pair<std::size_t, std::uint64_t> out{0, 0};
  for (const auto& set : lru_) {
    if (set->piece) {
      ++out.first;
      out.second += set->memory_bytes;
    }
  }
  return out;
}

std::vector<PointSetInfo> PointSetStore::list(const std::string& after, std::size_t limit, bool* more,
                                              const std::function<bool(const std::string&)>& visible) {
  std::vector<std::string> ids;
  if (DIR* dir = ::opendir(dir_.c_str())) {
    while (const dirent* e = ::readdir(dir)) {
      std::string id = data_dir::set_id_of_file_name(e->d_name);
      if (!id.empty() && id > after && (!visible || visible(id))) ids.push_back(std::move(id));
    }
    ::closedir(dir);
  }
  std::sort(ids.begin(), ids.end());
  std::vector<PointSetInfo> out;
  for (const std::string& id : ids) {
    if (out.size() == limit) break;
    auto i = info(id);
    if (i.is_ok()) out.push_back(std::move(i).value());
  }
  if (more != nullptr) *more = !out.empty() && out.back().id < ids.back();
  return out;
}

Status PointSetStore::remove(const std::string& id) {
  if (!is_valid_id(id)) {
    return not_an_id(id);
  }
  forget(id);
  if (::unlink(data_path(id).c_str()) != 0) {
    if (errno == ENOENT) return {Code::kNotFound, "point set " + id + " not found"};
    return {Code::kInternal, "cannot delete point set " + id + ": " + errno_text()};
  }
  ::unlink(name_path(id).c_str());
  std::error_code ignored;
  std::filesystem::remove_all(data_dir::pieces_dir(dir_, id), ignored);
  remove_owner_markers(id);
  fsync_dir(dir_);
  return Status::ok();
}

std::size_t PointSetStore::load_all(const std::function<bool(const std::string&)>& skip) {
  std::size_t loaded = 0;
  bool more = true;
  std::string after;
  while (more) {
    const auto page = list(after, 1000, &more);
    for (const PointSetInfo& info : page) {
      after = info.id;
      {
        std::lock_guard lock(mutex_);
        if (index_.count(info.id) != 0) continue;
      }
      if (skip && skip(info.id)) continue;
      // Verifies (quarantining what fails); keeps what fits the budget as it is now.
      auto charge = budget_.try_charge(
          estimated_memory(info.count, info.dimension, info.weighted, !info.periodic_box.empty()), /*reclaim=*/false);
      auto set = load_from_disk(info.id, charge ? std::move(*charge) : MemoryBudget::Charge{});
      if (!set.is_ok()) continue;
      ++loaded;
      if (set.value()->charge.bytes() != 0) remember(std::move(set).value());
    }
  }
  return loaded;
}

std::uint64_t PointSetStore::memory_in_use() const {
  std::lock_guard lock(mutex_);
  return in_use_;
}

std::size_t PointSetStore::loaded_count() const {
  std::lock_guard lock(mutex_);
  return static_cast<std::size_t>(std::count_if(lru_.begin(), lru_.end(), [](const auto& set) { return !set->piece; }));
}

}  // namespace spokemesh::service
