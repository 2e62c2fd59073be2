#include "auth.hpp"

#include <openssl/crypto.h>

#include <fstream>
#include <mutex>
#include <sstream>

namespace spokemesh::service {

Result<std::shared_ptr<Authenticator>> Authenticator::create(std::string keys_file, std::string token) {
  auto auth = std::shared_ptr<Authenticator>(new Authenticator(std::move(keys_file), std::move(token)));
  auto keys = auth->read_keys();
  if (!keys.is_ok()) return keys.status();
  auth->keys_ = std::move(keys).value();
  return auth;
}

Result<std::vector<Authenticator::Key>> Authenticator::read_keys() const {
  std::vector<Key> keys;
  if (!token_.empty()) keys.push_back({token_, {"admin", true}});
  if (keys_file_.empty()) return keys;
  std::ifstream in(keys_file_);
  if (!in) return invalid_argument("--keys: cannot read " + keys_file_);
  std::string line;
  for (int number = 1; std::getline(in, line); ++number) {
    if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
    std::istringstream words(line);
    std::string key, tenant, role, extra;
    if (!(words >> key)) continue;  // blank or comment
    const std::string where = "--keys: " + keys_file_ + " line " + std::to_string(number);
    if (!(words >> tenant)) return invalid_argument(where + ": expected `key tenant [admin]`");
    const bool admin = static_cast<bool>(words >> role);
    if (admin && role != "admin")
      return invalid_argument(where + ": the third word must be `admin`, not \"" + role + "\"");
    if (words >> extra) return invalid_argument(where + ": more than `key tenant [admin]`");
    if (key.size() < 16) return invalid_argument(where + ": keys must be at least 16 characters");
    for (const Key& k : keys) {
      if (k.key == key) return invalid_argument(where + ": a key given twice");
    }
    keys.push_back({key, {tenant, admin}});
  }
  if (keys.empty()) return invalid_argument("--keys: " + keys_file_ + " holds no keys");
  return keys;
}

bool Authenticator::enabled() const {
  std::shared_lock lock(mutex_);
  return !keys_.empty();
}

std::size_t Authenticator::key_count() const {
  std::shared_lock lock(mutex_);
  return keys_.size();
}

Status Authenticator::reload() {
  auto keys = read_keys();
  if (!keys.is_ok()) return keys.status();
  std::unique_lock lock(mutex_);
  keys_ = std::move(keys).value();
  return Status::ok();
}

Result<Principal> Authenticator::authenticate(std::string_view authorization, const char* where) const {
  std::shared_lock lock(mutex_);
  if (keys_.empty()) return Principal{"", true};  // open mode
  constexpr std::string_view kBearer = "Bearer ";
  if (authorization.substr(0, kBearer.size()) == kBearer) {
    const std::string_view presented = authorization.substr(kBearer.size());
    // Every key is compared, each in constant time, so timing does not tell which
    // key (or how much of one) matched.
    const Key* found = nullptr;
    for (const Key& k : keys_) {
      if (k.key.size() == presented.size() && CRYPTO_memcmp(k.key.data(), presented.data(), presented.size()) == 0) {
        found = &k;
      }
    }
    if (found != nullptr) return found->principal;
  }
  return Status{Code::kUnauthenticated, std::string("missing or unknown API key (bearer token) in the ") + where +
                                            " (expected `Bearer <key>`)"};
}

}  // namespace spokemesh::service
