// The zip container of a .npz, laid out here byte for byte (no zip library): members
// stored (no compression) with the time stamp 1980-01-02 00:00 and the external
// attributes of a regular file of mode 0600, so that the same arrays make the same
// bytes. Zip64 fields appear only where they are needed: both sizes in the local
// header and the central entry of a member over 4 GiB - 1, the offset in the central
// entry of a member that starts beyond it, and the zip64 end records when the central
// directory does. (This is the layout libzip 1.7.3 gave these files before this writer
// replaced it, so files written by either compare equal.)
//
// One writer, two programs: the core's write_npz (io/npz.cpp) writes member after
// member; spokemesh-mpi's ranks write the members' data at offsets known from their
// sizes, combine each member's CRC-32 from their parts (zlib's crc32_combine), and
// rank 0 writes the local headers and the central directory last.
//
// Thread safety: pure functions.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace spokemesh {

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

}  // namespace spokemesh
