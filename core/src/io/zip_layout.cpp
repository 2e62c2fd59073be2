#include "spokemesh/zip_layout.hpp"

namespace spokemesh {

namespace {

constexpr std::uint64_t k32 = 0xFFFFFFFFull;
constexpr std::uint16_t kDosDate = 0x0022;  // 1980-01-02 (time 00:00 is 0)
constexpr std::uint16_t kMadeBy = 0x033F;   // made by Unix, zip 6.3
constexpr std::uint32_t kExternal = 0100600u << 16;

void put16(std::string& s, std::uint16_t v) {
  s += static_cast<char>(v & 0xFF);
  s += static_cast<char>(v >> 8);
}
void put32(std::string& s, std::uint32_t v) {
  for (int b = 0; b < 4; ++b) s += static_cast<char>((v >> (8 * b)) & 0xFF);
}
void put64(std::string& s, std::uint64_t v) {
  for (int b = 0; b < 8; ++b) s += static_cast<char>((v >> (8 * b)) & 0xFF);
}
std::uint32_t low32(std::uint64_t v, bool saturate) {
  return saturate ? static_cast<std::uint32_t>(k32) : static_cast<std::uint32_t>(v);
}

// The fields a local header and a central entry share, from "version needed" to the
// uncompressed size: no flags, stored, the fixed time stamp, the CRC and the sizes.
void put_entry(std::string& s, std::uint16_t needed, const ZipMember& m, bool big) {
  put16(s, needed);
  put16(s, 0);  // flags
  put16(s, 0);  // stored
  put16(s, 0);  // time 00:00
  put16(s, kDosDate);
  put32(s, m.crc);
  put32(s, low32(m.size, big));
  put32(s, low32(m.size, big));
}

}  // namespace

std::uint64_t zip_local_header_size(const std::string& name, std::uint64_t size) {
  return 30 + name.size() + (size > k32 ? 20 : 0);
}

std::string zip_local_header(const ZipMember& m) {
  const bool big = m.size > k32;
  std::string s;
  put32(s, 0x04034B50);
  put_entry(s, big ? 45 : 10, m, big);
  put16(s, static_cast<std::uint16_t>(m.name.size()));
  put16(s, big ? 20 : 0);
  s += m.name;
  if (big) {
    put16(s, 0x0001);
    put16(s, 16);
    put64(s, m.size);
    put64(s, m.size);
  }
  return s;
}

std::string zip_central_directory(const std::vector<ZipMember>& members, std::uint64_t at) {
  std::string s;
  for (const ZipMember& m : members) {
    const bool big = m.size > k32, far = m.offset > k32;
    const std::uint16_t extra = static_cast<std::uint16_t>((big || far ? 4 : 0) + (big ? 16 : 0) + (far ? 8 : 0));
    put32(s, 0x02014B50);
    put16(s, kMadeBy);
    put_entry(s, big || far ? 45 : 10, m, big);
    put16(s, static_cast<std::uint16_t>(m.name.size()));
    put16(s, extra);
    put16(s, 0);  // comment
    put16(s, 0);  // disk
    put16(s, 0);  // internal attributes
    put32(s, kExternal);
    put32(s, low32(m.offset, far));
    s += m.name;
    if (extra != 0) {
      put16(s, 0x0001);
      put16(s, static_cast<std::uint16_t>(extra - 4));
      if (big) {
        put64(s, m.size);
        put64(s, m.size);
      }
      if (far) put64(s, m.offset);
    }
  }
  const std::uint64_t size = s.size(), entries = members.size();
  const bool zip64 = at > k32;
  if (zip64) {
    const std::uint64_t record = at + size;
    put32(s, 0x06064B50);
    put64(s, 44);
    put16(s, 45);
    put16(s, 45);
    put32(s, 0);
    put32(s, 0);
    put64(s, entries);
    put64(s, entries);
    put64(s, size);
    put64(s, at);
    put32(s, 0x07064B50);
    put32(s, 0);
    put64(s, record);
    put32(s, 1);
  }
  put32(s, 0x06054B50);
  put16(s, 0);
  put16(s, 0);
  put16(s, static_cast<std::uint16_t>(entries));
  put16(s, static_cast<std::uint16_t>(entries));
  put32(s, low32(size, size > k32));
  put32(s, low32(at, zip64));
  put16(s, 0);
  return s;
}

}  // namespace spokemesh
