// libFuzzer: domain files of any shape as a hostile client sends them (REST's POST
// body, gRPC's Domain.shape): the first byte picks the format, the rest is the file.
// Whatever the bytes, parsing either refuses with a message or gives a domain whose
// points can be located; it never crashes and never runs unbounded.
#include <cstddef>
#include <cstdint>
#include <string>

#include "geojson_domain.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  static const char* const kNames[] = {"f.off", "f.obj", "f.stl", "f.rings", "f.geojson"};
  const std::string name = kNames[data[0] % 5];
  const std::string bytes(reinterpret_cast<const char*>(data + 1), size - 1);
  auto shape = spokemesh::parse_domain_bytes(bytes, name);
  if (!shape.is_ok()) return shape.status().message().empty() ? __builtin_trap(), 0 : 0;
  const int d = shape->dimension();
  const double probes[3][3] = {{0, 0, 0}, {0.5, 0.25, 0.125}, {1e3, -1e3, 7}};
  for (const auto& x : probes) (void)shape->locate(x);
  (void)d;
  return 0;
}
