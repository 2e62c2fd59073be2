// spokemesh-mpi's input: each rank's slice of the point file (MPI-IO for .npy; rank 0
// reads text with the CLI's reader and scatters), and the checks one process makes of
// a whole set, made on the slices (docs/distributed.md, "Reading").
//
// Thread safety: collective (main thread).
#pragma once

#include <cstdint>
#include <string>

#include "comm.hpp"
#include "split.hpp"
#include "spokemesh/status.hpp"

namespace spokemesh::mpi {

// This rank's rows of IN: [first, first + count) of n, d coordinates each.
struct Slice {
  std::uint64_t n = 0, first = 0;
  Points points;
};

// This rank's slice of IN (.npy by MPI-IO, anything else as text through rank 0), with
// the CLI's errors, alike on every rank. Collective.
Result<Slice> read_slice(Comm& comm, const std::string& path);

// What PointSet::validate checks of a whole set, on slices: the dimension (2 or 3
// here), the count and the affine span. Duplicates are found by the split. Collective.
Status check_set(Comm& comm, const Slice& slice, const std::string& path);

}  // namespace spokemesh::mpi
