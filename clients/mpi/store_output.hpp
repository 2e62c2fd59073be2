// What `spokemesh-mpi store` writes besides the pieces (pieces.hpp): the set's file as
// spokemesh-server stores an upload (<id>.points, named by the SHA-256 of its bytes,
// so the servers find it and its id is the one an upload of the same points gets), and
// the owner map, each in bounded memory per rank.
//
// Thread safety: collective; main thread only.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "comm.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::mpi {

// Rank 0 writes the set's bytes (dimension u32, count u64, then every rank's slice of
// the coordinates, received in rank order) to a temporary file in `dir`, hashing them
// as they pass; every rank gets the id (64 hex digits) and the temporary file's path,
// which the caller renames to <dir>/<id>.points once the pieces are in place.
Result<std::pair<std::string, std::string>> write_set_file(Comm& comm, const std::string& dir, int d, std::uint64_t n,
                                                           std::span<const double> slice_coords);

// Writes the owner map `path` (n uint32 LE): every rank sends each (point, piece) it
// owns to the rank whose slice holds the point, which writes its slice in one piece.
Status write_owner_map(Comm& comm, const std::string& path, std::uint64_t n,
                       const std::vector<std::pair<std::uint64_t, std::uint32_t>>& mine);

}  // namespace spokemesh::mpi
