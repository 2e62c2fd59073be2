// The zip container of a .npz written in parallel: the bytes libzip 1.7.3 (Debian
// bookworm) gives the CLI's cell files (core/src/cells/cell_io.cpp), so that
// `spokemesh-mpi cells` writes the same file. Each member is stored (no compression)
// with the time stamp 1980-01-02 00:00 and the external attributes of the CLI's
// scratch files (a regular file, mode 0600); zip64 fields appear exactly where libzip
// puts them: both sizes in the local header and the central entry of a member of 4 GiB
// or more, the offset in the central entry of a member that starts beyond 4 GiB, and
// the zip64 end records when the central directory does. (Checked against libzip with
// a 4.4 GB member; the boundary at exactly 2^32 - 1 bytes is libzip's ">".)
//
// The ranks write the members' data at offsets known from their sizes; the CRC-32 of
// each member is combined from the ranks' parts (zlib's crc32_combine), and rank 0
// writes the local headers and the central directory last.
//
// Thread safety: pure functions.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace spokemesh::mpi {

struct ZipMember {
  std::string name;
  std::uint64_t size = 0;    // bytes of the member (stored: compressed = uncompressed)
  std::uint32_t crc = 0;     // CRC-32 of those bytes
  std::uint64_t offset = 0;  // of its local header from the start of the file
};

// Bytes of the local header that precedes a member of `size` bytes named `name`.
std::uint64_t zip_local_header_size(const std::string& name, std::uint64_t size);
std::string zip_local_header(const ZipMember& member);
// The central directory and end records for members in order, starting at `at`.
std::string zip_central_directory(const std::vector<ZipMember>& members, std::uint64_t at);

}  // namespace spokemesh::mpi
