// libFuzzer target: the REST upload's JSON body (service/upload_json.cpp), with small
// limits so that the point and budget paths are reached too. Any body must give a
// header and coordinates that agree, or one error naming what and where.
#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

#include "upload_json.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace spokemesh::service;
  Limits limits;
  limits.max_points = 1000;
  limits.max_dimension = 16;
  MemoryBudget budget(64 << 10);
  MemoryBudget::Charge charge = budget.empty_charge();
  UploadHeader header;
  std::vector<double> coords, weights;
  const std::string_view body(reinterpret_cast<const char*>(data), size);
  const spokemesh::Status s = read_upload_json(body, limits, header, coords, weights, &charge, &budget);
  if (s.is_ok()) {
    if (static_cast<std::size_t>(header.dimension) * static_cast<std::size_t>(header.count) != coords.size()) {
      __builtin_trap();  // the header must describe the coordinates read
    }
  } else if (s.message().empty()) {
    __builtin_trap();
  }
  if (charge.bytes() != budget.used()) __builtin_trap();  // every byte held is charged
  return 0;
}
