// Authentication, written once for both transports: API keys with tenants.
//
// Keys come from a file (--keys FILE), one per line: `key tenant [admin]` ('#' starts a
// comment), re-read on SIGHUP (a file that fails to parse keeps the old keys and logs
// why). The single --auth-token-file token is one more key, of tenant "admin" with
// admin rights. With neither, the server is open: every caller is an admin of tenant ""
// (development and trusted networks only).
//
// A request carries its key as `authorization: Bearer <key>` (gRPC metadata or HTTP
// header). A point set belongs to the tenants that uploaded it (PointSetStore keeps
// one marker per tenant; the set itself is stored once); a tenant sees, queries and
// deletes only its own sets, an admin all of them. Health and readiness need no key.
//
// Thread safety: authenticate() and reload() may run concurrently (a reader-writer
// lock over the key table).
#pragma once

#include <memory>
#include <shared_mutex>
#include <string>
#include <string_view>
#include <vector>

#include "spokemesh/status.hpp"

namespace spokemesh::service {

// Who is calling.
struct Principal {
  std::string tenant;  // "" only in open mode
  bool admin = false;
};

class Authenticator {
 public:
  // keys_file: "" for none; token: "" for none.
  static Result<std::shared_ptr<Authenticator>> create(std::string keys_file, std::string token);

  // Whether requests need a key.
  bool enabled() const;
  // Re-reads the keys file (SIGHUP). On an error the old keys stay; the status says why.
  Status reload();
  // The principal of an `authorization` value ("Bearer <key>"); UNAUTHENTICATED when
  // keys are required and it is missing or unknown. `where` names the header or
  // metadata in the message.
  Result<Principal> authenticate(std::string_view authorization, const char* where) const;
  std::size_t key_count() const;

 private:
  struct Key {
    std::string key;
    Principal principal;
  };
  Authenticator(std::string keys_file, std::string token)
      : keys_file_(std::move(keys_file)), token_(std::move(token)) {}
  Result<std::vector<Key>> read_keys() const;

  const std::string keys_file_;
  const std::string token_;
  mutable std::shared_mutex mutex_;
  std::vector<Key> keys_;
};

}  // namespace spokemesh::service
